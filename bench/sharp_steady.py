"""Sharp and steady: the mouth's detail and flicker per resolution, per synthesis method.

For held-out clips of people with a personalized model (``bench/person_diagnosis.py`` made them
under ``runs/diagnosis/``) and upscaled copies of one of them (1080 and 2160 lines), runs
``lipsynth speak`` with the clip's own audio into the clip (no re-timing: the original is the
ground truth, paper 000's Video J) once per ``synthesize.detail`` method, and compares output with
original (``lipsynth.lipsync_quality``, dlib on both):

* sharpness — variance of the Laplacian in the mouth box, output / original;
* detail energy — mean power of the band below ≈ IOD/8 wavelengths, output / original (the band
  scales with the face, so 256² and 4K are measured alike);
* flicker — mean |frame difference| in the box, output / original;
* detail flicker — that band's change between frames after DIS motion compensation, output / original;
* mouth error / static mouth error and the inner-lip opening correlation (lip sync must not suffer).

Writes ``results/sharp_steady.json`` (with commit, date and machine), ``docs/sharp_steady.md`` with
its chart ``docs/img/sharp_steady.png`` and side-by-side mouth crops (original | median |
aligned | two_band) ``docs/img/sharp_steady_<case>.jpg``.

    python bench/sharp_steady.py                  # all cases (~15 min on 2 cores)
    python bench/sharp_steady.py --cases 512 720  # some
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import re
import subprocess
import sys
import time
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import cv2
import numpy as np
import yaml


from lipsynth import lipsync_quality as quality
from pipeline.io import media
from pipeline.params import load_params

ROOT = Path(__file__).resolve().parents[1]
DIAG = ROOT / "runs" / "diagnosis"
SHARED = ROOT.parent / "shared" / "data"
WORK = ROOT / "bench" / "results" / "sharp_steady"
METHODS = ("median", "aligned", "two_band")
# name → (model folder, held-out clip, upscale to this many lines or None)
CASES = {
    "256": (DIAG / "lieu" / "model", DIAG / "lieu" / "w" / "footage" / "lieu_60s_s005.mp4", None),
    "512": (DIAG / "hdtf_aoc" / "model", DIAG / "hdtf_aoc" / "w" / "footage" / "WDA_AlexandriaOcasioCortez_000_s002.mp4", None),
    "720x576": (DIAG / "grid_s4" / "model", SHARED / "grid_s4" / "brwt1n.mp4", None),
    "1080": (DIAG / "hdtf_aoc" / "model", DIAG / "hdtf_aoc" / "w" / "footage" / "WDA_AlexandriaOcasioCortez_000_s002.mp4", 1080),
    "2160": (DIAG / "hdtf_aoc" / "model", DIAG / "hdtf_aoc" / "w" / "footage" / "WDA_AlexandriaOcasioCortez_000_s002.mp4", 2160),
}
# the same footage with the face stored as small as before the texture followed the face to 512 px (crop capped
# at 448 px, texture at 256 px: at 1080 and 2160 lines the face is stored smaller than it is filmed)
COARSER = {"ingest": {"max_crop_size": 448}, "frontalize": {"max_texture_size": 256}}
VARIANTS = {"1080 tex256": ("1080", COARSER), "2160 tex256": ("2160", COARSER)}
# the same people's source footage, for ``--model`` (a model of your choice instead of the diagnosis ones)
SOURCES = {"256": SHARED / "lieu" / "lieu_60s.mp4", "512": SHARED / "hdtf" / "WDA_AlexandriaOcasioCortez_000.mp4",
           "720x576": SHARED / "grid_s4" / "brwt1n.mp4", "1080": SHARED / "hdtf" / "WDA_AlexandriaOcasioCortez_000.mp4",
           "2160": SHARED / "hdtf" / "WDA_AlexandriaOcasioCortez_000.mp4"}
KEYS = ("sharpness_ratio", "detail_energy_ratio", "flicker_ratio", "detail_flicker_ratio", "error_ratio", "opening_corr")


def upscaled(clip: Path, lines: int) -> Path:
    """``clip`` resized (Lanczos) to ``lines`` rows, aspect kept, its audio copied; cached."""
    out = WORK / "footage" / f"{clip.stem}_{lines}.mp4"
    if out.is_file():
        return out
    out.parent.mkdir(parents=True, exist_ok=True)
    info = media.probe(clip)
    size = (int(round(info.width * lines / info.height / 2)) * 2, lines)
    samples, _ = media.read_audio(clip)
    media.write_video(out, (cv2.resize(f, size, interpolation=cv2.INTER_LANCZOS4) for _, f in media.iter_frames(clip)),
                      info.fps, audio=samples, crf=16)
    return out


def speak(model: Path, clip: Path, out: Path, params: Path, tracked: bool = False) -> tuple[float, dict]:
    """Run ``lipsynth speak`` (own audio, own target, no re-timing): wall seconds and the texture
    synthesis phases (thread ms per frame) from its log. ``tracked``: the same run with the target's
    own tracked lips in place of the model's shapes (``bench/speak_oracle.py``)."""
    t0 = time.perf_counter()
    command = ([sys.executable, str(ROOT / "bench" / "speak_oracle.py")] if tracked else
               [sys.executable, "-m", "lipsynth.cli", "speak", "--no-retime"])
    r = subprocess.run([*command, "--model", str(model), "--audio", str(clip), "--target", str(clip), "--out", str(out),
                        "--params", str(params), "--cache", str(WORK / "cache")], cwd=ROOT, capture_output=True, text=True)
    if r.returncode:
        raise SystemExit(f"speak failed on {clip}: {r.stderr.strip()[-800:]}")
    seconds = time.perf_counter() - t0
    line = next((s for s in r.stderr.splitlines() if "synthesized" in s and "thread time per frame" in s), "")
    phases = dict((k, float(v)) for k, v in re.findall(r"(\w+) ([\d.]+)", line.split("thread time per frame:")[-1]))
    return seconds, phases


def mouth_strip(paths: list[Path], box, frames=(12, 30, 48)) -> np.ndarray:
    """Rows: one per video (original, then each method); columns: mouth crops at ``frames``."""
    x0, y0, x1, y1 = box
    rows = []
    for path in paths:
        imgs = {i: f for i, (_, f) in enumerate(media.iter_frames(path)) if i in frames}
        rows.append(np.hstack([imgs[i][y0:y1, x0:x1] for i in frames if i in imgs]))
    s = np.vstack(rows)
    scale = 720 / s.shape[1]
    return cv2.resize(s, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_CUBIC)


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 4, figsize=(16, 4.2))
    cases = list(dict.fromkeys(r["case"] for r in rows))
    methods = list(dict.fromkeys(r["method"] for r in rows))
    width = 0.8 / len(methods)
    for ax, key in zip(axes, KEYS[:4]):
        for j, m in enumerate(methods):
            vals = [next((r[key] for r in rows if r["case"] == c and r["method"] == m), np.nan) for c in cases]
            ax.bar(np.arange(len(cases)) + (j - (len(methods) - 1) / 2) * width, vals, width, label=m)
        if "flicker" in key:
            ax.axhline(1.2, color="g", ls="--", lw=1)          # the goal: at most 1.2 × the real video's
        else:
            ax.axhspan(0.9, 1.1, color="g", alpha=0.12)        # the goal: 0.9–1.1 of the real mouth
        ax.axhline(1.0, color="k", lw=0.8)
        ax.set_xticks(range(len(cases)), cases, rotation=35, ha="right")
        ax.set_title(key.replace("_", " ") + " (output / real)")
    axes[0].legend(loc="lower left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def page(summary: dict) -> str:
    rows = summary["rows"]
    lines = ["<!-- Written by `python bench/sharp_steady.py`; do not edit. -->", "# Sharp and steady mouths", "",
             f"Measured {summary['date']} on commit `{summary['commit']}` ({summary['machine']}) by "
             "`bench/sharp_steady.py`: `lipsynth speak` with each clip's own audio into the clip, no "
             f"re-timing, once per `synthesize.detail`, model `{summary.get('model', 'runs/diagnosis/<person>/model')}` "
             "(the mouths come from the target's own frames: another person's path); every figure is output / the "
             "real video (1 = as the real mouth). Textures follow the face up to 512 px (`frontalize.max_texture_size`; "
             "the weighted median runs at ≤ 256 px, `synthesize.median_max_size`); rows named `tex256` store the face "
             "as coarsely as the former defaults (`ingest.max_crop_size: 448`, `frontalize.max_texture_size: 256`), "
             "smaller than a 1080- or 2160-line face is filmed. Rows marked `(tracked lips)` replace the model's mouth shapes by the target's own tracked "
             "lips (`bench/speak_oracle.py`): what texture synthesis and compositing reach when the shapes are right — the "
             "gap between a method's two rows is the shape model's share. Detail energy and detail flicker measure the band of wavelengths below ≈ IOD/8, motion "
             "compensated for flicker. The goals: sharpness 0.9–1.1 (green band), flicker at most 1.2 (dashed). Texture ms/frame is the thread time "
             "of candidate search, weighted median, teeth and detail (one run; `bench/synthesize.py` measures speed "
             "properly); speak frames/s is the whole run's wall time over its frames (model loading and the self-check "
             "included; the first run of a footage also pays the target's preprocessing unless an earlier run cached it).", "",
             "![sharpness and flicker per resolution](img/sharp_steady.png)", "",
             "| footage | method | sharpness | detail energy | flicker | detail flicker | mouth error / static | opening corr | texture ms/frame | speak frames/s |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['case']} ({r['size']}) | {r['method']} | {r['sharpness_ratio']:.2f} | "
                     f"{r['detail_energy_ratio']:.2f} | {r['flicker_ratio']:.2f} | {r['detail_flicker_ratio']:.2f} | "
                     f"{r['error_ratio']:.2f} | {r['opening_corr']:.2f} | {r['texture_ms']:.1f} | {r['frames_per_second']:.1f} |")
    methods = list(dict.fromkeys(r["method"] for r in rows))
    lines += ["", "Mouth crops, top to bottom: original, " + ", ".join(methods) + "; three frames each:", ""]
    for case in dict.fromkeys(r["case"] for r in rows):
        lines += [f"![{case}](img/sharp_steady_{case.replace(' ', '_')}.jpg)", ""]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", nargs="*", default=[*CASES, *VARIANTS], choices=[*CASES, *VARIANTS])
    ap.add_argument("--methods", nargs="*", default=list(METHODS), choices=list(METHODS))
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="override a key for every method: section.key=value, a bare key is synthesize's, e.g. --set "
                         "detail_switch_cost=4 --set frontalize.max_texture_size=512 (repeatable)")
    ap.add_argument("--model", type=Path, help="use this model for every case (e.g. models/base) and the people's "
                    "source clips from ../shared/data, instead of bench/person_diagnosis.py's models and held-out clips")
    ap.add_argument("--tag", default="", help="suffix of the output videos' names (keeps runs apart)")
    ap.add_argument("--shapes", nargs="*", default=["model"], choices=["model", "tracked"],
                    help="mouth shapes: the model's (what users get) and/or the target's own tracked lips "
                         "(bench/speak_oracle.py: what the texture synthesis and compositing reach with perfect shapes)")
    ap.add_argument("--dry", action="store_true", help="print the rows only; write no results, page or images")
    ap.add_argument("--page-only", action="store_true", help="only redraw the page and chart from results/sharp_steady.json")
    a = ap.parse_args()
    overrides = {}                                   # section → {key: value}; a bare key is synthesize's
    for k, v in (s.split("=", 1) for s in a.set):
        section, _, key = k.rpartition(".")
        overrides.setdefault(section or "synthesize", {})[key] = yaml.safe_load(v)
    if a.page_only:
        summary = json.loads((ROOT / "results" / "sharp_steady.json").read_text())
        plot(summary["rows"], ROOT / "docs" / "img" / "sharp_steady.png")
        (ROOT / "docs" / "sharp_steady.md").write_text(page(summary) + "\n")
        return
    WORK.mkdir(parents=True, exist_ok=True)
    base = yaml.safe_load((ROOT / "params.yaml").read_text())
    lm_params = load_params(ROOT / "params.yaml").landmarks
    rows = []
    for case in a.cases:
        footage, extra = VARIANTS.get(case, (case, {}))
        model, clip, lines = CASES[footage]
        if a.model:
            model, clip = a.model, SOURCES[footage]
        if not model.is_dir() or not clip.is_file():
            raise SystemExit(f"{case}: needs {model} and {clip} (run bench/person_diagnosis.py first)")
        clip = upscaled(clip, lines) if lines else clip
        ref = quality.video_landmarks(clip, lm_params)
        outs = []
        for method, shapes in [(m, sh) for sh in a.shapes for m in a.methods]:
            changes = {sec: {**extra.get(sec, {}), **overrides.get(sec, {})} for sec in {*extra, *overrides}}
            tree = dict(base, **{sec: dict(base[sec], **kv) for sec, kv in changes.items()})
            tree["synthesize"] = dict(tree["synthesize"], detail=method)
            params = WORK / f"params_{method}.yaml"
            params.write_text(yaml.safe_dump(tree, sort_keys=False))
            label = method if shapes == "model" else f"{method} (tracked lips)"
            out = WORK / (f"{case.replace(' ', '_')}_{method}{'_tracked' if shapes == 'tracked' else ''}"
                          f"{'_' + a.model.name if a.model else ''}{'_' + a.tag if a.tag else ''}.mp4")
            seconds, phases = speak(model, clip, out, params, tracked=shapes == "tracked")
            q = quality.compare(*quality.video_landmarks(out, lm_params), *ref)
            n = q["frames"]
            row = dict(case=case, size=f"{ref[0].shape[2]}×{ref[0].shape[1]}", method=label, clip=clip.name,
                       frames=n, frames_per_second=n / seconds,
                       texture_ms=sum(phases.get(k, 0.0) for k in ("candidate_search", "weighted_median", "teeth", "detail")),
                       error_ratio=q["mouth_error_px"] / q["static_mouth_error_px"],
                       **{k: q[k] for k in KEYS if k != "error_ratio"})
            rows.append(row)
            outs.append(out)
            print(json.dumps(row), flush=True)
        if a.dry:
            continue
        strip = mouth_strip([clip, *outs], q["mouth_box"])
        (ROOT / "docs" / "img").mkdir(exist_ok=True)
        cv2.imwrite(str(ROOT / "docs" / "img" / f"sharp_steady_{case.replace(' ', '_')}.jpg"), strip[..., ::-1],
                    [cv2.IMWRITE_JPEG_QUALITY, 90])
    if a.dry:
        return
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    summary = dict(commit=commit, date=time.strftime("%Y-%m-%d"), machine=f"{platform.processor() or platform.machine()}, "
                   f"{os.cpu_count()} cores", model=str(a.model) if a.model else "runs/diagnosis/<person>/model",
                   rows=rows)
    (ROOT / "results").mkdir(exist_ok=True)
    (ROOT / "results" / "sharp_steady.json").write_text(json.dumps(summary, indent=1) + "\n")
    plot(rows, ROOT / "docs" / "img" / "sharp_steady.png")
    (ROOT / "docs" / "sharp_steady.md").write_text(page(summary) + "\n")
    print("wrote results/sharp_steady.json, docs/sharp_steady.md")


if __name__ == "__main__":
    main()
