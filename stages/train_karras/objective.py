"""The training objective and schedule of Karras et al. 2017 (paper 001 §4.3–§4.5), as pure functions.

Loss (§4.3): a minibatch holds B/2 *temporal pairs* (two adjacent frames), rows 2i and 2i+1.

    P(x)  = mean over output components of (y − ŷ)²                       (Eq. 1, per sample)
    M(x)  = 2 · mean over components of (m[y] − m[ŷ])²,  m = pair difference   (Eq. 2, per pair)
    R'(x) = 2 · mean over E of m[e]²                                     (Eq. 3, per pair)
    R(x)  = R'(x) / mean over batch and E of e²                          (Eq. 4)

Each term is divided by the square root of a bias-corrected moving average (β = 0.99) of its
minibatch second raw moment (Eqs. 5–6, ``TermNormaliser``) and the three are summed — no
hand-set weights.

Schedule (§4.5): Adam; the learning rate rises tenfold geometrically during the first epoch, then
falls as 1/√t, and over the last 30 epochs ramps smoothly to zero while Adam's β1 goes from 0.9 to
0.5 (``schedule``). Time-shift augmentation (§4.4): a uniform shift of up to ±half a 30 fps frame
(16.6 ms) per pair, the same for both frames of a pair (``pair_shifts``).
"""
from __future__ import annotations

import math

import numpy as np
import torch

BETA = 0.99
EPS = 1e-8
MAX_SHIFT_S = 0.5 / 30.0            # ±16.6 ms: half a frame at 30 fps
RAMP_DOWN_EPOCHS = 30


def position_term(y: torch.Tensor, y_hat: torch.Tensor) -> torch.Tensor:
    """Eq. 1 per sample: (B, D) targets and outputs → (B,)."""
    return ((y - y_hat) ** 2).mean(1)


def pair_difference(x: torch.Tensor) -> torch.Tensor:
    """m[·]: the second frame of each temporal pair minus the first; (B, D) → (B/2, D)."""
    return x[1::2] - x[0::2]


def motion_term(y: torch.Tensor, y_hat: torch.Tensor) -> torch.Tensor:
    """Eq. 2 per pair: (B, D) → (B/2,)."""
    return 2.0 * ((pair_difference(y) - pair_difference(y_hat)) ** 2).mean(1)


def emotion_term(e: torch.Tensor) -> torch.Tensor:
    """Eqs. 3–4 per pair: the pair difference of the emotion vectors (B, E), relative to their
    mean square over the batch (so shrinking e cannot make the term vanish) → (B/2,)."""
    return 2.0 * (pair_difference(e) ** 2).mean(1) / (e ** 2).mean().clamp_min(1e-12)


class TermNormaliser:
    """Eqs. 5–6 for one loss term: ℓ = mean(term) / (√v̂ + ε), v the moving average (β) of the
    minibatch mean of term², v̂ = v / (1 − β^t) (startup bias corrected)."""

    def __init__(self, beta: float = BETA):
        self.beta, self.v, self.t = beta, 0.0, 0

    def __call__(self, term: torch.Tensor) -> torch.Tensor:
        self.t += 1
        self.v = self.beta * self.v + (1 - self.beta) * float((term.detach() ** 2).mean())
        v_hat = self.v / (1 - self.beta ** self.t)
        return term.mean() / (math.sqrt(v_hat) + EPS)

    def state(self) -> dict:
        return dict(v=self.v, t=self.t)


class KarrasLoss:
    """ℓ = ℓ^P + ℓ^M + ℓ^R with one normaliser per term; also returns the raw term means."""

    def __init__(self, beta: float = BETA, use_motion: bool = True, use_emotion: bool = True):
        self.norm = {k: TermNormaliser(beta) for k in ("position", "motion", "emotion")}
        self.use_motion, self.use_emotion = use_motion, use_emotion

    def __call__(self, y, y_hat, e) -> tuple[torch.Tensor, dict]:
        terms = {"position": position_term(y, y_hat)}
        if self.use_motion:
            terms["motion"] = motion_term(y, y_hat)
        if self.use_emotion and e is not None:
            terms["emotion"] = emotion_term(e)
        loss = sum(self.norm[k](v) for k, v in terms.items())
        return loss, {k: float(v.detach().mean()) for k, v in terms.items()}


def schedule(epoch: float, epochs: int, base_lr: float, ramp_down: int = RAMP_DOWN_EPOCHS) -> tuple[float, float]:
    """(learning rate, Adam β1) at fractional ``epoch`` ∈ [0, epochs).

    Epoch 0 → 1: geometric ramp from base_lr / 10 to base_lr; then base_lr / √epoch; over the
    last ``ramp_down`` epochs (fewer for short runs: at most a third of them) a smooth
    (half-cosine) ramp of the rate to zero and of β1 from 0.9 to 0.5.
    """
    if epoch < 1.0:
        lr = base_lr * 10.0 ** (epoch - 1.0)
    else:
        lr = base_lr / math.sqrt(epoch)
    down = min(ramp_down, epochs / 3)
    start = epochs - down
    if epoch <= start or down <= 0:
        return lr, 0.9
    f = min((epoch - start) / down, 1.0)
    smooth = 0.5 * (1 + math.cos(math.pi * f))          # 1 → 0
    return lr * smooth, 0.5 + 0.4 * smooth


def pair_shifts(n_pairs: int, rng: np.random.Generator, max_shift_s: float = MAX_SHIFT_S) -> np.ndarray:
    """Time shifts (s) for a minibatch of pairs, repeated for both members: (2·n_pairs,)."""
    return np.repeat(rng.uniform(-max_shift_s, max_shift_s, n_pairs), 2)


def shifted_targets(targets: np.ndarray, frame_time: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Targets (T, D) of one video, linearly interpolated at arbitrary times (s) → (len(times), D)
    (held at the ends), for time-shifted training samples."""
    idx = np.interp(times, frame_time, np.arange(len(frame_time)))
    lo = np.clip(np.floor(idx).astype(int), 0, len(frame_time) - 1)
    hi = np.clip(lo + 1, 0, len(frame_time) - 1)
    w = (idx - lo)[:, None]
    return (1 - w) * targets[lo] + w * targets[hi]
