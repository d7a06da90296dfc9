"""Preprocessing a target in this process or on a LocalCluster: which is faster, by the target's length.

    python bench/target_cluster.py [--repeats 3]     # results/target_cluster.json, docs/target_cluster.md + .png

``lipsynth prepare`` (what ``speak`` and ``live`` run first: ingest → landmarks → identity → frontalize into a fresh
cache) of targets from 3 s to 22 s, at their own sizes, run as users run it (a new process each time), once with
``cluster.address: in-process`` and once on a LocalCluster of one worker per core (``cluster.n_workers`` set).
Wall seconds, medians of ``--repeats`` runs, the two modes alternating. ``lipsynth.target.IN_PROCESS_MAX_FRAMES``
(targets up to that many frames skip the LocalCluster) is chosen from this page.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

from bench.bench_results import publish, stamp          # noqa: E402
from lipsynth.target import IN_PROCESS_MAX_FRAMES       # noqa: E402
from pipeline.io import media                           # noqa: E402
import numpy as np                                      # noqa: E402
import yaml                                             # noqa: E402

DATA = ROOT.parent / "shared" / "data"
TARGETS = [DATA / "grid_s1" / "video" / "sran9s.mp4", DATA / "strangers" / "w2lft_ian.mp4",
           DATA / "strangers" / "vrt_face4.mp4", DATA / "hdtf" / "WDA_KatieHill_000.mp4",
           DATA / "strangers" / "latsync_demo1.mp4", DATA / "strangers" / "latsync_demo2.mp4",
           DATA / "strangers" / "sky_drive2.mp4"]
MODES = {"in_process": dict(address="in-process"), "local_cluster": dict(n_workers=os.cpu_count() or 1)}


def params_file(folder: Path, cluster: dict) -> Path:
    """params.yaml with ``cluster`` overridden, written into ``folder``."""
    tree = yaml.safe_load((ROOT / "params.yaml").read_text())
    tree["cluster"].update(cluster)
    path = folder / "params.yaml"
    path.write_text(yaml.safe_dump(tree, sort_keys=False))
    return path


def prepare_seconds(target: Path, params: Path, cache: Path) -> float:
    """Wall seconds of ``lipsynth prepare target`` (the shipped base) into the empty folder ``cache``."""
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "lipsynth.cli", "prepare", str(target), "--model", str(ROOT / "models" / "base"),
                    "--params", str(params), "--cache", str(cache)], cwd=ROOT, check=True, capture_output=True)
    return time.perf_counter() - t0


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6.5, 3.6))
    frames = [r["frames"] for r in rows]
    for mode, mark in (("in_process", "o-"), ("local_cluster", "s--")):
        ax.plot(frames, [r[mode]["median_s"] for r in rows], mark, label=mode.replace("_", " "))
    ax.axvline(IN_PROCESS_MAX_FRAMES, color="grey", lw=0.8, ls=":", label="IN_PROCESS_MAX_FRAMES")
    ax.set_xlabel("target frames")
    ax.set_ylabel("lipsynth prepare (s, median)")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def page(summary: dict) -> str:
    """docs/target_cluster.md from the bench's summary."""
    rows = summary["targets"]
    faster = [r["frames"] for r in rows if r["in_process"]["median_s"] <= r["local_cluster"]["median_s"]]
    lines = [f"<!-- written by bench/target_cluster.py at {summary['commit']}; do not edit -->",
             "# Preprocessing a target: in this process or on a LocalCluster", "",
             f"`lipsynth prepare` of a new target into an empty cache, a fresh process each run; medians of "
             f"{summary['repeats']} runs on {summary['machine']} ({summary['date']}). Targets of at most "
             f"{summary['in_process_max_frames']} frames (`lipsynth.target.IN_PROCESS_MAX_FRAMES`) skip the LocalCluster "
             "when `cluster.address` and `cluster.n_workers` are unset.", "",
             f"Here the process alone was as fast or faster on {len(faster)} of {len(rows)} targets, the longest of them "
             f"{max(faster, default=0)} frames: starting the workers (imports, dlib's models in each) costs as much as "
             "they save on two cores. With more cores they can pay off sooner (not measured here), so the bound stays "
             "below that.", "",
             "![prepare seconds by target length](target_cluster.png)", "",
             "| target | frames | size | in process (s) | LocalCluster (s) |", "|---|---|---|---|---|"]
    lines += [f"| {r['target']} | {r['frames']} | {r['size']} | {r['in_process']['median_s']:.1f} | "
              f"{r['local_cluster']['median_s']:.1f} |" for r in rows]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--page-only", action="store_true", help="rewrite docs/target_cluster.md from the results file")
    a = ap.parse_args()
    if a.page_only:
        (ROOT / "docs" / "target_cluster.md").write_text(page(json.loads((ROOT / "results" / "target_cluster.json")
                                                                      .read_text())) + "\n")
        return
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        files = {m: params_file((tmp / m).mkdir() or tmp / m, c) for m, c in MODES.items()}
        for target in TARGETS:
            info = media.probe(target)
            row = dict(target=target.name, frames=max(info.n_frames, int(info.duration * info.fps)),
                       size=f"{info.width}×{info.height}")
            runs = {m: [] for m in MODES}
            for k in range(a.repeats):
                for m in MODES:
                    runs[m].append(prepare_seconds(target, files[m], tmp / f"cache-{m}-{target.stem}-{k}"))
            for m in MODES:
                row[m] = dict(runs_s=[round(s, 2) for s in runs[m]], median_s=round(float(np.median(runs[m])), 2))
            print(row, flush=True)
            rows.append(row)
    rows.sort(key=lambda r: r["frames"])
    plot(rows, ROOT / "docs" / "target_cluster.png")          # beside its page: mkdocs serves docs/ only
    summary = dict(stamp(), repeats=a.repeats, in_process_max_frames=IN_PROCESS_MAX_FRAMES, targets=rows)
    publish("target_cluster", summary, page(summary))


if __name__ == "__main__":
    main()
