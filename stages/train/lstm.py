"""The time-delayed LSTM of paper 000 §3.1.1 and §4.2: MFCC (28-D, 100 Hz) → mouth PCA (20-D).

One unidirectional LSTM layer (60 cells) and a linear read-out; the output at step t is the
mouth shape of step t − d (target delay d = 20 steps = 200 ms), so the network hears d steps
of the future before it commits to a shape (Eq. 1–6). Inputs are normalised by the training
mean/variance; outputs are the unnormalised PCA coefficients; L2 loss; Adam; truncated
back-propagation through time over windows of ``bptt`` steps with batches of ``batch_size``
parallel streams whose state carries across windows; a budget of ``steps`` optimizer steps (one
per window), validated every ``val_every`` steps, with optional early stopping (``patience``).
"""
from __future__ import annotations

import logging
import math
import time

import numpy as np
import torch

from pipeline.models.adam import adam
from pipeline.models.delayed_lstm import DelayedLSTM, predict_sequence
from pipeline.models.training_budget import Budget, EarlyStopping, StepPlan
from pipeline.params import Train

log = logging.getLogger("lipsynth.train")


def delayed_pairs(x: np.ndarray, y: np.ndarray, ok: np.ndarray, delay: int):
    """Align one sequence for a target delay: input step t is trained against target t − d.

    ``d`` zero frames (= the training mean after normalisation) are appended to the input so the
    last ``d`` shapes are produced too. Returns x' (m+d, n_in), y' (m+d, n_out), mask (m+d,).
    """
    m = len(x)
    xd = np.concatenate([x, np.zeros((delay, x.shape[1]), x.dtype)])
    yd = np.concatenate([np.zeros((delay, y.shape[1]), y.dtype), y])
    md = np.concatenate([np.zeros(delay, bool), ok])
    assert len(xd) == len(yd) == m + delay
    return xd, yd, md


def make_streams(seqs: list, batch_size: int, bptt: int, rng: np.random.Generator):
    """Concatenate sequences in random order and fold them into ≤ ``batch_size`` parallel streams.

    Returns X (B, L, n_in), Y (B, L, n_out), M (B, L) with L a multiple of ``bptt``.
    """
    order = rng.permutation(len(seqs))
    X = np.concatenate([seqs[i][0] for i in order])
    Y = np.concatenate([seqs[i][1] for i in order])
    M = np.concatenate([seqs[i][2] for i in order])
    B = max(1, min(batch_size, len(X) // bptt))
    L = (len(X) // (B * bptt)) * bptt
    if L == 0:
        L, B = len(X), 1
    n = B * L
    return X[:n].reshape(B, L, -1), Y[:n].reshape(B, L, -1), M[:n].reshape(B, L)


def masked_l2(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean over valid steps of the squared error summed over coefficients (canonical px²)."""
    se = ((pred - target) ** 2).sum(-1)
    return (se * mask).sum() / mask.sum().clamp(min=1)


def velocity_l2(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean over pairs of valid consecutive steps of the squared error of the motion (canonical px² per 10 ms²).

    pred, target (B, L, K), mask (B, L) float: the shape error says nothing of how a mouth moves; this does."""
    both = mask[:, 1:] * mask[:, :-1]
    se = (((pred[:, 1:] - pred[:, :-1]) - (target[:, 1:] - target[:, :-1])) ** 2).sum(-1)
    return (se * both).sum() / both.sum().clamp(min=1)


def opening_decorrelation(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor,
                          opening: torch.Tensor) -> torch.Tensor:
    """1 − the correlation over time of the predicted and true inner-lip opening, averaged over streams.

    ``opening`` (K,): the opening's gradient in the PCA coefficients (``opening_direction``), so the opening
    of a shape y is y · opening up to a constant. Streams with fewer than 10 valid steps, or with a still true
    mouth, are left out (a correlation needs motion)."""
    a, b = pred @ opening, target @ opening                                    # (B, L)
    n = mask.sum(1)
    ma = (a * mask).sum(1) / n.clamp(min=1)
    mb = (b * mask).sum(1) / n.clamp(min=1)
    da, db = (a - ma[:, None]) * mask, (b - mb[:, None]) * mask
    cov = (da * db).sum(1)
    va, vb = (da ** 2).sum(1), (db ** 2).sum(1)
    ok = (n >= 10) & (vb > 1e-6 * n.clamp(min=1))
    if not bool(ok.any()):
        return pred.sum() * 0.0
    corr = cov[ok] / torch.sqrt(va[ok] * vb[ok] + 1e-12)
    return (1.0 - corr).mean()


def opening_direction(basis: dict, top: int = 13, bottom: int = 16) -> np.ndarray:
    """(K,) float32: d(opening)/d(coefficients) for the PCA ``basis`` (mean (2P,), components (K, 2P)) of the
    18 lip points: the vertical distance from inner-lip point ``top`` (62) to ``bottom`` (66) is
    linear in the coefficients (canonical texture px)."""
    comp = np.asarray(basis["components"], np.float64).reshape(len(basis["components"]), -1, 2)
    return (comp[:, bottom, 1] - comp[:, top, 1]).astype(np.float32)


def shape_loss(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor, p: Train,
               opening: torch.Tensor | None) -> torch.Tensor:
    """The training loss: the paper's L2 on the shape, plus ``p.velocity_weight`` × ``velocity_l2`` and
    ``p.opening_corr_weight`` × ``opening_decorrelation`` (both 0 by default: the paper's loss alone)."""
    loss = masked_l2(pred, target, mask)
    if p.velocity_weight:
        loss = loss + p.velocity_weight * velocity_l2(pred, target, mask)
    if p.opening_corr_weight and opening is not None:
        loss = loss + p.opening_corr_weight * opening_decorrelation(pred, target, mask, opening)
    return loss


def train(train_seqs: list, val_seqs: list, p: Train, delay: int, device, seed: int = 0,
          desc: str = "lstm", budget: Budget | None = None, init: dict | None = None,
          opening: np.ndarray | None = None) -> tuple[DelayedLSTM, list[dict], int]:
    """Train one model for a budget of optimizer steps (``pipeline.models.training_budget``).

    Parameters
    ----------
    train_seqs, val_seqs : list of (x (m, D) normalised float32, y (m, 20), ok (m,) bool); a training
        x may also be (K, m, D): K augmented copies of the same audio, one drawn per epoch
    p : train params (hidden, layers, batch_size, bptt, lr; steps, val_every, patience unless
        ``budget`` is given; ``fine_tune`` when ``init`` is given).
    init : a starting point (``stages/train/fine_tune.initial_state``: state, hidden, layers) instead
        of random weights; ``p.fine_tune == "output"`` then trains the read-out layer only. With
        ``init["anchor"]`` = λ > 0 the loss adds λ · Σ ‖θ − θ₀‖² over the trained weights (L2-SP:
        fine-tuning pulled toward its starting point, ``stages/train/adapt.py``).
    opening : (n_out,) the opening's direction in the outputs (``opening_direction``), for
        ``p.opening_corr_weight``; the validation loss stays the L2 on the shape.

    Returns
    -------
    model (the weights of the best validation point when early stopping is on, else the last),
    history (one dict per validation point: step, epoch, train_loss — the mean since the previous
    point —, val_loss, seconds), and the step whose weights were kept.
    """
    from tqdm import tqdm

    budget = (budget or Budget(p.steps, p.val_every, p.patience, p.min_delta)).check("train")
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    model, trained = initial_model(train_seqs[0][0].shape[-1], train_seqs[0][1].shape[1], p, device, init)
    opt = adam(trained, p.lr)
    anchor = float(init.get("anchor", 0.0)) if init else 0.0
    opening_t = None if opening is None else torch.as_tensor(opening, dtype=torch.float32, device=device)
    start = [w.detach().clone() for w in trained] if anchor else []
    # x may hold K variants (K, m, n_in) of the same audio (VTLP copies): each epoch draws one per video
    variants = [[delayed_pairs(xv, y, ok, delay) for xv in (x if x.ndim == 3 else x[None])] for x, y, ok in train_seqs]
    frames = sum(len(v[0][0]) for v in variants)
    B = max(1, min(p.batch_size, frames // p.bptt))
    steps_per_epoch = max(1, frames // (B * p.bptt))            # make_streams: L // bptt windows
    plan = StepPlan(f"LSTM {desc} (d={delay})", budget, steps_per_epoch, f"{frames / 100:,.0f} s of audio", log,
                    calibrate=min(5, budget.steps))
    stopper = EarlyStopping(budget)
    history, step, total, count, t0, stop = [], 0, 0.0, 0.0, time.perf_counter(), False
    bar = tqdm(total=budget.steps, desc=f"train {desc} (d={delay})", unit="step", dynamic_ncols=True)
    while step < budget.steps and not stop:
        model.train()
        shifted = [v[0] if len(v) == 1 else v[rng.integers(len(v))] for v in variants]
        X, Y, M = (torch.from_numpy(a).to(device) for a in make_streams(shifted, p.batch_size, p.bptt, rng))
        state = None
        for a in range(0, X.shape[1], p.bptt):
            pred, state = model(X[:, a:a + p.bptt], state)
            state = tuple(s.detach() for s in state)
            loss = shape_loss(pred, Y[:, a:a + p.bptt], M[:, a:a + p.bptt].float(), p, opening_t)
            opt.zero_grad()
            if anchor:
                pull = sum(((w - w0) ** 2).sum() for w, w0 in zip(trained, start))
                (loss + anchor * pull).backward()
            else:
                loss.backward()
            opt.step()
            w = float(M[:, a:a + p.bptt].sum())
            total, count = total + loss.item() * w, count + w
            step += 1
            plan.step_done()
            bar.update(1)
            if budget.is_validation_step(step):
                val = evaluate_loss(model, val_seqs, delay, device) if val_seqs else float("nan")
                model.train()
                history.append(dict(step=step, epoch=step / steps_per_epoch, train_loss=total / max(count, 1),
                                    val_loss=val, seconds=time.perf_counter() - t0))
                total, count = 0.0, 0.0
                bar.set_postfix(train=f"{history[-1]['train_loss']:.3f}", val=f"{val:.3f}")
                stop = stopper.update(step, val, model.state_dict())
            if stop or step >= budget.steps:
                break
    bar.close()
    kept = keep_best(model, stopper, budget, step, stop, f"LSTM {desc} (d={delay})")
    model.eval()
    return model, history, kept


def initial_model(n_in: int, n_out: int, p: Train, device, init: dict | None) -> tuple[DelayedLSTM, list]:
    """The network (random weights, or ``init``'s) on ``device`` and the weights to train (all, or the
    read-out only when fine-tuning with ``p.fine_tune == "output"``)."""
    if init is None:
        model = DelayedLSTM(n_in, p.hidden, n_out, p.layers).to(device)
        return model, list(model.parameters())
    model = DelayedLSTM(n_in, init["hidden"], n_out, init["layers"], init.get("skip", False))
    model.load_state_dict(init["state"])
    model = model.to(device)
    return model, list(model.out.parameters()) if p.fine_tune == "output" else list(model.parameters())


def keep_best(model: DelayedLSTM, stopper: EarlyStopping, budget: Budget, step: int, stop: bool, name: str) -> int:
    """With early stopping on, load the best validation point's weights into ``model``; returns the step
    whose weights are kept (``step``, the last, otherwise)."""
    kept = step
    if budget.patience is not None and stopper.best_state is not None and stopper.best_step != step:
        model.load_state_dict(stopper.best_state)
        kept = stopper.best_step
    if stop:
        log.info("%s: early stop at step %d of %d (no gain for %d validations); keeping step %d "
                 "(val loss %.4f)", name, step, budget.steps, budget.patience, kept, stopper.best_value)
    return kept


def evaluate_loss(model: DelayedLSTM, seqs: list, delay: int, device) -> float:
    """The training loss on whole sequences (state reset per sequence)."""
    se, n = 0.0, 0
    for x, y, ok in seqs:
        pred = predict_sequence(model, x, delay, device)
        se += float((((pred - y) ** 2).sum(-1) * ok).sum())
        n += int(ok.sum())
    return se / max(n, 1) if n else math.nan
