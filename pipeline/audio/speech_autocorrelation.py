"""Audio input of the Karras et al. network (paper 001 §3.2): autocorrelations of a 520 ms window.

The track (16 kHz mono) is scaled to the full [−1, 1] range. For an output pose at time t the
window is t ± 260 ms, cut into 64 frames of 256 samples (16 ms) every 128 samples (8 ms):
64 · 128 + 128 = 8320 samples = 520 ms. Each frame loses its DC component, is Hann-windowed, and
gives K = 32 autocorrelation coefficients (lags 0…31) → a 64 × 32 array per output frame.

Storing the 64 × 32 windows would cost 8 KB per output frame (float32) — more than the ~1 KB per
frame the issue allows — so they are computed on the fly, for any (time-shifted) centre.
"""
from __future__ import annotations

import numpy as np

from pipeline.errors import BadInputError

SAMPLE_RATE = 16000
FRAME = 256
HOP = 128
FRAMES = 64
LAGS = 32
HALF = FRAMES * HOP // 2 + HOP // 2          # 4160 samples = 260 ms each side of the centre
WINDOW_BYTES = FRAMES * LAGS * 4


def normalise_track(samples: np.ndarray, source="audio") -> np.ndarray:
    """Scale to max |x| = 1 (float64). Digital silence has nothing to scale: BadInputError."""
    x = np.asarray(samples, np.float64)
    peak = float(np.max(np.abs(x))) if len(x) else 0.0
    if not np.isfinite(peak):
        raise BadInputError(source, "audio samples are not finite")
    if peak <= 0:
        raise BadInputError(source, "the audio is silent: nothing to analyse")
    return x / peak


def frame_autocorrelation(frames: np.ndarray) -> np.ndarray:
    """(..., 256) frames → (..., 32): DC removed, Hann window, Σ_n x[n] x[n + k] for k = 0…31."""
    x = frames - frames.mean(-1, keepdims=True)
    x = x * np.hanning(FRAME + 2)[1:-1]                      # the symmetric Hann without its zero ends
    spec = np.fft.rfft(x, n=2 * FRAME, axis=-1)
    return np.fft.irfft(np.abs(spec) ** 2, n=2 * FRAME, axis=-1)[..., :LAGS]


def padded_track(samples: np.ndarray, source="audio") -> np.ndarray:
    """The normalised track, zero-padded so any window centred inside it can be cut (float64)."""
    if len(samples) < 2 * HALF:
        raise BadInputError(source, f"audio too short for one 520 ms window ({len(samples) / SAMPLE_RATE:.2f} s)")
    pad = HALF + FRAME
    return np.pad(normalise_track(samples, source), (pad, pad))


def windows(padded: np.ndarray, times: np.ndarray) -> np.ndarray:
    """(T, 64, 32) float32 windows centred at ``times`` (s) of a ``padded_track``."""
    centre = np.round(np.asarray(times, np.float64) * SAMPLE_RATE).astype(int)
    starts = centre[:, None] - HALF + HOP * np.arange(FRAMES)[None, :] + HALF + FRAME   # (T, 64)
    starts = np.clip(starts, 0, len(padded) - FRAME)
    frames = padded[starts[..., None] + np.arange(FRAME)]                               # (T, 64, 256)
    return frame_autocorrelation(frames).astype(np.float32)


def autocorrelation_features(samples: np.ndarray, times: np.ndarray, source="audio") -> np.ndarray:
    """(T, 64, 32) float32 windows centred at ``times`` (s) of a 16 kHz track (zero beyond its ends).

    The track is normalised first (``normalise_track``); a track shorter than one 520 ms window
    raises BadInputError naming ``source``.
    """
    return windows(padded_track(samples, source), times)
