"""``lipsynth personalize`` — a model of a new person from their footage (about a minute is enough).

    lipsynth personalize VIDEO [VIDEO ...] --out models/NAME [--base models/BASE]

1. Footage: one video (or a few) is cut into segments of ``--segment-seconds`` and split in time —
   the last ``--val-fraction`` of each video is held out (``data.split: time``); many clips are split
   by whole clip as usual.
2. Preprocessing with the pipeline's own stages (ingest → landmarks → frontalize → pca → whisper)
   into ``--work`` (default ``runs/personalize/NAME``), with the params of ``--params`` otherwise.
3. Training the LSTM on the person's training part: fine-tuned from ``--base`` (a base model,
   ``bench/base_model.py``; its read-out is re-expressed in the person's mouth PCA) or from scratch,
   with ``--steps`` optimizer steps. The model folder carries the person's candidate bank, identity
   and 3D face, so ``lipsynth speak --model models/NAME`` animates them.
4. Evaluation on the held-out part (mouth error against the tracked lips, ratio to the mean shape,
   opening correlation) and the time taken, printed.

The footage must show one person's face, with their speech. Too-short footage, footage without
audio or without a face stop with one line naming the file; so do footage in which another person
appears (a segment or video whose face is not the footage's person: ``lipsynth.footage_check``) and
footage whose face is tracked for less than 1.5 segments in all (each file's usable seconds listed).
"""
from __future__ import annotations

import argparse
import importlib
import json
import logging
import sys
import time
from pathlib import Path

import yaml

from lipsynth import footage_check
from pipeline.errors import LipsynthError, ParameterError
from pipeline.io.runner import run_main, setup_logging
from pipeline.io.segments import cut_video
from pipeline.params import as_dict, load_params, parse

log = logging.getLogger("lipsynth.personalize")
STAGES = (("ingest", "stages.ingest.ingest"), ("landmarks", "stages.landmarks.landmarks"),
          ("frontalize", "stages.frontalize.frontalize"), ("pca", "stages.pca.pca"),
          ("whisper", "stages.whisper.whisper"), ("train", "stages.train.train"))
FEW_VIDEOS = 5             # fewer videos than this are split in time, not by video


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
             init_from=str(args.base) if args.base else None, fine_tune=args.fine_tune, extra_corpora=[])
    if base_config:
        t.update(features=base_config.get("features", "mfcc"), delay=int(base_config["delay"]),
                 feature_norm=base_config.get("feature_norm", "corpus"), vtlp_warps=[], pitch_shifts=[])
        if base_config.get("encoder"):
            tree["whisper"].update(window_seconds=base_config["encoder"]["window_s"],
                                   overlap_seconds=base_config["encoder"]["overlap_s"])
    return as_dict(parse(tree, str(work / "params.yaml")))


def run(args) -> dict:
    t0 = time.perf_counter()
    name = Path(args.out).name
    work = Path(args.work or Path("runs") / "personalize" / name)
    work.mkdir(parents=True, exist_ok=True)
    if not Path(args.out).parent.is_dir():
        raise ParameterError(f"--out {args.out}: folder {Path(args.out).parent} does not exist")
    base_config = None
    if args.base:
        from pipeline.models.model_folder import read_config
        base_config = read_config(args.base)
        if base_config["model"] != "lstm":
            raise ParameterError(f"--base {args.base}: a {base_config['model']} model; personalize fine-tunes LSTMs")
    videos = [Path(v) for v in args.videos]
    footage: list[str] | str = [str(v) for v in videos]
    if len(videos) < FEW_VIDEOS:
        folder = work / "footage"
        footage = str(folder)
        for v in videos:
            cut_video(v, args.segment_seconds, folder)
    else:
        args.segment_seconds = None
    params = plan(args, base_config, footage, work)
    pfile = work / "params.yaml"
    pfile.write_text(yaml.safe_dump(params, sort_keys=False, allow_unicode=True))
    times = {}
    for stage, module in STAGES:
        s0 = time.perf_counter()
        log.info("== %s", stage)
        code = importlib.import_module(module).main(["--params", str(pfile)])
        if code:
            raise LipsynthError(f"personalize: the {stage} stage failed (params {pfile}); see the line above")
        if stage == "landmarks":            # one person, enough tracked face — before the long stages
            footage_check.check(params["ingest"]["out"], params["landmarks"]["out"],
                                params["speak"]["same_speaker_distance"], min_seconds=1.5 * (args.segment_seconds or 10.0))
        times[stage] = time.perf_counter() - s0
    metrics = json.loads((work / "metrics.json").read_text())
    val, mean = metrics["val"], metrics["baseline_mean_shape"]
    summary = dict(model=str(args.out), base=str(args.base) if args.base else None, fine_tune=args.fine_tune,
                   steps=args.steps, seconds=round(time.perf_counter() - t0, 1),
                   stage_seconds={k: round(v, 1) for k, v in times.items()},
                   held_out_clips=val.get("n_clips"), mouth_error_iod_pct=val["mouth_error_iod_pct"],
                   ratio_to_mean_shape=metrics["ratio_to_mean_shape"], opening_corr=val.get("median_opening_corr"),
                   mean_shape_error_iod_pct=mean["mouth_error_iod_pct"])
    (work / "summary.json").write_text(json.dumps(summary, indent=2))
    print(f"personalized {args.out} in {summary['seconds'] / 60:.1f} min "
          f"({', '.join(f'{k} {v:.0f} s' for k, v in times.items())})")
    print(f"held-out footage ({val.get('n_clips')} clips): mouth error {val['mouth_error_iod_pct']:.2f} % IOD "
          f"(mean shape {mean['mouth_error_iod_pct']:.2f} %, ratio {metrics['ratio_to_mean_shape']:.2f}), "
          f"opening correlation {val.get('median_opening_corr', float('nan')):.2f}")
    print(f"next: lipsynth speak --model {args.out} --audio SPEECH --target VIDEO_OF_THEM --out out.mp4")
    return summary


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="lipsynth personalize", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("videos", nargs="+", help="footage of the person (one video of about a minute is enough)")
    ap.add_argument("--out", required=True, help="the model folder to write (models/NAME)")
    ap.add_argument("--base", help="a base model to fine-tune (bench/base_model.py); none: train from scratch")
    ap.add_argument("--fine-tune", choices=("all", "output"), default="all",
                    help="with --base: train all weights (default) or only the read-out layer")
    ap.add_argument("--steps", type=int, default=600, help="training budget in optimizer steps (default 600)")
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
