"""Render a frontal texture back into a frame at the frame's pose (paper 000 §3.4.2, last line).

The inverse of the frontal warp: for each frame pixel near the face, intersect its viewing ray
with the extended face surface (the same geometry the texture was frontalized with) to find the
canonical point it sees, i.e. the texture pixel to sample. The ray intersection is solved on a
grid 4× coarser than the frame (the mapping is smooth) and the map is upsampled.
"""
from __future__ import annotations

import cv2
import numpy as np

from pipeline.face.geometry import project
from pipeline.face.canonical import Surface, TextureWindow, frontal_landmarks


def texture_footprint(points: np.ndarray, rvec, tvec, K: np.ndarray, frame_shape, margin: int = 4):
    """Bounding box (x0, y0, x1, y1) in frame pixels of the projected texture, clipped to the frame."""
    uv = project(points.reshape(-1, 3), rvec, tvec, K)
    h, w = frame_shape[:2]
    x0, y0 = np.floor(uv.min(0)).astype(int) - margin
    x1, y1 = np.ceil(uv.max(0)).astype(int) + margin
    return max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)


def inverse_map(box, surface: Surface, window: TextureWindow, rvec, tvec, K: np.ndarray,
                step: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Texture coordinates seen by every pixel of ``box`` = (x0, y0, x1, y1).

    Returns
    -------
    map_u, map_v : (y1 − y0, x1 − x0) float32 texture pixel coordinates (for cv2.remap).
    """
    x0, y0, x1, y1 = box
    xs = np.arange(x0, x1 + step, step, dtype=np.float64)
    ys = np.arange(y0, y1 + step, step, dtype=np.float64)
    gx, gy = np.meshgrid(xs, ys)
    pix = np.column_stack([gx.ravel(), gy.ravel()])
    # start from the inverse of the affine map texture-plane → frame fitted on the window corners
    c = window.size - 1
    corners_uv = np.array([[0, 0], [c, 0], [0, c], [c, c]], np.float64)
    corners_mm = window.to_mm(corners_uv)
    corners_px = project(np.column_stack([corners_mm, surface.z(corners_mm[:, 0], corners_mm[:, 1])]), rvec, tvec, K)
    A, _ = cv2.estimateAffine2D(corners_px, corners_mm)
    start = pix @ A[:, :2].T + A[:, 2]
    xy = frontal_landmarks(pix, start, surface, rvec, tvec, K, iterations=8)
    uv = window.to_pixels(xy).astype(np.float32).reshape(len(ys), len(xs), 2)
    return upsample_grid(uv, step, (y1 - y0, x1 - x0))


def upsample_grid(coarse: np.ndarray, step: int, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear interpolation of values sampled every ``step`` px (sample k at pixel k·step) to every
    pixel of ``shape`` = (h, w): (coarse (n, m, 2) float32) → two (h, w) float32 maps.

    Sample-aligned (pixel k·step gets sample k exactly). ``cv2.resize`` would not do: it aligns pixel
    *centres* of the two grids, which shifts the map by up to (1 − 1/step)/2 samples — 1.5 frame px at
    step 4 (measured: 0.7 texture px mean error on a 720p face)."""
    h, w = shape
    fx = np.broadcast_to(np.arange(w, dtype=np.float32) / step, (h, w))
    fy = np.broadcast_to((np.arange(h, dtype=np.float32) / step)[:, None], (h, w))
    full = cv2.remap(coarse, np.ascontiguousarray(fx), np.ascontiguousarray(fy), cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)
    return np.ascontiguousarray(full[..., 0]), np.ascontiguousarray(full[..., 1])


def render(texture: np.ndarray, map_u: np.ndarray, map_v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sample ``texture`` (T, T, C) at the maps; also return coverage (1 inside the texture, 0 outside).

    Returns (h, w, C) image and (h, w) float32 coverage with a 2-pixel soft edge.
    """
    T = texture.shape[0]
    img = cv2.remap(texture, map_u, map_v, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
    edge = np.minimum.reduce([map_u, map_v, T - 1 - map_u, T - 1 - map_v])
    return img, np.clip(edge / 2.0, 0.0, 1.0).astype(np.float32)
