"""``lipsynth personalize`` — a model of a new person from their footage (about a minute is enough).

    lipsynth personalize VIDEO [VIDEO ...] --out models/NAME [--base models/base | none]

1. Footage: fewer than five videos are cut into segments of ``--segment-seconds`` and split in time
   (``data.split: time``): the last ``--val-fraction`` of each video is held out. Clips too short to
   split on their own are pooled into one group in the order given, and the pool's last segments
   (its last clips) are held out. Five or more videos are split by whole video. One line says what
   was held out.
2. Preprocessing with the pipeline's own stages (ingest → landmarks → frontalize → pca → whisper)
   into ``--work`` (default ``runs/personalize/NAME``), with the params of ``--params`` otherwise.
   Footage whose mouth never moves (a photo, a still video) stops here with one line.
3. Adaptation of the base model (default: the shipped ``models/base``, GRID s1's read speech,
   hash-checked), after each recording's own audio–video offset is estimated and undone
   (``stages/train/offsets.py``): the base as is, two ridge read-outs (of its LSTM and of the encoder
   states), their average, the person's own shapes retrieved on a Viterbi path, and a fine-tune
   are scored fold by fold over the person's segments by opening correlation and mouth error; a
   candidate replaces the base only when it beats it beyond noise (``stages/train/selection.py``,
   ``stages/train/adapt.py``). ``--base none`` trains from scratch instead (``--steps`` optimizer
   steps). The model folder carries the person's candidate bank, identity and 3D face, so
   ``lipsynth speak --model models/NAME`` animates them.
4. The held-out figures (mouth error against the tracked lips, ratio to the mean shape, opening
   correlation) of each candidate and the time taken, printed.

The footage must show one person's face, with their speech. Too-short footage, footage without
audio or without a face stop with one line naming the file; so do footage in which another person
appears (a segment or video whose face is not the footage's person: ``lipsynth.footage_check``) and
footage whose face is tracked for less than 1.5 segments in all (each file's usable seconds listed).
"""
from __future__ import annotations

import argparse
import json
import logging
import shutil
import time
from pathlib import Path

import numpy as np
import yaml

from lipsynth import footage_check
from pipeline.errors import LipsynthError, ParameterError
from pipeline.io.runner import run_main, setup_logging
from pipeline.io import media
from pipeline.io.segments import cut_video, segment_bounds, time_split, video_seconds
from pipeline.params import as_dict, front_end_store, load_params, parse
from stages import registry
from stages.registry import PREPROCESSING

log = logging.getLogger("lipsynth.personalize")
FEW_VIDEOS = 5             # fewer videos than this are split in time, not by video
MIN_MOUTH_MOTION = 1.0     # % IOD: an inner-lip opening varying less than this is a mouth that never moves


def cut_footage(videos: list[Path], seconds: float, folder: Path, pool_name: str) -> list[Path]:
    """Segments of ``videos`` in ``folder``: each video its own time-split group when every one is long
    enough to split (≥ 1.5 segments), otherwise one pooled group ``<pool_name>_sNNN`` in the given order."""
    shutil.rmtree(folder, ignore_errors=True)
    durations = [video_seconds(media.probe(v)) for v in videos]
    if all(len(segment_bounds(d, seconds)) >= 2 for d in durations):
        return [seg for v in videos for seg in cut_video(v, seconds, folder)]
    out: list[Path] = []
    for v in videos:
        out += cut_video(v, seconds, folder, stem=pool_name, first_index=len(out), min_segments=1)
    if len(out) < 2:
        raise LipsynthError(f"{', '.join(map(str, videos))}: {sum(durations):.1f} s of footage in all: too short to split "
                            f"into training and held-out parts (needs at least {1.5 * seconds:g} s, or several clips)")
    log.info("%d clips too short to split on their own: pooled as %s_s000…%s_s%03d in the order given",
             len(videos), pool_name, pool_name, len(out) - 1)
    return out


def held_out_line(segments: list[Path], val_fraction: float) -> str:
    """One line naming the held-out segments and their share of the footage (pure but for probing)."""
    split = time_split([s.stem for s in segments], val_fraction)
    held = [s for s in segments if split[s.stem] == "val"]
    secs = {s: video_seconds(media.probe(s)) for s in segments}
    return (f"held out: {', '.join(s.name for s in held)} ({sum(secs[s] for s in held):.1f} s of "
            f"{sum(secs.values()):.1f} s, the end of the footage)")


def tracker_floor(ingest_path: str, landmark_params: dict) -> float:
    """``footage_check.tracker_floor`` on the first held-out clip; one line when it is below
    ``MIN_FLOOR_CORR`` (lips too noisy to learn from or to score)."""
    from pipeline.params import Landmarks
    clip, corr = footage_check.tracker_floor(ingest_path, Landmarks(**landmark_params))
    log.info("tracker floor: the lips tracked on %s and on its re-encoding correlate %.2f", clip, corr)
    if corr < footage_check.MIN_FLOOR_CORR:
        raise LipsynthError(f"{clip}: the tracked lips are too noisy to learn from (their opening on the clip and on "
                            f"its re-encoding correlate {corr:.2f}, at least {footage_check.MIN_FLOOR_CORR} needed): "
                            f"a larger, sharper or better-lit face is needed")
    if not np.isfinite(corr):
        log.warning("tracker floor: too few frames of %s tracked twice to measure it; not checked", clip)
    return corr


def mouth_motion_pct(landmarks_path: str) -> float:
    """How much the mouth moves: the standard deviation of the tracked inner-lip opening over all
    tracked frames, in % of the median interocular distance (speech: several %; a photo: tracker noise)."""
    from pipeline.face.dlib_face import interocular
    from pipeline.io.store import open_group
    from pipeline.measures.lipsync_measures import inner_opening
    g = open_group(landmarks_path)
    valid = np.asarray(g["valid"][...], bool)
    if valid.sum() < 2:
        return 0.0
    lms = np.asarray(g["landmarks"].oindex[np.flatnonzero(valid)], np.float64)
    return float(100 * inner_opening(lms).std() / np.median(interocular(lms)))


def plan(args, base_config: dict | None, footage, work: Path) -> dict:
    """The params tree of one personalization (pure apart from reading ``args.params``)."""
    tree = as_dict(load_params(args.params))
    tree["data"].update(videos=footage, val_fraction=args.val_fraction, on_bad_input="skip",
                        split="time" if args.segment_seconds else "video")
    for stage in ("ingest", "landmarks", "frontalize", "pca", "whisper", "phonetic"):
        tree[stage]["out"] = str(work / "store" / f"{stage}.zarr")
    t = tree["train"]
    t.update(out=str(args.out), metrics=str(work / "metrics.json"), plots=str(work / "train_loss.csv"),
             baselines=False, steps=args.steps, val_every=max(1, args.steps // 20), patience=None,
             init_from=None, fine_tune="all", extra_corpora=[])
    if base_config:
        t.update(features=base_config.get("features", "mfcc"), delay=int(base_config["delay"]),
                 feature_norm=base_config.get("feature_norm", "corpus"), vtlp_warps=[], pitch_shifts=[])
        if base_config.get("encoder"):
            tree["whisper"].update(window_seconds=base_config["encoder"]["window_s"],
                                   overlap_seconds=base_config["encoder"]["overlap_s"],
                                   layers=list(base_config["encoder"].get("layers", [5])))
    t["feature_store"] = front_end_store(tree)
    return as_dict(parse(tree, str(work / "params.yaml")))


def resolve_base(base: str | None) -> str | None:
    """The base model folder: the shipped one by default (hash-checked), None for ``none``."""
    from pipeline.models.base_model import SHIPPED, verify
    if base and base.lower() == "none":
        return None
    folder = Path(base) if base else SHIPPED
    if not base and not (folder / "MANIFEST.json").is_file():
        raise LipsynthError(f"{folder}: the shipped base model is missing (check out models/base, or rebuild it with "
                            f"`python bench/shipped_base.py`; --base none trains from scratch)")
    try:
        verify(folder)
    except LipsynthError as exc:
        raise ParameterError(f"--base: {exc}") from None
    return str(folder)


def run(args) -> dict:
    t0 = time.perf_counter()
    name = Path(args.out).name
    work = Path(args.work or Path("runs") / "personalize" / name)
    work.mkdir(parents=True, exist_ok=True)
    if not Path(args.out).parent.is_dir():
        raise ParameterError(f"--out {args.out}: folder {Path(args.out).parent} does not exist")
    args.base = resolve_base(args.base)
    base_config = None
    if args.base:
        from pipeline.models.mouth_prediction import open_model
        base_config = open_model(args.base).config      # the base checked whole before any long work
    videos = [Path(v) for v in args.videos]
    footage: list[str] | str = [str(v) for v in videos]
    if len(videos) < FEW_VIDEOS:
        folder = work / "footage"
        footage = str(folder)
        segments = cut_footage(videos, args.segment_seconds, folder, name)
        print(held_out_line(segments, args.val_fraction))
    else:
        args.segment_seconds = None
    params = plan(args, base_config, footage, work)
    pfile = work / "params.yaml"
    pfile.write_text(yaml.safe_dump(params, sort_keys=False, allow_unicode=True))
    times, floor = {}, float("nan")
    # the person's stores, then (from scratch only: with --base the candidates adapt the base) the LSTM
    stages = PREPROCESSING if args.base else (*PREPROCESSING, "train")
    for stage in stages:
        s0 = time.perf_counter()
        log.info("== %s", stage)
        code = registry.stage(stage).main(["--params", str(pfile)])
        if code:
            raise LipsynthError(f"personalize: the {stage} stage failed (params {pfile}); see the line above")
        if stage == "landmarks":            # one person, enough tracked face, lips the tracker sees — before the long stages
            footage_check.check(params["ingest"]["out"], params["landmarks"]["out"],
                                params["speak"]["same_speaker_distance"], min_seconds=1.5 * (args.segment_seconds or 10.0))
            motion = mouth_motion_pct(params["landmarks"]["out"])
            if motion < MIN_MOUTH_MOTION:
                raise LipsynthError(f"{', '.join(map(str, videos))}: the mouth barely moves in the footage (its opening "
                                    f"varies by {motion:.2f} % of the eye distance, at least {MIN_MOUTH_MOTION:g} % "
                                    f"needed): a photo or a still video cannot teach lip motion")
            floor = tracker_floor(params["ingest"]["out"], params["landmarks"])
        times[stage] = time.perf_counter() - s0
    if args.base:
        from pipeline.params import parse
        from stages.train import adapt
        s0 = time.perf_counter()
        log.info("== adapt (from %s)", args.base)
        metrics = adapt.run(parse(params, str(pfile)), args.base, anchor=args.anchor)
        times["adapt"] = time.perf_counter() - s0
    else:
        metrics = json.loads((work / "metrics.json").read_text())
    val, mean = metrics["val"], metrics["baseline_mean_shape"]
    summary = dict(model=str(args.out), base=args.base, steps=args.steps, seconds=round(time.perf_counter() - t0, 1),
                   stage_seconds={k: round(v, 1) for k, v in times.items()}, chosen=metrics.get("chosen", "scratch"),
                   candidates=metrics.get("candidates"), folds=(metrics.get("folds") or {}).get("table"),
                   offsets={k: {kk: v[kk] for kk in ("offset_ms", "best_lag_ms", "reliable", "reason")}
                            for k, v in (metrics.get("offsets") or {}).items()},
                   held_out_clips=val.get("n_clips"), mouth_error_iod_pct=val["mouth_error_iod_pct"],
                   ratio_to_mean_shape=metrics["ratio_to_mean_shape"], opening_corr=val.get("median_opening_corr"),
                   mean_shape_error_iod_pct=mean["mouth_error_iod_pct"], tracker_floor_corr=floor)
    (work / "summary.json").write_text(json.dumps(summary, indent=2))
    print(f"personalized {args.out} in {summary['seconds'] / 60:.1f} min "
          f"({', '.join(f'{k} {v:.0f} s' for k, v in times.items())})")
    for cand, f in (metrics.get("candidates") or {}).items():
        print(f"  candidate {cand:<15} held-out ratio to the mean shape {f['ratio_to_mean_shape']:.2f}, opening "
              f"correlation {f['median_opening_corr']:.2f}{'   ← kept' if cand == metrics['chosen'] else ''}")
    print(f"held-out footage ({val.get('n_clips')} clips): mouth error {val['mouth_error_iod_pct']:.2f} % IOD "
          f"(mean shape {mean['mouth_error_iod_pct']:.2f} %, ratio {metrics['ratio_to_mean_shape']:.2f}), "
          f"opening correlation {val.get('median_opening_corr', float('nan')):.2f}")
    if metrics["ratio_to_mean_shape"] >= 1.0:
        print(f"warning: worse than the person's mean mouth shape on the held-out part (ratio "
              f"{metrics['ratio_to_mean_shape']:.2f}): the tracked lips of this footage follow the speech too little")
    print(f"next: lipsynth speak --model {args.out} --audio SPEECH --target VIDEO_OF_THEM --out out.mp4")
    return summary


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="lipsynth personalize", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("videos", nargs="+", help="footage of the person (one video of about a minute is enough)")
    ap.add_argument("--out", required=True, help="the model folder to write (models/NAME)")
    ap.add_argument("--base", help="the base model to adapt (default: the shipped models/base, GRID s1 read speech); "
                                   "none: train from scratch")
    ap.add_argument("--steps", type=int, default=600, help="training budget in optimizer steps (default 600)")
    ap.add_argument("--anchor", type=float, default=1e-3,
                    help="fine-tuning's pull toward the base weights, λ in λ·Σ‖θ − θ₀‖² (default 0.001)")
    ap.add_argument("--segment-seconds", type=float, default=10.0,
                    help="fewer than 5 videos are cut into segments of this length and split in time (default 10)")
    ap.add_argument("--val-fraction", type=float, default=0.2, help="share held out (default 0.2: the last fifth)")
    ap.add_argument("--params", default="params.yaml", help="params for everything else (default params.yaml)")
    ap.add_argument("--work", help="folder for the segments, stores and metrics (default runs/personalize/NAME)")
    ap.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    a = ap.parse_args(argv)
    setup_logging(a.verbose)
    return run_main(run, a)


if __name__ == "__main__":
    raise SystemExit(main())
