"""How long the README's test command takes: read the log of a ``.ci/run`` on a fresh clone and write the times.

    rm -rf ../ci-check && git clone -q . ../ci-check && (cd ../ci-check && CI=true bash .ci/run > /tmp/ci.log 2>&1)
    python bench/test_times.py --log /tmp/ci.log

Writes ``results/test_times.json`` (phases, the 15 slowest tests of each run, commit, date, machine) and
prints the phases and the slowest slow tests. A tool to run by hand (e.g. when trimming CI's time); no docs
page quotes it, since CI cannot commit a rewritten page — CI's own log shows the slowest tests
(``--durations=15``).
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
    a = ap.parse_args()
    times = parse_log(a.log.read_text(errors="replace"))
    commit = times.pop("commit") or a.commit
    if commit is None:
        sys.exit(f"{a.log}: no 'ci: commit' line; say which commit it ran with --commit")
    record = dict(commit=commit, date=datetime.datetime.now().isoformat(timespec="minutes"),
                  machine=f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores", **times)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(record, indent=1))

    fast, slow = times["runs"]
    install = times["total_seconds"] - fast["seconds"] - slow["seconds"]
    print(f"commit {commit}, {record['machine']}")
    print(f"install and documentation build  {minutes(install)}")
    print(f"fast tests ({fast['passed']} passed, {fast['skipped']} skipped)  {minutes(fast['seconds'])}")
    print(f"slow tests ({slow['passed']} passed, {slow['skipped']} skipped)  {minutes(slow['seconds'])}")
    print(f"all of .ci/run  {minutes(times['total_seconds'])}")
    print("slowest slow tests:")
    for r in slow["slowest"]:
        print(f"  {r['seconds']:7.0f} s  {r['when']:8s} {r['test']}")
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
