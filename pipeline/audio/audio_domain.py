"""How far new audio is from a model's training audio: one number, and a warning when it is far.

A model learns one speaker on one microphone. Audio of another voice or channel moves the
utterance's mean MFCC away from the training corpus's; the shift is measured in units of the
corpus's per-dimension standard deviation:

    shift = sqrt( mean_k ( (mean_t x[t, k] − μ_k) / σ_k )² )

over the 28 MFCC dimensions k (``pipeline.audio.audio_features.mfcc_features`` of RMS-normalised
audio), μ, σ the training videos' MFCC mean and std (all frames). The model folder stores μ, σ
and the shifts of the corpus's own *validation* videos (held out of training: what a new
recording of the same speaker looks like) in ``audio_domain.json``; audio is called far when its
shift exceeds ``factor`` × the largest of them.

Measured on GRID s1 (LSTM model folder, 30 validation clips): the speaker's own held-out clips
0.06–0.26 (median 0.11); another GRID speaker (s4, 720×576 recordings) 0.32–0.52; HDTF radio
and interview speech 0.62–1.08; Obama addresses 0.72–0.86; Macron (French) 0.72.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

FILE = "audio_domain.json"


def corpus_statistics(features: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Per-dimension mean (D,) and std (D,) over all frames of ``features`` [(T_i, D)]."""
    x = np.concatenate([np.asarray(f, np.float64) for f in features])
    return x.mean(0), np.maximum(x.std(0), 1e-6)


def utterance_shift(features: np.ndarray, mean: np.ndarray, std: np.ndarray) -> float:
    """RMS over dimensions of the utterance's mean z-score: 0 = the corpus's average audio.

    features : (T, D) frames of one utterance; mean, std : (D,) corpus statistics.
    Returns the shift in corpus standard deviations (float ≥ 0).
    """
    x = np.asarray(features, np.float64)
    if x.ndim != 2 or x.shape[1] != len(mean) or not len(x):
        raise ValueError(f"features of shape {x.shape} do not match {len(mean)} corpus dimensions")
    z = (x.mean(0) - mean) / std
    return float(np.sqrt(np.mean(z ** 2)))


def reference(train: list[np.ndarray], held_out: list[np.ndarray]) -> dict:
    """The record stored in a model folder: corpus statistics of ``train`` and the shifts of the
    ``held_out`` utterances (validation videos; the training ones when there are none)."""
    mean, std = corpus_statistics(train)
    shifts = [utterance_shift(f, mean, std) for f in (held_out or train) if len(f)]
    return dict(mean=mean.tolist(), std=std.tolist(), held_out_shifts=[round(s, 4) for s in shifts],
                held_out_max=float(max(shifts)), held_out_median=float(np.median(shifts)))


def export(folder, ingest_path: str) -> dict:
    """Write ``audio_domain.json`` into the model folder from the ingest store's MFCC (training
    videos → statistics, validation videos → reference shifts); returns the record."""
    from pipeline.io.store import open_group
    src = open_group(ingest_path)
    mfcc = np.asarray(src["mfcc"][...], np.float32)
    parts: dict[str, list] = {"train": [], "val": []}
    for v in src.attrs["videos"]:
        if v.get("excluded") or not v.get("n_mfcc") or v.get("split") not in parts:
            continue
        parts[v["split"]].append(mfcc[v["first_mfcc"]:v["first_mfcc"] + v["n_mfcc"]])
    if not parts["train"]:
        raise ValueError(f"{ingest_path}: no training video with audio features")
    rec = reference(parts["train"], parts["val"])
    (Path(folder) / FILE).write_text(json.dumps(rec))
    return dict(held_out_max=round(rec["held_out_max"], 4), held_out_median=round(rec["held_out_median"], 4))


def load(folder) -> dict | None:
    """The model folder's record, or None for folders trained before it existed."""
    path = Path(folder) / FILE
    if not path.is_file():
        return None
    rec = json.loads(path.read_text())
    rec["mean"], rec["std"] = np.asarray(rec["mean"]), np.asarray(rec["std"])
    return rec


def assess(features: np.ndarray, record: dict, factor: float) -> dict:
    """Shift of ``features`` (T, D) against a model's record; ``far`` when above factor × the
    largest held-out shift. Returns dict(shift, limit, far)."""
    shift = utterance_shift(features, record["mean"], record["std"])
    limit = factor * record["held_out_max"]
    return dict(shift=round(shift, 4), limit=round(limit, 4), far=bool(shift > limit))
