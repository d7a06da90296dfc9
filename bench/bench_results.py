"""Where a bench's figures go: ``results/<name>.json`` (with commit, date and machine) and ``docs/<name>.md``."""
from __future__ import annotations

import json
import os
import platform
import subprocess
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def stamp() -> dict:
    """The commit (short hash of HEAD), today's date and the machine (processor, cores) a measurement ran on."""
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    return dict(commit=commit, date=time.strftime("%Y-%m-%d"),
                machine=f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores")


def publish(name: str, summary: dict, page: str) -> None:
    """Write ``summary`` to results/<name>.json and ``page`` (Markdown) to docs/<name>.md."""
    (ROOT / "results").mkdir(exist_ok=True)
    (ROOT / "results" / f"{name}.json").write_text(json.dumps(summary, indent=1) + "\n")
    (ROOT / "docs" / f"{name}.md").write_text(page + "\n")
    print(f"wrote results/{name}.json, docs/{name}.md")
