"""synthesize.teeth — the teeth proxy of paper 000 §3.2.3 (Eq. 13–14) and the masks it needs.

The median texture of ``stages.synthesize.texture`` lacks the teeth's detail. Two real frames, an upper and a lower
teeth proxy (``pick_teeth_proxies``), lend theirs: in the median's teeth region (``teeth_mask``) the high frequencies
of each proxy are overlaid (``high_pass``, ``overlay``), the lower proxy moved with the jaw (``jaw_shift``).
Conventions (texture planes, ``lip_uv``, float intensities) are those of ``stages.synthesize.texture``.
"""
from __future__ import annotations

from typing import Callable

import cv2
import numpy as np

# lip_uv rows (dlib point − 48)
OUTER = np.arange(12)                    # 48–59
INNER = np.arange(12, 20)                # 60–67
INNER_LEFT, INNER_TOP, INNER_RIGHT, INNER_BOTTOM = 12, 14, 16, 18   # 60, 62, 64, 66
LOWER_LIP = np.array([8, 9, 10, 17, 18, 19])                        # 56–58, 65–67 (follow the jaw)


def _rgb(texture: np.ndarray) -> np.ndarray:
    """(T, T, 3) RGB as is; (3T/2, T) I420 (the frontalize store's format) → RGB."""
    return cv2.cvtColor(np.ascontiguousarray(texture), cv2.COLOR_YUV2RGB_I420) if texture.ndim == 2 else texture


def _lip20(lip_uv: np.ndarray) -> np.ndarray:
    """(68|20|18, 2) → (20, 2) float32 dlib points 48–67 (see module docstring)."""
    p = np.asarray(lip_uv, np.float32)
    if p.shape == (68, 2):
        return p[48:68]
    if p.shape == (20, 2):
        return p
    if p.shape == (18, 2):
        return np.concatenate([p[:12], p[[0]], p[12:15], p[[6]], p[15:18]])
    raise ValueError(f"lip points must be (68, 2), (20, 2) or (18, 2), got {p.shape}")


def _polygon(points: np.ndarray, shape: tuple, grow_px: int = 0) -> np.ndarray:
    """(H, W) uint8 0/1 filled polygon (1/16 px vertex precision), optionally dilated."""
    m = np.zeros(shape[:2], np.uint8)
    cv2.fillPoly(m, [np.round(np.asarray(points) * 16).astype(np.int32)], 1, cv2.LINE_8, shift=4)
    if grow_px > 0:
        m = cv2.dilate(m, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * grow_px + 1,) * 2))
    return m


def _feather(mask: np.ndarray, px: float) -> np.ndarray:
    """0/1 mask → float32 soft mask (Gaussian σ = px; exactly 0 beyond ~4σ)."""
    m = mask.astype(np.float32)
    return cv2.GaussianBlur(m, (0, 0), px) if px > 0 else m


def teeth_mask(texture_rgb: np.ndarray, lip_uv: np.ndarray, s_max: float = 0.45,
               v_min: float = 0.45) -> np.ndarray:
    """Teeth pixels (§3.2.3): saturation ≤ s_max and value ≥ v_min inside the inner lip.

    Parameters
    ----------
    texture_rgb : (H, W, 3) uint8 RGB.
    lip_uv : lip points (see module docstring); the polygon is the inner lip 60–67.
    s_max, v_min : HSV thresholds in [0, 1] (OpenCV's 8-bit S, V divided by 255).

    Returns
    -------
    (H, W) bool.
    """
    hsv = cv2.cvtColor(np.ascontiguousarray(texture_rgb), cv2.COLOR_RGB2HSV)
    inside = _polygon(_lip20(lip_uv)[INNER], hsv.shape).astype(bool)
    return inside & (hsv[..., 1] <= s_max * 255) & (hsv[..., 2] >= v_min * 255)


def upper_weight(lip_uv: np.ndarray, shape: tuple, ramp_px: float = 1.0) -> np.ndarray:
    """(H, W) float32: 1 above the mouth's split line, 0 below, linear over ``ramp_px``.

    The split line has the direction of the inner-corner line 60→64 and passes through the
    middle of the opening (midpoint of 62 and 66). On a symmetric mouth that is the corner
    line itself; on real footage the corners sit ~20 % of the opening above the middle (GRID),
    and the pure corner line would hand the upper teeth's lower edge to the lower proxy.
    """
    p = _lip20(lip_uv).astype(np.float64)
    d = p[INNER_RIGHT] - p[INNER_LEFT]
    nrm = np.array([-d[1], d[0]]) / max(np.hypot(*d), 1e-9)           # points down (v grows)
    mid = 0.5 * (p[INNER_TOP] + p[INNER_BOTTOM])
    v, u = np.mgrid[:shape[0], :shape[1]].astype(np.float32)
    dist = (u - mid[0]) * nrm[0] + (v - mid[1]) * nrm[1]
    return np.clip(0.5 - dist / ramp_px, 0, 1).astype(np.float32)


def jaw_shift(median_lip_uv: np.ndarray, proxy_lip_uv: np.ndarray) -> np.ndarray:
    """(Δu, Δv) px that moves the lower proxy onto the median's jaw: mean of the lower-lip
    points 56–58, 65–67 of the median minus those of the proxy. Positive Δv = median jaw lower."""
    return (_lip20(median_lip_uv)[LOWER_LIP].astype(np.float64).mean(0)
            - _lip20(proxy_lip_uv)[LOWER_LIP].astype(np.float64).mean(0))


def high_pass(T01: np.ndarray, sigma: float, strength: float) -> np.ndarray:
    """Eq. 13: H = (T − G_σ*T)·s + 0.5 clipped to [0, 1], per channel.

    T01 : (H, W[, C]) float in [0, 1]; sigma px; strength s. Returns float32 like T01.
    """
    t = np.asarray(T01, np.float32)
    blur = cv2.GaussianBlur(t, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    return np.clip((t - blur) * strength + 0.5, 0, 1)


def overlay(I01: np.ndarray, H: np.ndarray) -> np.ndarray:
    """Eq. 14 overlay blend: 2IH where H < 0.5, else 1 − 2(1 − I)(1 − H). Float32 in [0, 1]."""
    i = np.asarray(I01, np.float32)
    h = np.asarray(H, np.float32)
    return np.where(h < 0.5, 2 * i * h, 1 - 2 * (1 - i) * (1 - h))


def proxy_high_pass(proxy_rgb: np.ndarray, lip_uv: np.ndarray, sigmas=(1.0, 2.0, 4.0),
                    strength: float = 0.6,
                    feather_px: float = 1.0) -> np.ndarray:
    """(S, H, W, 3) float32 Eq. 13 high-passes of a proxy, one per σ, kept only inside the
    proxy's inner lip (grown 1 px, feathered; 0.5 = neutral elsewhere) so that lip edges of the
    proxy never reach the median's teeth."""
    t = np.asarray(proxy_rgb, np.float32) / 255.0
    gate = _feather(_polygon(_lip20(lip_uv)[INNER], t.shape, grow_px=1), feather_px)[..., None]
    return np.stack([0.5 + gate * (high_pass(t, s, strength) - 0.5) for s in sigmas])


def prepare_proxies(upper_rgb: np.ndarray, upper_lip_uv: np.ndarray, lower_rgb: np.ndarray,
                    lower_lip_uv: np.ndarray, sigmas=(1.0, 2.0, 4.0),
                    strength: float = 0.6,
                    feather_px: float = 1.0) -> dict:
    """Precompute the proxies' high-passes once per target video.

    Returns dict(upper=(S,H,W,3), lower=(S,H,W,3) float32, upper_lip_uv, lower_lip_uv (20,2)).
    """
    return dict(upper=proxy_high_pass(upper_rgb, upper_lip_uv, sigmas, strength, feather_px),
                lower=proxy_high_pass(lower_rgb, lower_lip_uv, sigmas, strength, feather_px),
                upper_lip_uv=_lip20(upper_lip_uv), lower_lip_uv=_lip20(lower_lip_uv))


def proxies_from_frames(get_texture: Callable, frontal_landmarks: np.ndarray, upper: int,
                        lower: int, **kw) -> dict:
    """``prepare_proxies`` from two frame indices; ``get_texture(indices)`` → (k, T, T, 3) RGB
    or (k, 3T/2, T) I420; ``kw``: sigmas, strength, feather_px."""
    up, lo = (_rgb(t) for t in get_texture(np.array([upper, lower])))
    return prepare_proxies(up, frontal_landmarks[upper], lo, frontal_landmarks[lower], **kw)


def _mouth_box(lip: np.ndarray, shape: tuple, margin: int) -> tuple[int, int, int, int]:
    """(u0, v0, u1, v1) bounding box of the outer lip grown by margin, clipped to the image."""
    lo = np.floor(lip[OUTER].min(0)).astype(int) - margin
    hi = np.ceil(lip[OUTER].max(0)).astype(int) + margin + 1
    return max(lo[0], 0), max(lo[1], 0), min(hi[0], shape[1]), min(hi[1], shape[0])


def apply_teeth_detail(median_rgb: np.ndarray, median_lip_uv: np.ndarray, proxies: dict | None,
                       jaw_shift_uv=None, s_max: float = 0.45,
                       v_min: float = 0.45, feather_px: float = 1.0,
                       unsharp_sigma: float = 1.0,
                       unsharp_amount: float = 0.5) -> np.ndarray:
    """Teeth enhancement with prepared proxies (see ``enhance_teeth``); proxies=None → only the
    unsharp masking. Only a box around the mouth is touched; every other pixel is returned as is.

    Returns (H, W, 3) uint8.
    """
    lip = _lip20(median_lip_uv)
    mouth_grow, mouth_feather = 2, 2.0 * max(feather_px, 0.5)
    margin = int(np.ceil(mouth_grow + 4 * mouth_feather + 4 * unsharp_sigma)) + 2
    u0, v0, u1, v1 = _mouth_box(lip, median_rgb.shape, margin)
    crop = median_rgb[v0:v1, u0:u1]
    lip_c = lip - np.float32([u0, v0])
    img = crop.astype(np.float32) / 255.0
    teeth = teeth_mask(crop, lip_c, s_max, v_min) if proxies is not None else None
    if teeth is not None and teeth.any():
        closed = cv2.morphologyEx(teeth.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
        soft = _feather(closed & _polygon(lip_c[INNER], crop.shape), feather_px)
        up = soft * upper_weight(lip_c, crop.shape)
        a_up, a_lo = up[..., None], (soft - up)[..., None]
        d = jaw_shift(lip, proxies["lower_lip_uv"]) if jaw_shift_uv is None else np.asarray(jaw_shift_uv)
        m = np.float32([[1, 0, u0 - d[0]], [0, 1, v0 - d[1]]])               # dst(p) = H(p − Δ)
        for h_up, h_lo in zip(proxies["upper"], proxies["lower"]):
            h_lo = cv2.warpAffine(h_lo, m, (u1 - u0, v1 - v0), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                  borderMode=cv2.BORDER_CONSTANT, borderValue=(0.5, 0.5, 0.5))
            img = overlay(img, 0.5 + a_up * (h_up[v0:v1, u0:u1] - 0.5) + a_lo * (h_lo - 0.5))
    if unsharp_amount > 0:
        mouth = _feather(_polygon(lip_c[OUTER], crop.shape, grow_px=mouth_grow), mouth_feather)[..., None]
        detail = img - cv2.GaussianBlur(img, (0, 0), unsharp_sigma, borderType=cv2.BORDER_REFLECT)
        img = img + (unsharp_amount * mouth) * detail
    out = median_rgb.copy()
    out[v0:v1, u0:u1] = np.clip(img * 255.0 + 0.5, 0, 255).astype(np.uint8)
    return out


def enhance_teeth(median_rgb: np.ndarray, median_lip_uv: np.ndarray, upper_proxy_rgb: np.ndarray,
                  upper_lip_uv: np.ndarray, lower_proxy_rgb: np.ndarray, lower_lip_uv: np.ndarray,
                  jaw_shift_uv=None, sigmas=(1.0, 2.0, 4.0), strength: float = 0.6,
                  unsharp_sigma: float = 1.0,
                  unsharp_amount: float = 0.5, s_max: float = 0.45,
                  v_min: float = 0.45, feather_px: float = 1.0) -> np.ndarray:
    """Teeth-proxy enhancement of a median texture (§3.2.3, Eq. 13–14) + unsharp masking.

    In the median's teeth region (``teeth_mask``, closed 3×3, feathered) the multi-scale
    high-pass of the upper proxy is overlaid above the split line (``upper_weight``) and that of
    the lower proxy, translated by the jaw offset, below it; one overlay per σ. Then
    I + a(I − G*I) inside the outer lip grown 2 px (feathered).

    Parameters
    ----------
    median_rgb : (T, T, 3) uint8 weighted-median texture.
    median_lip_uv : lip points of the median — the weight-averaged candidate landmarks
        (``weighted_lip_points``), not a detection on the blurry median.
    upper_proxy_rgb, lower_proxy_rgb : (T, T, 3) uint8 proxy frames; *_lip_uv their landmarks.
    jaw_shift_uv : (Δu, Δv) px moving the lower proxy onto the median's jaw; None →
        ``jaw_shift(median_lip_uv, lower_lip_uv)``.
    sigmas : Eq. 13 Gaussian σ's (px); strength : Eq. 13 s.
    unsharp_sigma (px), unsharp_amount : unsharp masking; amount 0 disables it.
    s_max, v_min : teeth thresholds (``teeth_mask``); feather_px : soft-border σ (px).

    Returns
    -------
    (T, T, 3) uint8; pixels farther than ~(2 + 8·feather + 4·unsharp_sigma) px from the outer
    lip are unchanged.
    """
    proxies = prepare_proxies(upper_proxy_rgb, upper_lip_uv, lower_proxy_rgb, lower_lip_uv,
                              sigmas, strength, feather_px)
    return apply_teeth_detail(median_rgb, median_lip_uv, proxies, jaw_shift_uv, s_max, v_min,
                              feather_px, unsharp_sigma, unsharp_amount)


def teeth_stats(texture_rgb: np.ndarray, lip_uv: np.ndarray, s_max: float = 0.45,
                v_min: float = 0.45) -> tuple[int, int, float]:
    """(upper teeth px, lower teeth px, variance of the grey Laplacian in the outer-lip box)."""
    lip = _lip20(lip_uv)
    teeth = teeth_mask(texture_rgb, lip, s_max, v_min)
    up = upper_weight(lip, teeth.shape) >= 0.5
    u0, v0, u1, v1 = _mouth_box(lip, teeth.shape, 1)
    grey = cv2.cvtColor(np.ascontiguousarray(texture_rgb[v0:v1, u0:u1]), cv2.COLOR_RGB2GRAY)
    return int((teeth & up).sum()), int((teeth & ~up).sum()), float(cv2.Laplacian(grey, cv2.CV_32F).var())


def pick_teeth_proxies(textures, frontal_landmarks: np.ndarray, valid: np.ndarray, yaw=None,
                       top_k: int = 64, yaw_scale: float = np.radians(10), s_max: float = 0.45,
                       v_min: float = 0.45, upper: int | None = None,
                       lower: int | None = None) -> tuple[int, int]:
    """Automatic choice of the upper- and lower-teeth proxy frames (the paper picks them by hand).

    Only the ``top_k`` valid frames with the largest inner-lip opening (66 − 62, v) are
    decoded. Each gets score = teeth area in its upper (resp. lower) half / max · sharpness
    (Laplacian variance in the mouth box) / max · opening / max · exp(−(yaw/yaw_scale)²).

    Parameters
    ----------
    textures : (N, T, T, 3) uint8 RGB array, or a callable indices → (k, T, T, 3) RGB or
        (k, 3T/2, T) I420 (called once, with sorted indices).
    frontal_landmarks : (N, 68, 2) px. valid : (N,) bool usable frames.
    yaw : optional (N,) head yaw, radians (0 = frontal); yaw_scale in radians.
    upper, lower : frame indices that override the automatic choice.

    Returns
    -------
    (upper_index, lower_index) ints into the N frames.
    """
    if upper is not None and lower is not None:
        return int(upper), int(lower)
    lm = np.asarray(frontal_landmarks, np.float32)
    ok = np.asarray(valid, bool) & np.isfinite(lm[:, 48:68]).all((1, 2))
    if not ok.any():
        raise ValueError("no valid frame to take a teeth proxy from")
    opening = np.where(ok, lm[:, 66, 1] - lm[:, 62, 1], -np.inf)
    k = min(int(top_k), int(ok.sum()))
    cand = np.sort(np.argpartition(-opening, k - 1)[:k])
    imgs = textures(cand) if callable(textures) else np.asarray(textures[cand])
    st = np.array([teeth_stats(_rgb(im), lm[i], s_max, v_min) for im, i in zip(imgs, cand)], np.float64)
    common = st[:, 2] / max(st[:, 2].max(), 1e-12) * np.clip(opening[cand], 0, None) / max(opening[cand].max(), 1e-12)
    if yaw is not None:
        common = common * np.exp(-(np.asarray(yaw, np.float64)[cand] / yaw_scale) ** 2)
    best = [int(cand[np.argmax(st[:, j] / max(st[:, j].max(), 1.0) * common)]) for j in (0, 1)]
    return (best[0] if upper is None else int(upper)), (best[1] if lower is None else int(lower))
