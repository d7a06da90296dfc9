"""Mouth-shape space (paper 000 §3.1, "Mouth Shape Features"): the 18 lip points of a frontalized
frame as a 36-D vector, and its PCA basis.

A basis is a dict with ``mean`` (36,) and ``components`` (k, 36) in canonical texture pixels
(see ``pipeline.face.canonical``); it is fitted by the ``pca`` stage and carried by every model folder,
identified by ``fingerprint``.
"""
from __future__ import annotations

import hashlib

import numpy as np

from pipeline.face.dlib_face import LIP_POINTS


def lip_vectors(frontal_landmarks: np.ndarray) -> np.ndarray:
    """(N, 68, 2) frontal landmarks → (N, 36) lip vectors [x0, y0, x1, y1, …] (canonical px)."""
    return frontal_landmarks[:, LIP_POINTS].reshape(len(frontal_landmarks), -1)


def project(x: np.ndarray, basis: dict) -> np.ndarray:
    """(n, 36) → (n, k) coefficients."""
    return (x - basis["mean"]) @ basis["components"].T


def reconstruct(coeffs: np.ndarray, basis: dict) -> np.ndarray:
    """(n, k) coefficients → (n, 18, 2) lip points in canonical texture pixels."""
    return (coeffs @ basis["components"] + basis["mean"]).reshape(len(coeffs), -1, 2)


def fingerprint(basis: dict) -> str:
    """Short hash identifying a PCA basis (a model trained on another basis must not use this one)."""
    h = hashlib.sha1()
    for k in ("mean", "components"):
        h.update(np.ascontiguousarray(basis[k], np.float32).tobytes())
    return h.hexdigest()[:16]


def resample_to_100hz(coeffs: np.ndarray, valid: np.ndarray, frame_time: np.ndarray, n_out: int,
                      rate: float = 100.0) -> tuple[np.ndarray, np.ndarray]:
    """Linear interpolation of per-frame coefficients onto t = i / rate, i < n_out.

    Parameters
    ----------
    coeffs : ndarray
        (T, k) per-frame coefficients.
    valid : ndarray
        (T,) bool.
    frame_time : ndarray
        (T,) seconds from the video start.
    n_out : int
        Output frames.
    rate : float
        Output rate (Hz).

    Returns
    -------
    coeffs : ndarray
        (n_out, k) float32.
    valid : ndarray
        (n_out,) bool — valid where both bracketing frames are valid (times past the last frame
        hold the last frame, valid if it is).
    """
    t = np.arange(n_out) / rate
    hi = np.clip(np.searchsorted(frame_time, t, side="right"), 1, len(frame_time) - 1)
    lo = hi - 1
    span = np.maximum(frame_time[hi] - frame_time[lo], 1e-9)
    w = np.clip((t - frame_time[lo]) / span, 0.0, 1.0)[:, None]
    filled = np.where(valid[:, None], coeffs, 0.0)
    out = (1 - w) * filled[lo] + w * filled[hi]
    ok = (valid[lo] | (w[:, 0] == 1.0)) & (valid[hi] | (w[:, 0] == 0.0))
    return out.astype(np.float32), ok
