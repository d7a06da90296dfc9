"""Image resampling that gives the same bytes on any x86-64 CPU.

OpenCV picks SSE4, AVX2 or AVX-512 code at run time, and its float paths (and ``warpAffine``'s
coordinate arithmetic) round differently on each, so a corpus rendered on one machine differed
from the same corpus rendered on another. Here the sampling positions are computed in float64 with
plain NumPy element-wise arithmetic (no BLAS, no fused multiply-add), turned into OpenCV's own
fixed-point map format (integer pixel + 1/32-pixel interpolation table index) by exact rounding,
and resampled by ``cv2.remap``'s integer-only 8-bit bilinear path.
"""
from __future__ import annotations

import cv2
import numpy as np

TABLE = cv2.INTER_TAB_SIZE                 # 32 sub-pixel positions per axis
SHIFT = TABLE.bit_length() - 1             # log2(TABLE)


def _positions_in_table_steps(coords) -> np.ndarray:
    """Positions (px) → int32 counts of 1/TABLE px, rounded half to even; NaN → far outside, ±inf clipped."""
    f = np.asarray(coords, np.float64) * TABLE
    np.nan_to_num(f, copy=False, nan=-1e6)
    np.clip(f, -32000 * TABLE, 32000 * TABLE, out=f)
    return np.rint(f).astype(np.int32)


def fixed_point_maps(map_x: np.ndarray, map_y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Float sampling positions (H, W) (source px) → OpenCV's (H, W, 2) int16 and (H, W) uint16 maps."""
    qx, qy = _positions_in_table_steps(map_x), _positions_in_table_steps(map_y)
    xy = np.stack([qx >> SHIFT, qy >> SHIFT], axis=-1).astype(np.int16)      # arithmetic shift: floor division
    frac = ((qy & (TABLE - 1)) * TABLE + (qx & (TABLE - 1))).astype(np.uint16)
    return xy, frac


def remap(image: np.ndarray, map_x: np.ndarray, map_y: np.ndarray, border_mode: int = cv2.BORDER_REPLICATE) -> np.ndarray:
    """Bilinear ``image[map_y, map_x]`` (uint8 image; maps (H, W) in source px), bit-exact across CPUs."""
    if image.dtype != np.uint8:
        raise TypeError(f"remap: expected a uint8 image, got {image.dtype}")
    xy, frac = fixed_point_maps(map_x, map_y)
    return cv2.remap(image, xy, frac, cv2.INTER_LINEAR, borderMode=border_mode)


def warp_affine(image: np.ndarray, matrix: np.ndarray, size: tuple[int, int],
                border_mode: int = cv2.BORDER_REFLECT) -> np.ndarray:
    """``cv2.warpAffine(image, matrix, size)`` (forward 2 × 3 ``matrix``: source → output px; size (W, H)),
    bilinear, bit-exact across CPUs."""
    m = np.asarray(matrix, np.float64)
    a, b, c, d = m[0, 0], m[0, 1], m[1, 0], m[1, 1]
    det = a * d - b * c
    ia, ib, ic, id_ = d / det, -b / det, -c / det, a / det            # the 2 × 2 inverse, explicitly
    w, h = size
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float64) - m[0, 2], np.arange(h, dtype=np.float64) - m[1, 2])
    return remap(image, ia * gx + ib * gy, ic * gx + id_ * gy, border_mode)
