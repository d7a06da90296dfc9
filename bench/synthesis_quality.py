"""Quality of audio → video on real footage: clips as their own target (paper 000 §4.1, Video J).

Each validation clip of a preprocessed corpus is re-synthesized from its own audio into itself
without re-timing; the output is compared with the original (``lipsynth.lipsync_quality``):
mouth landmark error next to a static mouth, inner-lip opening correlation, mouth-region mean
absolute difference, sharpness ratio, flicker ratio. Also prints ms/frame per phase.

    python bench/synthesis_quality.py --params runs/grid_s1/params.yaml --clips 20 --exclude-target
    python bench/synthesis_quality.py --params runs/grid_s1/params.yaml --clips 20 --path speak

``--path speak`` runs ``lipsynth speak`` on each validation clip's file (held out of training,
preprocessed outside the corpus store) — the product's path; the default is the DVC path.

``--params`` is the corpus's params file (its stores and model); the synthesize/composite
settings come from the project's params.yaml. Writes ``--out``/quality.json, per-clip MP4s and
a PNG strip (original | output) of the first clip.
"""
from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import logging
import shutil
import time
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import cv2
import numpy as np
import yaml


from lipsynth import lipsync_quality as quality
from pipeline.params import check, load_params
from pipeline.io.runner import setup_logging
from lipsynth.speak import speak
from stages.composite import composite
from stages.synthesize import synthesize

ROOT = Path(__file__).resolve().parents[1]


def strip(original: Path, output: Path, box, frames=(10, 25, 40, 55)) -> np.ndarray:
    """Mouth crops of the original (top) and output (bottom) at a few frames, ×3."""
    from pipeline.io import media
    rows = []
    for path in (original, output):
        imgs = {i: f for i, (_, f) in enumerate(media.iter_frames(path)) if i in frames}
        x0, y0, x1, y1 = box
        rows.append(np.hstack([imgs[i][y0:y1, x0:x1] for i in frames if i in imgs]))
    s = np.vstack(rows)
    return cv2.resize(s, None, fx=3, fy=3, interpolation=cv2.INTER_CUBIC)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--params", required=True, help="params file of the preprocessed corpus (stores, model)")
    ap.add_argument("--clips", type=int, default=10, help="validation clips to evaluate")
    ap.add_argument("--exclude-target", action="store_true",
                    help="candidates only from training videos (the true frames cannot be copied)")
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="override a synthesize/composite param, e.g. --set synthesize.n=20 (repeatable)")
    ap.add_argument("--path", choices=("store", "speak"), default="store",
                    help="store: the DVC path (target read from the corpus store); speak: what users run — "
                         "`lipsynth speak` on the clip's file, preprocessed outside the store (the clip is held out "
                         "of training: a validation clip)")
    ap.add_argument("--names", nargs="*", default=None, help="evaluate these validation clips (names) instead")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "quality")
    a = ap.parse_args()
    setup_logging()
    logging.getLogger("lipsynth.composite").setLevel(logging.WARNING)
    corpus = load_params(a.params)
    project = load_params(ROOT / "params.yaml")
    a.out.mkdir(parents=True, exist_ok=True)
    stores = synthesize.open_stores(corpus)
    videos = [v for v in stores["frontalize"].attrs["videos"]
              if v["split"] == "val" and v["n_frames"] and not v.get("excluded")]
    if a.names:
        videos = [v for v in videos if v["name"] in a.names]
    else:       # spread over the validation clips
        videos = sorted(videos, key=lambda v: v["name"])
        videos = [videos[k] for k in np.unique(np.linspace(0, len(videos) - 1, min(a.clips, len(videos))).round().astype(int))]
    results, timings, walls = [], [], []
    for v in videos:
        p = copy.deepcopy(corpus)
        p.synthesize = dataclasses.replace(project.synthesize, audio=v["path"], target=v["name"], retime=False,
                                           model=corpus.train.out, exclude_target_from_pool=a.exclude_target)
        p.composite = dataclasses.replace(project.composite, diagnostic=False)
        for item in a.set:
            key, value = item.split("=", 1)
            section, name = key.split(".", 1)
            setattr(getattr(p, section), name, yaml.safe_load(value))
            check(getattr(p, section), section, "--set")
        store = a.out / f".{v['name']}.synthesize.zarr"
        mp4 = a.out / f"{v['name']}.mp4"
        t0 = time.perf_counter()
        if a.path == "speak":
            ms = speak(v["path"], v["path"], str(mp4), p, model=corpus.train.out, retime=False, cache=a.out / "cache")
            report = ms.pop("report")
        else:
            ms = synthesize.run(p, str(store), stores, v)
            ms.update(composite.run(p, str(store), str(mp4), corpus.frontalize.out, v["path"], v["path"]))
            report = dict(self_check=ms.pop("self_check", None))
        walls.append((time.perf_counter() - t0) / v["n_frames"])
        shutil.rmtree(store, ignore_errors=True)
        out = quality.video_landmarks(mp4, corpus.landmarks)
        ref = quality.video_landmarks(v["path"], corpus.landmarks)
        q = quality.compare(*out, *ref)
        q["clip"] = v["name"]
        q["fallen_back"] = (report.get("self_check") or {}).get("fallen_back")
        q["identity_distance"] = report.get("identity_distance")
        results.append(q)
        timings.append(ms)
        print(f"{v['name']}: mouth {q['mouth_error_px']:.2f} px ({q['mouth_error_iod_pct']:.2f}% IOD), static "
              f"{q['static_mouth_error_px']:.2f} px, opening corr {q['opening_corr']:.3f}, MAD {q['mouth_mad']:.1f}, "
              f"sharpness {q['sharpness_ratio']:.2f}, flicker {q['flicker_ratio']:.2f}, best lag {q['opening_best_lag']}, "
              f"fallen back {q['fallen_back']}", flush=True)
        if len(results) == 1:
            cv2.imwrite(str(a.out / f"{v['name']}_mouth_strip.png"), strip(Path(v["path"]), mp4, q["mouth_box"])[..., ::-1])
    keys = ["mouth_error_px", "mouth_error_iod_pct", "static_mouth_error_px", "static_mouth_error_iod_pct",
            "opening_corr", "mouth_mad", "sharpness_ratio", "flicker_ratio"]
    median = {k: float(np.nanmedian([r[k] for r in results])) for k in keys}
    median["error_ratio"] = median["mouth_error_px"] / median["static_mouth_error_px"]
    median["within_1_frame"] = float(np.mean([abs(r["opening_best_lag"]) <= 1 for r in results]))
    keys += ["error_ratio", "within_1_frame"]
    phases = {k: float(np.median([t.get(k, 0.0) for t in timings])) for k in timings[0]}
    summary = dict(clips=len(results), path=a.path, exclude_target=a.exclude_target,
                   frames_fallen_back=int(sum(r["fallen_back"] or 0 for r in results)), overrides=a.set, median=median, ms_per_frame_median=phases,
                   per_clip=results)
    (a.out / "quality.json").write_text(json.dumps(summary, indent=2) + "\n")
    print("\nmedian over", len(results), "clips:")
    for k in keys:
        print(f"  {k:<28} {median[k]:.3f}")
    print("thread time, ms/frame (median over clips):", ", ".join(f"{k} {v:.1f}" for k, v in phases.items()),
          f"; wall {1000 * np.median(walls):.1f} ms/frame → {1 / np.median(walls):.1f} frames/s")


if __name__ == "__main__":
    main()
