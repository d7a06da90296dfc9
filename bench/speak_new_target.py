"""Time to output of ``lipsynth speak`` on a target video it has never seen (nothing cached).

    python bench/speak_new_target.py [--repeats 3] [--seconds 10] [--model runs/grid_s1/base/model]

The target: ``obama_08.mp4`` (1280×720, 29.97 fps, 4.8 s) played forward, backward, forward…
to ``--seconds`` (one continuous shot, built once into bench/results/speak_new_target). The
audio: the first ``--seconds`` of the radio speech of ../shared/data/hdtf. Every repeat runs
the command users run, in its own process, with an empty ``--cache`` folder, so preprocessing
(ingest → landmarks → frontalize on one dask cluster), model loading, synthesis and compositing
are all counted; the result MP4 appears (atomically) when the process ends, so the wall time
is the time to the first output. Prints each run's wall time and when (s after speak's first
log line) each step's closing log line came, then the median. The goal (issue 25): ≤ 2 × the target's duration.
"""
from __future__ import annotations

import argparse
import re
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

from pipeline.io import media  # noqa: E402
from bench.synthesize import long_speech  # noqa: E402  (bench/synthesize.py)

SHARED = ROOT.parent / "shared" / "data"
STEPS = [("ingest", "lipsynth.ingest INFO: stored"), ("landmarks", "lipsynth.landmarks INFO: valid"),
         ("identity", "lipsynth.speak INFO: identity"), ("frontalize", "lipsynth.frontalize INFO: frontalized"),
         ("synthesize", "lipsynth.synthesize INFO: synthesized"), ("composite", "lipsynth.composite INFO: wrote")]


def ping_pong_target(out: Path, seconds: float) -> Path:
    """obama_08 forward, backward, forward… to ``seconds``, with its own audio looped alike."""
    if out.exists():
        return out
    src = SHARED / "obama" / "obama_08.mp4"
    fps = media.probe(src).fps
    frames = [rgb for _, rgb in media.iter_frames(src)]
    order = np.r_[np.arange(len(frames)), np.arange(len(frames) - 2, 0, -1)]
    n = int(round(seconds * fps))
    audio, _ = media.read_audio(src, 48000)
    hop = 48000 / fps
    clip = np.concatenate([audio[int(j * hop):int(j * hop) + int(round(hop))] for j in np.resize(order, n)])
    tmp = out.with_name(out.stem + ".tmp.mp4")
    media.write_video(tmp, (frames[j] for j in np.resize(order, n)), fps, clip, 48000)
    tmp.replace(out)
    return out


def one_run(target: Path, audio: Path, model: str, work: Path) -> tuple[float, dict]:
    cache, out = work / "cache", work / "out.mp4"
    shutil.rmtree(cache, ignore_errors=True)
    out.unlink(missing_ok=True)
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "lipsynth.cli", "speak", "--audio", str(audio), "--target", str(target),
                        "--out", str(out), "--model", model, "--cache", str(cache)], cwd=ROOT,
                       capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if r.returncode != 0 or not out.is_file():
        sys.exit(f"speak failed:\n{r.stderr[-3000:]}")
    stamps = {}
    log = r.stderr.splitlines()
    start = None
    for line in log:
        m = re.match(r"(\d\d):(\d\d):(\d\d) ", line)
        if not m:
            continue
        t = int(m[1]) * 3600 + int(m[2]) * 60 + int(m[3])
        start = t if start is None else start
        for name, key in STEPS:
            if key in line and name not in stamps:
                stamps[name] = t - start
    return wall, stamps


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--model", default="runs/grid_s1/base/model", help="model folder (relative to the project root)")
    a = ap.parse_args()
    work = ROOT / "bench" / "results" / "speak_new_target"
    work.mkdir(parents=True, exist_ok=True)
    target = ping_pong_target(work / f"obama_08_{a.seconds:g}s.mp4", a.seconds)
    audio = long_speech(work / f"speech_{a.seconds:g}s.wav", a.seconds)
    runs = []
    for i in range(a.repeats):
        wall, stamps = one_run(target, audio, a.model, work)
        runs.append(wall)
        print(f"run {i + 1}: {wall:.1f} s to the output  (steps done at, s after the first log line: "
              + ", ".join(f"{k} {v}" for k, v in stamps.items()) + ")", flush=True)
    med = statistics.median(runs)
    print(f"\n{target.name} (1280×720, {a.seconds:g} s, not cached) + {a.seconds:g} s of speech: median {med:.1f} s "
          f"to the output = {med / a.seconds:.2f} × the target's duration (goal ≤ 2.00)")


if __name__ == "__main__":
    main()
