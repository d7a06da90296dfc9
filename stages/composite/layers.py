"""Jaw correction (§3.4.1) and the four compositing layers (§3.4.2), in the canonical texture.

Layers, front to back: 1) the synthesized lower face above the chin, 2) the target's torso /
shirt, 3) the synthesized neck below the chin, 4) the rest of the target frame. With two
sources (synthesized texture, target frame) this is one alpha for the synthesized texture:
a = M1 + (1 − M1)(1 − M2) M3. The chin is a spline through the jaw-contour landmarks.
"""
from __future__ import annotations

import cv2
import numpy as np
from scipy.interpolate import CubicSpline

from pipeline.video.flow import flow_at_most

CHIN = list(range(2, 15))           # jaw-contour landmarks used for the chin spline


def chin_spline(jaw_uv: np.ndarray, samples: int = 64) -> np.ndarray:
    """Cubic spline through jaw points (k, 2) in texture pixels, parametrised by chord length → (samples, 2)."""
    d = np.r_[0, np.cumsum(np.linalg.norm(np.diff(jaw_uv, axis=0), axis=1))]
    keep = np.r_[True, np.diff(d) > 1e-6]
    cs = CubicSpline(d[keep], jaw_uv[keep], axis=0)
    return cs(np.linspace(0, d[-1], samples))


def _fill(poly: np.ndarray, size: int) -> np.ndarray:
    m = np.zeros((size, size), np.uint8)
    cv2.fillPoly(m, [np.round(poly * 16).astype(np.int32)], 1, shift=4)
    return m.astype(np.float32)


def layer_masks(landmarks_uv: np.ndarray, size: int, feather: float, overlap: float = 3.0,
                neck_depth: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """Mouth-region (above the chin) and neck (below it) masks, (T, T) float32 in [0, 1].

    The mouth region is bounded by the chin spline and a line at the height of the nose tip
    (landmark 30), so cheeks, mouth, chin are replaced and the eyes/nose never are; the neck
    runs from ``overlap`` px above the chin down by ``neck_depth`` × the nose-to-chin height
    (fading out over its lower third), as wide as the middle half of the chin spline. The overlap keeps a = M1 + (1 − M1)(1 − M2) M3 at 1 across the feathered chin
    (two masks feathered at the same edge would leave a dark seam along the jawline).
    """
    spline = chin_spline(landmarks_uv[CHIN])
    top = landmarks_uv[30, 1]
    mouth_poly = np.vstack([spline, [[spline[-1, 0], top], [spline[0, 0], top]]])
    mouth = _fill(mouth_poly, size)
    n = len(spline)
    low = spline[n // 4:n - n // 4] - [0.0, overlap]    # the chin, between jaw points ≈5 and ≈11: the neck's width
    depth = neck_depth * (spline[:, 1].max() - top)      # the neck only matters just below the moving chin
    bottom = low[:, 1].max() + depth
    neck_poly = np.vstack([low, [[low[-1, 0], bottom], [low[0, 0], bottom]]])
    neck = _fill(neck_poly, size)
    fade = np.clip((bottom - np.arange(size, dtype=np.float32)) / max(depth / 3, 1.0), 0, 1)
    neck *= fade[:, None]                                # fade out over the lower third of its depth
    k = max(1, int(2 * round(feather) + 1))
    blur = lambda m: cv2.GaussianBlur(m, (k * 2 + 1, k * 2 + 1), feather)
    return blur(mouth), blur(neck)


def synth_alpha(mouth: np.ndarray, neck: np.ndarray, shirt: np.ndarray) -> np.ndarray:
    """Alpha of the synthesized texture over the target: a = M1 + (1 − M1)(1 − M2) M3."""
    return np.clip(mouth + (1 - mouth) * (1 - shirt) * neck, 0.0, 1.0)


def jaw_band(landmarks_uv: np.ndarray, size: int, width: float) -> np.ndarray:
    """Alpha map around the jawline (Fig. 7e): 1 on the chin spline, fading over ``width`` px."""
    m = np.zeros((size, size), np.uint8)
    cv2.polylines(m, [np.round(chin_spline(landmarks_uv[CHIN]) * 16).astype(np.int32)], False, 255,
                  thickness=1, shift=4)
    dist = cv2.distanceTransform(255 - m, cv2.DIST_L2, 3)
    return np.exp(-0.5 * (dist / width) ** 2).astype(np.float32)


def jaw_correction(synth_rgb: np.ndarray, target_rgb: np.ndarray, band: np.ndarray,
                   flow_max: int = 128) -> np.ndarray:
    """Warp the synthesized texture so its jawline meets the target's (§3.4.1, Fig. 7).

    Dense optical flow (DIS) from the target texture to the synthesized one gives, for every
    target pixel p, where its content sits in the synthesized texture (p + f(p)); the flow is
    masked by the jaw band and the synthesized texture is resampled at p + band(p)·f(p).
    Textures larger than ``flow_max`` px get the flow of their area-averaged copies at that size,
    upsampled: the jaw's misfit is a smooth shift of a few texture px — the scale the band and the
    flow's patches are set at (T = 128, where the pipeline was tuned) — and the flow's cost grows with T².
    """
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    flow = flow_at_most(dis, cv2.cvtColor(target_rgb, cv2.COLOR_RGB2GRAY), cv2.cvtColor(synth_rgb, cv2.COLOR_RGB2GRAY),
                        flow_max)
    ys, xs = np.nonzero(band > 1e-4)          # outside the band every pixel stays where it is: copied
    if not len(ys):
        return synth_rgb
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    b = band[y0:y1, x0:x1]
    mx = np.arange(x0, x1, dtype=np.float32)[None, :] + b * flow[y0:y1, x0:x1, 0]
    my = np.arange(y0, y1, dtype=np.float32)[:, None] + b * flow[y0:y1, x0:x1, 1]
    out = synth_rgb.copy()
    out[y0:y1, x0:x1] = cv2.remap(synth_rgb, mx, my, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
    return out


def pyramid_blend(front: np.ndarray, back: np.ndarray, alpha: np.ndarray, levels: int = 5) -> np.ndarray:
    """Laplacian-pyramid blend (Burt & Adelson 1983) of (h, w, 3) uint8 images with (h, w) alpha.

    Per level l the blend is G_l(a)·L_l(front) + (1 − G_l(a))·L_l(back) = L_l(back) + G_l(a)·L_l(front − back):
    the pyramid is linear, so only the difference is decomposed and ``back`` added after the
    collapse — half the pyramid work of decomposing both images, the same result.
    """
    h, w = alpha.shape
    levels = max(1, min(levels, int(np.log2(max(min(h, w), 2))) - 2))
    b = back.astype(np.float32)
    gd, ga = [front.astype(np.float32) - b], [alpha.astype(np.float32)]
    for _ in range(levels):
        gd.append(cv2.pyrDown(gd[-1]))
        ga.append(cv2.pyrDown(ga[-1]))
    out = ga[-1][..., None] * gd[-1]
    for lvl in range(levels - 1, -1, -1):
        size = (gd[lvl].shape[1], gd[lvl].shape[0])
        ld = gd[lvl] - cv2.pyrUp(gd[lvl + 1], dstsize=size)
        out = cv2.pyrUp(out, dstsize=size) + ga[lvl][..., None] * ld
    return np.clip(out + b + 0.5, 0, 255).astype(np.uint8)


def lab_stats(rgb: np.ndarray, region: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Per Lab channel mean and standard deviation (3,), (3,) of (T, T, 3) uint8 ``rgb`` over ``region``
    (T, T) bool; None when the region has fewer than 50 pixels."""
    mask = region.astype(np.uint8)
    if cv2.countNonZero(mask) < 50:
        return None
    m, s = cv2.meanStdDev(cv2.cvtColor(rgb, cv2.COLOR_RGB2LAB), mask=mask)
    return m.ravel(), s.ravel()


def colour_match(synth_rgb: np.ndarray, target_rgb: np.ndarray, region: np.ndarray,
                 target_stats: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Give the synthesized texture the target frame's colour statistics (per Lab channel mean
    and standard deviation over ``region``, the skin of the lower face).

    Candidates drawn from other videos of the corpus carry their own lighting and white
    balance; without this the replaced lower face is a different shade from the rest of the face.
    synth_rgb, target_rgb : (T, T, 3) uint8; region : (T, T) bool → (T, T, 3) uint8.
    ``target_stats``: ``lab_stats(target_rgb, region)`` when the caller has it (it depends on the target frame
    alone); ``target_rgb`` is then not read.
    """
    mask = region.astype(np.uint8)
    if cv2.countNonZero(mask) < 50:
        return synth_rgb
    s = cv2.cvtColor(synth_rgb, cv2.COLOR_RGB2LAB)
    ms, ss = (v.ravel() for v in cv2.meanStdDev(s, mask=mask))
    mt, st = target_stats if target_stats is not None else lab_stats(target_rgb, region)
    gain = np.clip((st + 1e-3) / (ss + 1e-3), 0.5, 2.0)
    out = s * gain.astype(np.float32) + (mt - ms * gain).astype(np.float32)
    return cv2.cvtColor(np.clip(out + 0.5, 0, 255).astype(np.uint8), cv2.COLOR_LAB2RGB)


def skin_region(landmarks_uv: np.ndarray, mouth: np.ndarray) -> np.ndarray:
    """(T, T) bool: the replaced lower face without the lips and mouth interior (outer lip polygon grown 3 px)."""
    T = mouth.shape[0]
    lips = np.zeros((T, T), np.uint8)
    cv2.fillPoly(lips, [np.round(landmarks_uv[48:60] * 16).astype(np.int32)], 1, shift=4)
    lips = cv2.dilate(lips, np.ones((7, 7), np.uint8))
    return (mouth > 0.99) & (lips == 0)
