"""The speaker's whole-face frontal texture, for the dense 3D head (paper 001's product, issue 34).

The frontalize stage keeps only the lower face (``frontalize.texture_x_mm`` × ``texture_y_mm``: below
the eyes). The head needs eyes, brows and forehead too, so a wider window of the same canonical plane
(``HEAD_X_MM`` × ``HEAD_Y_MM``, on the same extended surface f*) is sampled from a few training frames
that look at the camera with the mouth closed, and their per-pixel median is the head's texture: a
still face whose lips are shut (the mesh opens them; the mouth cavity and teeth are geometry).

Canonical model coordinates are mm, x right, y down, origin between the outer eye corners
(``pipeline.face.canonical``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.face.canonical import Surface, sample_image

HEAD_X_MM = (-95.0, 95.0)          #: the head window: cheek to cheek (mm from the eye midpoint)
HEAD_Y_MM = (-75.0, 185.0)         #: forehead to below the chin (mm)
UPPER_LIP_INNER, LOWER_LIP_INNER = 62, 66


@dataclass
class HeadWindow:
    """A rectangular window of the canonical plane: pixel (u, v) ↔ (x0 + u·mm_per_px, y0 + v·mm_per_px) mm."""

    x0: float
    y0: float
    mm_per_px: float
    width: int
    height: int

    @classmethod
    def covering(cls, mm_per_px: float, x_mm=HEAD_X_MM, y_mm=HEAD_Y_MM) -> "HeadWindow":
        return cls(float(x_mm[0]), float(y_mm[0]), float(mm_per_px),
                   int(round((x_mm[1] - x_mm[0]) / mm_per_px)), int(round((y_mm[1] - y_mm[0]) / mm_per_px)))

    def grid_points(self, surface: Surface) -> np.ndarray:
        """(height, width, 3) model points (mm) of every pixel, on the surface."""
        gx, gy = np.meshgrid(self.x0 + self.mm_per_px * np.arange(self.width),
                             self.y0 + self.mm_per_px * np.arange(self.height))
        return np.stack([gx, gy, surface.z(gx, gy)], axis=-1)

    def to_uv(self, xy_mm: np.ndarray) -> np.ndarray:
        """(..., 2) mm → texture coordinates in [0, 1] (u right, v up: OpenGL's convention)."""
        u = (xy_mm[..., 0] - self.x0) / (self.mm_per_px * self.width)
        v = 1.0 - (xy_mm[..., 1] - self.y0) / (self.mm_per_px * self.height)
        return np.stack([u, v], axis=-1)

    def as_array(self) -> np.ndarray:
        return np.array([self.x0, self.y0, self.mm_per_px, self.width, self.height], np.float64)

    @classmethod
    def from_array(cls, a) -> "HeadWindow":
        return cls(float(a[0]), float(a[1]), float(a[2]), int(a[3]), int(a[4]))


def pick_still_frames(rvecs: np.ndarray, landmarks_mm: np.ndarray, n: int = 41) -> np.ndarray:
    """Indices of up to ``n`` frames that face the camera with the mouth shut, spread over the input.

    Parameters
    ----------
    rvecs : ndarray
        (F, 3) head rotations (Rodrigues, rad) in the canonical frame: |rvec| is the turn from frontal.
    landmarks_mm : ndarray
        (F, 68, 2) frontal landmarks (mm).
    n : int
        The most frames returned.

    Returns
    -------
    ndarray
        (k,) int, increasing: the frames within the 40 % least turned and the 30 % least open.
    """
    turn = np.linalg.norm(rvecs, axis=1)
    opening = landmarks_mm[:, LOWER_LIP_INNER, 1] - landmarks_mm[:, UPPER_LIP_INNER, 1]
    ok = np.flatnonzero((turn <= np.quantile(turn, 0.4)) & (opening <= np.quantile(opening, 0.3)))
    if not len(ok):                 # ties at the quantiles can empty the intersection: least open of all
        ok = np.argsort(opening)[:n]
    return np.sort(ok[np.unique(np.linspace(0, len(ok) - 1, min(n, len(ok))).round().astype(int))])


def head_texture(images: list[np.ndarray], poses: np.ndarray, Ks: list[np.ndarray], crops: list, surface: Surface,
                 window: HeadWindow) -> np.ndarray:
    """Per-pixel median of the frames' frontal warps over the head window.

    Parameters
    ----------
    images : list of ndarray
        F RGB uint8 images (frames or ingest crops of them).
    poses : ndarray
        (F, 6) [rvec, tvec] of each frame (mm model → camera).
    Ks : list of ndarray
        F (3, 3) intrinsics (source-frame px).
    crops : list
        F (x0, y0, s) image-from-frame maps.
    surface : Surface
        The extended face surface f* (mm).
    window : HeadWindow
        The texture's window on the canonical plane.

    Returns
    -------
    ndarray
        (window.height, window.width, 3) uint8 RGB.
    """
    points = window.grid_points(surface)
    warps = np.stack([sample_image(im, points, p[:3], p[3:], K, c) for im, p, K, c in zip(images, poses, Ks, crops)])
    return np.median(warps, axis=0).round().astype(np.uint8)


def turned_view_texture(texture: np.ndarray, vertices: np.ndarray, triangles: np.ndarray, uv: np.ndarray,
                        yaw_deg: float, sharp: float = 0.6, flat: float = 0.35, sigma_mm: float = 5.0) -> np.ndarray:
    """The head texture for a view turned ``yaw_deg`` about the vertical axis: fine detail faded where that view
    squeezes the skin.

    The texture is a frontal capture; a turned view compresses the far side of the face across by
    ρ = cos(yaw) + ∂z/∂x · sin(yaw) (orthographic; ≈ 0.25 beside the nose and mouth at 35°). A smile line
    or a photo's highlight there becomes a thin hard streak, while on a real face that part of the far cheek
    hides behind the nose and the cheek's bulge. So where ρ < ``sharp`` the texture fades towards its own
    Gaussian blur (``sigma_mm``, within the skin only, so no backdrop bleeds in), fully at ρ ≤ ``flat``;
    elsewhere, and outside the skin, it is unchanged. Colours stay the person's own (no mirroring: the
    frontal capture's near side holds the same fold, and the photo's light makes the sides differ).

    Parameters
    ----------
    texture : ndarray
        (H, W, 3) uint8, the head texture (row 0 at v = 1).
    vertices, triangles, uv : ndarray
        The rest skin: (N, 3) mm (a height field z(x, y)), (F, 3), (N, 2) texture coordinates.
    yaw_deg : float
        The view's turn (positive: the camera to the face's +x side; its −x side is squeezed).

    Returns
    -------
    ndarray
        (H, W, 3) uint8.
    """
    from scipy.ndimage import gaussian_filter
    from scipy.spatial import cKDTree
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    face_n = np.cross(b - a, c - a)                                       # area-weighted normals
    n = np.zeros_like(vertices, dtype=np.float64)
    for k in range(3):
        np.add.at(n, triangles[:, k], face_n)
    dzdx = -n[:, 0] / np.where(np.abs(n[:, 2]) > 1e-12, n[:, 2], 1e-12)    # the plane z = f(x, y): n ∝ (−f_x, −f_y, 1)
    yaw = np.radians(yaw_deg)
    rho = np.cos(yaw) + dzdx * np.sin(yaw)
    weight = np.clip((sharp - rho) / (sharp - flat), 0.0, 1.0)
    H, W = texture.shape[:2]
    px = np.column_stack([uv[:, 0] * W, (1.0 - uv[:, 1]) * H])          # texel (col, row) of each vertex
    cols, rows = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    edge = np.median(np.linalg.norm(px[triangles[:, 1]] - px[triangles[:, 0]], axis=1))    # texels
    d, i = cKDTree(px).query(np.column_stack([cols.ravel(), rows.ravel()]), k=4)      # inverse-distance weights
    idw = 1.0 / np.maximum(d, 1e-6)
    w = ((weight[i] * idw).sum(1) / idw.sum(1)).reshape(H, W)
    skin = (d[:, 0] <= edge).reshape(H, W).astype(np.float64)                        # texels on the mesh
    mm_per_texel = np.ptp(vertices[:, 0]) / max(np.ptp(px[:, 0]), 1e-9)
    s = sigma_mm / mm_per_texel
    tex = texture.astype(np.float64)
    blur = gaussian_filter(tex * skin[..., None], (s, s, 0)) / np.maximum(gaussian_filter(skin, s), 1e-6)[..., None]
    w = (w * skin)[..., None]
    return np.clip(tex * (1.0 - w) + blur * w, 0, 255).round().astype(np.uint8)
