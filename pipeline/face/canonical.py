"""The canonical frontal frame (paper 000 §3.2.1): the speaker's extended face surface f*(x, y)
and the lower-face texture window on it, shared by frontalize (frame → texture) and composite
(texture → frame).

Model coordinates are millimetres with the outer eye corners ``IOD_MM`` apart (``pipeline.face.dlib_face``),
x right, y down, origin at the eye midpoint. Canonical texture pixel (u, v) ↔ model point
(x, y, f*(x, y)) mm with x = x0 + u · mm_per_px, y = y0 + v · mm_per_px.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import map_coordinates

from pipeline.face.geometry import project


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
