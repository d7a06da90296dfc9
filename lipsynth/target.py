"""One video outside the corpus, preprocessed like the corpus: ingest → landmarks → frontalize.

``lipsynth speak`` (and the benches) put new speech into any video of a speaker. That video runs
through the same three stages as the training corpus, with the params file's settings, into a
cache folder outside DVC keyed by the video's *content* (SHA-256) and those settings, so the
second use of the same target starts at once and a moved or renamed copy still hits. This is the
only place the preprocessing chain of a single target is written down.
"""
from __future__ import annotations

import copy
import hashlib
import json
import logging
import os
from pathlib import Path

from pipeline.parallel import client_for
from pipeline.params import Params, as_dict

log = logging.getLogger("lipsynth.target")

PREPROCESS = ("ingest", "landmarks", "frontalize")
CACHE_FORMAT = 2          # bump when the preprocessing code changes what it stores


def default_cache() -> Path:
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "lipsynth" / "targets"


def content_hash(path: Path, block: int = 1 << 20) -> str:
    """SHA-256 of a file's bytes (hex)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(block):
            h.update(chunk)
    return h.hexdigest()


def cache_key(video: Path, params: Params) -> str:
    """Identity of a preprocessed target: the file's content and the preprocessing settings."""
    settings = {k: {kk: vv for kk, vv in as_dict(getattr(params, k)).items() if kk != "out"} for k in PREPROCESS}
    ident = {"content": content_hash(video), "settings": settings, "format": CACHE_FORMAT}
    return hashlib.sha1(json.dumps(ident, sort_keys=True, default=str).encode()).hexdigest()[:16]


def preprocess_target(video: Path, params: Params, cache: Path) -> Params:
    """Params whose ingest/landmarks/frontalize outputs hold ``video`` alone (computed once, then cached).

    Returns a copy of ``params`` with ``data.videos`` = [video] and each preprocessing stage's
    ``out`` inside ``cache``; the stores are complete when this returns (each stage writes
    atomically, so an interrupted run leaves nothing that looks finished).
    """
    from stages.frontalize import frontalize
    from stages.ingest import ingest
    from stages.landmarks import landmarks
    p = copy.deepcopy(params)
    folder = cache / f"{video.stem}-{cache_key(video, params)}"
    p.data.videos, p.data.val_fraction, p.data.on_bad_input = [str(video.absolute())], 0.0, "error"
    for stage in PREPROCESS:
        getattr(p, stage).out = str(folder / f"{stage}.zarr")
    if (folder / "frontalize.zarr").is_dir():
        log.info("target %s: preprocessed stores found in %s", video, folder)
        return p
    log.info("target %s: preprocessing into %s (ingest → landmarks → frontalize)", video, folder)
    run = copy.deepcopy(p)
    with client_for(p.cluster) as client:          # one cluster for the three stages
        run.cluster.address = client.scheduler.address
        ingest.run(run, p.ingest.out, require_audio=False)       # the new speech replaces its audio
        landmarks.run(run, p.ingest.out, p.landmarks.out)
        frontalize.run(run, p.ingest.out, p.landmarks.out, p.frontalize.out)
    return p
