"""Validation measures shared by every model family and the baselines.

All errors are in canonical texture pixels (the frontal plane of the frontalize stage) and as a
percentage of the canonical inter-ocular distance.
"""
from __future__ import annotations

import numpy as np

from pipeline.face.dlib_face import INNER_BOTTOM, INNER_TOP, LIP_POINTS
from pipeline.models.mouth_pca import reconstruct

OPEN_TOP, OPEN_BOTTOM = LIP_POINTS.index(INNER_TOP), LIP_POINTS.index(INNER_BOTTOM)


def mouth_error(pred_pts: np.ndarray, true_pts: np.ndarray) -> np.ndarray:
    """Per-frame mean Euclidean distance over the 18 lip points. (T, 18, 2) ×2 → (T,)."""
    return np.linalg.norm(pred_pts - true_pts, axis=-1).mean(-1)


def opening(pts: np.ndarray) -> np.ndarray:
    """Inner-lip opening (distance of inner midpoints 62–66) of (T, 18, 2) lip points → (T,)."""
    return np.linalg.norm(pts[:, OPEN_TOP] - pts[:, OPEN_BOTTOM], axis=-1)


def lagged_correlation(pred: np.ndarray, true: np.ndarray, max_lag: int) -> dict[int, float]:
    """Pearson correlation of pred[t + lag] with true[t] for lag in [−max_lag, max_lag] frames.

    A positive best lag means the prediction lags the tracked mouth.
    """
    out = {}
    for lag in range(-max_lag, max_lag + 1):
        a = pred[max(lag, 0):len(pred) + min(lag, 0)]
        b = true[max(-lag, 0):len(true) + min(-lag, 0)]
        ok = np.isfinite(a) & np.isfinite(b)
        if ok.sum() > 3 and np.std(a[ok]) > 1e-6 and np.std(b[ok]) > 1e-6:
            out[lag] = float(np.corrcoef(a[ok], b[ok])[0, 1])
        else:
            out[lag] = float("nan")
    return out


def evaluate_videos(predictions: list[np.ndarray], truths: list[np.ndarray], valids: list[np.ndarray],
                    fps: list[float], basis: dict, iod_px: float, max_lag_s: float = 0.2) -> dict:
    """Summary measures over validation videos.

    Parameters
    ----------
    predictions : list of ndarray
        Per video, (T, k) predicted PCA coefficients at frame times.
    truths : list of ndarray
        Per video, (T, k) tracked coefficients.
    valids : list of ndarray
        Per video, (T,) bool: the frames whose mouth was tracked.
    fps : list of float
        Per video, frames per second.
    basis : dict
        The mouth PCA (``mean``, ``components``: coefficients → lip points, px).
    iod_px : float
        The speaker's inter-ocular distance (px), the unit of ``mouth_error_iod_pct``.
    max_lag_s : float
        The largest audio–visual lag searched (s).

    Returns
    -------
    dict
        ``mouth_error_px``, ``mouth_error_iod_pct``, and the audio–visual offset measures
        ``av_within_one_frame`` (fraction of clips whose best lag is within ±1 frame),
        ``median_opening_corr`` (lag 0), ``median_best_lag_frames`` and ``n_clips`` (the clips
        with a measured lag).
    """
    errs, per_clip = [], []
    for pred, true, ok, f in zip(predictions, truths, valids, fps):
        if ok.sum() == 0:
            continue
        pp, tp = reconstruct(pred, basis), reconstruct(np.nan_to_num(true), basis)
        errs.append(mouth_error(pp[ok], tp[ok]))
        po, to = opening(pp), np.where(ok, opening(tp), np.nan)
        corr = lagged_correlation(po, to, int(round(max_lag_s * f)))
        finite = {k: v for k, v in corr.items() if np.isfinite(v)}
        if finite:
            per_clip.append((max(finite, key=finite.get), corr[0]))
    e = float(np.concatenate(errs).mean()) if errs else float("nan")
    lags = np.array([c[0] for c in per_clip]) if per_clip else np.zeros(0)
    c0 = np.array([c[1] for c in per_clip]) if per_clip else np.zeros(0)
    return dict(mouth_error_px=e, mouth_error_iod_pct=100 * e / iod_px,
                av_within_one_frame=float(np.mean(np.abs(lags) <= 1)) if len(lags) else float("nan"),
                median_opening_corr=float(np.nanmedian(c0)) if len(c0) else float("nan"),
                median_best_lag_frames=float(np.median(lags)) if len(lags) else float("nan"),
                n_clips=len(per_clip))
