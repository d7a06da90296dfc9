"""Common entry-point plumbing: logging, one-line errors, non-zero exit codes."""
from __future__ import annotations

import json
import logging
import os
import sys
import time
from pathlib import Path

from pipeline.errors import LipsynthError


def setup_logging(verbose: bool = False) -> None:
    logging.basicConfig(level=logging.DEBUG if verbose else logging.INFO,
                        format="%(asctime)s %(name)s %(levelname)s: %(message)s", datefmt="%H:%M:%S")
    for noisy in ("distributed", "numba", "matplotlib", "PIL"):
        logging.getLogger(noisy).setLevel(logging.WARNING)


def run_main(fn, *args, **kwargs) -> int:
    """Call ``fn``; a LipsynthError becomes one line on stderr and exit code 2."""
    try:
        fn(*args, **kwargs)
    except LipsynthError as exc:
        print(f"lipsynth: error: {exc}", file=sys.stderr)
        return 2
    return 0


def write_timing(stage: str, ms_per_frame: dict, folder: str = "logs") -> Path:
    """Write a stage's per-phase timing (ms per frame) to ``logs/<stage>.timing.json``.

    Timings differ from run to run, so they never go into a DVC-tracked output or metric.
    """
    path = Path(folder) / f"{stage}.timing.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({k: round(v, 2) for k, v in ms_per_frame.items()}, indent=2) + "\n")
    return path


def stage_main(prog: str, doc: str, run, argv=None) -> int:
    """The command line of one stage: ``--params FILE`` and ``-v``; ``run(params)`` does the work."""
    import argparse

    from pipeline.params import load_params

    ap = argparse.ArgumentParser(prog=prog, description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--params", default="params.yaml", help="params file (default: params.yaml)")
    ap.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    a = ap.parse_args(argv)
    setup_logging(a.verbose)
    t0 = time.perf_counter()
    code = run_main(lambda: run(load_params(a.params)))
    if code == 0:
        record_wall_time(prog.split()[1].replace("-", "_"), time.perf_counter() - t0)
    return code


def record_wall_time(stage: str, seconds: float, folder: str = "logs") -> Path:
    """Add a stage's wall time (s, its work after start-up) to ``logs/stage_seconds.json`` (untracked)."""
    path = Path(folder) / "stage_seconds.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        table = json.loads(path.read_text())
    except (OSError, ValueError):
        table = {}
    table[stage] = round(seconds, 1)
    tmp = path.with_name(path.name + f".tmp-{os.getpid()}")
    tmp.write_text(json.dumps(table, indent=2) + "\n")
    os.replace(tmp, path)
    return path
