"""The same footage through an earlier commit's ``lipsynth speak`` and today's: mouths side by side.

    python bench/then_and_now.py [--then d8a31b7] [--cases 512 720x576 2160] [--model models/base]

For each case of ``bench/sharp_steady.py`` (the clip's own audio into the clip, no re-timing, the
same model), runs ``speak`` in a git worktree of ``--then`` (default: the commit issue 33's work
started from) and in this checkout (``synthesize.detail`` median and two_band), measures every
output against the original with ``lipsynth.lipsync_quality`` (dlib on both: sharpness, detail
energy, flicker, detail flicker, mouth error over a static mouth's) and writes mouth crops, top to
bottom original | then | now median | now two_band, to ``docs/img/then_and_now_<case>.jpg``, the
figures to ``results/then_and_now.json`` (with both commits, date and machine) and
``docs/then_and_now.md``. The worktree runs with this checkout's Python environment.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import cv2
import yaml

from bench import sharp_steady as ss
from bench.bench_results import publish, stamp
from lipsynth import lipsync_quality as quality
from pipeline.params import load_params

ROOT = ss.ROOT
WORK = ROOT / "bench" / "results" / "then_and_now"
KEYS = ("sharpness_ratio", "detail_energy_ratio", "flicker_ratio", "detail_flicker_ratio")


def worktree(commit: str) -> Path:
    """A detached worktree of ``commit`` under bench/results (made once)."""
    path = WORK / f"tree_{commit}"
    if not path.is_dir():
        WORK.mkdir(parents=True, exist_ok=True)
        subprocess.run(["git", "worktree", "add", "--detach", str(path), commit], cwd=ROOT, check=True,
                       capture_output=True)
    return path


def speak(tree: Path, model: Path, clip: Path, out: Path, detail: str | None) -> None:
    """``lipsynth speak --no-retime`` of ``tree``'s code (own audio into ``clip``); ``detail`` sets
    ``synthesize.detail`` (None: that tree's params.yaml as it is)."""
    params = yaml.safe_load((tree / "params.yaml").read_text())
    if detail:
        params["synthesize"]["detail"] = detail
    path = WORK / f"params_{tree.name}_{detail}.yaml"
    path.write_text(yaml.safe_dump(params, sort_keys=False))
    r = subprocess.run([sys.executable, "-m", "lipsynth.cli", "speak", "--no-retime", "--model", str(model.resolve()),
                        "--audio", str(clip.resolve()), "--target", str(clip.resolve()), "--out", str(out),
                        "--params", str(path), "--cache", str(WORK / f"cache_{tree.name}")],
                       cwd=tree, capture_output=True, text=True, env=dict(os.environ, PYTHONPATH=str(tree)))
    if r.returncode:
        raise SystemExit(f"speak ({tree.name}) failed on {clip}: {r.stderr.strip()[-800:]}")


def page(summary: dict) -> str:
    lines = ["<!-- Written by `python bench/then_and_now.py`; do not edit. -->", "# Then and now: the same mouths",
             "", f"Measured {summary['date']} ({summary['machine']}) by `bench/then_and_now.py`: `lipsynth speak "
             f"--no-retime` of each clip's own audio into the clip with model `{summary['model']}`, at commit "
             f"`{summary['then']}` (then) and `{summary['now']}` (now). Every figure is output / the real video "
             "(1 = as the real mouth; goals: sharpness 0.9–1.1, flicker ≤ 1.2).", "",
             "| footage | run | sharpness | detail energy | flicker | detail flicker | mouth error / static |",
             "|---|---|---|---|---|---|---|"]
    for r in summary["rows"]:
        lines.append(f"| {r['case']} ({r['size']}) | {r['run']} | {r['sharpness_ratio']:.2f} | "
                     f"{r['detail_energy_ratio']:.2f} | {r['flicker_ratio']:.2f} | {r['detail_flicker_ratio']:.2f} | "
                     f"{r['error_ratio']:.2f} |")
    lines += ["", "Mouth crops, top to bottom: original, then, now (median), now (two_band); three frames each:", ""]
    for case in dict.fromkeys(r["case"] for r in summary["rows"]):
        lines += [f"![{case}](img/then_and_now_{case}.jpg)", ""]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--then", default="d8a31b7", help="the earlier commit (default: where issue 33's work began)")
    ap.add_argument("--cases", nargs="*", default=["512", "720x576", "2160"], choices=list(ss.CASES))
    ap.add_argument("--model", type=Path, default=ROOT / "models" / "base")
    a = ap.parse_args()
    lm = load_params(ROOT / "params.yaml").landmarks
    then = worktree(a.then)
    rows = []
    for case in a.cases:
        _, _, lines = ss.CASES[case]
        clip = ss.upscaled(ss.SOURCES[case], lines) if lines else ss.SOURCES[case]
        ref = quality.video_landmarks(clip, lm)
        outs = []
        for run, tree, detail in (("then", then, None), ("now median", ROOT, "median"), ("now two_band", ROOT, "two_band")):
            out = WORK / f"{case}_{run.replace(' ', '_')}.mp4"
            speak(tree, a.model, clip, out, detail)
            q = quality.compare(*quality.video_landmarks(out, lm), *ref)
            row = dict(case=case, size=f"{ref[0].shape[2]}×{ref[0].shape[1]}", run=run, clip=clip.name,
                       error_ratio=q["mouth_error_px"] / q["static_mouth_error_px"], **{k: q[k] for k in KEYS})
            rows.append(row)
            outs.append(out)
            print(json.dumps(row), flush=True)
        strip = ss.mouth_strip([clip, *outs], q["mouth_box"])
        cv2.imwrite(str(ROOT / "docs" / "img" / f"then_and_now_{case}.jpg"), strip[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 90])
    st = stamp()
    summary = dict(then=a.then, now=st["commit"], date=st["date"], machine=st["machine"],
                   model=os.path.relpath(a.model, ROOT), rows=rows)
    publish("then_and_now", summary, page(summary))

if __name__ == "__main__":
    main()
