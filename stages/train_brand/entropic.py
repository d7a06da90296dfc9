"""Entropic estimation of a Gaussian-output HMM (paper 002 §4.2, Eqs. 1–4; Brand 1999 [4, 5]).

MAP re-estimation under the prior P_e(θ) ∝ e^{−H(θ)} (Eq. 2) with the compression entropy of
Eq. 4. The E-step (log-space forward–backward over many sequences) is hmmlearn's; the M-step is
this module's ``PuppetHMM._do_mstep``:

* transition rows — maximise Σ_j ω_j log θ_j + Σ_j θ_j log θ_j (ω: expected transition counts).
  Setting the Lagrangian's gradient to zero gives θ_j = −ω_j / W_{−1}(−ω_j e^{1+λ}) (Lambert W,
  branch −1, ``scipy.special.lambertw``); λ is the root of Σ_j θ_j(λ) = 1 (bisection: the sum
  rises monotonically with λ up to λ_max = −2 − log max ω, where W's argument reaches −1/e);
* trimming — zeroing θ_j gains about −θ_j ∂log P_e/∂θ_j in prior and loses θ_j ∂log f/∂θ_j in
  likelihood, so θ_j is trimmed when θ_j < exp(−g_j) with g_j = ∂log P(X|θ)/∂θ_j = ω_j / θ⁰_j
  (θ⁰: the parameters the E-step ran with). At an ML fixed point g_j equals the row's
  occupancy for every used entry, so the test removes the entries the MAP update is driving to
  extinction (θ_j falling fast from θ⁰_j), not well-supported ones; the row's largest entry is
  never trimmed;
* covariances — the entropy term ½ log((2πe)^d |K_i|) makes the MAP covariance
  Σ_t γ_ti (x_t − μ_i)(x_t − μ_i)ᵀ / (Σ_t γ_ti + 1);
* the prior's weight Z (P_e ∝ e^{−Z·H}; Z = 1 is the paper's) divides the evidence: with tens of
  thousands of frames Z = 1 hardly moves a row that has hundreds of counts;
* states — a state whose occupancy falls below ``min_state_frames`` (no longer used, or used
  too little to support a full covariance) is removed between iterations and logged.

``prior="ml"`` is the conventional maximum-likelihood (Baum–Welch) HMM on the same states and
data: the baseline.
"""
from __future__ import annotations

import logging

import time

import numpy as np
from hmmlearn.hmm import GaussianHMM
from scipy.special import lambertw

from pipeline.errors import LipsynthError
from pipeline.models.training_budget import format_duration

log = logging.getLogger("lipsynth.train_brand")
PRIORS = ("entropic", "ml")


def _theta(omega: np.ndarray, lam: float) -> np.ndarray:
    """θ_j(λ) = ω_j / u_j with u_j = −W_{−1}(−ω_j e^{1+λ}), i.e. the root u ≥ 1 of u − log u = c_j,
    c_j = −(log ω_j + 1 + λ) ≥ 1. Lambert W for moderate c; for c > 600 (arguments below
    double precision, where ``lambertw`` returns NaN) the fixed point u ← c + log u."""
    out = np.zeros_like(omega)
    pos = omega > 0
    c = np.maximum(-(np.log(omega[pos]) + 1.0 + lam), 1.0 + 1e-12)
    u = np.empty_like(c)
    small = c <= 600
    u[small] = -np.real(lambertw(-np.exp(-c[small]), -1))
    big = c[~small]
    v = big + np.log(big)
    for _ in range(6):
        v = big + np.log(v)
    u[~small] = v
    out[pos] = omega[pos] / u
    return out


def entropic_multinomial(omega: np.ndarray, weight: float = 1.0, iterations: int = 80) -> np.ndarray:
    """MAP multinomial θ (sums to 1) for evidence ω ≥ 0 under the entropic prior Π θ_j^(Z θ_j).

    ``weight`` Z = 1 is the paper's prior e^{−H}; Z scales it (the solution is that of ω / Z).
    Returns the maximum-likelihood ω / Σω when the evidence is too weak (Σθ < 1 at λ_max: the
    W_{−1} branch has no solution; happens only for Σω ≲ Z) and zeros for no evidence.
    """
    omega = np.asarray(omega, np.float64) / weight
    total = omega.sum()
    if total <= 0:
        return np.zeros_like(omega)
    hi = -2.0 - np.log(omega.max())
    if _theta(omega, hi).sum() < 1.0:
        return omega / total
    lo, step = hi - 1.0, 1.0
    while _theta(omega, lo).sum() > 1.0:
        step *= 2
        lo = hi - step
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if _theta(omega, mid).sum() < 1.0 else (lo, mid)
    theta = _theta(omega, hi)
    return theta / theta.sum()


def trim(theta: np.ndarray, gradient: np.ndarray, weight: float = 1.0) -> np.ndarray:
    """Zero the entries whose prior gain outweighs their likelihood loss, θ_j < exp(−g_j / Z) with
    g_j = ∂ log P(X|θ) / ∂θ_j (Brand's trimming test), keeping the largest; renormalised. A row
    of zeros stays zeros."""
    out = theta.copy()
    if out.sum() <= 0:
        return out
    kill = (out > 0) & (out < np.exp(-np.minimum(gradient / weight, 700.0)))
    kill[np.argmax(out)] = False
    out[kill] = 0.0
    return out / out.sum()


def entropic_transitions(counts: np.ndarray, previous: np.ndarray, trimming: bool, weight: float = 1.0) -> np.ndarray:
    """Row-wise entropic MAP (and trimming) of (K, K) expected transition counts ω, computed by the
    E-step under the ``previous`` transition matrix θ⁰: the likelihood's gradient is ω / θ⁰."""
    rows = [entropic_multinomial(c, weight) for c in counts]
    if trimming:
        with np.errstate(divide="ignore", invalid="ignore"):
            grad = np.where(previous > 0, counts / np.where(previous > 0, previous, 1.0), 0.0)
        rows = [trim(r, g, weight) for r, g in zip(rows, grad)]
    return np.array(rows)


def model_entropy(model: GaussianHMM) -> float:
    """H_C(θ) of Eq. 4: transition entropies plus the Gaussians' differential entropies (nats)."""
    t = model.transmat_
    with np.errstate(divide="ignore", invalid="ignore"):
        h = -np.nansum(np.where(t > 0, t * np.log(t), 0.0))
    d = model.n_features
    return float(h + sum(0.5 * (d * np.log(2 * np.pi * np.e) + np.linalg.slogdet(c)[1]) for c in model.covars_))


class PuppetHMM(GaussianHMM):
    """hmmlearn's Gaussian HMM (full covariances, log-space E-step) with the entropic or ML M-step."""

    def __init__(self, n_components=26, prior="entropic", trimming=True, reg=1e-3, random_state=0, weight=1.0):
        super().__init__(n_components=n_components, covariance_type="full", min_covar=reg, n_iter=1,
                         tol=0.0, random_state=random_state, params="stmc", init_params="stmc",
                         implementation="log")
        self.prior, self.trimming, self.reg, self.weight = prior, trimming, reg, weight

    def _do_mstep(self, stats):
        post = stats["post"]
        self.last_occupancy_ = post.copy()
        start = stats["start"]
        self.startprob_ = start / start.sum()
        if self.prior == "entropic":
            self.transmat_ = entropic_transitions(stats["trans"], self.transmat_, self.trimming, self.weight)
        else:
            rows = stats["trans"].sum(1, keepdims=True)
            self.transmat_ = np.where(rows > 0, stats["trans"] / np.where(rows > 0, rows, 1), 0.0)
        safe = np.maximum(post, 1e-10)
        self.means_ = stats["obs"] / safe[:, None]
        scatter = stats["obs*obs.T"] - safe[:, None, None] * np.einsum("ki,kj->kij", self.means_, self.means_)
        denom = safe + (self.weight if self.prior == "entropic" else 0.0)
        self._covars_ = scatter / denom[:, None, None] + self.reg * np.eye(self.n_features)[None]


def subset(model: PuppetHMM, keep: np.ndarray) -> PuppetHMM:
    """The model restricted to the states ``keep`` (bool (K,)); rows renormalised."""
    new = PuppetHMM(int(keep.sum()), model.prior, model.trimming, model.reg, model.random_state, model.weight)
    new.init_params = ""
    new.n_features = model.n_features
    start = model.startprob_[keep]
    new.startprob_ = start / start.sum() if start.sum() > 0 else np.full(keep.sum(), 1.0 / keep.sum())
    t = model.transmat_[np.ix_(keep, keep)]
    rows = t.sum(1, keepdims=True)
    dead = rows[:, 0] <= 0
    if dead.any():
        log.warning("%d state(s) lost every transition with the removed states; they restart uniformly", dead.sum())
    new.transmat_ = np.where(dead[:, None], 1.0 / keep.sum(), t / np.where(rows > 0, rows, 1))
    new.means_ = model.means_[keep]
    new.covars_ = model.covars_[keep]
    return new


def fit(X: np.ndarray, lengths: np.ndarray, n_states: int, prior: str, iterations: int, tol: float,
        reg: float, min_state_frames: float, trimming: bool = True, seed: int = 0, weight: float = 1.0,
        desc: str = "hmm"):
    """EM (entropic MAP or ML) on standardised observations X (N, d) split into ``lengths``.

    Returns (model, history): one dict per iteration with log_likelihood and log_posterior per
    frame of the parameters its E-step ran with (EM never lowers the log posterior, except where
    a state was removed or a transition trimmed by the first-order test), and the states and
    transitions before/after the iteration's M-step and removals.
    Stops when the per-frame log posterior improves by less than ``tol``.
    """
    if prior not in PRIORS:
        raise LipsynthError(f"prior {prior!r}: choose one of {', '.join(PRIORS)}")
    from tqdm import tqdm
    model = PuppetHMM(n_states, prior, trimming, reg, seed, weight)
    history, previous, t0 = [], -np.inf, time.perf_counter()
    bar = tqdm(range(iterations), desc=desc, unit="it", leave=False)
    for it in bar:
        if it == 2:                             # the first two iterations measure this machine's speed
            per_it = (time.perf_counter() - t0) / 2
            log.info("plan — %s: at most %d EM iterations over %s frames (stops when the log posterior per frame "
                     "gains < %g) ≈ %s at most on this machine (%.2f s/iteration measured)", desc, iterations,
                     f"{len(X):,}", tol, format_duration(iterations * per_it), per_it)
        # the E-step's likelihood belongs to the parameters it ran with: pair it with their prior
        log_prior = -weight * model_entropy(model) if prior == "entropic" and it > 0 else 0.0
        model.fit(X, lengths)
        model.init_params = ""
        ll = float(model.monitor_.history[-1]) / len(X)
        post = ll + log_prior / len(X)
        history.append(dict(iteration=it + 1, log_likelihood=ll, log_posterior=post, states=model.n_components,
                            transitions=int((model.transmat_ > 0).sum())))
        occupancy = model.last_occupancy_
        dead_rows = ~(model.transmat_.sum(1) > 0)
        keep = (occupancy >= min_state_frames) & ~dead_rows
        if not keep.all():
            for k in np.flatnonzero(~keep):
                log.info("%s: iteration %d removes state %d (occupancy %.1f frames%s)", desc, it + 1, k,
                         occupancy[k], ", no transitions left" if dead_rows[k] else "")
            if keep.sum() < 2:
                raise LipsynthError(f"{desc}: training removed all but {int(keep.sum())} state(s) — too little "
                                    f"face data for {n_states} states (lower brand.states or add video)")
            model = subset(model, keep)
        history[-1].update(states_after=model.n_components, transitions_after=int((model.transmat_ > 0).sum()))
        bar.set_postfix(ll=f"{ll:.3f}", states=model.n_components, trans=history[-1]["transitions_after"])
        if keep.all() and abs(post - previous) < tol:
            break
        previous = post
    return model, history
