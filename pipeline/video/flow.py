"""Dense optical flow of a large image found on smaller copies.

A face's misfit (the jaw against the target's, a real frame against the median's shape) is a smooth
field: its flow at a few hundred pixels, scaled up, is the flow at any size, while DIS's cost grows
with the pixel count. Jaw correction (``stages/composite/layers.py``) and two-band alignment
(``stages/synthesize/two_band.py``) both find theirs this way.
"""
from __future__ import annotations

import cv2
import numpy as np


def flow_at_most(dis, a: np.ndarray, b: np.ndarray, max_size: int, blur_sigma: float = 0.0) -> np.ndarray:
    """Flow F with a(p) ≈ b(p + F(p)), for square grey images larger than ``max_size`` found between their
    area-averaged copies of ``max_size`` px and scaled up (bilinear, × size / max_size).

    Parameters
    ----------
    dis : cv2.DISOpticalFlow
        Or any object with ``calc(grey0, grey1, None)``.
    a, b : ndarray
        (T, T) uint8 grey images.
    max_size : int
        px, the largest side the flow is computed at.
    blur_sigma : float
        px at the computed size; > 0 smooths both copies first (Gaussian).

    Returns
    -------
    ndarray
        (T, T, 2) float32 displacement (dx, dy) in px of the full size.
    """
    size = a.shape[0]
    n = min(size, int(max_size))

    def prepare(g):
        g = g if n == size else cv2.resize(g, (n, n), interpolation=cv2.INTER_AREA)
        return cv2.GaussianBlur(g, (0, 0), blur_sigma) if blur_sigma > 0 else g

    f = dis.calc(prepare(a), prepare(b), None)
    if n == size:
        return f
    return cv2.resize(f, (size, size), interpolation=cv2.INTER_LINEAR) * np.float32(size / n)
