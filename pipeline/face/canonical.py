"""The canonical frontal frame (paper 000 §3.2.1): the speaker's extended face surface f*(x, y)
and the lower-face texture window on it, shared by frontalize (frame → texture) and composite
(texture → frame).

Model coordinates are millimetres with the outer eye corners ``IOD_MM`` apart (``pipeline.face.dlib_face``),
x right, y down, origin at the eye midpoint. Canonical texture pixel (u, v) ↔ model point
(x, y, f*(x, y)) mm with x = x0 + u · mm_per_px, y = y0 + v · mm_per_px.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.ndimage import map_coordinates

from pipeline import resample
from pipeline.face.geometry import rotation


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

    def z_slopes(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Depth z and its slopes ∂z/∂x, ∂z/∂y (mm/mm) of the bilinear surface at (N,) model coordinates.

        Same surface as ``z`` (outside the grid the border value continues, so the slope across
        the border is 0); the slopes are those of the bilinear patch the point falls in.
        """
        H, W = self.depth.shape
        c = (np.asarray(x, np.float64) - self.x0) / self.step
        r = (np.asarray(y, np.float64) - self.y0) / self.step
        inside_c, inside_r = (c > 0) & (c < W - 1), (r > 0) & (r < H - 1)
        c, r = np.clip(c, 0, W - 1), np.clip(r, 0, H - 1)
        c0 = np.minimum(c.astype(np.intp), W - 2)
        r0 = np.minimum(r.astype(np.intp), H - 2)
        fc, fr = c - c0, r - r0
        d = self.depth
        z00, z01, z10, z11 = d[r0, c0], d[r0, c0 + 1], d[r0 + 1, c0], d[r0 + 1, c0 + 1]
        top = z00 + fc * (z01 - z00)
        bottom = z10 + fc * (z11 - z10)
        dzdx = np.where(inside_c, (z01 - z00) + fr * ((z11 - z10) - (z01 - z00)), 0.0) / self.step
        dzdy = np.where(inside_r, bottom - top, 0.0) / self.step
        return top + fr * (bottom - top), dzdx, dzdy


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


def surface_projection(xy: np.ndarray, surface: Surface, M: np.ndarray, m: np.ndarray):
    """Pixels of the surface points (x, y, f(x, y)) and the exact Jacobian of that projection.

    ``xy`` (N, 2) model mm; the homogeneous pixel is q = M·X + m (M = K·R, m = K·t). Returns (N, 2)
    pixels and the Jacobian's entries (a, b, c, d) = (∂u/∂x, ∂u/∂y, ∂v/∂x, ∂v/∂y), each (N,) px/mm.
    """
    z, zx, zy = surface.z_slopes(xy[:, 0], xy[:, 1])
    q = np.column_stack([xy, z]) @ M.T + m                   # (N, 3)
    uv = q[:, :2] / q[:, 2:3]
    dqx = M[:, 0] + np.outer(zx, M[:, 2])                    # (N, 3) ∂q/∂x
    dqy = M[:, 1] + np.outer(zy, M[:, 2])
    a, c = (dqx[:, :2] - uv * dqx[:, 2:3]).T / q[:, 2]       # ∂u/∂x, ∂v/∂x
    b, d = (dqy[:, :2] - uv * dqy[:, 2:3]).T / q[:, 2]       # ∂u/∂y, ∂v/∂y
    return uv, (a, b, c, d)


def frontal_landmarks(landmarks: np.ndarray, start_xy: np.ndarray, surface: Surface, rvec, tvec,
                      K: np.ndarray, iterations: int = 6) -> np.ndarray:
    """Intersect each landmark's viewing ray with the extended surface.

    Newton iterations on (x, y) so that project(x, y, f*(x, y)) equals the landmark, with the
    exact Jacobian of the projection of the bilinear surface (closed-form 2 × 2 solve per point);
    a point stops once its step is below 1e-3 mm, the others go on up to ``iterations``.

    Parameters
    ----------
    landmarks : ndarray
        (P, 2) pixels in the source frame.
    start_xy : ndarray
        (P, 2) starting model coordinates (mm), e.g. the 3D model's own x, y.
    surface : Surface
        The extended face surface f* (mm).
    rvec, tvec, K
        The frame's pose (Rodrigues rad, mm) and intrinsics (source-frame px).
    iterations : int
        The most Newton steps.

    Returns
    -------
    ndarray
        (P, 2) model coordinates (mm) on the canonical plane.
    """
    xy = start_xy.astype(np.float64).copy()
    target = np.asarray(landmarks, np.float64)
    M = K @ rotation(rvec)                                   # q = M·X + m is the homogeneous pixel
    m = K @ np.asarray(tvec, np.float64).reshape(3)
    active = np.arange(len(xy))                              # points still moving
    for _ in range(iterations):
        uv, (a, b, c, d) = surface_projection(xy[active], surface, M, m)
        ru, rv = (target[active] - uv).T
        det = a * d - b * c
        det = np.where(np.abs(det) < 1e-12, 1e-12, det)
        step = np.clip(np.column_stack([(d * ru - b * rv) / det, (a * rv - c * ru) / det]), -20, 20)
        xy[active] += step
        active = active[np.abs(step).max(1) >= 1e-3]
        if not len(active):
            break
    return xy


def sample_image(image: np.ndarray, points: np.ndarray, rvec, tvec, K: np.ndarray,
                 image_from_frame=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Resample ``image`` at the projections of the texture's model points.

    Parameters
    ----------
    image : ndarray
        (h, w, 3) uint8 — a frame or a face-region crop of it.
    points : ndarray
        (H, W, 3) model points of the texture pixels, mm (e.g. ``TextureWindow.grid_points``).
    rvec, tvec, K
        The frame's pose and intrinsics (source-frame pixels).
    image_from_frame : tuple
        (x0, y0, s) — the crop: frame pixel = (x0, y0) + s · image pixel.

    Returns
    -------
    ndarray
        (H, W, 3) uint8 frontal texture.
    """
    R = cv2.Rodrigues(np.asarray(rvec, np.float64).reshape(3))[0]
    x0, y0, s = image_from_frame
    A = np.array([[1 / s, 0, -x0 / s], [0, 1 / s, -y0 / s], [0, 0, 1]]) @ K    # frame → image pixels
    M = A @ R
    b = A @ np.asarray(tvec, np.float64).reshape(3)
    # element-wise float64 (no BLAS, whose kernels differ by CPU) and a bit-exact remap: the same bytes anywhere
    p = points.astype(np.float64, copy=False)
    u, v, w = (p[..., 0] * M[i, 0] + p[..., 1] * M[i, 1] + p[..., 2] * M[i, 2] + b[i] for i in range(3))
    return resample.remap(image, u / w, v / w, cv2.BORDER_REPLICATE, interpolation="cubic")   # bicubic: keeps the detail
