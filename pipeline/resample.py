"""Image resampling that gives the same bytes on any x86-64 CPU.

OpenCV picks SSE4, AVX2 or AVX-512 code at run time, and its float paths (and ``warpAffine``'s
coordinate arithmetic) round differently on each, so a corpus rendered on one machine differed
from the same corpus rendered on another. Here the sampling positions are computed in float64 with
plain NumPy element-wise arithmetic (no BLAS, no fused multiply-add), turned into OpenCV's own
fixed-point map format (integer pixel + 1/32-pixel interpolation table index) by exact rounding,
and resampled in integer arithmetic: bilinear by ``cv2.remap``'s integer-only 8-bit path, or bicubic
(Keys' a = −0.75, written out in NumPy: OpenCV's own rounds differently with and without AVX2) where
detail must survive — a bilinear sample between pixels averages its neighbours, so each bilinear
resampling of a face at its own scale removes about 30 % of the mouth's Laplacian variance, a bicubic
one about 6 % (GRID s4 frames, random sub-pixel offsets).
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


CUBIC_A = -0.75                            # Keys' cubic convolution parameter (OpenCV's INTER_CUBIC)
CUBIC_BITS = 11                            # tap weights in 1/2048: two passes stay inside int32


def _cubic_table() -> np.ndarray:
    """(TABLE, 4) int32 Keys weights of the taps at −1, 0, 1, 2 for each 1/TABLE px offset; each row sums to
    2**CUBIC_BITS exactly. Python float arithmetic on fixed constants: the same table on any CPU."""
    rows = []
    for i in range(TABLE):
        t, a = i / TABLE, CUBIC_A
        w = [((a * (t + 1) - 5 * a) * (t + 1) + 8 * a) * (t + 1) - 4 * a,
             ((a + 2) * t - (a + 3)) * t * t + 1,
             ((a + 2) * (1 - t) - (a + 3)) * (1 - t) * (1 - t) + 1]
        q = [round(x * (1 << CUBIC_BITS)) for x in w]
        rows.append(q + [(1 << CUBIC_BITS) - sum(q)])
    return np.array(rows, np.int32)


CUBIC_TABLE = _cubic_table()


def _taps(q: np.ndarray, n: int, border_mode: int) -> tuple[np.ndarray, np.ndarray]:
    """Positions in 1/TABLE px (int32) along an axis of length n → (4, …) source indices and weights."""
    base = (q >> SHIFT) - 1
    idx = np.stack([base + k for k in range(4)])
    if border_mode == cv2.BORDER_REPLICATE:
        idx = np.clip(idx, 0, n - 1)
    elif border_mode == cv2.BORDER_REFLECT:            # fedcba|abcdefgh|hgfedcb
        period = 2 * n
        idx = np.mod(idx, period)
        idx = np.where(idx >= n, period - 1 - idx, idx)
    else:
        raise ValueError(f"remap: cubic supports BORDER_REPLICATE and BORDER_REFLECT, got border mode {border_mode}")
    w = np.moveaxis(CUBIC_TABLE[q & (TABLE - 1)], -1, 0)
    return idx, w


def _round_cubic(acc: np.ndarray) -> np.ndarray:
    half = 1 << (2 * CUBIC_BITS - 1)
    return np.clip((acc + half) >> (2 * CUBIC_BITS), 0, 255).astype(np.uint8)


def remap_cubic(image: np.ndarray, map_x: np.ndarray, map_y: np.ndarray,
                border_mode: int = cv2.BORDER_REPLICATE) -> np.ndarray:
    """Bicubic ``image[map_y, map_x]`` in integer arithmetic: bit-exact on any CPU.

    OpenCV's own 8-bit bicubic path rounds differently with and without AVX2, so this one is
    written out: positions rounded to 1/32 px as in ``fixed_point_maps``, 4 × 4 Keys taps with weights
    in 1/2048 (rows summing exactly to 1), the sum formed in int32 (integer sums do not depend on
    their order) and rounded half up once.

    Parameters
    ----------
    image : ndarray
        (h, w) or (h, w, C) uint8.
    map_x, map_y : ndarray
        (H, W) float source positions (px); NaN lands outside and takes the border.
    border_mode : int
        ``cv2.BORDER_REPLICATE`` or ``cv2.BORDER_REFLECT``.

    Returns
    -------
    ndarray
        (H, W) or (H, W, C) uint8.
    """
    qx, qy = _positions_in_table_steps(map_x), _positions_in_table_steps(map_y)
    cols, wx = _taps(qx, image.shape[1], border_mode)
    rows, wy = _taps(qy, image.shape[0], border_mode)
    flat = image.reshape(image.shape[0] * image.shape[1], -1)
    extra = (None,) * (image.ndim - 2)
    acc = np.zeros(qx.shape + image.shape[2:], np.int32)
    row = np.empty_like(acc)
    for i in range(4):
        offset = rows[i] * image.shape[1]
        row[...] = 0
        for j in range(4):
            row += wx[j][(...,) + extra] * flat.take(offset + cols[j], axis=0).reshape(acc.shape)
        acc += wy[i][(...,) + extra] * row
    return _round_cubic(acc)


def sample_grid_cubic(image: np.ndarray, xs: np.ndarray, ys: np.ndarray,
                      border_mode: int = cv2.BORDER_REPLICATE) -> np.ndarray:
    """``remap_cubic`` on the axis-aligned grid ``image[ys[:, None], xs[None, :]]``, in two 1-D passes.

    Parameters
    ----------
    image : ndarray
        (h, w) or (h, w, C) uint8.
    xs, ys : ndarray
        (W,) and (H,) float source positions (px).
    border_mode : int
        ``cv2.BORDER_REPLICATE`` or ``cv2.BORDER_REFLECT``.

    Returns
    -------
    ndarray
        (H, W) or (H, W, C) uint8, the same bytes as ``remap_cubic`` with the broadcast maps.
    """
    cols, wx = _taps(_positions_in_table_steps(xs), image.shape[1], border_mode)
    rows, wy = _taps(_positions_in_table_steps(ys), image.shape[0], border_mode)
    used, where = np.unique(rows, return_inverse=True)          # only the rows the output needs
    src = image[used]
    extra = (None,) * (image.ndim - 2)
    across = np.zeros((len(used), len(xs)) + image.shape[2:], np.int32)
    for j in range(4):
        across += wx[j][(None, slice(None)) + extra] * src[:, cols[j]]
    acc = np.zeros((len(ys), len(xs)) + image.shape[2:], np.int32)
    where = where.reshape(rows.shape)
    for i in range(4):
        acc += wy[i][(slice(None), None) + extra] * across[where[i]]
    return _round_cubic(acc)


def remap(image: np.ndarray, map_x: np.ndarray, map_y: np.ndarray, border_mode: int = cv2.BORDER_REPLICATE,
          interpolation: str = "linear") -> np.ndarray:
    """``image[map_y, map_x]`` (uint8 image; maps (H, W) in source px), bit-exact across CPUs.

    ``interpolation``: "linear" (2 × 2 neighbours, OpenCV's fixed-point path) or "cubic" (4 × 4,
    sharper: ``remap_cubic``)."""
    if image.dtype != np.uint8:
        raise TypeError(f"remap: expected a uint8 image, got {image.dtype}")
    if interpolation == "cubic":
        return remap_cubic(image, map_x, map_y, border_mode)
    if interpolation != "linear":
        raise ValueError(f"remap: interpolation must be 'linear' or 'cubic', got {interpolation!r}")
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
