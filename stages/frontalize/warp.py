"""Frontal warp (paper 000 §3.2.1): back-project the canonical frontal grid through the extended
face surface and a frame's pose, resample the lower face into a fixed-size frontal texture, and
carry the 2D landmarks onto the canonical plane.

Canonical texture pixel (u, v) ↔ model point (x, y, f*(x, y)) mm with
x = x0 + u · mm_per_px, y = y0 + v · mm_per_px.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.ndimage import map_coordinates

from pipeline.geometry import project


@dataclass
class Surface:
    """The extended depth map f*(x, y) on a regular grid (mm)."""

    depth: np.ndarray     # (H, W) mm
    x0: float             # x of column 0 (mm)
    y0: float             # y of row 0 (mm)
    step: float           # grid spacing (mm)

    def z(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Bilinear depth at model coordinates (mm); the border value continues outside."""
        cols = (np.asarray(x) - self.x0) / self.step
        rows = (np.asarray(y) - self.y0) / self.step
        return map_coordinates(self.depth, [rows.ravel(), cols.ravel()], order=1, mode="nearest").reshape(np.shape(x))


@dataclass
class TextureWindow:
    """The lower-face window of the canonical plane that textures cover."""

    x0: float             # mm at u = 0
    y0: float             # mm at v = 0
    mm_per_px: float
    size: int             # texture is size × size

    def grid_points(self, surface: Surface) -> np.ndarray:
        """(size, size, 3) model points of every texture pixel."""
        u = self.x0 + self.mm_per_px * np.arange(self.size)
        v = self.y0 + self.mm_per_px * np.arange(self.size)
        gx, gy = np.meshgrid(u, v)
        return np.stack([gx, gy, surface.z(gx, gy)], axis=-1)

    def to_pixels(self, xy_mm: np.ndarray) -> np.ndarray:
        return (xy_mm - np.array([self.x0, self.y0])) / self.mm_per_px

    def to_mm(self, uv: np.ndarray) -> np.ndarray:
        return uv * self.mm_per_px + np.array([self.x0, self.y0])


def frontal_texture(image: np.ndarray, points: np.ndarray, rvec, tvec, K: np.ndarray,
                    image_from_frame=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Resample ``image`` at the projections of the texture's model points.

    Parameters
    ----------
    image : (h, w, 3) uint8 — a frame or a face-region crop of it.
    points : (T, T, 3) model points of the texture pixels (``TextureWindow.grid_points``).
    rvec, tvec, K : the frame's pose and intrinsics (source-frame pixels).
    image_from_frame : (x0, y0, s) — the crop: frame pixel = (x0, y0) + s · image pixel.

    Returns
    -------
    (T, T, 3) uint8 frontal texture.
    """
    R = cv2.Rodrigues(np.asarray(rvec, np.float64).reshape(3))[0]
    x0, y0, s = image_from_frame
    A = np.array([[1 / s, 0, -x0 / s], [0, 1 / s, -y0 / s], [0, 0, 1]]) @ K    # frame → image pixels
    M = (A @ R).astype(np.float32)
    b = (A @ np.asarray(tvec, np.float64).reshape(3)).astype(np.float32)
    uvw = points.reshape(-1, 3).astype(np.float32, copy=False) @ M.T + b
    mx = (uvw[:, 0] / uvw[:, 2]).reshape(points.shape[:2])
    my = (uvw[:, 1] / uvw[:, 2]).reshape(points.shape[:2])
    return cv2.remap(image, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def frontal_landmarks(landmarks: np.ndarray, start_xy: np.ndarray, surface: Surface, rvec, tvec,
                      K: np.ndarray, iterations: int = 6) -> np.ndarray:
    """Intersect each landmark's viewing ray with the extended surface.

    Newton iterations on (x, y) so that project(x, y, f*(x, y)) equals the landmark.

    Parameters
    ----------
    landmarks : (P, 2) pixels in the source frame.
    start_xy : (P, 2) starting model coordinates (mm), e.g. the 3D model's own x, y.

    Returns
    -------
    (P, 2) model coordinates (mm) on the canonical plane.
    """
    xy = start_xy.astype(np.float64).copy()
    h = 0.5                                                  # mm, finite-difference step
    offsets = np.array([[0.0, 0.0], [h, 0.0], [0.0, h]])
    n = len(xy)
    for _ in range(iterations):
        q = (xy[None] + offsets[:, None]).reshape(-1, 2)     # (3P, 2): point, +dx, +dy
        p = project(np.column_stack([q, surface.z(q[:, 0], q[:, 1])]), rvec, tvec, K).reshape(3, n, 2)
        J = np.stack([(p[1] - p[0]) / h, (p[2] - p[0]) / h], axis=-1)   # (P, 2, 2)
        step = np.linalg.solve(J, (landmarks - p[0])[..., None])[..., 0]
        xy += np.clip(step, -20, 20)
        if np.max(np.abs(step)) < 1e-3:
            break
    return xy


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
    """Telea (2004) fast-marching inpainting of ``mask`` (OpenCV)."""
    if not mask.any():
        return texture
    return cv2.inpaint(texture, mask.astype(np.uint8), radius, cv2.INPAINT_TELEA)
