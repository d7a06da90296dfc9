"""synthesize — new audio → lower-face textures timed to a target video (paper 000 §3.2–3.3).

1. Mouth shapes: the trained model (``synthesize.model``) turns the audio into 18 lip points
   per output frame at the target's frame rate (``pipeline.models.mouth_prediction``); a model trained on
   another PCA basis than the store's is refused.
2. Re-timing (§3.3, ``retime``): speech flags of the audio, motion speed + blinks of the target,
   the dynamic programme maps output frames to target frames (a target shorter than half the
   audio is first extended by ping-pong playback). ``synthesize.retime: false`` keeps the
   target's own timing (for evaluation against ground truth).
3. Texture (§3.2, ``texture``): per output frame, the n frames of the candidate pool nearest in
   mouth shape, σ by binary search so they carry α of the weight, weighted median, teeth proxy
   (upper/lower proxy frames picked automatically unless given) and unsharp masking.

The candidate pool is the target video's usable frames; when the target has fewer than
``pool_min`` of them, training frames of the corpus (same speaker) are added, up to
``pool_max`` (the paper's targets are minutes long; a 3 s clip alone cannot cover all shapes).

Store ``store/synthesize.zarr``: texture (N, T, T, 3) uint8 RGB, inpainted (N, T, T) uint8 (share
of the candidates' weight, ×255, for which a pixel was clothing inpainted by frontalize: the
composite keeps such pixels out of the neck layer), target_frame (N,) int32 (frame
of the target video shown at output frame i), repeated (N,) bool, lip_points (N, 18, 2)
predicted, candidate_landmarks (N, 68, 2) weight-averaged landmarks of the candidates, sigma
(N,); attrs: target (its index entry), fps, n_frames, pool_size, teeth_proxies (the upper and lower
proxy's pool frames; [] for two_band, which takes real frames' detail instead). Nothing in it
names a machine-specific path or a time measurement: the same inputs give the same bytes
(per-phase timing goes to ``logs/synthesize.timing.json``, outside DVC).

Run: ``python -m stages.synthesize.synthesize``. ``synthesize.target`` names a video of the corpus;
any other video goes through ``lipsynth speak`` (which preprocesses it outside DVC).
"""
from __future__ import annotations

import logging
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from pipeline.errors import LipsynthError, ParameterError
from pipeline.face.dlib_face import IOD_MM, LIP_POINTS
from pipeline.face.geometry import euler_degrees
from pipeline.models.mouth_prediction import load_audio, predict_mouth
from pipeline.params import Params, Synthesize
from pipeline.io.runner import stage_main, write_timing
from pipeline.io.threads import library_threads
from pipeline.io.store import atomic_output, create_group, open_group, resize_i420, take
from stages.synthesize import retime as rt
from stages.synthesize.speech_flags import speech_flags
from stages.synthesize import teeth as th
from stages.synthesize import texture as tx
from stages.synthesize import two_band

log = logging.getLogger("lipsynth.synthesize")
REFERENCE_TEXTURE = 128.0     #: texture px the px-valued params (teeth σ, feathers, unsharp σ) are given at


def find_video(videos: list[dict], target: str) -> dict | None:
    """The index entry of the corpus video named ``target``."""
    for v in videos:
        if v["name"] == target:
            return v
    return None


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


def retarget(lips: np.ndarray, model_mean: np.ndarray, target_shapes: np.ndarray, max_spread_gain: float = 1.0) -> np.ndarray:
    """Predicted lip shapes of a model trained on another corpus, moved onto the target's mouth.

    Each shape keeps its displacement from the model's mean shape, scaled by the ratio of the
    mean mouth widths (corner to corner), and is added to the target frames' mean shape: the
    model's speaker may hold the mouth lower, wider or narrower in the canonical frame, and
    without this the nearest candidates (§3.2.1) are the target's frames that happen to be
    furthest from its own mouth position.

    ``max_spread_gain`` > 1 also widens the displacements toward the target's own mouth motion: the
    RMS distance of the target frames' shapes from their mean over that of the scaled predictions,
    clipped to [1, max_spread_gain]. A model of one read speaker predicts a natural talker's opening
    at a quarter to a third of its own spread (the strangers of bench/strangers.py), so the nearest
    candidates all sit about the target's mean mouth and the rendered opening barely moves.

    lips : (N, 18, 2); model_mean : (18, 2); target_shapes : (M, 18, 2) texture px → (N, 18, 2).
    """
    target_mean = np.nanmean(target_shapes, axis=0)
    width = lambda s: np.linalg.norm(s[6] - s[0])                 # 48 → 54, the mouth corners
    scale = width(target_mean) / width(model_mean)
    moved = (lips - model_mean) * scale
    gain = 1.0
    if max_spread_gain > 1.0:
        rms = lambda d: float(np.sqrt(np.nanmean(np.sum(d ** 2, axis=-1))))
        own, predicted = rms(target_shapes - target_mean), rms(moved - moved.mean(0))
        gain = float(np.clip(own / predicted, 1.0, max_spread_gain)) if predicted > 0 and np.isfinite(own) else 1.0
    log.info("re-targeting predicted mouth shapes onto the target's mean mouth (offset %.1f px, width × %.2f, "
             "spread × %.2f)", float(np.linalg.norm((target_mean - model_mean).mean(0))), scale, gain)
    return target_mean + moved.mean(0) + (moved - moved.mean(0)) * gain if gain != 1.0 else target_mean + moved


def output_timing(samples: np.ndarray, n_out: int, target_landmarks: np.ndarray, fps: float, p: Synthesize):
    """Target frame per output frame (N,) and the repeated flags (§3.3)."""
    M = len(target_landmarks)
    if not p.retime:
        order = np.arange(M) if n_out <= M else rt.extend_by_ping_pong(M, n_out)
        mapping = order[:n_out] if len(order) >= n_out else np.resize(order, n_out)
        return mapping, np.zeros(n_out, bool)
    V = rt.motion_speed(target_landmarks) + p.alpha_b * rt.blink_flags(target_landmarks, p.blink_threshold)
    A = speech_flags(samples, 16000, fps, n_out, p.speech_threshold_db)
    order = np.arange(M)
    if n_out > 2 * M:
        order = rt.extend_by_ping_pong(M, n_out)
        log.info("target (%d frames) is shorter than half the audio (%d frames): extended to %d frames by "
                 "ping-pong playback", M, n_out, len(order))
    mapping = order[rt.retime(A, V[order], p.alpha_s, p.alpha_u)]
    repeated = np.r_[False, mapping[1:] == mapping[:-1]]
    log.info("re-timing: %d output frames over %d target frames, %d repeated, speech in %.0f%% of the audio",
             n_out, M, int(repeated.sum()), 100 * A.mean())
    return mapping, repeated


TWO_BAND_FROM = 160                               #: texture px from which ``detail: auto`` takes two_band


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


def detail_plan(lips: np.ndarray, shapes: np.ndarray, pool: np.ndarray, p: Synthesize) -> tuple[list, list]:
    """``synthesize.detail: two_band``: per output frame, the real frames whose detail it shows and
    their weights (``two_band.crossfade_plan`` of the Viterbi path, ``two_band.detail_sources``,
    whose unary cost is a pool frame's lip-shape distance / (2σ²) of that output frame, Eq. 11),
    and each frame's ``candidate_search`` (the texture reuses it)."""
    costs = np.zeros((len(lips), len(shapes)), np.float32)
    searches = []
    for i, lip in enumerate(lips):
        s = tx.candidate_search(lip, shapes, p.n, p.alpha)
        costs[i] = s.pop("all_d2") / (2 * s["sigma"] ** 2)
        searches.append(s)
    sources = two_band.detail_sources(costs, pool, p.detail_candidates, p.detail_switch_cost, p.detail_hold_cost,
                                       reach=p.n)
    runs = 1 + int(np.sum(np.diff(pool[sources]) != 1))
    log.info("two-band detail: %d output frames from %d runs of consecutive real frames", len(lips), runs)
    return two_band.crossfade_plan(sources, pool, p.detail_fade_frames), searches


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
    if method == "two_band":
        m = min(m, 16 * int(np.ceil(2 * REFERENCE_TEXTURE / p.detail_band_px / 16)))
    return m


def open_stores(params: Params, pca: bool = True) -> dict:
    """The stores synthesize reads: landmarks, frontalize, and pca when asked and present (only to
    check the model's PCA basis)."""
    stores = {"landmarks": open_group(params.landmarks.out), "frontalize": open_group(params.frontalize.out)}
    if pca and Path(params.pca.out).is_dir():
        stores["pca"] = open_group(params.pca.out)
    return stores


def corpus_target(stores: dict, name: str, frontalize_path: str) -> dict:
    """The index entry of the corpus video ``name`` (``synthesize.target``)."""
    entry = find_video(stores["frontalize"].attrs["videos"], name)
    if entry is None:
        names = [v["name"] for v in stores["frontalize"].attrs["videos"]]
        raise LipsynthError(f"synthesize.target={name!r}: not a video of the corpus in {frontalize_path} "
                            f"({', '.join(names[:5])}{', …' if len(names) > 5 else ''}); "
                            f"for any other video use `lipsynth speak`")
    return entry


def run(params: Params, out: str, stores: dict, entry: dict, mouth: dict | None = None) -> dict:
    """Synthesize the textures of ``entry`` (a video of ``stores``) saying ``synthesize.audio``
    into ``out``; returns the thread time per output frame of each phase (ms).

    ``mouth``: ``predict_mouth``'s output for that audio at the entry's frame rate, when the caller
    has it already (``lipsynth speak`` predicts while the target is preprocessed); None predicts here.
    """
    p = params.synthesize
    fr, lmg = stores["frontalize"], stores["landmarks"]
    n_usable = len(usable(fr, lmg, entry))
    if entry.get("excluded") or not n_usable or n_usable < p.min_target_fraction * entry["n_frames"]:
        sl = slice(entry["first_frame"], entry["first_frame"] + entry["n_frames"])
        n_face = int(np.asarray(lmg["valid"][sl]).sum())
        why = (f"a tracked face in only {n_face} of {entry['n_frames']} frames" if entry.get("excluded") or
               n_face < p.min_target_fraction * entry["n_frames"] else
               f"a face in {n_face} of {entry['n_frames']} frames, but a head pose (3D fit within "
               f"frontalize.max_reprojection) in only {n_usable}: the 3D face model does not fit this video")
        raise LipsynthError(f"{entry['path']}: target has {why} (synthesize.min_target_fraction={p.min_target_fraction})")
    timing: dict = {}
    t0 = t_start = time.perf_counter()
    samples = load_audio(p.audio)
    if mouth is None:
        mouth = predict_mouth(samples, p.model, entry["fps"], device=p.device, source=p.audio, emotion=p.emotion)
    same_corpus = "pca" in stores and mouth["pca_fingerprint"] == stores["pca"].attrs["fingerprint"]
    lips = mouth["lip_points"].astype(np.float64)
    store_iod = IOD_MM / fr.attrs["texture_window"]["mm_per_px"]
    if mouth["iod_px"] and abs(mouth["iod_px"] - store_iod) > 1e-3:
        # same canonical window in mm, other texture size: scale the model's texture pixels to the store's
        log.info("model texture scale %.1f px per IOD, target store %.1f: lip points rescaled", mouth["iod_px"], store_iod)
        lips *= store_iod / mouth["iod_px"]
        mouth["mean_shape"] = mouth["mean_shape"] * (store_iod / mouth["iod_px"])
    n_out = len(lips)
    timing["prediction"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    sl = slice(entry["first_frame"], entry["first_frame"] + entry["n_frames"])
    target_lm = np.asarray(lmg["landmarks"][sl], np.float64)
    target_lm[~np.asarray(lmg["valid"][sl])] = np.nan
    mapping, repeated = output_timing(samples, n_out, target_lm, entry["fps"], p)
    timing["retiming"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    pool, pool_tex, pool_cloth, flm, pose = read_pool(stores, entry, p)
    shapes = flm[:, LIP_POINTS]
    if p.retarget == "always" or (p.retarget == "auto" and not same_corpus):
        lips = retarget(lips, mouth["mean_shape"], shapes, p.max_spread_gain)
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
    plan = searches = proxies = None
    teeth = []
    method = detail_method(p.detail, pool_tex.shape[2])
    if method == "two_band":              # real detail replaces the teeth proxy and the unsharp mask
        detail["unsharp_amount"] = 0.0
        plan, searches = detail_plan(lips, shapes, pool, p)
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
    timing["candidate_pool"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    phases = dict(candidate_search=0.0, weighted_median=0.0, teeth=0.0, **({"detail": 0.0} if plan else {}))

    def one(i):
        wanted = lips[i].reshape(len(LIP_POINTS), 2)
        if method != "aligned":
            get = lambda idx: small[idx]                                               # noqa: E731
        else:                                   # candidates moved onto the wanted lip points first
            get = lambda idx: two_band.align_candidates(                                  # noqa: E731
                small[idx], scale * flm[idx][:, ALIGNED], scale * np.concatenate([wanted, flm[idx[0]][NOSE]]),
                scale * px * p.detail_warp_px)
        rgb, info = tx.synthesize_texture(lips[i], shapes, get, flm, p.n, p.alpha, proxies, detail,
                                          search=searches[i] if searches else None, size=T)
        if method == "aligned":
            info["landmarks"][LIP_POINTS] = wanted
        if plan is not None:
            t_detail = time.perf_counter()
            sources = [(th._rgb(pool_tex[r]), flm[r], w) for r, w in plan[i]]
            rgb = two_band.two_band(rgb, info["landmarks"], sources, px * p.detail_band_px, px * p.detail_warp_px,
                                    flow_max=p.median_max_size)
            info["seconds"]["detail"] = time.perf_counter() - t_detail
        w = info["weights"] / info["weights"].sum()
        cloth = np.tensordot(w.astype(np.float32), small_cloth[info["indices"]].astype(np.float32), 1)
        if scale != 1:                                   # area fractions ×255 at the median's size
            cloth = cv2.resize(cloth / 255, (T, T), interpolation=cv2.INTER_LINEAR)
        return rgb, info["landmarks"], info["sigma"], info["seconds"], np.round(cloth * 255).astype(np.uint8)

    with atomic_output(out) as tmp:
        g = create_group(tmp)
        inpainted = g.create_array("inpainted", shape=(n_out, T, T), dtype="uint8", chunks=(8, T, T),
                                   shards=(256, T, T))
        tex = g.create_array("texture", shape=(n_out, T, T, 3), dtype="uint8", chunks=(8, T, T, 3),
                             shards=(256, T, T, 3))
        cand = np.zeros((n_out, 68, 2), np.float32)
        sig = np.zeros(n_out, np.float32)
        with ThreadPoolExecutor(p.threads) as ex, library_threads(1):
            for a in tqdm(range(0, n_out, 256), desc="synthesize", unit="block", dynamic_ncols=True):
                res = list(ex.map(one, range(a, min(a + 256, n_out))))
                tex[a:a + len(res)] = np.stack([r[0] for r in res])
                inpainted[a:a + len(res)] = np.stack([r[4] for r in res])
                cand[a:a + len(res)] = [r[1] for r in res]
                sig[a:a + len(res)] = [r[2] for r in res]
                for r in res:
                    for k, v in r[3].items():
                        phases[k] += v
        timing.update(phases)                              # thread time per phase (threads run in parallel)
        g.create_array("target_frame", data=mapping.astype(np.int32))
        g.create_array("repeated", data=repeated)
        g.create_array("lip_points", data=lips.astype(np.float32))
        g.create_array("candidate_landmarks", data=cand)
        g.create_array("sigma", data=sig)
        ms = {k: 1000 * v / n_out for k, v in timing.items()}
        g.attrs.update(dict(target=entry, fps=entry["fps"], n_frames=n_out, pool_size=int(len(pool)),
                            teeth_proxies=teeth))
    log.info("synthesized %d textures in %.1f s (thread time per frame: %s ms)", n_out, time.perf_counter() - t_start,
             ", ".join(f"{k} {v:.1f}" for k, v in ms.items()))
    return ms


def run_stage(params: Params) -> dict:
    """The DVC stage: the corpus video ``synthesize.target`` saying ``synthesize.audio``."""
    stores = open_stores(params)
    entry = corpus_target(stores, params.synthesize.target, params.frontalize.out)
    ms = run(params, params.synthesize.out, stores, entry)
    write_timing("synthesize", ms)
    return ms


def main(argv=None) -> int:
    return stage_main("lipsynth synthesize", __doc__, run_stage, argv)


if __name__ == "__main__":
    raise SystemExit(main())
