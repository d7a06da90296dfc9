"""The recording's own audio–video offset, estimated before a person's model is fitted (issue 47).

Natural footage is often a few frames out of sync (a phone's audio path, an edit). Fitted as it is,
a model learns the offset, and its mouths then lead or trail every new voice by it. The offset is a
property of the recording, so it is estimated without the base model's timing: for each candidate lag
the person's mouth (PCA coefficients y, 100 Hz) is shifted against the audio's encoder states x and a
ridge map y_t ≈ V x_t + b is scored by leave-one-segment-out error; the lag of least error is the
offset. The encoder's states see the whole window around t, so a map can fit any lag a little; only
the right one lets it fit well.

    lag > 0: the mouth moves ``lag`` steps after the sound that goes with it (the video is late);
             the aligned target is y'_t = y_{t+lag}.

A mouth moves before its sound (it opens, then the voice starts), so footage in sync has a best lag
below 0: ``SYNCED_LAG`` is that lag, measured on GRID speaker 4 (known sync; ``lipsynth personalize
../shared/data/grid_s4/*.mp4``: its 24 training and held-out clips pooled, −60 ms). The recording's
offset is the best lag minus ``SYNCED_LAG``; only that is undone, and only when it is more than one
tried step (20 ms) from sync.

Pure functions (no I/O): ``adapt`` calls ``estimate`` per source video and ``shift`` per segment.
"""
from __future__ import annotations

import numpy as np

MAX_LAG_STEPS = 20           # ±0.2 s at 100 Hz (±5 frames at 25 fps)
LAG_STEP = 2                 # 20 ms between tried lags
ALPHA = 1.0                  # ridge strength per frame (the middle of adapt's grid)
MIN_GAIN = 0.01              # the best lag must lower the error by 1 % from lag 0 to be believed
SYNCED_LAG = -6              # the best lag of footage in sync (steps): GRID s4, −60 ms (module doc)


def shift(y: np.ndarray, ok: np.ndarray, lag: int) -> tuple[np.ndarray, np.ndarray]:
    """Targets (m, k) and their validity (m,) moved so that row t holds row t + ``lag``; rows whose source
    falls outside are invalid (and hold the nearest valid value, never read)."""
    m = len(y)
    src = np.arange(m) + int(lag)
    inside = (src >= 0) & (src < m)
    src = np.clip(src, 0, m - 1)
    return y[src], ok[src] & inside


def ridge(Z: np.ndarray, Y: np.ndarray, lam: float) -> np.ndarray:
    """(D + 1, k) ridge map with a free bias of rows Z (n, D) to Y (n, k)."""
    Za = np.hstack([Z, np.ones((len(Z), 1))])
    reg = np.full(Za.shape[1], lam)
    reg[-1] = 0.0
    return np.linalg.solve(Za.T @ Za + np.diag(reg), Za.T @ Y)


def cv_error(xs: list, ys: list, oks: list) -> float:
    """Leave-one-segment-out mean squared error of the ridge map (``ALPHA`` per frame)."""
    n = sum(int(o.sum()) for o in oks)
    se = 0.0
    for k in range(len(xs)):
        Z = np.concatenate([x[o] for i, (x, o) in enumerate(zip(xs, oks)) if i != k])
        Y = np.concatenate([y[o] for i, (y, o) in enumerate(zip(ys, oks)) if i != k])
        M = ridge(Z, Y, ALPHA * len(Z))
        pred = np.hstack([xs[k], np.ones((len(xs[k]), 1))])[oks[k]] @ M
        se += float(((pred - ys[k][oks[k]]) ** 2).sum())
    return se / max(n, 1)


def estimate(xs: list, ys: list, oks: list, max_lag: int = MAX_LAG_STEPS, step: int = LAG_STEP,
             synced: int = SYNCED_LAG) -> dict:
    """Offset (steps at 100 Hz) of one recording from its segments: normalised encoder states ``xs`` (m, D),
    mouth coefficients ``ys`` (m, k), validity ``oks`` (m,). Needs ≥ 2 segments.

    Returns dict(lag (the recording's offset, steps: the best lag minus ``synced``; 0 when it cannot be
    estimated), best (the best lag), errors {lag: cv error}, reliable, reason)."""
    if len(xs) < 2:
        return dict(lag=0, errors={}, reliable=False, reason="one segment: nothing to cross-validate")
    moving = np.concatenate([y[o] for y, o in zip(ys, oks)]) if any(o.any() for o in oks) else np.zeros((0, 1))
    if len(moving) < 50 or float(moving.std(0).max()) < 1e-6:
        return dict(lag=0, errors={}, reliable=False, reason="no visible mouth motion")
    errors = {}
    for lag in range(-max_lag, max_lag + 1, step):
        shifted = [shift(y, o, lag) for y, o in zip(ys, oks)]
        errors[lag] = cv_error(xs, [s[0] for s in shifted], [s[1] for s in shifted])
    best = min(errors, key=errors.get)
    gain = 1.0 - errors[best] / errors[0]
    if best != 0 and gain < MIN_GAIN:
        return dict(lag=0, best=best, errors=errors, reliable=False,
                    reason=f"the error changes by {gain:.1%} at most over ±{max_lag} steps (silence, or a mouth "
                           f"that does not follow the sound)")
    if abs(best) >= max_lag - step // 2:
        return dict(lag=0, best=best, errors=errors, reliable=False,
                    reason=f"the least error is at the edge of ±{max_lag} steps: no offset within reach")
    offset = int(best - synced)
    return dict(lag=offset if abs(offset) > step else 0, best=int(best), errors=errors, reliable=True, reason="")


def recording_of(segment_name: str) -> str:
    """The source video of a segment ``<stem>_sNNN`` (``pipeline.io.segments.cut_video``'s names)."""
    stem, sep, tail = segment_name.rpartition("_s")
    return stem if sep and tail.isdigit() else segment_name
