"""One video outside the corpus, preprocessed like the corpus: ingest → landmarks → frontalize.

``lipsynth speak`` (and the benches) put new speech into any video of a speaker. That video runs
through the same three stages as the training corpus, with the params file's settings, into a
cache folder outside DVC keyed by the video's *content* (SHA-256) and those settings, so the
second use of the same target starts at once and a moved or renamed copy still hits. This is the
only place the preprocessing chain of a single target is written down.
"""
from __future__ import annotations

import copy
import dataclasses
import hashlib
import json
import logging
import os
import re
from pathlib import Path

import numpy as np

from pipeline.errors import LipsynthError, ParameterError
from pipeline.io.parallel import IN_PROCESS, SharedCluster, client_address, client_for
from pipeline.params import Params, as_dict

log = logging.getLogger("lipsynth.target")

PREPROCESS = ("ingest", "landmarks", "frontalize")
CACHE_FORMAT = 7          # bump when the preprocessing code changes what it stores (6: bicubic crops and textures;
                          # 7: 3D models whose lips were fitted as depth rejected)
FRONTALIZE_FORMAT = 3     # bump when only frontalize changes what it stores (ingest and landmarks are kept)
                          # (2, 3: a factorisation that is no face, or stretched in depth, falls back to the depth prior)
IN_PROCESS_MAX_FRAMES = 300   # a target this short is preprocessed in this process, without a LocalCluster: starting
                              # its worker processes (imports, dlib's models in each) costs more than they save
                              # (bench/target_cluster.py, results/target_cluster.json)


def warm_up_worker() -> None:
    """Run on each worker of ``speak``'s cluster at its start (``SharedCluster(warm_up=...)``): import the
    preprocessing stages and load dlib's detector, landmark predictor and face-recognition network, so
    the worker that ingest (one task per video) leaves idle is ready for landmarks and identity."""
    from pipeline.face import dlib_face, identity
    from stages.frontalize import frontalize  # noqa: F401
    from stages.ingest import ingest  # noqa: F401
    from stages.landmarks import landmarks  # noqa: F401
    dlib_face.detector()
    dlib_face.predictor()
    identity.recogniser()


def cluster_for_frames(cluster, n_frames: int):
    """The ``cluster`` params to preprocess a target of ``n_frames`` frames with: ``cluster`` itself when it
    asks for workers (``cluster.address`` or ``cluster.n_workers`` set) or for a long target; a copy with
    ``address: in-process`` for a target of at most ``IN_PROCESS_MAX_FRAMES`` frames on the default
    LocalCluster. The stores are the same bytes either way."""
    if cluster.address or cluster.n_workers is not None or n_frames > IN_PROCESS_MAX_FRAMES:
        return cluster
    log.info("target of %d frames: preprocessed in this process (no LocalCluster up to %d frames: "
             "lipsynth.target.IN_PROCESS_MAX_FRAMES)", n_frames, IN_PROCESS_MAX_FRAMES)
    return dataclasses.replace(cluster, address=IN_PROCESS)


def target_cluster(cluster, video) -> object:
    """``cluster_for_frames`` for ``video``, its length read from the header (frames, else duration × rate)."""
    from pipeline.io import media
    info = media.probe(video)
    return cluster_for_frames(cluster, max(info.n_frames, int(info.duration * info.fps)))


def default_cache() -> Path:
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "lipsynth" / "targets"


def content_hash(path: Path, block: int = 1 << 20) -> str:
    """SHA-256 of a file's bytes (hex)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(block):
            h.update(chunk)
    return h.hexdigest()


def settings_of(params: Params, stages) -> dict:
    return {k: {kk: vv for kk, vv in as_dict(getattr(params, k)).items() if kk != "out"} for k in stages}


def cache_key(video: Path, params: Params) -> str:
    """Identity of a preprocessed target's folder: the file's content and the ingest/landmarks settings
    (frontalize stores inside it are named by their own settings: ``frontalize_name``)."""
    ident = {"content": content_hash(video), "settings": settings_of(params, PREPROCESS[:2]), "format": CACHE_FORMAT}
    return hashlib.sha1(json.dumps(ident, sort_keys=True, default=str).encode()).hexdigest()[:16]


def frontalize_name(params: Params, shape3d: np.ndarray | None) -> str:
    """``frontalize-<hash>.zarr``: one store per frontalize settings (texture window) and 3D face model."""
    h = hashlib.sha1(json.dumps(dict(settings_of(params, ("frontalize",)), format=FRONTALIZE_FORMAT), sort_keys=True,
                                default=str).encode())
    if shape3d is not None:
        h.update(np.ascontiguousarray(shape3d, np.float32).tobytes())
    return f"frontalize-{h.hexdigest()[:12]}.zarr"


class NotPreparedError(LipsynthError):
    """A target that ``lipsynth live`` needs preprocessed is not in the cache."""

    def __init__(self, video: Path, cache: Path):
        super().__init__(f"{video}: target not prepared (nothing for it in {cache} with these params); prepare it "
                         f"once with: lipsynth prepare {video} --model MODEL" + (f" --cache {cache}" if cache != default_cache() else ""))


def preprocess_target(video: Path, params: Params, cache: Path, shape3d: np.ndarray | None = None,
                      shared: SharedCluster | None = None, prepared_only: bool = False) -> Params:
    """Params whose ingest/landmarks/frontalize outputs hold ``video`` alone (computed once, then cached).

    Returns a copy of ``params`` with ``data.videos`` = [video] and each preprocessing stage's
    ``out`` inside ``cache``; the stores are complete when this returns (each stage writes
    atomically, so an interrupted run leaves nothing that looks finished).

    ``shape3d`` (68, 3) mm: frontalize with this 3D face model (a model folder's corpus model,
    for a target of the same speaker) instead of one fitted to the video alone; each model gets
    its own frontalize store in the cache folder.

    ``shared``: run the stages on this cluster (one for a whole ``speak``) instead of a cluster of
    their own. ``prepared_only``: raise ``NotPreparedError`` rather than run a stage.
    """
    p = landmarked_target(video, params, cache, shared, prepared_only)
    p.frontalize.out = str(Path(p.frontalize.out).with_name(frontalize_name(p, shape3d)))
    if Path(p.frontalize.out).is_dir():
        return p
    if prepared_only:
        raise NotPreparedError(video, cache)
    from stages.frontalize import frontalize
    log.info("target %s: frontalizing with %s", video, "the model's 3D face" if shape3d is not None else
             "its own 3D face model")
    with (shared.client() if shared else client_for(p.cluster)) as client:
        run = copy.deepcopy(p)
        run.cluster.address = client_address(client)
        frontalize.run(run, p.ingest.out, p.landmarks.out, p.frontalize.out, shape3d=shape3d)
    return p


def landmarked_target(video: Path, params: Params, cache: Path, shared: SharedCluster | None = None,
                      prepared_only: bool = False) -> Params:
    """Like ``preprocess_target`` but only ingest and landmarks are guaranteed to exist."""
    from stages.ingest import ingest
    from stages.landmarks import landmarks
    p = copy.deepcopy(params)
    if p.speak.target_shard_frames % p.ingest.chunk_frames or p.speak.target_shard_frames % p.frontalize.chunk_frames:
        raise ParameterError(f"speak.target_shard_frames={p.speak.target_shard_frames}: must be a multiple of "
                             f"ingest.chunk_frames and frontalize.chunk_frames")
    p.ingest.shard_frames = p.speak.target_shard_frames     # one video: several shards, so several workers
    folder = cache / f"{video.stem}-{cache_key(video, p)}"
    p.data.videos, p.data.val_fraction, p.data.on_bad_input = [str(video.absolute())], 0.0, "error"
    for stage in PREPROCESS:
        getattr(p, stage).out = str(folder / f"{stage}.zarr")
    if (folder / "landmarks.zarr").is_dir():
        log.info("target %s: preprocessed stores found in %s", video, folder)
        return p
    if prepared_only:
        raise NotPreparedError(video, cache)
    log.info("target %s: preprocessing into %s (ingest → landmarks)", video, folder)
    run = copy.deepcopy(p)
    with (shared.client() if shared else client_for(p.cluster)) as client:      # one cluster for both stages
        # one video is one ingest task: it runs here, while the workers start (and warm up)
        run.cluster.address = IN_PROCESS
        try:
            ingest.run(run, p.ingest.out, require_audio=False)       # the new speech replaces its audio
            run.cluster.address = client_address(client)
            landmarks.run(run, p.ingest.out, p.landmarks.out)
        except LipsynthError as exc:
            from pipeline.io.store import project_path
            message = without_training_hints(str(exc)).replace(project_path(video.absolute()), str(video))
            raise LipsynthError(message) from None
    return p


TRAINING_HINTS = (" (set data.on_bad_input: skip to leave such videos out)",
                  " — set data.on_bad_input: skip to leave it out")


def without_training_hints(message: str) -> str:
    """A stage's message for ``speak``: the advice to skip videos of a training corpus (a param
    ``speak`` does not have) removed, and a setting it names (``section.key=value``) said to be one
    of the ``--params`` file, speak's own option."""
    for hint in TRAINING_HINTS:
        message = message.replace(hint, "")
    return re.sub(r"\b([a-z_]+\.[a-z_]+=[^\s)]+)", r"\1 of --params", message)
