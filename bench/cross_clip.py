"""Another clip's audio into the target: lip sync and sharpness with the true frames out of the pool.

    python bench/cross_clip.py [--pairs 6] [--methods median two_band] [--model models/base]

Own-audio measures (the yardstick, ``bench/sharp_steady.py``) put the target's own frame of every
sound into the candidate pool, and ``two_band``'s Viterbi, which favours consecutive source frames,
can then replay the original: they flatter it. Here each pair of GRID s4 clips (a person no model
has met; sorted names, pair i = clips 2i and 2i + 1) gets ``lipsynth speak --audio A --target B
--no-retime``: B's frames are the pool, A's words are said. Lip sync is measured against A's real
mouth (the same person saying those words: inner-lip opening correlation; the mouth's shape error —
the 20 mouth points centred on their mean, in units of each video's inter-ocular distance, since the two
heads stand in different places — over a static mouth's, A's mean shape), sharpness and flicker against B's real mouth (the same framing), with
``lipsynth.lipsync_quality`` (dlib on both).

Writes ``results/cross_clip.json`` (with commit, date and machine) and ``docs/cross_clip.md``.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import numpy as np
import yaml

from bench.bench_results import publish, stamp
from lipsynth import lipsync_quality as quality
from pipeline.params import load_params

ROOT = Path(__file__).resolve().parents[1]
CLIPS = ROOT.parent / "shared" / "data" / "grid_s4"
WORK = ROOT / "bench" / "results" / "cross_clip"
SYNC = ("opening_corr", "error_ratio")                                  # against A (the words)
LOOK = ("sharpness_ratio", "detail_energy_ratio", "flicker_ratio", "detail_flicker_ratio")   # against B (the face)


def shape_error_ratio(out_lm: np.ndarray, out_ok: np.ndarray, ref_lm: np.ndarray, ref_ok: np.ndarray) -> float:
    """Mean mouth-shape error of the output against the reference over that of the reference's mean
    shape. Landmarks (N, 68, 2) px; the mouth points are centred per frame and divided by the
    video's median inter-ocular distance."""
    n = min(len(out_lm), len(ref_lm))
    ok = out_ok[:n] & ref_ok[:n]

    def shapes(lm):
        mouth = lm[:n][ok][:, quality.LIPS]
        return (mouth - mouth.mean(1, keepdims=True)) / np.median(quality.interocular(lm[:n][ok]))
    o, r = shapes(out_lm), shapes(ref_lm)
    err = np.linalg.norm(o - r, axis=2).mean()
    static = np.linalg.norm(r.mean(0) - r, axis=2).mean()
    return float(err / static)


def speak(model: Path, audio: Path, target: Path, out: Path, params: Path) -> None:
    r = subprocess.run([sys.executable, "-m", "lipsynth.cli", "speak", "--model", str(model), "--audio", str(audio),
                        "--target", str(target), "--out", str(out), "--no-retime", "--params", str(params),
                        "--cache", str(WORK / "cache")], cwd=ROOT, capture_output=True, text=True)
    if r.returncode:
        raise SystemExit(f"speak failed on {audio.name} → {target.name}: {r.stderr.strip()[-800:]}")


def page(summary: dict) -> str:
    lines = ["<!-- Written by `python bench/cross_clip.py`; do not edit. -->", "# Another clip's words into the target", "",
             f"Measured {summary['date']} on commit `{summary['commit']}` ({summary['machine']}) by `bench/cross_clip.py`, "
             f"model `{summary['model']}`: {summary['pairs']} pairs of GRID s4 clips (a person the model never met), "
             "`lipsynth speak --audio A --target B --no-retime` — the target's frames are the candidate pool but none of "
             "them says A's words, unlike the own-audio measures, where the true frame is always in the pool. Lip sync "
             "against A's real mouth (inner-lip opening correlation at lag 0; mouth-shape error, points centred and in "
             "inter-ocular units, over that of A's mean shape), "
             "sharpness, detail energy and flicker against B's (1 = as the real mouth). Medians over the pairs"
             + (f"; params.yaml with {', '.join(summary['settings'])}." if summary.get("settings") else ".") + "", "",
             "| method | opening corr | mouth error / static | sharpness | detail energy | flicker | detail flicker |",
             "|---|---|---|---|---|---|---|"]
    for m, r in summary["medians"].items():
        lines.append(f"| {m} | {r['opening_corr']:.2f} | {r['error_ratio']:.2f} | {r['sharpness_ratio']:.2f} | "
                     f"{r['detail_energy_ratio']:.2f} | {r['flicker_ratio']:.2f} | {r['detail_flicker_ratio']:.2f} |")
    lines += ["", "Per pair (A → B): " + "; ".join(
        f"{p['audio']} → {p['target']} {p['method']} corr {p['opening_corr']:.2f}" for p in summary["rows"]) + "."]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pairs", type=int, default=6)
    ap.add_argument("--methods", nargs="*", default=["median", "two_band"], choices=["median", "aligned", "two_band"])
    ap.add_argument("--model", type=Path, default=ROOT / "models" / "base")
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="override a params.yaml key for every method (repeatable)")
    ap.add_argument("--dry", action="store_true", help="print the rows only; write no results or page")
    a = ap.parse_args()
    clips = sorted(CLIPS.glob("*.mp4"))
    if len(clips) < 2 * a.pairs:
        raise SystemExit(f"{CLIPS}: {len(clips)} clips, {2 * a.pairs} needed for {a.pairs} pairs")
    WORK.mkdir(parents=True, exist_ok=True)
    base = yaml.safe_load((ROOT / "params.yaml").read_text())
    for item in a.set:
        key, _, value = item.partition("=")
        section, _, name = key.partition(".")
        base[section] = dict(base[section], **{name: yaml.safe_load(value)})
    lm_params = load_params(ROOT / "params.yaml").landmarks
    rows = []
    for i in range(a.pairs):
        audio, target = clips[2 * i], clips[2 * i + 1]
        said, face = quality.video_landmarks(audio, lm_params), quality.video_landmarks(target, lm_params)
        for method in a.methods:
            params = WORK / f"params_{method}.yaml"
            params.write_text(yaml.safe_dump(dict(base, synthesize=dict(base["synthesize"], detail=method)), sort_keys=False))
            out = WORK / f"{audio.stem}_into_{target.stem}_{method}{'_set' if a.set else ''}.mp4"
            speak(a.model, audio, target, out, params)
            got = quality.video_landmarks(out, lm_params)
            sync, look = quality.compare(*got, *said), quality.compare(*got, *face)
            row = dict(audio=audio.stem, target=target.stem, method=method, opening_corr=sync["opening_corr"],
                       error_ratio=shape_error_ratio(got[1], got[2], said[1], said[2]), **{k: look[k] for k in LOOK})
            rows.append(row)
            print(json.dumps(row), flush=True)
    medians = {m: {k: float(np.median([r[k] for r in rows if r["method"] == m])) for k in SYNC + LOOK} for m in a.methods}
    print(json.dumps(medians, indent=1))
    if a.dry:
        return
    summary = dict(stamp(), model=os.path.relpath(a.model, ROOT), pairs=a.pairs, settings=a.set,
                   medians=medians, rows=rows)
    publish("cross_clip", summary, page(summary))

if __name__ == "__main__":
    main()
