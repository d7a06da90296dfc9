"""``lipsynth speak`` — new audio + any video of the speaker → lip-synced MP4, outside DVC.

Runs the same code as the DVC stages: the target video is preprocessed on the fly (ingest →
landmarks → frontalize, with the params file's settings) into a cache folder keyed by the
file's content and those settings, so a second run with the same target starts at once; then
synthesize (mouth shapes from the model, re-timing, mouth texture) and composite (jaw
correction, layers, render-back, pyramid blend, H.264 + AAC).

Who is the target? The target's face descriptor (dlib's face-recognition ResNet) is compared
with the speaker the model folder records (``pipeline/models/speaker_bank``):

* the model's speaker: the target is frontalized with the corpus 3D face model (pose alone per
  frame), the predicted mouth shapes are used as they are (one PCA frame), and candidates come
  from the target's frames and the model folder's candidate bank (training frames), as in the
  DVC pipeline;
* another person: the target's own 3D model, candidates from the target alone (never another
  face's mouth), predicted shapes re-targeted onto its mean mouth; a warning when the target
  covers few distinct mouth shapes.

A target whose 3D fit failed is refused before synthesis, naming the fit; every output frame is
re-read by dlib (``composite.self_check``) and frames whose mouth is wrong fall back to the
target frame with a cross-fade.

Examples
--------
  lipsynth speak --audio new_speech.wav --target speaker.mp4 --out result.mp4
  lipsynth speak --audio a.m4a --target t.mp4 --out o.mp4 --model models/lstm --no-retime
"""
from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import logging
import shutil
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from lipsynth.target import default_cache, landmarked_target, preprocess_target, target_cluster, warm_up_worker
from pipeline.audio import front_ends
from pipeline.face import identity
from pipeline.errors import BadInputError, NoLipSyncError, ParameterError
from pipeline.face.dlib_face import IOD_MM, LIP_POINTS, interocular
from pipeline.face.geometry import rotation, rotation_angle_deg
from pipeline.models.model_folder import load_speaker
from pipeline.models.mouth_prediction import check_emotion, load_audio, open_model, predict_mouth
from pipeline.io.parallel import IN_PROCESS, SharedCluster, run_tasks
from pipeline.io.store import open_group
from pipeline.params import Params, load_params
from pipeline.io.runner import run_main, setup_logging
from stages.composite import composite
from stages.ingest.ingest import probe_video
from stages.synthesize import synthesize

log = logging.getLogger("lipsynth.speak")


def target_identity(p: Params, n_frames: int, cluster: SharedCluster | None = None) -> np.ndarray | None:
    """Median face descriptor (128,) of the preprocessed target (its ingest + landmarks stores).

    The descriptors (≈ 0.1 s of CPU each) are computed on the workers of ``cluster`` when it is
    running (the target was just preprocessed on it), else here (also for an in-process ``cluster``).
    """
    src, lmg = open_group(p.ingest.out), open_group(p.landmarks.out)
    v = lmg.attrs["videos"][0]
    landmarks = np.asarray(lmg["landmarks"][...])
    frames = identity.sampled_frames(np.asarray(lmg["valid"][...]), n_frames)
    if not len(frames):
        return None
    if cluster is not None and cluster.running and cluster.cluster.address != IN_PROCESS:
        with cluster.client() as client:
            n = max(1, min(len(frames), len(client.scheduler_info()["workers"])))
            parts = np.array_split(frames, n)
            jobs = [dict(ingest=str(Path(p.ingest.out).absolute()), frames=part.tolist(), landmarks=landmarks[part],
                         crop=v["crop"]) for part in parts]
            d = np.concatenate(run_tasks(client, identity.stored_descriptors, jobs, "identity", "frame",
                                         [len(part) for part in parts]))
    else:
        d = identity.frame_descriptors(src["crops"], frames, landmarks[frames], v["crop"])
    return identity.identity(d)


def distinct_shapes(shapes: np.ndarray, radius: float) -> int:
    """Size of a greedy ``radius``-net of mouth shapes (M, 18, 2): how many clearly different
    shapes (mean point distance > radius, texture px) a candidate pool offers."""
    kept: list[np.ndarray] = []
    for s in shapes[np.all(np.isfinite(shapes), axis=(1, 2))]:
        if not kept or np.linalg.norm(np.asarray(kept) - s, axis=2).mean(1).min() > radius:
            kept.append(s)
    return len(kept)


def fit_report(p: Params, target: str) -> dict:
    """How well the target's 3D fit went, before any synthesis: raises when it failed.

    Returns dict(frames, face, posed, reprojection_iod (median RMS reprojection / inter-ocular
    distance over the frames with a face), max_jump_deg (largest head rotation between
    consecutive posed frames)).
    """
    fr, lmg = open_group(p.frontalize.out), open_group(p.landmarks.out)
    v = fr.attrs["videos"][0]
    sl = slice(v["first_frame"], v["first_frame"] + v["n_frames"])     # the arrays are padded to whole shards
    face_ok = np.asarray(lmg["valid"][sl])
    posed = np.asarray(fr["pose_valid"][sl])
    err = np.asarray(fr["reprojection_error"][sl], np.float64)
    iod = interocular(np.asarray(lmg["landmarks"][sl], np.float64))
    rel = err[face_ok] / iod[face_ok]
    rel = rel[np.isfinite(rel)]
    R = [rotation(r) for r in np.asarray(fr["pose"][sl], np.float64)[:, :3]]
    jumps = [rotation_angle_deg(R[i], R[i + 1]) for i in range(len(R) - 1) if posed[i] and posed[i + 1]]
    rep = dict(frames=len(posed), face=int(face_ok.sum()), posed=int(posed.sum()),
               reprojection_iod=float(np.median(rel)) if len(rel) else float("nan"),
               max_jump_deg=float(max(jumps, default=0.0)), method=fr.attrs["model"].get("method"))
    log.info("target 3D fit (%s model): face in %d of %d frames, pose accepted in %d, median reprojection %.3f × IOD, "
             "largest pose jump %.1f°", rep["method"], rep["face"], rep["frames"], rep["posed"],
             rep["reprojection_iod"], rep["max_jump_deg"])
    s = p.speak
    if rep["face"] and (rep["posed"] < p.synthesize.min_target_fraction * rep["frames"]
                        or not rep["reprojection_iod"] <= s.max_reprojection_median):
        raise BadInputError(target, f"the 3D face model does not fit this video: median reprojection error "
                                    f"{rep['reprojection_iod']:.2f} × inter-ocular distance (limit "
                                    f"speak.max_reprojection_median={s.max_reprojection_median}), head pose accepted "
                                    f"in {rep['posed']} of {rep['frames']} frames ({rep['face']} with a face)")
    if rep["max_jump_deg"] > s.max_pose_jump_deg:
        log.warning("%s: the head pose jumps by %.1f° between two frames (speak.max_pose_jump_deg=%.0f): expect "
                    "a visible jump in the output there", target, rep["max_jump_deg"], s.max_pose_jump_deg)
    return rep


def front_end_advice(config: dict) -> str:
    """Which front end suits audio far from the training voice, for a model with ``config``
    (measured by bench/cross_speaker.py on GRID s1 models, see docs/front_ends.md)."""
    features = config.get("features", "mfcc")
    if features == "whisper":
        return "this model's front end (Whisper's encoder) was trained on many voices; lip sync on far voices may still be weaker"
    if front_ends.uses_mfcc(features):
        return ("a model trained on the whisper front end (train.features: whisper; pretrained on many speakers) "
                "follows other voices better")
    if features == "phonetic":
        return "this model's phone indicators do not depend on the voice, but expect the lips to lag by a few frames"
    return "this model already has the most voice-robust front end measured; lip sync on other voices stays weaker"


def audio_domain_check(samples, model: str, p: Params, audio: str) -> dict | None:
    """Warn (one line) when the audio is far from the model's training audio (``pipeline.audio.audio_domain``),
    naming the front end that would suit it."""
    from pipeline.audio import audio_domain
    from pipeline.audio import audio_features
    from pipeline.models.model_folder import read_config
    record = audio_domain.load(model)
    if record is None:
        return None
    res = audio_domain.assess(audio_features.mfcc_features(samples), record, p.speak.audio_shift_factor)
    if res["far"]:
        log.warning("%s: this audio is far from the model's training audio (MFCC shift %.2f training std; the "
                    "speaker's own held-out clips reach %.2f, limit speak.audio_shift_factor × that = %.2f): another "
                    "voice or microphone — expect weaker lip sync; %s", audio, res["shift"],
                    record["held_out_max"], res["limit"], front_end_advice(read_config(model)))
    else:
        log.info("audio: MFCC shift %.2f training std from the model's training audio (limit %.2f)", res["shift"],
                 res["limit"])
    return res


def choose_speaker(p: Params, model: str, target: str, cluster: SharedCluster | None = None) -> tuple[dict | None, dict]:
    """Is the target the model's speaker? Returns (the model's speaker when it is and its bank fits, report)."""
    speaker = load_speaker(model)
    if speaker is None:
        log.warning("%s has no speaker record (trained before identities were stored): treating the target as "
                    "another person (its own 3D model, mouths from the target only)", model)
        return None, dict(identity_distance=None, same_speaker=False)
    who = target_identity(p, p.speak.identity_frames, cluster)
    dist = identity.distance(who, speaker["identity"]) if who is not None else float("inf")
    same = dist < p.speak.same_speaker_distance
    log.info("identity: target is %.3f from the model's speaker (same person below speak.same_speaker_distance=%.2f, "
             "the corpus's own frames reach %.3f): %s", dist, p.speak.same_speaker_distance,
             float(speaker["identity_spread"].max()), "same speaker" if same else "another person")
    return (speaker if same else None), dict(identity_distance=round(dist, 4), same_speaker=bool(same))


def with_texture_window(params: Params, window: dict) -> Params:
    """A copy of ``params`` whose frontalize stage makes ``window`` (a store's ``texture_window``:
    x0, y0 mm, mm_per_px, size px) — the model's candidate bank and the target's textures must match."""
    p = copy.deepcopy(params)
    side = window["size"] * window["mm_per_px"]
    p.frontalize.texture_size = int(window["size"])
    p.frontalize.texture_x_mm = [window["x0"], window["x0"] + side]
    p.frontalize.texture_y_mm = [window["y0"], window["y0"] + side]
    return p


def same_window(a: dict, b: dict) -> bool:
    """Do two texture windows cover the same mm with the same pixels (up to float rounding)?"""
    return a["size"] == b["size"] and all(abs(a[k] - b[k]) <= 1e-9 * max(1.0, abs(a[k])) for k in ("x0", "y0", "mm_per_px"))


@dataclasses.dataclass
class Prepared:
    """What synthesis needs, once the target is preprocessed and the speaker known: the run's params, the
    target's stores (with the model's candidate bank for the model's own speaker), the target's index entry,
    the predicted mouth (None: predict in synthesis) and the report so far."""
    params: Params
    stores: dict
    entry: dict
    mouth: dict | None
    report: dict


def speak(audio: str, target: str, out: str, params: Params, model: str | None = None, retime: bool = True,
          cache: Path | None = None, diagnostic: bool = False, emotion=None, report_path: str | None = None) -> dict:
    """Write ``out`` (MP4): the speaker of ``target`` saying ``audio``.

    Returns ms/frame per phase and a ``report`` (identity distance, path taken, 3D fit, self-check), also
    written as JSON to ``report_path`` when given. Raises ``NoLipSyncError`` (after writing ``out``) when most
    output frames are the untouched target (``lip_sync_verdict``).
    """
    if not str(out).lower().endswith(".mp4"):
        raise ParameterError(f"--out {out}: expected an .mp4 file name")
    if not Path(out).absolute().parent.is_dir():
        raise ParameterError(f"--out {out}: the folder {Path(out).absolute().parent} does not exist")
    prep = prepare(audio, target, params, model, retime, cache, diagnostic, emotion)
    ms = synthesize_and_composite(prep, str(audio), str(target), out)
    prep.report["self_check"] = ms.pop("self_check", None)
    ms["report"] = prep.report
    if report_path is not None:
        Path(report_path).write_text(json.dumps(prep.report, indent=1, default=str) + "\n")
    lip_sync_verdict(prep.report["self_check"], prep.params.speak, target, out)
    return ms


CAUSES = dict(face_error="the rendered nose and chin are off the target's (its 3D fit does not hold there)",
              mouth_error="dlib reads another mouth on the output than the one synthesized",
              sharpness="the rendered mouth is far sharper than the target's own",
              not_posed="the target's head pose was not found (no face, or the 3D model does not fit)")


def lip_sync_verdict(check: dict | None, s, target: str, out: str) -> float | None:
    """Say plainly when lip sync was not made: the share of output frames left as the untouched target (the
    self-check's fallbacks and frames without a head pose) and its main cause.

    Logs one warning above ``s.warn_fallback_share``; raises ``NoLipSyncError`` above ``s.max_fallback_share``
    (``out`` is written: the message says so). Returns the share (None without a self-check)."""
    if not check or not check.get("frames"):
        return None
    counts = dict(check["failed_by"], not_posed=check["not_posed"])
    share = (check["fallen_back"] + check["not_posed"]) / check["frames"]
    if share <= s.warn_fallback_share:
        return share
    cause = max(counts, key=counts.get)
    line = (f"lip sync not made on {share:.0%} of the output frames ({check['fallen_back'] + check['not_posed']} of "
            f"{check['frames']}: the untouched target there); main cause: {CAUSES[cause]} ({counts[cause]} frames)")
    if share > s.max_fallback_share:
        raise NoLipSyncError(target, f"{line}; {out} was written anyway (speak.max_fallback_share="
                                     f"{s.max_fallback_share})")
    log.warning("%s: %s", target, line)
    return share


def synthesize_and_composite(prep: Prepared, audio: str, target: str, out: str) -> dict:
    """Texture synthesis, then compositing (each with its own threads) into ``out``; returns the thread time
    per frame of each phase (ms). (Run at the same time, handing frames over, the two took more CPU on
    two cores — their working sets evict each other from the caches — and were slower in all.)"""
    work = Path(tempfile.mkdtemp(prefix=".lipsynth-speak-", dir=Path(out).absolute().parent))
    try:
        ms = synthesize.run(prep.params, str(work / "synthesize.zarr"), prep.stores, prep.entry, mouth=prep.mouth)
        ms.update(composite.run(prep.params, str(work / "synthesize.zarr"), out, prep.params.frontalize.out,
                                target, audio))
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return ms


def prepare_target(target: str, params: Params, model: str, cache: Path | None = None,
                   cluster: SharedCluster | None = None, prepared_only: bool = False) -> tuple[Params, dict, dict, dict]:
    """Preprocess ``target`` (cached), decide whose mouths to use and open its stores: everything of ``speak`` that
    depends on the target and the model, not on the audio. Returns (the run's params, stores, the target's index
    entry, report). ``prepared_only``: refuse (``NotPreparedError``) instead of preprocessing (``lipsynth live``)."""
    cache = cache or default_cache()
    p = landmarked_target(Path(target), params, cache, cluster, prepared_only)
    speaker, report = choose_speaker(p, model, target, cluster)
    if speaker is not None and speaker["bank"] is not None:     # frontalize as the model's bank was: same window
        p = with_texture_window(p, open_group(speaker["bank"]).attrs["texture_window"])
    p = preprocess_target(Path(target), p, cache, shape3d=None if speaker is None else speaker["shape3d"],
                          shared=cluster, prepared_only=prepared_only)
    report["fit"] = fit_report(p, target)
    stores = synthesize.open_stores(p, pca=False)
    window = stores["frontalize"].attrs["texture_window"]
    if speaker is not None and speaker["bank"] is not None:
        bank = open_group(speaker["bank"])
        if same_window(bank.attrs["texture_window"], window):
            stores["bank"] = bank
        else:
            log.warning("the model's candidate bank has another texture window (%s) than these params (%s): "
                        "mouths from the target only", bank.attrs["texture_window"], window)
    # the model's PCA frame is the target's when both share the corpus 3D model and the bank
    p.synthesize.retarget = "never" if "bank" in stores else "always"
    report["path"] = "same speaker: corpus 3D model + candidate bank" if "bank" in stores else \
        "another person: own 3D model, target's mouths, re-targeted shapes"
    entry = dict(stores["frontalize"].attrs["videos"][0], path=str(target))     # messages name the user's file
    if "bank" not in stores:
        fr, lmg = stores["frontalize"], stores["landmarks"]
        own = synthesize.usable(fr, lmg, entry)
        shapes = np.asarray(fr["frontal_landmarks"][...], np.float64)[own][:, LIP_POINTS]
        iod_px = IOD_MM / window["mm_per_px"]
        n_shapes = distinct_shapes(shapes, 0.02 * iod_px)
        report["distinct_mouth_shapes"] = n_shapes
        if n_shapes < p.speak.min_mouth_shapes:
            log.warning("%s: the target covers only %d distinct mouth shapes (%d usable frames; "
                        "speak.min_mouth_shapes=%d): mouths it never showed are made by warping the nearest ones "
                        "(synthesize.detail: auto → aligned) — a longer target video of this person helps", target, n_shapes, len(own),
                        p.speak.min_mouth_shapes)
    log.info("speak: %s", report["path"])
    return p, stores, entry, report


def few_shapes(report: dict, p: Params) -> bool:
    """Does ``synthesize.detail: auto`` take ``aligned`` for this target? When another person's target covers fewer
    than ``speak.min_mouth_shapes`` distinct mouth shapes, the words' mouths are mostly not among its frames, and
    repeating the nearest (median, two_band) shows the few it has: warped onto the wanted shapes instead, the
    rendered opening follows the model (bench/cross_clip.py, GRID s4's 3-s targets: cross-clip opening corr
    per method on docs/cross_clip.md). Self-replay scores lower with it: its true frames, which two_band's
    Viterbi replays, are not what a dub has."""
    n = report.get("distinct_mouth_shapes")
    return p.synthesize.detail == "auto" and n is not None and n < p.speak.min_mouth_shapes


def prepare(audio: str, target: str, params: Params, model: str | None = None, retime: bool = True,
            cache: Path | None = None, diagnostic: bool = False, emotion=None) -> Prepared:
    """Check the inputs, preprocess ``target`` (cached), decide whose mouths to use and predict the mouth
    shapes of ``audio`` (in a thread, while the workers preprocess): everything of ``speak`` before synthesis."""
    for path, what in ((audio, "audio"), (target, "target video")):
        if not Path(path).is_file():
            raise BadInputError(path, f"{what} file not found")
    model = model or params.synthesize.model
    samples = load_audio(audio)                # a bad audio file fails now, not after preprocessing,
    fps = probe_video(str(target), params.ingest, require_audio=False)["fps"]   # so does a target failing header checks
    model = open_model(model)                  # and a bad model folder (any family): opened once, passed on
    check_emotion(model, emotion)              # and an emotion the model cannot take
    domain = audio_domain_check(samples, model, params, audio)
    # the mouth shapes depend on the audio, the model and the target's frame rate alone: predicted in a
    # thread of this process while the workers preprocess the target
    predicting = ThreadPoolExecutor(1, thread_name_prefix="predict_mouth")
    mouth = predicting.submit(predict_mouth, samples, model, fps, device=params.synthesize.device, source=str(audio),
                              emotion=emotion)
    try:
        with SharedCluster(target_cluster(params.cluster, target), warm_up=warm_up_worker) as cluster:   # one for all
            p, stores, entry, report = prepare_target(target, params, model, cache, cluster)
        report["audio_domain"] = domain
        p.synthesize.audio, p.synthesize.retime, p.synthesize.model = str(audio), retime, str(model)
        if few_shapes(report, p):
            p.synthesize.detail = "aligned"
            log.info("synthesize.detail: auto → aligned (the target covers %d distinct mouth shapes: the nearest "
                     "mouths are warped onto each wanted shape rather than repeated)", report["distinct_mouth_shapes"])
        p.synthesize.emotion = emotion
        p.composite.diagnostic = diagnostic
        return Prepared(p, stores, entry, mouth.result() if entry["fps"] == fps else None, report)
    finally:
        predicting.shutdown(wait=False, cancel_futures=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="lipsynth speak", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--audio", required=True, help="new speech: any audio or video file (any rate, channels)")
    ap.add_argument("--target", required=True, help="video of the speaker to put the speech into")
    ap.add_argument("--out", required=True, help="output MP4 (replaced only when the run succeeds)")
    ap.add_argument("--model", default=None, help="model folder of any family, or an ensemble of them (`lipsynth "
                    "ensemble`); default: synthesize.model of the params file")
    ap.add_argument("--no-retime", action="store_true",
                    help="keep the target's timing (paper §3.3 off; for evaluation against ground truth)")
    ap.add_argument("--diagnostic", action="store_true",
                    help="also write OUT.diagnostic.mp4: target | result | synthesized texture")
    ap.add_argument("--emotion", default=None,
                    help="Karras models: emotion candidate K, or K1:K2:t to interpolate two (default: the model's "
                         "default, candidate 0; list them with `lipsynth emotions --model DIR`)")
    ap.add_argument("--params", default=None,
                    help="params file (default: ./params.yaml, else the one installed with lipsynth)")
    ap.add_argument("--cache", type=Path, default=None,
                    help=f"folder for preprocessed targets (default: {default_cache()})")
    ap.add_argument("--report", default=None, metavar="JSON",
                    help="also write what speak found (identity, path, 3D fit, self-check with its fallbacks) as JSON")
    ap.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    a = ap.parse_args(argv)
    setup_logging(a.verbose)
    params = a.params or ("params.yaml" if Path("params.yaml").is_file() else Path(__file__).parents[1] / "params.yaml")
    return run_main(lambda: speak(a.audio, a.target, a.out, load_params(params), a.model,
                                  not a.no_retime, a.cache, a.diagnostic, a.emotion, a.report))


if __name__ == "__main__":
    raise SystemExit(main())
