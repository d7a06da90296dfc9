"""The person's own mouth shapes, retrieved for new audio (issue 47; after Video Rewrite, Bregler et al.
1997, and Voice Puppetry's remapping, paper 002 §4).

A parametric model predicts a shape per 10-ms step; retrieval turns that into a path through the
person's *real* shapes, with their own articulation: for each video frame of the new audio, the
``K`` training frames whose keys are nearest are candidates, and a Viterbi pass picks one per frame,
trading key distance against shape continuity,

    cost(path) = Σ_t d(q_t, key_{i_t}) / d̃  +  smooth · Σ_t (‖y_{i_t} − y_{i_{t−1}}‖ / s̃)²,

d̃ the median candidate distance and s̃ the median step of the person's own shapes between
consecutive frames. The keys are the base model's predictions with ``context`` frames either side
(the audio as the model hears it: a learned metric on the encoder states, where raw 384-D states are
dominated by what is not the mouth). Pure NumPy: ``adapt`` builds the database, ``predict_mouth``
retrieves.
"""
from __future__ import annotations

import numpy as np

K = 10                  # candidates per frame
SMOOTH = 1.0            # weight of shape continuity against key distance
CONTEXT = 1             # frames of context either side in a key
STEP = 4                # 100-Hz steps per frame of a key's context and of the Viterbi pass (25 fps)
MIN_FRAMES = 250        # a database of fewer valid steps (2.5 s) holds too few shapes to retrieve from


def keys(c100: np.ndarray, context: int = CONTEXT, step: int = STEP) -> np.ndarray:
    """(m, k) predictions at 100 Hz → (m, k · (2·context + 1)) keys: each step with its neighbours
    ``step`` steps apart (edges repeated)."""
    c = np.asarray(c100, np.float32)
    idx = np.arange(len(c))
    return np.concatenate([c[np.clip(idx + j * step, 0, len(c) - 1)] for j in range(-context, context + 1)], 1)


def viterbi(cost: np.ndarray, shapes: np.ndarray, smooth: float, scale: float) -> np.ndarray:
    """Index (T,) into the K candidates of each frame minimising candidate cost (T, K) plus
    ``smooth`` · (jump / ``scale``)² between consecutive frames' shapes (T, K, k)."""
    T, n = cost.shape
    acc, back = cost[0].astype(np.float64), np.zeros((T, n), int)
    for t in range(1, T):
        jump = np.linalg.norm(shapes[t][:, None] - shapes[t - 1][None], axis=2) / scale
        total = acc[None, :] + smooth * jump ** 2                       # (to, from)
        back[t] = total.argmin(1)
        acc = total.min(1) + cost[t]
    path = np.zeros(T, int)
    path[-1] = int(acc.argmin())
    for t in range(T - 1, 0, -1):
        path[t - 1] = back[t, path[t]]
    return path


def retrieve(query: np.ndarray, db_keys: np.ndarray, db_values: np.ndarray, k: int = K, smooth: float = SMOOTH,
             step: int = STEP) -> np.ndarray:
    """Shapes (m, c) at 100 Hz for query keys (m, d): the Viterbi path through the ``k`` nearest of
    ``db_keys`` (n, d) at every ``step``-th step, their ``db_values`` (n, c), linearly interpolated between."""
    q = np.asarray(query, np.float64)
    db, vals = np.asarray(db_keys, np.float64), np.asarray(db_values, np.float64)
    k = min(k, len(db))
    at = np.arange(0, len(q), step)
    d = (q[at] ** 2).sum(1)[:, None] - 2 * q[at] @ db.T + (db ** 2).sum(1)[None]
    cand = np.argsort(d, 1, kind="stable")[:, :k]
    cost = np.take_along_axis(d, cand, 1)
    cost = np.maximum(cost, 0) / max(float(np.median(cost)), 1e-12)
    scale = max(float(np.median(np.linalg.norm(np.diff(vals[::step], axis=0), axis=1))), 1e-9)
    chosen = vals[cand[np.arange(len(at)), viterbi(cost, vals[cand], smooth, scale)]]
    steps = np.arange(len(q))
    return np.stack([np.interp(steps, at, chosen[:, j]) for j in range(vals.shape[1])], 1)
