"""Files of public repositories taken from their git mirrors (``fetch``'s ``MIRRORS/owner+name/repo``), hash-checked.

Used by the benches whose footage lives in other repositories (``bench/tight_crops.py``, ``bench/natural_corpus.py``):
their manifests name repository, commit, path and SHA-256; the footage never goes into this project's git.
"""
from __future__ import annotations

import hashlib
import subprocess
from pathlib import Path


def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def git_blob(clip: dict, path: str, want: str, mirrors: Path) -> bytes:
    """The bytes of ``path`` at ``clip["commit"]`` of ``clip["repo"]``'s mirror, checked against the SHA-256
    ``want``; ValueError with one line naming what is wrong (no mirror, no such file, another hash)."""
    git_dir = mirrors / clip["repo"].replace("/", "+") / "repo"
    if not (git_dir / "HEAD").is_file():
        raise ValueError(f"no git mirror of {clip['repo']} at {git_dir.parent} (fetch github:{clip['repo']})")
    r = subprocess.run(["git", f"--git-dir={git_dir}", "show", f"{clip['commit']}:{path}"], capture_output=True)
    if r.returncode:
        why = (r.stderr.decode(errors="replace").strip().splitlines() or [f"rc {r.returncode}"])[-1]
        raise ValueError(f"{clip['repo']} {clip['commit'][:12]}:{path} not in {git_dir}: {why}")
    if (got := sha256(r.stdout)) != want:
        raise ValueError(f"{clip['repo']} {clip['commit'][:12]}:{path} has SHA-256 {got[:16]}…, the manifest says {want[:16]}…")
    return r.stdout
