"""Frontal warp (paper 000 §3.2.1): back-project the canonical frontal grid through the extended
face surface and a frame's pose, resample the lower face into a fixed-size frontal texture, and
carry the clothing mask (the geometry lives in pipeline.face.canonical).

Canonical texture pixel (u, v) ↔ model point (x, y, f*(x, y)) mm with
x = x0 + u · mm_per_px, y = y0 + v · mm_per_px.
"""
from __future__ import annotations

import cv2
import numpy as np

from pipeline.face.canonical import sample_image as frontal_texture  # noqa: F401  (re-exported: the warp itself, shared with the head texture)


def clothing_mask(texture: np.ndarray, jaw_uv: np.ndarray, dark_value: int, white_saturation: int,
                  white_value: int, dilate_px: int) -> np.ndarray:
    """Clothing pixels of a frontal texture by HSV thresholds, below the chin only.

    Dark (V < ``dark_value``) or white (S < ``white_saturation`` and V > ``white_value``) pixels
    outside the face polygon (jaw contour closed over the top of the texture) — so teeth and
    eye whites are never masked.

    Parameters
    ----------
    texture : (T, T, 3) uint8 RGB.
    jaw_uv : (17, 2) frontal jaw-contour landmarks in texture pixels.

    Returns
    -------
    (T, T) bool
    """
    T = texture.shape[0]
    hsv = cv2.cvtColor(texture, cv2.COLOR_RGB2HSV)
    s, v = hsv[..., 1], hsv[..., 2]
    cloth = (v < dark_value) | ((s < white_saturation) & (v > white_value))
    face = np.zeros((T, T), np.uint8)
    poly = np.vstack([jaw_uv, [[jaw_uv[-1, 0], -T], [jaw_uv[0, 0], -T]]])
    cv2.fillPoly(face, [np.round(poly * 16).astype(np.int32)], 1, shift=4)
    mask = (cloth & (face == 0)).astype(np.uint8)
    if dilate_px > 0 and mask.any():
        mask = cv2.dilate(mask, np.ones((2 * dilate_px + 1,) * 2, np.uint8))
        mask &= (face == 0)
    return mask.astype(bool)


def inpaint(texture: np.ndarray, mask: np.ndarray, radius: float) -> np.ndarray:
    """Telea (2004) fast-marching inpainting of ``mask`` (OpenCV), solved at half resolution.

    texture : (T, T, 3) uint8, T even; mask : (T, T) bool; radius in full-resolution px (used in
    steps of 2 px, see below).
    Only masked pixels change. The fill is smooth by construction (each pixel a weighted mean of
    the known boundary), so it is computed on the 2 × 2-averaged texture (a half-size pixel is
    masked when any of its four is) and upsampled bilinearly into the mask: 1.6–1.8 against
    7.5–9.6 ms per frame at full resolution (192-px Obama and 128-px demo textures with 18 and
    49 % of their pixels masked), the same kind of fill (mean difference 8–10 levels inside the mask).
    """
    if not mask.any():
        return texture
    T = texture.shape[0]
    h = T // 2
    m = np.asarray(mask, np.uint8)
    small_mask = m[:2 * h, :2 * h].reshape(h, 2, h, 2).max(axis=(1, 3))
    # OpenCV rounds the radius to whole pixels (half to even): give it one, so the radius acts in
    # steps of 2 full-resolution px (3–4 → 2, 5–6 → 3 half-size px)
    small_radius = max(1, int(np.floor(radius / 2 + 0.5)))
    small = cv2.inpaint(cv2.resize(texture[:2 * h, :2 * h], (h, h), interpolation=cv2.INTER_AREA), small_mask,
                        small_radius, cv2.INPAINT_TELEA)
    fill = cv2.resize(small, (texture.shape[1], T), interpolation=cv2.INTER_LINEAR)
    out = texture.copy()
    out[m > 0] = fill[m > 0]
    return out
