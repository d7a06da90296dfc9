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
