"""Is the mouth drawn where the tracked mouth is, whatever the footage's size? (issue 33 item 2)

A GRID s1 clip is upscaled (bicubic) 1×, 2×, 4× and 10× (360×288 → 3600×2880) and used as its
own audio and target through ``lipsynth speak --no-retime``. dlib re-tracks output and original
on frames scaled to the same width (720 px, so every scale gets the same detail) and compares:

    mouth       mean distance of the 20 mouth points, × inter-ocular distance (IOD)
    nose_chin   the same for the nose (27–35) and chin (6–10): the rest of the rendered lower face
    mouth_dy    the mouth's vertical offset (output − original), × IOD: + is lower

Medians over frames, per scale. Goal: mouth at 10× within the 1× figure + 0.01.

    python bench/geometry_scale.py [--model runs/grid_s1/base_shipped/model] [--clip bgin3a]

Writes results/geometry_scale.json (commit, date, machine) and a plot beside it.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]

from pipeline.face import dlib_face  # noqa: E402
from pipeline.io import media  # noqa: E402

SCALES = (1, 2, 4, 10)


def tracked(path, width: int) -> np.ndarray:
    """(N, 68, 2) dlib points per frame (NaN where no face), found at ``width`` px, in video px."""
    out = []
    for _, g in media.iter_frames(path, "gray"):
        k = width / g.shape[1]
        small = cv2.resize(g, None, fx=k, fy=k, interpolation=cv2.INTER_AREA if k < 1 else cv2.INTER_CUBIC)
        found = dlib_face.detect_face(small, 1)
        out.append(dlib_face.predict_landmarks(small, found[0]) / k if found else np.full((68, 2), np.nan))
    return np.array(out)


def compare(original: np.ndarray, output: np.ndarray) -> dict:
    n = min(len(original), len(output))
    a, b = original[:n], output[:n]
    iod = np.linalg.norm(a[:, 36:42].mean(1) - a[:, 42:48].mean(1), axis=1)

    def dist(ix):
        return float(np.nanmedian(np.linalg.norm(a[:, ix] - b[:, ix], axis=2).mean(1) / iod))
    return dict(mouth=dist(slice(48, 68)), nose_chin=dist(np.r_[27:36, 6:11]),
                mouth_dy=float(np.nanmedian((b[:, 48:68, 1] - a[:, 48:68, 1]).mean(1) / iod)),
                iod_px=float(np.nanmedian(iod)), frames=int(n))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default="runs/grid_s1/base_shipped/model")
    ap.add_argument("--clip", default="bgin3a", help="GRID s1 clip (held out of the shipped base's training)")
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "geometry_scale.json")
    a = ap.parse_args()
    source = ROOT.parent / "shared" / "data" / "grid_s1" / "video" / f"{a.clip}.mp4"
    info = media.probe(source)
    audio, _ = media.read_audio(source, 48000)
    frames = [f for _, f in media.iter_frames(source)]
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for s in SCALES:
            target = tmp / f"{a.clip}_{s}x.mp4"
            media.write_video(target, (f if s == 1 else cv2.resize(f, None, fx=s, fy=s, interpolation=cv2.INTER_CUBIC)
                                       for f in frames), info.fps, audio, 48000)
            out = tmp / f"out_{s}x.mp4"
            t0 = time.perf_counter()
            r = subprocess.run([sys.executable, "-m", "lipsynth.cli", "speak", "--model", a.model, "--audio", str(source),
                                "--target", str(target), "--out", str(out), "--no-retime", "--cache", str(tmp / "cache")],
                               cwd=ROOT, capture_output=True, text=True)
            if r.returncode:
                sys.exit(f"speak failed at {s}×: {r.stderr[-2000:]}")
            rows[f"{s}x"] = dict(compare(tracked(target, 720), tracked(out, 720)), width=info.width * s,
                                 height=info.height * s, speak_seconds=round(time.perf_counter() - t0, 1))
            print(f"{s:>3}× {info.width * s}×{info.height * s}: " + "  ".join(
                f"{k} {v:.4f}" for k, v in rows[f"{s}x"].items() if k in ("mouth", "nose_chin", "mouth_dy")), flush=True)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(dict(commit=commit, date=datetime.datetime.now().isoformat(timespec="minutes"),
                                     machine=f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores",
                                     clip=a.clip, model=a.model, scales=rows,
                                     goal_met=rows["10x"]["mouth"] <= rows["1x"]["mouth"] + 0.01), indent=1))
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 3.2))
    for key in ("mouth", "nose_chin", "mouth_dy"):
        ax.plot(SCALES, [rows[f"{s}x"][key] for s in SCALES], "o-", label=key)
    ax.axhline(rows["1x"]["mouth"] + 0.01, ls=":", c="grey", label="goal: 1× mouth + 0.01")
    ax.set_xscale("log")
    ax.set_xticks(SCALES, [f"{s}×" for s in SCALES])
    ax.set_xlabel("footage scale (360×288 → 3600×2880)")
    ax.set_ylabel("× IOD (median over frames)")
    ax.legend(fontsize=8)
    ax.set_title(f"speak output vs original, dlib re-tracked ({a.clip}, {commit})", fontsize=9)
    fig.tight_layout()
    fig.savefig(a.out.with_suffix(".png"), dpi=110)
    page = ROOT / "docs" / "geometry_scale.md"
    lines = [f"<!-- written by bench/geometry_scale.py at {commit}; do not edit -->",
             "# The mouth in place at any footage size", "",
             f"GRID s1 clip `{a.clip}` upscaled and spoken into with its own audio (`lipsynth speak --no-retime`, "
             f"model `{a.model}`); dlib re-tracks output and original at 720 px wide. Medians over frames, "
             "in inter-ocular distances (IOD). Goal (issue 33): the mouth at 10× within the 1× figure + 0.01.", "",
             "| scale | frame | IOD (px) | mouth | nose and chin | mouth height offset | speak (s) |",
             "|---|---|---|---|---|---|---|"]
    lines += [f"| {k} | {r['width']}×{r['height']} | {r['iod_px']:.0f} | {r['mouth']:.4f} | {r['nose_chin']:.4f} | "
              f"{r['mouth_dy']:+.4f} | {r['speak_seconds']} |" for k, r in rows.items()]
    lines += ["", "![mouth, nose and chin error against footage scale](geometry_scale.png)", "",
              f"Commit {commit}, machine {platform.processor() or platform.machine()}."]
    page.write_text("\n".join(lines) + "\n")
    import shutil
    shutil.copy(a.out.with_suffix(".png"), page.with_suffix(".png"))
    print(f"wrote {a.out}, {a.out.with_suffix('.png')} and {page}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
