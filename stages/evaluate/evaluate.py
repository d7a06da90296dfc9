"""evaluate — the synthesized video against ground truth on validation clips (paper 000 §4.1, Video J).

Each of ``evaluate.clips`` validation clips (spread over the validation split by name) is
re-synthesized from its own audio into itself, without re-timing and — with
``evaluate.exclude_target_from_pool`` — with mouth candidates only from other videos, so the true
frames cannot be copied. The clip then has a ground truth: its original frames. Synthesis and
compositing run the ``synthesize`` and ``composite`` stages' own entry points in a subprocess
(a stage imports no other stage) with a temporary params file; everything else comes from the
project's params (model, stores, synthesize/composite settings).

Landmarks of the original are found per frame (dlib HOG box + 68 points); the output is read
with the original's boxes (same head pose, same timing), so differences are the mouth's. The
pure measures are ``pipeline.measures.lipsync_measures``: mouth landmark error (px, % IOD) next to a
static mouth, inner-lip opening correlation and best lag, mouth MAD, sharpness and flicker ratios.

Outputs: ``evaluate.metrics`` (per clip and medians) and ``evaluate.out``/ with per clip
``<clip>.mp4`` (the result), ``<clip>.diagnostic.mp4`` (target | result | texture, when
``evaluate.diagnostic``) and ``<clip>.opening.csv`` (inner-lip opening per frame of the output and
of the original, px). Per-phase timing goes to ``logs/evaluate.timing.json`` (untracked).

Run: ``python -m stages.evaluate.evaluate``.
"""
from __future__ import annotations

import json
import logging
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import yaml

from pipeline.face import dlib_face
from pipeline.io import media
from pipeline.errors import LipsynthError
from pipeline.measures.lipsync_measures import compare, inner_opening
from pipeline.params import Params, as_dict
from pipeline.io.runner import stage_main, write_timing
from pipeline.io.store import atomic_output, open_group

log = logging.getLogger("lipsynth.evaluate")
MEDIAN_KEYS = ["mouth_error_px", "mouth_error_iod_pct", "static_mouth_error_px", "static_mouth_error_iod_pct",
               "opening_corr", "mouth_mad", "sharpness_ratio", "flicker_ratio"]


def pick_clips(videos: list[dict], n: int) -> list[dict]:
    """``n`` validation clips spread over the validation split sorted by name (all when fewer)."""
    val = sorted((v for v in videos if v.get("split") == "val" and v.get("n_frames") and not v.get("excluded")),
                 key=lambda v: v["name"])
    if not val or n <= 0:
        return []
    picks = np.unique(np.linspace(0, len(val) - 1, min(n, len(val))).round().astype(int))
    return [val[k] for k in picks]


def clip_params(params: Params, video: dict, work: Path, exclude_target: bool, diagnostic: bool) -> dict:
    """The params tree that synthesizes ``video`` from its own audio into itself, outputs in ``work``."""
    tree = as_dict(params)
    tree["synthesize"].update(audio=video["path"], target=video["name"], retime=False,
                              exclude_target_from_pool=exclude_target, out=str(work / "synthesize.zarr"))
    tree["composite"].update(out_dir=str(work / "composite"), diagnostic=diagnostic)
    return tree


# the stages run as subprocesses (a stage imports no other stage); `lipsynth dvc-deps` reads this
SUBPROCESS_MODULES = ("stages.synthesize.synthesize", "stages.composite.composite")


def run_stage_subprocess(module: str, params_file: Path) -> None:
    """``python -m <module> --params <file>`` from the project root; a failure stops with its last line."""
    r = subprocess.run([sys.executable, "-m", module, "--params", str(params_file)], capture_output=True, text=True)
    if r.returncode != 0:
        last = (r.stderr.strip().splitlines() or ["(no output)"])[-1]
        raise LipsynthError(f"evaluate: {module} failed on {params_file.name}: {last}")


def landmarks_with_boxes(path, boxes: list | None, upsample: int = 1):
    """Grey frames (N, H, W), landmarks (N, 68, 2) and validity (N,) of a video. With ``boxes=None``
    a face is detected on every frame; the boxes used are returned too (None where none was found)."""
    grays = np.stack([np.ascontiguousarray(g) for _, g in media.iter_frames(path, "gray")])
    lms = np.zeros((len(grays), 68, 2))
    ok = np.zeros(len(grays), bool)
    used = []
    for i, g in enumerate(grays):
        if boxes is None:
            found = dlib_face.detect_face(g, upsample)
            box = None if found is None else found[0]
        else:
            box = boxes[i] if i < len(boxes) else None
        used.append(box)
        if box is not None:
            lms[i] = dlib_face.predict_landmarks(g, box)
            ok[i] = True
    return grays, lms, ok, used


def measure(result: Path, original: Path, upsample: int = 1) -> tuple[dict, np.ndarray]:
    """Measures of ``result`` against ``original`` and the opening series (N, 2): output, original (px)."""
    ref_g, ref_lm, ref_ok, boxes = landmarks_with_boxes(original, None, upsample)
    out_g, out_lm, out_ok, _ = landmarks_with_boxes(result, boxes)
    q = compare(out_g, out_lm, out_ok, ref_g, ref_lm, ref_ok)
    n = q["frames"]
    series = np.full((n, 2), np.nan)
    series[out_ok[:n], 0] = inner_opening(out_lm[:n][out_ok[:n]])
    series[ref_ok[:n], 1] = inner_opening(ref_lm[:n][ref_ok[:n]])
    return q, series


def summarise(results: list[dict]) -> dict:
    """Medians over clips (NaN-safe), the error ratio to a static mouth and the share within one frame."""
    if not results:
        return {}
    med = {k: float(np.nanmedian([r[k] for r in results])) for k in MEDIAN_KEYS}
    med["error_ratio"] = med["mouth_error_px"] / med["static_mouth_error_px"]
    med["within_1_frame"] = float(np.mean([abs(r["opening_best_lag"]) <= 1 for r in results]))
    return med


def rounded(x, digits: int = 6):
    """Floats rounded (stable JSON across last-bit differences); NaN → None."""
    if isinstance(x, dict):
        return {k: rounded(v, digits) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [rounded(v, digits) for v in x]
    if isinstance(x, float):
        return None if not np.isfinite(x) else round(x, digits)
    return x


def write_opening_csv(path: Path, series: np.ndarray, fps: float) -> None:
    lines = ["frame,time_s,output_px,original_px"]
    for i, (o, r) in enumerate(series):
        f = lambda v: "" if not np.isfinite(v) else f"{v:.3f}"
        lines.append(f"{i},{i / fps:.4f},{f(o)},{f(r)}")
    path.write_text("\n".join(lines) + "\n")


def run(params: Params) -> dict:
    e = params.evaluate
    videos = open_group(params.frontalize.out).attrs["videos"]
    clips = pick_clips(videos, e.clips)
    if not clips:
        raise LipsynthError(f"evaluate: no validation clips in {params.frontalize.out} (data.val_fraction)")
    logs = Path("logs")
    saved = {n: (logs / n).read_bytes() for n in ("synthesize.timing.json", "composite.timing.json")
             if (logs / n).is_file()}
    results, timing = [], {}
    try:
        with atomic_output(e.out) as tmp:
            tmp.mkdir(parents=True)
            for v in clips:
                t0 = time.perf_counter()
                work = tmp / f".work-{v['name']}"
                work.mkdir()
                pfile = work / "params.yaml"
                pfile.write_text(yaml.safe_dump(clip_params(params, v, work, e.exclude_target_from_pool, e.diagnostic),
                                                sort_keys=False, allow_unicode=True))
                for module in SUBPROCESS_MODULES:
                    run_stage_subprocess(module, pfile)
                t1 = time.perf_counter()
                comp = json.loads((logs / "composite.timing.json").read_text())
                os.replace(work / "composite" / "result.mp4", tmp / f"{v['name']}.mp4")
                if e.diagnostic:
                    os.replace(work / "composite" / "result.diagnostic.mp4", tmp / f"{v['name']}.diagnostic.mp4")
                shutil.rmtree(work)
                q, series = measure(tmp / f"{v['name']}.mp4", Path(v["path"]), params.landmarks.detect_upsample)
                write_opening_csv(tmp / f"{v['name']}.opening.csv", series, float(v["fps"]))
                q.update(clip=v["name"], fps=float(v["fps"]), fallen_back=comp.get("self_check_fallen_back"),
                         video=f"{v['name']}.mp4",
                         diagnostic_video=f"{v['name']}.diagnostic.mp4" if e.diagnostic else None,
                         opening_csv=f"{v['name']}.opening.csv")
                results.append(q)
                timing[v["name"]] = {"synthesize_composite_s": t1 - t0, "measure_s": time.perf_counter() - t1}
                log.info("%s: mouth %.2f px (%.2f%% IOD), static %.2f px, opening corr %.3f, sharpness %.2f, "
                         "flicker %.2f", v["name"], q["mouth_error_px"], q["mouth_error_iod_pct"],
                         q["static_mouth_error_px"], q["opening_corr"], q["sharpness_ratio"], q["flicker_ratio"])
    finally:
        for n, data in saved.items():      # the subprocesses wrote their timings over the DVC stages' ones
            (logs / n).write_bytes(data)
    summary = rounded({"model": params.train.model, "model_folder": params.synthesize.model,
                       "setting": "Video J: each clip re-synthesized from its own audio, no re-timing",
                       "exclude_target_from_pool": e.exclude_target_from_pool, "clips": len(results),
                       "out": e.out, "median": summarise(results), "per_clip": results})
    with atomic_output(e.metrics, suffix=".json") as part:
        part.write_text(json.dumps(summary, indent=2) + "\n")
    flat = {f"{c}_{k}": v for c, t in timing.items() for k, v in t.items()}
    write_timing("evaluate", flat)     # seconds per clip (untracked: timings differ from run to run)
    return summary


def main(argv=None) -> int:
    return stage_main("lipsynth evaluate", __doc__, run, argv)


if __name__ == "__main__":
    raise SystemExit(main())
