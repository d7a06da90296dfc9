"""Other people's footage as extra training sequences for a base model (issue 23: a model that transfers).

A base model learns the audio → mouth mapping on the main store (its PCA basis, its validation
videos) and, with ``train.extra_corpora``, also on the preprocessed stores of other people. Each
extra corpus is a folder holding ``ingest.zarr``, ``landmarks.zarr``, ``frontalize.zarr`` and
``whisper.zarr`` (the stages run with that folder as their outputs; ``bench/base_model.py`` does
it). Its frames become training targets in the main basis:

    x' = (x − mean_v) · iod_main / iod_corpus + mean_main

with x the (36,) frontal lip vector of a frame, ``mean_v`` the mean over the valid frames of its
own video: every clip keeps its own face's motion (how far this mouth opens, rounds, spreads,
scaled to the main store's interocular distance) while its resting shape — who the person is —
is replaced by the main speaker's. The targets are then projected on the main PCA basis and put on
the 100 Hz feature axis like the ``pca`` stage does. Extra videos only ever train; the main
store's validation videos stay the validation set, so in-domain figures stay comparable.
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from pipeline.audio import front_ends
from pipeline.errors import LipsynthError, ParameterError
from pipeline.face.dlib_face import IOD_MM
from pipeline.io.store import open_group
from pipeline.models.mouth_pca import lip_vectors, project, resample_to_100hz

log = logging.getLogger("lipsynth.train")
STORES = ("ingest", "landmarks", "frontalize", "whisper")
MIN_VALID = 0.5          # a video with fewer valid frames than this share is left out (face lost)


def corpus_paths(folder: str) -> dict[str, Path]:
    """The four stores of one extra corpus; one clear error when a folder or store is missing."""
    root = Path(folder)
    paths = {k: root / f"{k}.zarr" for k in STORES}
    missing = [k for k, p in paths.items() if not p.exists()]
    if missing:
        raise LipsynthError(f"train.extra_corpora: {folder}: missing {', '.join(m + '.zarr' for m in missing)} "
                            f"(run ingest, landmarks, frontalize and whisper with outputs in that folder)")
    return paths


def retargeted(lips: np.ndarray, valid: np.ndarray, scale: float, main_mean: np.ndarray) -> np.ndarray:
    """(n, 36) lip vectors of one video → the same motion about the main speaker's mean shape.

    Parameters
    ----------
    lips : (n, 36) canonical px of this corpus; valid : (n,) bool
    scale : iod_main / iod_corpus (canonical px of the main store per px of this corpus)
    main_mean : (36,) the main PCA basis' mean

    Returns
    -------
    (n, 36) float64; rows of invalid frames are left as they are (their targets are masked).
    """
    if not valid.any():
        raise ParameterError("retargeted: no valid frame to take the video's mean shape from")
    own_mean = lips[valid].mean(0)
    return (lips - own_mean) * scale + main_mean


def load(folders: list[str], features: str, basis: dict, iod_main: float, repeat: int = 1) -> list[dict]:
    """Training sequences of the extra corpora, in ``load_sequences``' form (``x``, ``y``, ``ok``, …).

    Parameters
    ----------
    folders : extra corpus folders; features : the main model's front end (must be ``whisper``)
    basis : main PCA basis (``mean`` (36,), ``components`` (k, 36)); iod_main : its canonical IOD (px)
    repeat : every extra video appears this many times in the list (weights few minutes of other
        people against hours of the main speaker)
    """
    if not folders:
        return []
    if not front_ends.uses_whisper(features) or front_ends.uses_mfcc(features):
        raise ParameterError(f"train.extra_corpora needs train.features: whisper (got {features!r}): MFCC of other "
                             "recording set-ups are not normalised alike")
    if not isinstance(repeat, int) or repeat < 1:
        raise ParameterError(f"train.extra_repeat={repeat!r}: a whole number ≥ 1")
    seqs = []
    for folder in folders:
        paths = corpus_paths(folder)
        src, lmg, fr, wh = (open_group(str(paths[k])) for k in STORES)
        flm = np.asarray(fr["frontal_landmarks"][...], np.float64)
        valid = np.asarray(fr["pose_valid"][...]) & np.asarray(lmg["valid"][...])
        lips = lip_vectors(flm)
        iod = IOD_MM / fr.attrs["texture_window"]["mm_per_px"]
        ftime = np.asarray(src["frame_time"][...])
        states = wh["states"]
        kept = 0
        for v in fr.attrs["videos"]:
            f0, n, m0, m = v["first_frame"], v["n_frames"], v["first_mfcc"], v["n_mfcc"]
            ok = valid[f0:f0 + n]
            if v.get("excluded") or not m or ok.mean() < MIN_VALID:
                log.warning("extra corpus %s: %s left out (%.0f%% of its frames have a valid face)", folder, v["name"],
                            100 * ok.mean() if n else 0)
                continue
            y = np.where(ok[:, None], project(retargeted(lips[f0:f0 + n], ok, iod_main / iod, basis["mean"]), basis),
                         0.0)
            y100, ok100 = resample_to_100hz(y, ok, ftime[f0:f0 + n], m)
            x = front_ends.combine(features, None, None, np.asarray(states[m0:m0 + m], np.float32))
            seqs += [dict(name=f"{Path(folder).name}/{v['name']}", fps=v["fps"], x=x, y=y100, ok=ok100, extra=True)
                     for _ in range(repeat)]
            kept += 1
        log.info("extra corpus %s: %d videos, %.0f s of audio (× %d)", folder, kept,
                 sum(len(s["x"]) for s in seqs[-kept * repeat:]) / 100 / repeat if kept else 0, repeat)
    return seqs
