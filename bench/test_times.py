"""How long the README's test command takes: read the log of a ``.ci/run`` on a fresh clone and write the times.

    rm -rf ../ci-check && git clone -q . ../ci-check && (cd ../ci-check && CI=true bash .ci/run > /tmp/ci.log 2>&1)
    python bench/test_times.py --log /tmp/ci.log

Writes ``results/test_times.json`` (phases, the 15 slowest tests of each run, commit, date, machine),
``docs/test_times.md`` and a bar chart of the slowest tests (``docs/test_times.png``). The docs quote these
files; nothing here is typed by hand.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SUMMARY = re.compile(r"^(?P<passed>\d+) passed(?:, (?P<skipped>\d+) skipped)?.* in (?P<seconds>[\d.]+)s")
DURATION = re.compile(r"^(?P<seconds>[\d.]+)s (?P<when>setup|call|teardown)\s+(?P<test>\S+)")


def parse_log(text: str) -> dict:
    """The two pytest runs (fast, slow) and the total of a ``.ci/run`` log.

    Returns ``{"runs": [{"passed", "skipped", "seconds", "slowest": [{"test", "when", "seconds"}]}, …],
    "total_seconds"}``; raises ``ValueError`` when the log does not hold two finished runs."""
    runs, slowest = [], []
    for line in text.splitlines():
        if m := DURATION.match(line.strip()):
            slowest.append(dict(test=m["test"], when=m["when"], seconds=float(m["seconds"])))
        elif m := SUMMARY.match(line.strip().strip("=").strip()):
            runs.append(dict(passed=int(m["passed"]), skipped=int(m["skipped"] or 0), seconds=float(m["seconds"]),
                             slowest=slowest))
            slowest = []
    total = re.search(r"ci: finished in (\d+) s", text)
    commit = re.search(r"^ci: commit (\w+)", text, re.M)
    if len(runs) != 2 or total is None:
        raise ValueError(f"expected the fast and the slow run and the 'ci: finished' line, found {len(runs)} runs"
                         f"{'' if total else ' and no finish line'}")
    return dict(runs=runs, total_seconds=int(total[1]), commit=commit[1] if commit else None)


def minutes(s: float) -> str:
    return f"{s / 60:.1f} min"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--log", type=Path, required=True, help="output of .ci/run on a fresh clone")
    ap.add_argument("--commit", help="the commit the log ran (a log from before .ci/run printed it)")
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "test_times.json")
    ap.add_argument("--page", type=Path, default=ROOT / "docs" / "test_times.md")
    a = ap.parse_args()
    times = parse_log(a.log.read_text(errors="replace"))
    commit = times.pop("commit") or a.commit
    if commit is None:
        sys.exit(f"{a.log}: no 'ci: commit' line; say which commit it ran with --commit")
    record = dict(commit=commit, date=datetime.datetime.now().isoformat(timespec="minutes"),
                  machine=f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores", **times)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(record, indent=1))

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fast, slow = times["runs"]
    top = sorted(slow["slowest"], key=lambda r: r["seconds"])
    fig, ax = plt.subplots(figsize=(11, 0.32 * len(top) + 1.2))
    ax.barh([f"{r['test'].split('::')[-1][:46]} ({r['when']})" for r in top], [r["seconds"] for r in top], color="#4477aa")
    ax.set_xlabel("seconds")
    ax.set_title("The 15 slowest slow tests")
    fig.tight_layout()
    fig.savefig(a.page.with_suffix(".png"), dpi=90)
    install = times["total_seconds"] - fast["seconds"] - slow["seconds"]
    lines = [f"<!-- written by bench/test_times.py at {commit}; do not edit -->", "# How long the tests take", "",
             "The README's test command as CI runs it (`.ci/run` on a fresh clone of the commit below: install, documentation "
             "build, fast tests, slow tests).", "",
             "| phase | tests | time |", "|---|---|---|",
             f"| install and documentation build | | {minutes(install)} |",
             f"| fast tests | {fast['passed']} passed, {fast['skipped']} skipped | {minutes(fast['seconds'])} |",
             f"| slow tests | {slow['passed']} passed, {slow['skipped']} skipped | {minutes(slow['seconds'])} |",
             f"| **all of `.ci/run`** | | **{minutes(times['total_seconds'])}** |", "",
             "![the slowest slow tests](test_times.png)", "",
             "| slowest slow tests | phase | s |", "|---|---|---|",
             *[f"| `{r['test']}` | {r['when']} | {r['seconds']:.0f} |" for r in slow["slowest"]], "",
             f"Commit {commit}; written {record['date']} on {record['machine']}."]
    a.page.write_text("\n".join(lines) + "\n")
    print(f"wrote {a.out}, {a.page} and {a.page.with_suffix('.png')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
