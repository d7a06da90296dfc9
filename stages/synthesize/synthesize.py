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

import dataclasses
import logging
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from tqdm import tqdm

from pipeline.errors import LipsynthError
from pipeline.face.dlib_face import IOD_MM
from pipeline.models.mouth_prediction import load_audio, predict_mouth
from pipeline.params import Params, Synthesize
from pipeline.io.runner import stage_main, write_timing
from pipeline.io.threads import library_threads
from pipeline.io.store import atomic_output, create_group, open_group
from stages.synthesize import retime as rt
from stages.synthesize.speech_flags import speech_flags
from stages.synthesize import texture as tx
from stages.synthesize import two_band
from stages.synthesize.texture_pool import REAL_DETAIL, synthesize_frame, texture_pool, usable

log = logging.getLogger("lipsynth.synthesize")


def find_video(videos: list[dict], target: str) -> dict | None:
    """The index entry of the corpus video named ``target``."""
    for v in videos:
        if v["name"] == target:
            return v
    return None


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
    return Retarget.fit(lips, model_mean, target_shapes, max_spread_gain)(lips)


def spread_gain(own: np.ndarray, predicted: np.ndarray, max_gain: float) -> float:
    """RMS spread of ``own`` deviations (M, 18, 2) over that of ``predicted`` ones (N, 18, 2), clipped to
    [1, ``max_gain``]: how much to widen predicted mouth motion (never narrowed; 1 when undefined)."""
    if max_gain <= 1.0:
        return 1.0
    rms = lambda d: float(np.sqrt(np.nanmean(np.sum(d ** 2, axis=-1))))
    o, p = rms(own), rms(predicted)
    return float(np.clip(o / p, 1.0, max_gain)) if p > 0 and np.isfinite(o) else 1.0


@dataclasses.dataclass
class Retarget:
    """The map of ``retarget``: shapes (..., 18, 2) → target_mean + centre + (moved − centre) · gain, with
    moved = (shape − model_mean) · scale. ``fit`` takes centre and gain from a sequence of predictions (the
    output's own, offline; the target audio's, live, where the output's future is unknown)."""
    model_mean: np.ndarray
    target_mean: np.ndarray
    scale: float
    centre: np.ndarray
    gain: float

    @classmethod
    def fit(cls, lips: np.ndarray, model_mean: np.ndarray, target_shapes: np.ndarray,
            max_spread_gain: float = 1.0) -> "Retarget":
        target_mean = np.nanmean(target_shapes, axis=0)
        width = lambda s: np.linalg.norm(s[6] - s[0])                 # 48 → 54, the mouth corners
        scale = width(target_mean) / width(model_mean)
        moved = (lips - model_mean) * scale
        gain = spread_gain(target_shapes - target_mean, moved - moved.mean(0), max_spread_gain)
        log.info("re-targeting predicted mouth shapes onto the target's mean mouth (offset %.1f px, width × %.2f, "
                 "spread × %.2f)", float(np.linalg.norm((target_mean - model_mean).mean(0))), scale, gain)
        return cls(model_mean, target_mean, scale, moved.mean(0), gain)

    def __call__(self, lips: np.ndarray) -> np.ndarray:
        moved = (lips - self.model_mean) * self.scale
        if self.gain == 1.0:
            return self.target_mean + moved
        return self.target_mean + self.centre + (moved - self.centre) * self.gain


def widen(lips: np.ndarray, pool_shapes: np.ndarray, max_gain: float) -> np.ndarray:
    """Predicted shapes of the pool's own speaker (same PCA frame: no re-targeting), their motion widened
    toward the pool's: deviations from the prediction's mean × the RMS spread of the pool's shapes over that
    of the predictions, clipped to [1, ``max_gain``].

    An LSTM regressing to the mean predicts a person's mouth motion at a half to a third of its spread
    (bench/speak_stages.py: 0.48 on Lieu's held-out part); the nearest candidates then all sit about the
    mean mouth, the rendered opening moves less than dlib's own jitter on the output and the re-tracked
    output follows the prediction at ≈ 0.5. The gain is affine: the prediction's correlation with the
    speech is kept. lips : (N, 18, 2); pool_shapes : (M, 18, 2) texture px → (N, 18, 2).
    """
    centre = lips.mean(0)
    gain = spread_gain(pool_shapes - np.nanmean(pool_shapes, 0), lips - centre, max_gain)
    log.info("predicted mouth motion widened toward the candidate pool's own (spread × %.2f)", gain)
    return centre + (lips - centre) * gain


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


def check_target(stores: dict, entry: dict, p: Synthesize) -> None:
    """Refuse a target with too few usable frames (``synthesize.min_target_fraction``), naming why: too few
    tracked faces, or faces whose 3D fit failed."""
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


def predicted_lips(samples: np.ndarray, stores: dict, entry: dict, p: Synthesize,
                   mouth: dict | None) -> tuple[np.ndarray, dict, bool]:
    """The lip points (N, 18, 2) float64 at the store's texture scale, ``mouth`` (predicted here when None; its
    mean_shape rescaled with the lips) and whether the model was trained on the store's PCA basis."""
    if mouth is None:
        mouth = predict_mouth(samples, p.model, entry["fps"], device=p.device, source=p.audio, emotion=p.emotion)
    same_corpus = "pca" in stores and mouth["pca_fingerprint"] == stores["pca"].attrs["fingerprint"]
    lips = mouth["lip_points"].astype(np.float64)
    store_iod = IOD_MM / stores["frontalize"].attrs["texture_window"]["mm_per_px"]
    if mouth["iod_px"] and abs(mouth["iod_px"] - store_iod) > 1e-3:
        # same canonical window in mm, other texture size: scale the model's texture pixels to the store's
        log.info("model texture scale %.1f px per IOD, target store %.1f: lip points rescaled", mouth["iod_px"], store_iod)
        lips *= store_iod / mouth["iod_px"]
        mouth["mean_shape"] = mouth["mean_shape"] * (store_iod / mouth["iod_px"])
    return lips, mouth, same_corpus


def target_landmarks(lmg, entry: dict) -> np.ndarray:
    """The target's tracked landmarks (M, 68, 2) float64, NaN where no face was tracked."""
    sl = slice(entry["first_frame"], entry["first_frame"] + entry["n_frames"])
    target_lm = np.asarray(lmg["landmarks"][sl], np.float64)
    target_lm[~np.asarray(lmg["valid"][sl])] = np.nan
    return target_lm


def synthesize_textures(g, tp, lips: np.ndarray, p: Synthesize, searches: list | None,
                        plan: list | None) -> tuple[np.ndarray, np.ndarray, dict]:
    """Every output frame's ``synthesize_frame`` on ``p.threads`` threads, in blocks of 256, into the arrays
    texture and inpainted of the group ``g``; returns candidate_landmarks (N, 68, 2), sigma (N,) and the
    thread seconds per phase summed over the frames."""
    n_out, T = len(lips), tp.T
    phases = dict(candidate_search=0.0, weighted_median=0.0, teeth=0.0, **({"detail": 0.0} if plan else {}))

    def one(i):
        return synthesize_frame(tp, lips[i], p, searches[i] if searches else None, plan[i] if plan else None)

    inpainted = g.create_array("inpainted", shape=(n_out, T, T), dtype="uint8", chunks=(8, T, T),
                               shards=(256, T, T))
    tex = g.create_array("texture", shape=(n_out, T, T, 3), dtype="uint8", chunks=(8, T, T, 3),
                         shards=(256, T, T, 3))
    cand = np.zeros((n_out, 68, 2), np.float32)
    sig = np.zeros(n_out, np.float32)
    with ThreadPoolExecutor(p.threads) as ex, library_threads(1):
        for a in tqdm(range(0, n_out, 256), desc="synthesize", unit="block", dynamic_ncols=True):
            res = list(ex.map(one, range(a, min(a + 256, n_out))))
            tex[a:a + len(res)] = np.stack([r.rgb for r in res])
            inpainted[a:a + len(res)] = np.stack([r.inpainted for r in res])
            cand[a:a + len(res)] = [r.landmarks for r in res]
            sig[a:a + len(res)] = [r.sigma for r in res]
            for r in res:
                for k, v in r.seconds.items():
                    phases[k] += v
    return cand, sig, phases


def run(params: Params, out: str, stores: dict, entry: dict, mouth: dict | None = None) -> dict:
    """Synthesize the textures of ``entry`` (a video of ``stores``) saying ``synthesize.audio``
    into ``out``; returns the thread time per output frame of each phase (ms).

    ``mouth``: ``predict_mouth``'s output for that audio at the entry's frame rate, when the caller
    has it already (``lipsynth speak`` predicts while the target is preprocessed); None predicts here.
    """
    p = params.synthesize
    check_target(stores, entry, p)
    timing: dict = {}
    t0 = t_start = time.perf_counter()
    samples = load_audio(p.audio)
    lips, mouth, same_corpus = predicted_lips(samples, stores, entry, p, mouth)
    n_out = len(lips)
    timing["prediction"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    mapping, repeated = output_timing(samples, n_out, target_landmarks(stores["landmarks"], entry), entry["fps"], p)
    timing["retiming"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    tp = texture_pool(stores, entry, p)
    if p.retarget == "always" or (p.retarget == "auto" and not same_corpus):
        lips = retarget(lips, mouth["mean_shape"], tp.shapes, p.max_spread_gain)
    elif p.max_spread_gain > 1.0:
        lips = widen(lips, tp.shapes, p.max_spread_gain)
    plan = searches = None
    if tp.method in REAL_DETAIL:
        plan, searches = detail_plan(lips, tp.shapes, tp.pool, p)
    timing["candidate_pool"] = time.perf_counter() - t0
    with atomic_output(out) as tmp:
        g = create_group(tmp)
        cand, sig, phases = synthesize_textures(g, tp, lips, p, searches, plan)
        timing.update(phases)                              # thread time per phase (threads run in parallel)
        g.create_array("target_frame", data=mapping.astype(np.int32))
        g.create_array("repeated", data=repeated)
        g.create_array("lip_points", data=lips.astype(np.float32))
        g.create_array("candidate_landmarks", data=cand)
        g.create_array("sigma", data=sig)
        ms = {k: 1000 * v / n_out for k, v in timing.items()}
        g.attrs.update(dict(target=entry, fps=entry["fps"], n_frames=n_out, pool_size=int(len(tp.pool)),
                            teeth_proxies=tp.teeth))
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
