"""Audio front ends a frame-feature model can be trained on (``train.features``).

    mfcc            paper 000's 28-D MFCC (``pipeline.audio.audio_features``) — the paper-exact choice
    phonetic        40 pocketsphinx phone indicators (``pipeline.audio.phone_features``): speaker-independent
    mfcc+phonetic   both, concatenated (68-D): MFCC columns first
    whisper         384-D encoder states of Whisper tiny.en (``pipeline.audio.whisper_encoder``): learned
                    from many speakers; windowed as the ``whisper`` stage's params say (recorded in the model)

All run at 100 Hz on the same time axis (frame t centred at t / 100 s). ``frame_features``
computes them for new audio; the training stores hold the MFCC (ingest), the phone
indicators (the ``phonetic`` stage) and the encoder states (the ``whisper`` stage) so training
reads the same numbers.
"""
from __future__ import annotations

import numpy as np

from pipeline.audio.audio_features import FEATURE_DIM as MFCC_DIM
from pipeline.audio.audio_features import cmvn, mfcc_features
from pipeline.errors import ParameterError
from pipeline.audio.phone_features import PHONE_DIM, phone_indicators
from pipeline.audio.whisper_encoder import STATE_DIM as WHISPER_DIM

FRONT_ENDS = ("mfcc", "phonetic", "mfcc+phonetic", "whisper")


def check(front_end: str) -> None:
    if front_end not in FRONT_ENDS:
        raise ParameterError(f"front end {front_end!r}: choose one of {', '.join(FRONT_ENDS)}")


def uses_mfcc(front_end: str) -> bool:
    return front_end in ("mfcc", "mfcc+phonetic")


def uses_phones(front_end: str) -> bool:
    return front_end in ("phonetic", "mfcc+phonetic")


def uses_whisper(front_end: str) -> bool:
    return front_end == "whisper"


def feature_dim(front_end: str, whisper_layers: int = 1) -> int:
    """Width D of ``front_end``'s frames (``whisper_layers``: how many encoder layers the whisper states join)."""
    check(front_end)
    return (MFCC_DIM * uses_mfcc(front_end) + PHONE_DIM * uses_phones(front_end)
            + WHISPER_DIM * whisper_layers * uses_whisper(front_end))


def combine(front_end: str, mfcc: np.ndarray | None, phones: np.ndarray | None,
            states: np.ndarray | None = None) -> np.ndarray:
    """(T, D) float32 frames of ``front_end`` from (T, 28) MFCC, (T, 40) phone indicators and/or (T, 384)
    encoder states."""
    check(front_end)
    parts = ([mfcc] if uses_mfcc(front_end) else []) + ([phones] if uses_phones(front_end) else []) + \
        ([states] if uses_whisper(front_end) else [])
    if any(p is None for p in parts):
        raise ParameterError(f"front end {front_end!r} needs {'MFCC and phone indicators' if len(parts) > 1 else 'its features'}")
    n = min(len(p) for p in parts)
    return np.concatenate([np.asarray(p[:n], np.float32) for p in parts], axis=1)


def frame_features(samples: np.ndarray, front_end: str, encoder: dict | None = None) -> np.ndarray:
    """(T, D) frames of ``front_end`` for 16 kHz mono RMS-normalised ``samples``, T = 1 + S // 160.

    ``encoder``: the whisper window settings the model was trained with (``window_s``, ``overlap_s``;
    default 10 s and 2 s)."""
    check(front_end)
    mfcc = mfcc_features(samples) if uses_mfcc(front_end) else None
    phones = phone_indicators(samples) if uses_phones(front_end) else None
    states = None
    if uses_whisper(front_end):
        from pipeline.audio.whisper_layers import whisper_features
        states = whisper_features(samples, 1 + len(samples) // 160, **(encoder or {}))
    return combine(front_end, mfcc, phones, states)


def normalised_columns(front_end: str, width: int) -> np.ndarray:
    """(width,) bool: the columns ``train.feature_norm: utterance`` normalises (MFCC and encoder states;
    phone indicators stay 0/1)."""
    cols = np.zeros(width, bool)
    if uses_mfcc(front_end):
        cols[:MFCC_DIM] = True
    if uses_whisper(front_end):
        cols[MFCC_DIM * uses_mfcc(front_end) + PHONE_DIM * uses_phones(front_end):] = True   # 384 per encoder layer
    return cols


def utterance_norm(x: np.ndarray, front_end: str) -> np.ndarray:
    """Per-utterance CMVN of the MFCC columns and of the encoder states (``train.feature_norm: utterance``);
    indicators stay 0/1."""
    x = np.array(x, np.float32)
    cols = normalised_columns(front_end, x.shape[1])
    x[:, cols] = cmvn(x[:, cols])
    return x


def check_width(x: np.ndarray, front_end: str, expected: int, source: str) -> None:
    """A model trained on ``expected``-wide frames refuses others with one clear line."""
    if x.shape[1] != expected:
        raise ParameterError(f"{source}: the model expects {expected}-D input frames but its front end "
                             f"{front_end!r} gives {x.shape[1]}-D (model folder from another version or front end?)")
