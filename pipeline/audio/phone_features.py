"""Phonetic audio front end: pocketsphinx phone recognition → per-10 ms phone indicators.

MFCC describe the speaker's voice and channel as much as the speech; a phone recogniser trained
on many speakers (CMU Sphinx's en-us acoustic model, shipped in the ``pocketsphinx`` wheel)
maps any voice onto the same 40 classes. ``recognize_phones`` decodes a whole utterance with
the phone language model (allphone search, batch cepstral mean normalisation);
``phone_indicators`` turns the segments into a (T, 40) one-hot matrix on the MFCC time axis
(frame t at t / 100 s, ``pipeline.audio.audio_features``). Pocketsphinx's allphone search gives one
best path and no lattice, so each frame carries its recognised phone with weight 1 — phone-class
indicators, not posteriors. Fillers (noise, breath, unknown) count as silence.

Cost: 42–55 ms of one core per second of audio (``bench/cross_speaker.py`` prints it).
"""
from __future__ import annotations

import os

import numpy as np

from pipeline.audio.audio_features import HOP, SAMPLE_RATE
from pipeline.errors import ParameterError

#: CMU phone set of the en-us model (39 phones) + silence; column order of the indicators
PHONES = ("SIL", "AA", "AE", "AH", "AO", "AW", "AY", "B", "CH", "D", "DH", "EH", "ER", "EY", "F", "G",
          "HH", "IH", "IY", "JH", "K", "L", "M", "N", "NG", "OW", "OY", "P", "R", "S", "SH", "T",
          "TH", "UH", "UW", "V", "W", "Y", "Z", "ZH")
PHONE_DIM = len(PHONES)
_INDEX = {p: i for i, p in enumerate(PHONES)}


def _decoder():
    """A new decoder (≈ 10 ms): one per utterance. A reused decoder carries its live cepstral-mean
    estimate from one utterance into the next, so a video's phones would depend on which videos
    the same worker decoded before it."""
    import pocketsphinx
    model = os.path.join(pocketsphinx.get_model_path(), "en-us")
    # lw / beams: CMU's recommended allphone settings (wide beams, phone-LM weight 2)
    return pocketsphinx.Decoder(hmm=os.path.join(model, "en-us"), allphone=os.path.join(model, "en-us-phone.lm.bin"),
                                lm=None, dict=None, lw=2.0, beam=1e-20, pbeam=1e-20, loglevel="FATAL")


def recognize_phones(samples: np.ndarray, sample_rate: int = SAMPLE_RATE) -> list[tuple[str, int, int]]:
    """Phone segments of one utterance.

    Parameters
    ----------
    samples : ndarray of shape (S,)
        Mono audio at 16 kHz (any level: it is peak-scaled to 16-bit PCM first).
    sample_rate : int
        Must be 16000 (Hz).

    Returns
    -------
    list of tuple
        (phone, first_frame, last_frame) with frames of 10 ms (pocketsphinx's), phone in
        ``PHONES``; empty for audio the recogniser finds nothing in.
    """
    if sample_rate != SAMPLE_RATE:
        raise ParameterError(f"recognize_phones expects {SAMPLE_RATE} Hz audio, got {sample_rate} Hz (resample first)")
    x = np.asarray(samples, np.float64)
    if x.ndim != 1:
        raise ParameterError(f"recognize_phones expects mono (S,) audio, got shape {x.shape}")
    x = np.nan_to_num(x)
    peak = float(np.abs(x).max()) if len(x) else 0.0
    if peak < 1e-6:                                  # digital silence: nothing to recognise
        return []
    pcm = np.round(x / peak * 29000).astype(np.int16).tobytes()
    d = _decoder()
    d.start_utt()
    d.process_raw(pcm, full_utt=True)
    d.end_utt()
    return [(s.word if s.word in _INDEX else "SIL", int(s.start_frame), int(s.end_frame)) for s in d.seg()]


def phone_indicators(samples: np.ndarray, n_frames: int | None = None) -> np.ndarray:
    """(T, 40) float32 one-hot phone indicators at 100 Hz (columns ``PHONES``).

    T = ``n_frames`` or 1 + S // 160 (the MFCC frame count of the same audio). Frames the
    recogniser does not cover (its edges, silence) are silence.
    """
    n = int(n_frames) if n_frames is not None else 1 + len(samples) // HOP
    out = np.zeros((n, PHONE_DIM), np.float32)
    out[:, 0] = 1.0
    for phone, a, b in recognize_phones(samples):
        a, b = max(a, 0), min(b + 1, n)
        if a < b:
            out[a:b] = 0.0
            out[a:b, _INDEX[phone]] = 1.0
    return out
