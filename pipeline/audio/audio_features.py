"""Paper 000 §3.1 "Audio Features": RMS-normalised 16 kHz mono → 28-D MFCC features at 100 Hz.

25 ms Hann windows every 10 ms, power spectrum, 40 triangular mel filters, log, DCT-II to 13
cepstra, plus the log mean energy of the window, plus first temporal derivatives of all 14.
Frame t is centred at time t / 100 s.
"""
from __future__ import annotations

import numpy as np
import scipy.fft
import scipy.signal

from pipeline.errors import ParameterError

SAMPLE_RATE = 16000
WIN = 400        # 25 ms at 16 kHz
HOP = 160        # 10 ms at 16 kHz
N_FFT = 512
N_MELS = 40
N_CEPS = 13
FEATURE_DIM = 2 * (N_CEPS + 1)   # 28
EPS = 1e-10


def rms_normalize(samples: np.ndarray, target_dbfs: float = -23.0, max_gain_db: float = 40.0) -> np.ndarray:
    """Scale audio so its RMS is ``target_dbfs`` (ffmpeg-normalize's RMS mode).

    Gain is capped at ``max_gain_db`` so digital silence stays silent rather than becoming
    amplified noise. Returns float32 (S,).
    """
    rms = float(np.sqrt(np.mean(np.square(samples, dtype=np.float64)))) if len(samples) else 0.0
    if rms <= 0:
        return samples.astype(np.float32)
    gain = min(10 ** (target_dbfs / 20) / rms, 10 ** (max_gain_db / 20))
    return np.clip(samples * gain, -1.0, 1.0).astype(np.float32)


def frame_signal(samples: np.ndarray, win: int = WIN, hop: int = HOP) -> np.ndarray:
    """Zero-pad by win//2 on both sides and cut into frames; returns (T, win), T = 1 + S // hop."""
    padded = np.pad(samples.astype(np.float64), (win // 2, win // 2))
    n = 1 + len(samples) // hop
    need = (n - 1) * hop + win
    if len(padded) < need:
        padded = np.pad(padded, (0, need - len(padded)))
    idx = np.arange(win)[None, :] + hop * np.arange(n)[:, None]
    return padded[idx]


_MEL: dict = {}


def hz_to_mel(f):
    """HTK mel scale."""
    return 2595.0 * np.log10(1.0 + np.asarray(f, np.float64) / 700.0)


def mel_to_hz(m):
    return 700.0 * (10.0 ** (np.asarray(m, np.float64) / 2595.0) - 1.0)


def vtlp_warp(freqs, alpha: float, sample_rate: int = SAMPLE_RATE, f_hi: float = 4800.0) -> np.ndarray:
    """Vocal-tract-length perturbation (Jaitly & Hinton 2013): frequency f (Hz) → f·α below the
    boundary f_hi·min(α, 1)/α, then linear so that Nyquist stays at Nyquist. α = 1 is the identity;
    α > 1 stretches the spectrum (a shorter vocal tract), α < 1 compresses it."""
    f = np.asarray(freqs, np.float64)
    nyq = sample_rate / 2
    knee = f_hi * min(alpha, 1.0) / alpha
    top = nyq - (nyq - f_hi * min(alpha, 1.0)) / (nyq - knee) * (nyq - f)
    return np.where(f <= knee, f * alpha, top)


def mel_filterbank(n_mels: int = N_MELS, n_fft: int = N_FFT, sample_rate: int = SAMPLE_RATE,
                   warp: float = 1.0) -> np.ndarray:
    """(n_mels, n_fft // 2 + 1) triangular filters with peak 1, equally spaced on the HTK mel
    scale from 0 Hz to Nyquist; ``warp`` ≠ 1 reads the spectrum through ``vtlp_warp``."""
    key = (n_mels, n_fft, sample_rate, float(warp))
    if key in _MEL:
        return _MEL[key]
    edges = mel_to_hz(np.linspace(0.0, hz_to_mel(sample_rate / 2), n_mels + 2))
    bins = np.linspace(0.0, sample_rate / 2, n_fft // 2 + 1)
    if warp != 1.0:
        bins = vtlp_warp(bins, warp, sample_rate)
    lo, mid, hi = edges[:-2, None], edges[1:-1, None], edges[2:, None]
    up = (bins[None] - lo) / (mid - lo)
    down = (hi - bins[None]) / (hi - mid)
    _MEL[key] = np.maximum(0.0, np.minimum(up, down))
    return _MEL[key]


def log_mel(samples: np.ndarray, warp: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Log mel energies (T, 40) and log mean energy (T,) of each 25 ms window."""
    frames = frame_signal(samples)
    window = scipy.signal.get_window("hann", WIN, fftbins=True)
    power = np.abs(np.fft.rfft(frames * window, n=N_FFT)) ** 2
    mel = np.log(power @ mel_filterbank(warp=warp).T + EPS)
    energy = np.log(np.mean(frames ** 2, axis=1) + EPS)
    return mel, energy


def delta(x: np.ndarray, width: int = 2) -> np.ndarray:
    """Regression first derivative along time (HTK, ±``width`` frames, edges repeated). (T, D) → (T, D)."""
    t = len(x)
    padded = np.pad(x, ((width, width), (0, 0)), mode="edge")
    num = sum(k * (padded[width + k:width + k + t] - padded[width - k:width - k + t]) for k in range(1, width + 1))
    return num / (2 * sum(k * k for k in range(1, width + 1)))


def static_cepstra(samples: np.ndarray, warp: float = 1.0) -> np.ndarray:
    """(T, 14): 13 MFCC (DCT-II of the log mel energies) and the log mean energy per 10 ms frame."""
    mel, energy = log_mel(samples, warp)
    ceps = scipy.fft.dct(mel, type=2, norm="ortho", axis=1)[:, :N_CEPS]
    return np.concatenate([ceps, energy[:, None]], axis=1)


def mfcc_features(samples: np.ndarray, sample_rate: int = SAMPLE_RATE, warp: float = 1.0) -> np.ndarray:
    """28-D features at 100 Hz: 13 MFCC, log mean energy, and their deltas.

    Parameters
    ----------
    samples : ndarray of shape (S,)
        Mono audio at 16 kHz, already RMS-normalised (see ``rms_normalize``).
    sample_rate : int
        Must be 16000 (Hz).
    warp : float
        VTLP factor α (``vtlp_warp``; training augmentation, ``train.vtlp_warps``); 1 = the paper.

    Returns
    -------
    ndarray
        (1 + S // 160, 28) float32: one row per 10 ms.
    """
    if sample_rate != SAMPLE_RATE:
        raise ParameterError(f"mfcc_features expects {SAMPLE_RATE} Hz audio, got {sample_rate} Hz (resample first)")
    if samples.ndim != 1:
        raise ParameterError(f"mfcc_features expects mono (S,) audio, got shape {samples.shape}")
    static = static_cepstra(samples, warp)
    return np.concatenate([static, delta(static)], axis=1).astype(np.float32)


def cmvn(features: np.ndarray) -> np.ndarray:
    """Cepstral mean and variance normalisation over one utterance: (T, D) → (T, D) float32,
    every dimension zero-mean, unit-variance over the T frames."""
    x = np.asarray(features, np.float64)
    return ((x - x.mean(0)) / np.maximum(x.std(0), 1e-6)).astype(np.float32)


def pitch_shifted_mfcc(samples: np.ndarray, semitones: float) -> np.ndarray:
    """28-D MFCC (as ``mfcc_features``) of the audio with its pitch shifted by ``semitones`` and its
    formants and timing kept — an augmentation for training (``train.pitch_shifts``).

    The audio is resampled by r = 2^(semitones/12) (pitch, formants and tempo all × r); the mel
    filterbank then reads the spectrum through ``vtlp_warp`` with α = 1/r, which moves the
    formants back (exactly below the warp's knee), and the static cepstra are interpolated back
    onto the original 10 ms frame times before the deltas are taken. Returns (1 + S // 160, 28).
    """
    from scipy.signal import resample_poly
    from fractions import Fraction
    x = np.asarray(samples, np.float64)
    r = 2.0 ** (semitones / 12.0)
    q = Fraction(r).limit_denominator(200)                   # r ≈ p / q: 16 kHz audio read r× faster
    y = resample_poly(x, q.denominator, q.numerator)
    static = static_cepstra(y.astype(np.float32), warp=1.0 / r)          # frames at t' = k / 100 s of y
    n = 1 + len(x) // HOP
    t_new = np.arange(len(static)) / 100.0 * (q.numerator / q.denominator)   # the same instants in x's time
    t = np.arange(n) / 100.0
    back = np.stack([np.interp(t, t_new, static[:, j]) for j in range(static.shape[1])], axis=1)
    return np.concatenate([back, delta(back)], axis=1).astype(np.float32)



SILENCE_DBFS = -65.0     #: below this RMS (after RMS normalisation) audio holds no speech: digital silence, faint hiss


def silent_frames(samples: np.ndarray, n_frames: int | None = None, floor_dbfs: float = -55.0,
                  below_peak_db: float | None = 35.0, min_ms: float = 150.0) -> np.ndarray:
    """(T,) bool: 10-ms frames (frame t centred at t / 100 s, T = 1 + S // 160 unless given) inside a
    stretch of at least ``min_ms`` whose 25-ms RMS is below max(``floor_dbfs``, loudest − ``below_peak_db``)
    dBFS (``below_peak_db=None``: below ``floor_dbfs`` alone).

    With the defaults: the pauses of a recording (the training pauses whose mouth is a model's rest
    shape); with ``floor_dbfs=SILENCE_DBFS, below_peak_db=None``: digital silence or faint noise, where
    no front end has anything to read (``mouth_prediction.rest_in_silence``)."""
    x = np.asarray(samples, np.float64)
    n = 1 + len(x) // HOP if n_frames is None else int(n_frames)
    db = 10 * np.log10(np.mean(frame_signal(x) ** 2, axis=1) + 1e-12)
    db = np.pad(db, (0, max(0, n - len(db))), constant_values=-120.0)[:n]
    quiet = db < (floor_dbfs if below_peak_db is None else max(floor_dbfs, float(db.max()) - below_peak_db))
    run = max(1, int(round(min_ms / 10)))
    out = np.zeros(n, bool)
    start = None
    for t, q in enumerate(np.append(quiet, False)):
        if q and start is None:
            start = t
        elif not q and start is not None:
            if t - start >= run:
                out[start:t] = True
            start = None
    return out
