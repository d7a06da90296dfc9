"""The shipped base model: an LSTM of read speech that every personalization starts from.

    models/base/
        weights.pt, config.json, arrays.npz   an LSTM model folder (``model_folder``), no speaker
        MANIFEST.json                         SHA-256 of those files, corpus, licence, recipe, commit

``bench/shipped_base.py`` writes it; ``verify`` checks the hashes before anything loads it, so a
truncated or hand-edited file is one clear error instead of a model that quietly predicts wrong.
"""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

from pipeline.models.model_folder import ModelError, read_config

MODEL_FILES = ("weights.pt", "config.json", "arrays.npz")
LIVE_FILES = ("live.pt", "live.json")          #: the LSTM taught the live front end (``bench/live_student.py``)
SHIPPED = Path(__file__).resolve().parents[2] / "models" / "base"


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def write_manifest(folder, provenance: dict) -> dict:
    """Write ``MANIFEST.json`` (the files' SHA-256 and ``provenance``) into ``folder``; returns it."""
    folder = Path(folder)
    names = MODEL_FILES + tuple(n for n in LIVE_FILES if (folder / n).is_file())
    manifest = dict(provenance, files={name: sha256(folder / name) for name in names})
    (folder / "MANIFEST.json").write_text(json.dumps(manifest, indent=2) + "\n")
    return manifest


def verify(folder) -> dict:
    """Check a base model folder against its manifest; returns its config.

    Raises ModelError naming the folder and the first file that is missing or differs. A folder
    without a manifest (a base built by hand, ``bench/base_model.py``) is read as any model folder.
    """
    folder = Path(folder)
    manifest_path = folder / "MANIFEST.json"
    if manifest_path.is_file():
        manifest = json.loads(manifest_path.read_text())
        for name, digest in manifest.get("files", {}).items():
            path = folder / name
            if not path.is_file():
                raise ModelError(f"{folder}: {name} is missing (MANIFEST.json lists it)")
            if sha256(path) != digest:
                raise ModelError(f"{folder}: {name} does not match MANIFEST.json (SHA-256 differs: a damaged or "
                                 f"edited file; rebuild with `python bench/shipped_base.py` or check out models/base)")
    config = read_config(folder)
    if config["model"] != "lstm":
        raise ModelError(f"{folder}: a {config['model']} model; a base model is an LSTM")
    return config
