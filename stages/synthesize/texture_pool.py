"""The candidate pool of a target and one output frame's texture from it (paper 000 §3.2).

``texture_pool`` reads the pool (the target's usable frames, the corpus's when the target is short, a model's
candidate bank) and prepares what every frame shares: the textures the weighted median runs on, the teeth
proxies, the detail settings. ``synthesize_frame`` makes one frame's texture for wanted lip points: the
``synthesize`` stage calls it for every output frame, ``lipsynth live`` as each frame's shape arrives.
"""
from __future__ import annotations

import dataclasses
import logging
import time

import cv2
import numpy as np

from pipeline.errors import ParameterError
from pipeline.face.dlib_face import LIP_POINTS
from pipeline.face.geometry import euler_degrees
from pipeline.params import Synthesize
from pipeline.io.store import resize_i420, take
from stages.synthesize import teeth as th
from stages.synthesize import texture as tx
from stages.synthesize import two_band

log = logging.getLogger("lipsynth.synthesize")
REFERENCE_TEXTURE = 128.0     #: texture px the px-valued params (teeth σ, feathers, unsharp σ) are given at


def usable(fr, lmg, v: dict) -> np.ndarray:
    """Local indices of the frames of video ``v`` with a valid pose and landmarks."""
    sl = slice(v["first_frame"], v["first_frame"] + v["n_frames"])
    return np.flatnonzero(np.asarray(fr["pose_valid"][sl]) & np.asarray(lmg["valid"][sl]))


def candidate_pool(stores: dict, target: dict, p: Synthesize) -> np.ndarray:
    """Global frame indices (into the target's stores) of the candidate pool; target frames first."""
    fr, lmg = stores["frontalize"], stores["landmarks"]
    own = target["first_frame"] + usable(fr, lmg, target)
    if p.exclude_target_from_pool:
        own = own[:0]                                  # evaluation: the true frames may not be copied
    if len(own) >= p.pool_min:
        return own
    others = [v for v in fr.attrs["videos"] if v["split"] == "train" and v["n_frames"] and not v.get("excluded")
              and v["name"] != target["name"]]
    if not others:
        log.debug("candidate pool: the target's %d usable frames", len(own))
        return own
    # whole videos spread evenly over the corpus: contiguous runs are cheap to read from the store
    room = p.pool_max - len(own)
    per_video = np.median([v["n_frames"] for v in others])
    m = min(len(others), int(np.ceil(room / max(per_video, 1))))
    picked = [others[k] for k in np.unique(np.linspace(0, len(others) - 1, m).round().astype(int))]
    extra = np.concatenate([v["first_frame"] + usable(fr, lmg, v) for v in picked])[:room]
    log.info("target has %d usable frames (< pool_min %d): adding %d training frames of the corpus",
             len(own), p.pool_min, len(extra))
    return np.concatenate([own, extra])


def read_pool(stores: dict, entry: dict, p: Synthesize):
    """The candidate pool's frames: ids (P,) int64, textures (P, 3T/2, T) I420, clothing masks
    (P, T, T) bool, frontal landmarks (P, 68, 2) and poses (P, 6).

    Frames of the stores (``candidate_pool``) carry their global frame index as id; when
    ``stores`` has a ``bank`` (a model folder's candidate bank, ``lipsynth speak`` for a target of
    the model's speaker) its frames follow with ids −1, −2, …
    """
    fr = stores["frontalize"]
    pool = candidate_pool(stores, entry, p)
    parts = [pool, take(fr["texture"], pool), take(fr["clothing_mask"], pool),
             np.asarray(take(fr["frontal_landmarks"], pool), np.float64), np.asarray(take(fr["pose"], pool), np.float64)]
    if "bank" in stores:
        b = stores["bank"]
        room = max(p.pool_max - len(pool), 0)
        k = np.arange(b["texture"].shape[0])
        k = k[np.unique(np.linspace(0, len(k) - 1, min(room, len(k))).round().astype(int))] if room else k[:0]
        bank = [-1 - k, np.asarray(b["texture"][...])[k], np.asarray(b["clothing_mask"][...])[k],
                np.asarray(b["frontal_landmarks"][...], np.float64)[k], np.asarray(b["pose"][...], np.float64)[k]]
        log.info("candidate pool: %d frames of the target + %d of the model's candidate bank", len(pool), len(k))
        parts = [np.concatenate([a, c]) for a, c in zip(parts, bank)]
    return tuple(parts)


TWO_BAND_FROM = 160                               #: texture px from which ``detail: auto`` takes two_band
ALIGNING = ("aligned", "warped")                  #: methods whose candidates are warped onto the wanted lips first
REAL_DETAIL = ("two_band", "warped")              #: methods that put a real frame's detail over the median


def detail_method(detail: str, texture_size: int) -> str:
    """The texture method ``synthesize.detail`` names; ``auto``: ``two_band`` for textures of at least
    ``TWO_BAND_FROM`` px, else ``median``. Measured (docs/sharp_steady.md, metrics/evaluate.json, the held-out
    GRID s1 yardstick): at 128 px (GRID s1, the synthetic speaker) candidates are registered to within a
    texture pixel, the median is as sharp as a real frame and one real frame's detail overshoots (yardstick
    sharpness 1.33 against the median's 1.19, error ratio 0.774 against 0.750); from ≈ 200 px (GRID s4,
    HDTF, 1080, 4K) the median's misregistration spans pixels and blurs (0.58–0.75 of the real mouth) while
    two bands reach 0.9."""
    if detail != "auto":
        return detail
    method = "two_band" if texture_size >= TWO_BAND_FROM else "median"
    log.info("synthesize.detail: auto → %s (texture %d px; two_band from %d)", method, texture_size, TWO_BAND_FROM)
    return method


NOSE = np.r_[27:36]                               # anchored (at the nearest candidate's) while the lips are aligned
ALIGNED = np.r_[LIP_POINTS, NOSE]


def median_pool(pool_tex: np.ndarray, max_size: int) -> tuple[np.ndarray, float]:
    """The pool's textures for the weighted median: (P, 3m/2, m) I420 with m = min(T, ``max_size``), and
    m / T. Textures larger than ``synthesize.median_max_size`` are area-averaged down once here: the
    median's cost grows with T² while what it contributes — two_band keeps only its low band — does not."""
    T = pool_tex.shape[2]
    m = min(T, int(max_size))
    if m == T:
        return pool_tex, 1.0
    log.info("weighted median at %d px (texture %d px)", m, T)
    return np.stack([resize_i420(t, m) for t in pool_tex]), m / T


def median_size(texture_size: int, method: str, p: Synthesize) -> int:
    """Texture px the weighted median runs at: at most ``synthesize.median_max_size``; for two_band also at
    most what its low band can show. That band is the median blurred by σ = ``detail_band_px`` × T/128, which
    leaves nothing of wavelengths below 2σ; a median sampled at 2 px per σ (T × 2/σ = 256 / detail_band_px px,
    rounded up to 16, whatever T) resolves all of them. At 720p (T = 192) that is 128 px: less than half
    the median's work for the same low band."""
    m = min(int(texture_size), p.median_max_size)
    if method in REAL_DETAIL:
        m = min(m, 16 * int(np.ceil(2 * REFERENCE_TEXTURE / p.detail_band_px / 16)))
    return m


@dataclasses.dataclass
class TexturePool:
    """What texture synthesis draws on for one target: the candidate pool (ids (P,), I420 textures (P, 3T/2, T),
    clothing masks, frontal landmarks (P, 68, 2), poses), its lip shapes (P, 18, 2), the textures the weighted
    median runs on (``small``, at ``scale`` × T) with their clothing share, the texture method, the teeth
    proxies (median method) and the detail settings (px scaled to T)."""
    pool: np.ndarray
    tex: np.ndarray
    flm: np.ndarray
    pose: np.ndarray
    shapes: np.ndarray
    small: np.ndarray
    scale: float
    small_cloth: np.ndarray
    method: str
    proxies: dict | None
    detail: dict
    px: float
    T: int
    teeth: list


def texture_pool(stores: dict, entry: dict, p: Synthesize) -> TexturePool:
    """Read the candidate pool of ``entry`` and prepare everything ``synthesize_frame`` needs."""
    pool, pool_tex, pool_cloth, flm, pose = read_pool(stores, entry, p)
    up, lo = p.teeth_upper, p.teeth_lower

    def to_pool(j):
        hit = np.flatnonzero(pool == entry["first_frame"] + j) if j is not None else None
        if j is not None and not len(hit):
            raise ParameterError(f"synthesize.teeth_upper/teeth_lower={j}: frame {j} of {entry['name']} is not a "
                                 f"usable frame of the candidate pool (0 … {entry['n_frames'] - 1}, tracked face)")
        return None if j is None else int(hit[0])

    px = pool_tex.shape[2] / REFERENCE_TEXTURE        # the px params are given at T = 128: same mm at any texture size
    detail = dict(s_max=p.teeth_s_max, v_min=p.teeth_v_min, feather_px=px * p.teeth_feather_px,
                  unsharp_sigma=px * p.unsharp_sigma, unsharp_amount=p.unsharp_amount)
    proxies = None
    teeth = []
    method = detail_method(p.detail, pool_tex.shape[2])
    if method in REAL_DETAIL:             # real detail replaces the teeth proxy and the unsharp mask
        detail["unsharp_amount"] = 0.0
    else:
        yaw = np.radians([euler_degrees(r)[0] for r in pose[:, :3]])        # frontal proxies preferred
        upper, lower = th.pick_teeth_proxies(lambda idx: pool_tex[idx], flm, np.ones(len(pool), bool), yaw=yaw,
                                             s_max=p.teeth_s_max, v_min=p.teeth_v_min, upper=to_pool(up),
                                             lower=to_pool(lo))
        proxies = th.proxies_from_frames(lambda idx: pool_tex[idx], flm, upper, lower,
                                         sigmas=tuple(px * s for s in p.teeth_sigmas), strength=p.teeth_strength,
                                         feather_px=px * p.teeth_feather_px)
        teeth = [int(pool[upper]), int(pool[lower])]
        log.info("teeth proxies: upper = pool frame %d, lower = pool frame %d%s", upper, lower,
                 " (given)" if up is not None or lo is not None else " (automatic)")
    T = pool_tex.shape[2]
    small, scale = median_pool(pool_tex, median_size(T, method, p))
    m = small.shape[2]
    small_cloth = pool_cloth if scale == 1 else np.stack(          # clothing share ×255 at the median's size
        [cv2.resize(c.astype(np.uint8) * np.uint8(255), (m, m), interpolation=cv2.INTER_AREA) for c in pool_cloth])
    return TexturePool(pool, pool_tex, flm, pose, flm[:, LIP_POINTS], small, scale, small_cloth, method, proxies,
                       detail, px, T, teeth)


@dataclasses.dataclass(frozen=True)
class FrameTexture:
    """One output frame made by ``synthesize_frame``."""
    rgb: np.ndarray             #: (T, T, 3) uint8, the texture
    landmarks: np.ndarray       #: (68, 2) texture px, weight-averaged over the candidates
    sigma: float                #: σ of the candidate weights (Eq. 12)
    seconds: dict               #: thread seconds per phase (candidate_search, weighted_median, teeth[, detail])
    inpainted: np.ndarray       #: (T, T) uint8, the candidates' clothing-inpainted share ×255


def synthesize_frame(tp: TexturePool, lip: np.ndarray, p: Synthesize, search: dict | None = None,
                     sources: list | None = None) -> FrameTexture:
    """One output frame's texture for the wanted lip points ``lip`` (18, 2) texture px.

    ``search``: its ``candidate_search`` when done already; ``sources``: its detail sources [(pool row,
    weight)] (``two_band``)."""
    wanted = lip.reshape(len(LIP_POINTS), 2)
    small, scale, flm, px, T = tp.small, tp.scale, tp.flm, tp.px, tp.T
    if tp.method not in ALIGNING:
        get = lambda idx: small[idx]
    else:                                   # candidates moved onto the wanted lip points first
        get = lambda idx: two_band.align_candidates(
            small[idx], scale * flm[idx][:, ALIGNED], scale * np.concatenate([wanted, flm[idx[0]][NOSE]]),
            scale * px * p.detail_warp_px)
    rgb, info = tx.synthesize_texture(lip, tp.shapes, get, flm, p.n, p.alpha, tp.proxies, tp.detail,
                                      search=search, size=T)
    if tp.method in ALIGNING:
        info["landmarks"][LIP_POINTS] = wanted
    if sources is not None:
        t_detail = time.perf_counter()
        real = [(th._rgb(tp.tex[r]), flm[r], w) for r, w in sources]
        rgb = two_band.two_band(rgb, info["landmarks"], real, px * p.detail_band_px, px * p.detail_warp_px,
                                flow_max=p.median_max_size)
        info["seconds"]["detail"] = time.perf_counter() - t_detail
    w = info["weights"] / info["weights"].sum()
    cloth = np.tensordot(w.astype(np.float32), tp.small_cloth[info["indices"]].astype(np.float32), 1)
    if scale != 1:                                   # area fractions ×255 at the median's size
        cloth = cv2.resize(cloth / 255, (T, T), interpolation=cv2.INTER_LINEAR)
    return FrameTexture(rgb, info["landmarks"], info["sigma"], info["seconds"], np.round(cloth * 255).astype(np.uint8))
