"""Voice features at a video-like frame rate for the Voice Puppetry HMM (paper 002 §4.1).

Brand's vocal representation is "a mix of LPC and RASTA-PLP audio features" plus "formant
frequencies" and band energies. ``kind="paper"`` builds that mix from maintained libraries:

    LPC          12 coefficients a1…a12 (``librosa.lpc``) of each Hann-windowed 25 ms frame
    RASTA-PLP    13 cepstra (``spafe.features.rplp``, 25 ms Hamming windows, hop 10 ms)
    formants     F1, F2, F3 in kHz (Praat's Burg method via ``praat-parselmouth``); unvoiced
                 frames (no formant) take the value interpolated from the nearest voiced ones
    band energy  log energy in 0–0.5, 0.5–1, 1–2, 2–4, 4–8 kHz
                 → 33 values per 10 ms

``kind="mfcc"`` is the project's 28-D MFCC (13 cepstra, log energy, their deltas; paper 000).
``kind="whisper"`` is the 384-D encoder states of Whisper tiny.en (``pipeline.audio.whisper_encoder``,
default windows); the Voice Puppetry stage projects them on a PCA of its training voice.
Both are computed at 100 Hz and averaged over each output frame's period (frame k covers
[k − ½, k + ½) / rate seconds), so a model trained at 25 Hz reads 4 feature frames per state.
The audio is dithered (±1e-5 full scale, fixed seed) so digital silence gives finite values.
"""
from __future__ import annotations

import numpy as np

from pipeline.audio import audio_features
from pipeline.audio.whisper_encoder import STATE_DIM
from pipeline.errors import BadInputError, ParameterError

KINDS = ("paper", "mfcc", "whisper")
LPC_ORDER = 12
RPLP_ORDER = 13
BANDS_HZ = ((0, 500), (500, 1000), (1000, 2000), (2000, 4000), (4000, 8000))
DIMS = {"paper": LPC_ORDER + RPLP_ORDER + 3 + len(BANDS_HZ), "mfcc": audio_features.FEATURE_DIM, "whisper": STATE_DIM}
DITHER = 1e-5


def _dithered(samples: np.ndarray) -> np.ndarray:
    noise = np.random.default_rng(0).standard_normal(len(samples))
    return samples.astype(np.float64) + DITHER * noise


def lpc_coefficients(samples: np.ndarray) -> np.ndarray:
    """(S,) 16 kHz → (1 + S // 160, 12) LPC a1…a12 of Hann-windowed 25 ms frames (frame t centred at t/100 s)."""
    import librosa
    frames = audio_features.frame_signal(samples) * np.hanning(audio_features.WIN)
    a = librosa.lpc(frames, order=LPC_ORDER, axis=-1)
    return a[:, 1:]


def rasta_plp(samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """RASTA-PLP cepstra (n, 13) and their frame centres (n,) s."""
    from spafe.features.rplp import rplp
    from spafe.utils.preprocessing import SlidingWindow
    win, hop = audio_features.WIN / audio_features.SAMPLE_RATE, audio_features.HOP / audio_features.SAMPLE_RATE
    c = rplp(samples, fs=audio_features.SAMPLE_RATE, order=RPLP_ORDER, window=SlidingWindow(win, hop, "hamming"))
    return np.asarray(c, np.float64), win / 2 + hop * np.arange(len(c))


def formants(samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """F1–F3 (n, 3) in kHz (Praat Burg, 5 formants below 5.5 kHz) and frame centres (n,) s."""
    import parselmouth
    sound = parselmouth.Sound(samples, audio_features.SAMPLE_RATE)
    fm = sound.to_formant_burg(time_step=0.01, max_number_of_formants=5, maximum_formant=5500, window_length=0.025)
    t = np.asarray(fm.xs())
    f = np.array([[fm.get_value_at_time(k, x) for k in (1, 2, 3)] for x in t], np.float64).reshape(-1, 3) / 1000.0
    for j, default in enumerate((0.5, 1.5, 2.5)):          # unvoiced gaps: interpolate from voiced frames
        ok = np.isfinite(f[:, j])
        f[:, j] = np.interp(t, t[ok], f[ok, j]) if ok.any() else default
    return f, t


def band_energies(samples: np.ndarray) -> np.ndarray:
    """(1 + S // 160, 5) log energies of the 25 ms frames in ``BANDS_HZ``."""
    frames = audio_features.frame_signal(samples) * np.hanning(audio_features.WIN)
    power = np.abs(np.fft.rfft(frames, n=audio_features.N_FFT)) ** 2
    hz = np.fft.rfftfreq(audio_features.N_FFT, 1 / audio_features.SAMPLE_RATE)
    return np.stack([np.log(power[:, (hz >= lo) & (hz < hi)].sum(1) + audio_features.EPS) for lo, hi in BANDS_HZ], 1)


def features_100hz(samples: np.ndarray, kind: str, encoder: dict | None = None) -> np.ndarray:
    """(1 + S // 160, DIMS[kind]) features of 16 kHz mono samples; row t is centred at t / 100 s.
    ``encoder``: whisper window settings (``window_s``, ``overlap_s``) for ``kind="whisper"``."""
    if kind not in KINDS:
        raise ParameterError(f"vocal features {kind!r}: choose one of {', '.join(KINDS)}")
    if kind == "whisper":
        from pipeline.audio.whisper_layers import whisper_features
        return whisper_features(np.asarray(samples, np.float32), None, **(encoder or {})).astype(np.float64)
    x = _dithered(samples)
    if kind == "mfcc":
        return audio_features.mfcc_features(x.astype(np.float32)).astype(np.float64)
    t100 = np.arange(1 + len(x) // audio_features.HOP) / 100.0
    rp, trp = rasta_plp(x)
    fm, tfm = formants(x)
    on_axis = lambda v, t: np.stack([np.interp(t100, t, v[:, j]) for j in range(v.shape[1])], 1)
    return np.concatenate([lpc_coefficients(x), on_axis(rp, trp), on_axis(fm, tfm), band_energies(x)], 1)


def pool_to_rate(f100: np.ndarray, n_frames: int, rate: float) -> np.ndarray:
    """Average 100 Hz rows over each frame period: frame k ← rows centred in [k − ½, k + ½) / rate.

    A frame period holding no row (rate > 100 Hz) takes the nearest row. Returns (n_frames, D).
    """
    t100 = np.arange(len(f100)) / 100.0
    k = np.floor(t100 * rate + 0.5).astype(int)
    keep = (k >= 0) & (k < n_frames)
    sums = np.zeros((n_frames, f100.shape[1]))
    counts = np.zeros(n_frames)
    np.add.at(sums, k[keep], f100[keep])
    np.add.at(counts, k[keep], 1)
    out = sums / np.maximum(counts, 1)[:, None]
    empty = counts == 0
    if empty.any():
        nearest = np.clip(np.round(np.arange(n_frames)[empty] / rate * 100).astype(int), 0, len(f100) - 1)
        out[empty] = f100[nearest]
    return out


def vocal_features(samples: np.ndarray, kind: str, rate: float, n_frames: int, source="audio",
                   encoder: dict | None = None) -> np.ndarray:
    """(n_frames, DIMS[kind]) features of 16 kHz mono ``samples`` at ``rate`` frames/s.

    Raises BadInputError naming ``source`` when the audio holds less than one frame or the
    features are not finite.
    """
    if n_frames < 1 or len(samples) < audio_features.WIN:
        raise BadInputError(source, f"audio too short for one {1000 / rate:.0f} ms frame of the voice model")
    f = pool_to_rate(features_100hz(samples, kind, encoder), n_frames, rate)
    if not np.isfinite(f).all():
        raise BadInputError(source, f"{kind} voice features are not finite (NaN/inf) — is the audio valid?")
    return f
