"""Preprocessing benchmark: ingest → landmarks → frontalize on real footage.

Prints, per corpus (GRID s1 clips at 360×288; the Obama clips at 720p): frames/s per stage and
per core (median of --repeats runs), peak RSS of the whole process tree, stored bytes/frame per
array, and the projection to a 17-hour corpus (core-hours; wall-hours on this machine and on
10 nodes × 32 cores). The stages run on one LocalCluster (one single-threaded worker per core)
that is started once; its start-up is timed and printed on its own, and "with start-up" adds
it — what one ``dvc repro`` of the three stages pays (each stage starts its own cluster).

    python bench/preprocess.py [--grid-clips 100] [--repeats 3]
"""
from __future__ import annotations

import argparse
import copy
import glob
import os
import shutil
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

import psutil

ROOT = Path(__file__).resolve().parents[1]

from pipeline.params import load_params  # noqa: E402
from pipeline.io.store import stored_bytes  # noqa: E402

SHARED = ROOT.parent / "shared" / "data"
STAGES = ("ingest", "landmarks", "frontalize")


class PeakRSS:
    """Samples every 0.1 s the summed RSS of this process and all its descendants (``peak``) and
    the largest RSS of any one descendant — a worker process (``worker_peak``)."""

    def __init__(self):
        self.peak, self.worker_peak, self._stop = 0, 0, threading.Event()

    def _run(self):
        me = psutil.Process()
        while not self._stop.is_set():
            total = 0
            for p in [me] + me.children(recursive=True):
                try:
                    rss = p.memory_info().rss
                except psutil.Error:
                    continue
                total += rss
                if p.pid != me.pid:
                    self.worker_peak = max(self.worker_peak, rss)
            self.peak = max(self.peak, total)
            time.sleep(0.1)

    def __enter__(self):
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._t.join()


def run_stage(stage, params):
    from stages.frontalize import frontalize
    from stages.ingest import ingest
    from stages.landmarks import landmarks
    if stage == "ingest":
        ingest.run(params, params.ingest.out)
    elif stage == "landmarks":
        landmarks.run(params, params.ingest.out, params.landmarks.out)
    else:
        frontalize.run(params, params.ingest.out, params.landmarks.out, params.frontalize.out)


def bench_corpus(name, videos, address, repeats, workdir, cores, startup=0.0):
    params = copy.deepcopy(load_params(ROOT / "params.yaml"))
    params.data.videos = videos
    params.cluster.address = address
    for s in STAGES:
        getattr(params, s).out = str(workdir / f"{name}-{s}.zarr")
    times = {s: [] for s in STAGES}
    peak = {s: 0 for s in STAGES}
    worker_peak = {s: 0 for s in STAGES}
    for _ in range(repeats):
        for s in STAGES:
            with PeakRSS() as rss:
                t0 = time.perf_counter()
                run_stage(s, params)
                times[s].append(time.perf_counter() - t0)
            peak[s] = max(peak[s], rss.peak)
            worker_peak[s] = max(worker_peak[s], rss.worker_peak)
    import zarr
    g = zarr.open_group(params.ingest.out)
    n = sum(v["n_frames"] for v in g.attrs["videos"])           # real frames (the axis also has gaps)
    print(f"\n== {name}: {len(videos)} videos, {n} frames, {cores} worker processes (1 per core) ==")
    print(f"{'stage':<12}{'median s':>10}{'frames/s':>10}{'/core':>8}{'peak RSS MB':>13}{'per worker':>12}")
    total = 0.0
    for s in STAGES:
        med = statistics.median(times[s])
        total += med
        print(f"{s:<12}{med:>10.2f}{n / med:>10.1f}{n / med / cores:>8.1f}{peak[s] / 2**20:>13.0f}"
              f"{worker_peak[s] / 2**20:>12.0f}")
    print(f"{'all three':<12}{total:>10.2f}{n / total:>10.1f}{n / total / cores:>8.1f}")
    with_startup = total + 3 * startup                 # dvc repro: each stage starts its own cluster
    print(f"{'+ start-up':<12}{with_startup:>10.2f}{n / with_startup:>10.1f}{n / with_startup / cores:>8.1f}"
          f"   (3 cluster start-ups of {startup:.1f} s, one per stage as dvc repro runs them)")
    print("stored bytes/frame:")
    per_frame = 0.0
    for s in STAGES:
        root = Path(getattr(params, s).out)
        for arr in sorted(p for p in root.rglob("zarr.json") if p.parent != root and p.parent.name != "model"):
            b = stored_bytes(arr.parent) / n
            per_frame += b
            print(f"  {s}/{arr.parent.relative_to(root)!s:<22}{b / 1024:>9.2f} KB")
    print(f"  {'total':<29}{per_frame / 1024:>9.2f} KB/frame")
    return n / total / cores, per_frame


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--grid-clips", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--memory-check", action="store_true",
                    help="also run landmarks on a quarter of the GRID clips to compare peak RSS")
    a = ap.parse_args()
    from distributed import Client, LocalCluster
    cores = os.cpu_count() or 1
    grid = sorted(glob.glob(str(SHARED / "grid_s1" / "video" / "*.mp4")))[:a.grid_clips]
    obama = sorted(glob.glob(str(SHARED / "obama" / "obama_0*.mp4")))
    if not grid or not obama:
        sys.exit(f"bench/preprocess.py: real footage not found under {SHARED}")
    work = Path(tempfile.mkdtemp(prefix="lipsynth-bench-"))
    try:
        t0 = time.perf_counter()
        with LocalCluster(n_workers=cores, threads_per_worker=1, dashboard_address=None) as lc, Client(lc):
            startup = time.perf_counter() - t0
            print(f"LocalCluster start-up: {startup:.1f} s ({cores} worker processes)")
            results = {}
            results["GRID 360x288"] = bench_corpus("grid", grid, lc.scheduler_address, a.repeats, work, cores,
                                                   startup)
            results["Obama 1280x720"] = bench_corpus("obama", obama, lc.scheduler_address, a.repeats, work,
                                                     cores, startup)
            if a.memory_check:
                bench_corpus("grid-quarter", grid[:len(grid) // 4], lc.scheduler_address, 1, work, cores)
        frames_17h = 17 * 3600 * 30
        print(f"\n== projection to a 17-hour corpus ({frames_17h:,} frames at 30 fps) ==")
        for k, (fps_core, bpf) in results.items():
            print(f"{k:<16} {fps_core:6.1f} frames/s/core → {frames_17h / fps_core / 3600:7.1f} core-hours "
                  f"({frames_17h / fps_core / 3600 / cores:.1f} h on this {cores}-core machine, "
                  f"{frames_17h / fps_core / 3600 / 320:.2f} h on 10 nodes × 32 cores); "
                  f"store {bpf * frames_17h / 2**30:.1f} GiB")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
