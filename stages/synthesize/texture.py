"""synthesize.texture — lower-face texture from a mouth shape (paper 000 §3.2.1–3.2.3).

Per output frame: the n target frames whose 18 lip points are nearest to the wanted shape
(§3.2.1) → σ such that those n carry α of the weight of all frames (Eq. 12) → Gaussian
weights (Eq. 11) → per-pixel, per-channel weighted median of their frontal textures
(Eq. 9–10) → high frequencies of two fixed teeth-proxy frames overlaid in the median's teeth
region, the lower proxy moved with the jaw (Eq. 13–14) → unsharp masking of the mouth.

Conventions
-----------
* Textures are (T, T, 3) RGB uint8 in the frontal texture plane (``pipeline.io.store.i420_to_rgb``
  of the ``frontalize`` store), landmarks are in the same texture pixels (u right, v down).
  Texture getters (``synthesize_texture``, ``pick_teeth_proxies``, ``proxies_from_frames``) may
  also return the store's (3T/2, T) I420 directly.
* ``lip_uv`` arguments are the dlib lip points 48–67 as a (20, 2) array, or a full (68, 2)
  landmark array, or the 18 ``LIP_POINTS`` of ``stages.pca.pca`` (48–59, 61–63, 65–67), in which
  case the missing inner corners 60/64 are taken as the outer corners 48/54.
* Intensities inside the teeth code are float32 in [0, 1]; everything returned is uint8.
"""
from __future__ import annotations

import time
from typing import Callable

import cv2
import numpy as np

from stages.synthesize.teeth import _rgb, apply_teeth_detail


# Keyword defaults below equal params.yaml's ``synthesize`` section (n, alpha, teeth_*, unsharp_*),
# which the stage always passes: sigmas (1, 2, 4) px at T = 128 (single teeth, teeth rows, the
# teeth band), strength 0.6 (Eq. 13 s per scale), s_max = v_min = 0.45 (HSV teeth thresholds:
# GRID's compressed teeth reach S ≈ 0.43; the dark cavity has V ≲ 0.42), feather 1 px, unsharp
# σ 1 px and amount 0.5.


# ----------------------------------------------------------------------------- candidates, σ, weights

def select_candidates(target: np.ndarray, shapes: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The n frames whose mouth shape is nearest to ``target`` (§3.2.1).

    Parameters
    ----------
    target : (18, 2) or (36,) lip points of the wanted shape, texture px.
    shapes : (M, 18, 2) or (M, 36) lip points of every usable target frame (finite), texture px.
    n : number of candidates (clipped to M).

    Returns
    -------
    idx : (n,) int rows of ``shapes``, nearest first.
    d2 : (M,) float64 squared L2 distance ‖S_i − S_target‖² of every frame, px².
    """
    s = np.asarray(shapes)
    s = s.reshape(len(s), -1).astype(np.result_type(s.dtype, np.float32), copy=False)
    t = np.asarray(target, s.dtype).reshape(-1)
    if s.shape[1] != t.size:
        raise ValueError(f"target has {t.size} values, shapes have {s.shape[1]}")
    diff = s - t
    d2 = np.einsum("ij,ij->i", diff, diff).astype(np.float64)
    n = min(int(n), len(d2))
    idx = np.argpartition(d2, n - 1)[:n]
    return idx[np.argsort(d2[idx], kind="stable")], d2


def candidate_share(d2: np.ndarray, idx: np.ndarray, sigma: float) -> float:
    """Σ_candidates w_i / Σ_all w_i for Eq. 11 weights (left/right ratio of Eq. 12), in [0, 1]."""
    x = np.asarray(d2, np.float64)
    e = np.exp(-(x - x.min()) / (2.0 * sigma ** 2))
    return float(e[idx].sum() / e.sum())


def solve_sigma(d2: np.ndarray, idx: np.ndarray, alpha: float = 0.9, tol: float = 1e-4,
                max_iter: int = 100) -> float:
    """σ (px) at which the candidates carry ``alpha`` of the total weight (Eq. 12).

    Bisection on t = log σ². The share is monotone in σ (every candidate is at least as near
    as every other frame), from ~1 at σ→0 down to n/M at σ→∞. Weights are computed with the
    minimum d2 subtracted (the share is invariant to it), so zeros and huge distances are safe.

    Parameters
    ----------
    d2 : (M,) squared distances of all usable frames (px²), finite.
    idx : (n,) candidate rows (the n smallest d2).
    alpha : wanted candidate share, (0, 1).
    tol : stop when |share − alpha| ≤ tol.

    Returns
    -------
    sigma : float, px. Achieved tolerance: |candidate_share(d2, idx, σ) − α| ≤ tol whenever α
        is reachable. Otherwise the bracket end is returned: the small end (share ≈
        #candidates tied at the minimum / #all frames tied there, < α) or the large end
        (α ≤ n/M, e.g. n = M: every frame is a candidate). All d2 equal → 1.0 (weights uniform).
    """
    x = np.asarray(d2, np.float64)
    x = x - x.min()
    cand = np.zeros(len(x), bool)
    cand[idx] = True
    xc, xo = x[cand], x[~cand]
    pos = x[(x > 0) & np.isfinite(x)]
    if pos.size == 0:
        return 1.0
    lo, hi = np.log(pos.min() / 1400.0), np.log(pos.max() * 5e5)   # exp(−x/2σ²): ~e^−700 … ~1

    def share(t):
        k = 0.5 * np.exp(-t)
        c = np.exp(-xc * k).sum()
        return c / (c + np.exp(-xo * k).sum())

    if share(lo) < alpha:
        return float(np.exp(0.5 * lo))
    if share(hi) > alpha:
        return float(np.exp(0.5 * hi))
    mid = 0.5 * (lo + hi)
    for _ in range(max_iter):
        mid = 0.5 * (lo + hi)
        s = share(mid)
        if abs(s - alpha) <= tol:
            break
        lo, hi = (mid, hi) if s > alpha else (lo, mid)
    return float(np.exp(0.5 * mid))


def weights(d2_candidates: np.ndarray, sigma: float) -> np.ndarray:
    """Eq. 11 weights exp(−d²/2σ²) of the candidates, normalised to sum 1 → (n,) float64."""
    x = np.asarray(d2_candidates, np.float64)
    w = np.exp(-(x - x.min()) / (2.0 * float(sigma) ** 2))
    return w / w.sum()


def weighted_lip_points(candidate_lip_points: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weight-averaged landmarks of the candidates (§3.2.3: a smooth jaw/lip position).

    candidate_lip_points : (n, P, 2) px (any point set, e.g. the 20 lip points or all 68);
    w : (n,) weights (normalised here). Returns (P, 2) float64 px.
    """
    w = np.asarray(w, np.float64)
    return np.tensordot(w / w.sum(), np.asarray(candidate_lip_points, np.float64), axes=1)


# ----------------------------------------------------------------------------- weighted median

def weighted_median(images: np.ndarray, w: np.ndarray, block: int = 8192) -> np.ndarray:
    """Per-pixel, per-channel weighted median (Eq. 9–10).

    For every value position the candidate values are sorted and the result is the first value
    at which the cumulative weight reaches half the total (so it is always one of the inputs;
    an exact half picks the lower value). Sorting uses 32-bit keys value·256 + candidate along
    contiguous rows (SIMD sort), ``block`` values at a time to stay in cache.

    Parameters
    ----------
    images : (n, ...) uint8, n ≤ 256 — e.g. (n, H, W, 3) RGB, or (n, 3H/2, W) I420.
    w : (n,) non-negative weights, positive sum (need not be normalised).

    Returns
    -------
    (...) uint8, the shape of one image.
    """
    images = np.asarray(images)
    n = len(images)
    w = np.asarray(w, np.float64)
    if images.dtype != np.uint8 or not 1 <= n <= 256 or w.shape != (n,):
        raise ValueError(f"need (n ≤ 256, …) uint8 images and (n,) weights, got {images.shape} "
                         f"{images.dtype}, {w.shape}")
    if np.any(w < 0) or not w.sum() > 0:
        raise ValueError("weights must be non-negative with a positive sum")
    if n == 1:
        return images[0].copy()
    x = np.ascontiguousarray(images.reshape(n, -1))
    lut = np.zeros(256, np.float32)
    lut[:n] = w / w.sum()
    out = np.concatenate([_median_block(x[:, s:s + block], lut) for s in range(0, x.shape[1], block)])
    return out.reshape(images.shape[1:])


def _median_block(x: np.ndarray, lut: np.ndarray) -> np.ndarray:
    """(n, P) uint8 values, lut[:n] = normalised weights → (P,) uint8 weighted medians."""
    n = len(x)
    # 32-bit keys: numpy's SIMD sort (x86-simd-sort) has 16-bit kernels only with AVX-512, 32-bit
    # ones with AVX2 too — 6–12× faster on CPUs without AVX-512, the same order everywhere
    keys = np.left_shift(cv2.transpose(x), 8, dtype=np.int32)              # (P, n)
    keys |= np.arange(n, dtype=np.int32)
    keys.sort(axis=1)
    keys = cv2.transpose(keys)                                              # (n, P) sorted by value
    wsorted = cv2.LUT(keys.astype(np.uint8), lut)           # low byte = candidate → (n, P) weights
    acc = np.zeros(keys.shape[1], np.float32)
    below = np.zeros(keys.shape[1], np.uint8)                               # values before the median
    half = np.float32(0.5) * lut.sum(dtype=np.float32)
    for row in wsorted[:-1]:
        acc += row
        below += acc < half
    return (np.take_along_axis(keys, below[None].astype(np.intp), 0)[0] >> 8).astype(np.uint8)


def candidate_search(target_shape: np.ndarray, shapes: np.ndarray, n: int = 50, alpha: float = 0.9) -> dict:
    """§3.2.1 and Eq. 12 for one frame: indices (n,) nearest first, their squared distances d2 (n,),
    σ (px) and the achieved share; ``all_d2`` (M,) the distance of every frame (the Viterbi of
    ``synthesize.detail: two_band`` reads it)."""
    idx, d2 = select_candidates(target_shape, shapes, n)
    sigma = solve_sigma(d2, idx, alpha)
    return dict(indices=idx, d2=d2[idx], sigma=sigma, share=candidate_share(d2, idx, sigma), all_d2=d2)


# ----------------------------------------------------------------------------- one frame

def synthesize_texture(target_shape: np.ndarray, shapes: np.ndarray, get_texture: Callable,
                       frontal_landmarks: np.ndarray, n: int = 50,
                       alpha: float = 0.9, proxies: dict | None = None,
                       params: dict | None = None, search: dict | None = None,
                       size: int | None = None) -> tuple[np.ndarray, dict]:
    """One output texture from one mouth shape (§3.2): candidates → σ → weights → weighted
    median → teeth enhancement + unsharp masking.

    Parameters
    ----------
    target_shape : (18, 2) or (36,) wanted lip points (``LIP_POINTS`` order), texture px.
    shapes : (M, 18, 2) lip points of the usable target frames (finite).
    get_texture : indices (n,) int rows of ``shapes`` → (n, T, T, 3) uint8 RGB, or (n, 3T/2, T)
        uint8 I420 as stored by frontalize (no per-candidate conversion, half the median's
        work; the median is then taken per Y/U/V plane instead of per R/G/B). Called once per
        frame with the candidates nearest first (sort them inside if the store prefers).
    frontal_landmarks : (M, 68, 2) px, same rows as ``shapes``.
    n, alpha : candidates and Eq. 12 α.
    proxies : ``prepare_proxies`` / ``proxies_from_frames`` output, or None (no teeth proxy;
        unsharp masking only).
    params : overrides of s_max, v_min, feather_px, unsharp_sigma, unsharp_amount
        (sigmas/strength live in ``proxies``).
    search : this frame's ``candidate_search`` when the caller has it already (it is not repeated).
    size : texture px T of ``frontal_landmarks`` and of the result, when ``get_texture`` returns smaller
        textures (``synthesize.median_max_size``): the median is upsampled (bicubic) to it before the teeth
        and the unsharp mask. None: the textures' own size.

    Returns
    -------
    rgb : (T, T, 3) uint8.
    info : dict(indices (n,), weights (n,), sigma px, share (achieved Eq. 12 ratio),
        landmarks (68, 2) weight-averaged candidate landmarks, lip_points (20, 2) = its 48–67,
        seconds: wall time of candidate_search (incl. σ), weighted_median, teeth (incl. unsharp)).
    """
    p = dict(s_max=0.45, v_min=0.45, feather_px=1.0, unsharp_sigma=1.0, unsharp_amount=0.5)
    unknown = set(params or {}) - set(p)
    if unknown:
        raise ValueError(f"synthesize_texture params: unknown {sorted(unknown)} (sigmas/strength go to prepare_proxies)")
    p.update(params or {})
    t0 = time.perf_counter()
    s = search if search is not None else candidate_search(target_shape, shapes, n, alpha)
    idx, sigma = s["indices"], s["sigma"]
    w = weights(s["d2"], sigma)
    t1 = time.perf_counter()
    median = _rgb(weighted_median(get_texture(idx), w))
    if size is not None and median.shape[0] != size:
        median = cv2.resize(median, (size, size), interpolation=cv2.INTER_CUBIC)
    t2 = time.perf_counter()
    lm = weighted_lip_points(np.asarray(frontal_landmarks)[idx], w)
    rgb = apply_teeth_detail(median, lm[48:68], proxies, None, p["s_max"], p["v_min"], p["feather_px"],
                             p["unsharp_sigma"], p["unsharp_amount"])
    t3 = time.perf_counter()
    info = dict(indices=idx, weights=w, sigma=sigma, share=s["share"],
                landmarks=lm, lip_points=lm[48:68],
                seconds=dict(candidate_search=t1 - t0, weighted_median=t2 - t1, teeth=t3 - t2))
    return rgb, info
