"""A causal audio front end: model input frames (100 Hz) from audio as it arrives (``lipsynth live``).

The offline front end (``front_ends.frame_features``) reads the whole file: its RMS normalisation, the
Whisper encoder's 10-s windows and the log-mel clamp all see the future. Here the audio arrives in pieces
and frame t (centred at t / 100 s) is committed once ``ahead_s`` of audio after it has arrived:

1. the gain is the running RMS normalisation (``audio_features.rms_normalize``'s target and cap, over the
   audio so far, at least 0.5 s of it);
2. every ``hop_s`` of new audio, one window — the last ``past_s`` before the first uncommitted frame,
   the hop, and the ``ahead_s`` after it — goes through the model's front end (the Whisper encoder on
   that window padded with silence to ``pad_s``, its log-mel clamped at the loudest power of the stream
   so far); the hop's frames are kept, the look-ahead's dropped (they are recomputed, with more future,
   by the next window);
3. ``feature_norm: utterance`` models get a running CMVN (the frames so far).

``ahead_s`` trades latency for lip sync: ``bench/live.py --curve`` measures the cost against the offline
front end.
"""
from __future__ import annotations

import numpy as np

from pipeline.audio import front_ends
from pipeline.audio.audio_features import HOP, SAMPLE_RATE
from pipeline.errors import ParameterError

RATE = SAMPLE_RATE // HOP                       #: frames per second (100)
TARGET_DBFS, MAX_GAIN_DB = -23.0, 40.0          #: as ``audio_features.rms_normalize``
MIN_GAIN_SECONDS = 0.5                          #: the running gain waits for this much audio (unity before)
#: the stream settings (s) ``lipsynth live`` runs by default and the shipped live LSTM was taught with
#: (``bench/live_student.py``): each window sees ``past_s`` before its new frames, ``hop_s`` of them and
#: ``ahead_s`` after, padded to ``pad_s``. A hop of 0.1 s rather than 0.2 s takes 50 ms off the median latency
#: (a frame waits for the end of its hop) for twice the encoder's work (docs/live_figures.md).
STREAM = dict(past_s=1.5, ahead_s=0.2, hop_s=0.1, pad_s=2.0)


class StreamingFeatures:
    """Push 16 kHz mono float samples in; get the frames (T_new, D) that are now final.

    Parameters
    ----------
    front_end : str
        The model's ``train.features`` (``mfcc``, ``whisper``, ``phonetic``, combinations).
    encoder : dict, optional
        The model's whisper settings (only ``window_s`` is replaced: the window is this one's).
    past_s, ahead_s, hop_s : float
        Seconds of context before, of look-ahead after, and of new frames per window.
    utterance_norm : bool
        Running CMVN (models trained with ``feature_norm: utterance``).
    pad_s : float
        A whisper window shorter than this (s) is padded to it (silence after the look-ahead, as
        Whisper pads its windows; the states just before an unpadded window's end follow the lips far less).
    """

    def __init__(self, front_end: str, encoder: dict | None = None, past_s: float = STREAM["past_s"],
                 ahead_s: float = STREAM["ahead_s"], hop_s: float = STREAM["hop_s"], utterance_norm: bool = False,
                 pad_s: float = STREAM["pad_s"]):
        front_ends.check(front_end)
        if not (past_s >= 0 and ahead_s >= 0 and hop_s > 0):
            raise ParameterError(f"streaming front end: past_s={past_s}, ahead_s={ahead_s} must be ≥ 0 and "
                                 f"hop_s={hop_s} > 0 (seconds)")
        self.front_end, self.encoder = front_end, dict(encoder or {})
        self.past, self.ahead, self.hop = (int(round(s * RATE)) for s in (past_s, ahead_s, hop_s))
        self.hop = max(self.hop, 1)
        self.pad = 2 * int(np.ceil(pad_s * RATE / 2))  # mel frames every whisper window is padded to
        self.peak = -10.0                                # loudest log10 mel power so far
        self.utterance_norm = utterance_norm
        self.buffer = np.zeros(0, np.float32)   # samples from frame ``self.offset`` on
        self.offset = 0                          # first frame the buffer holds (its sample offset × HOP)
        self.received = 0                        # samples so far
        self.done = 0                            # frames committed
        self.energy = [0.0]                      # Σ x² over the first k · HOP samples, k = 0, 1, …
        self.tail = np.zeros(0, np.float64)      # samples after the last whole HOP
        self.n, self.sum, self.sum2 = 0, 0.0, 0.0    # running CMVN: frames, Σx, Σx²

    def gain(self, upto: int) -> float:
        """The RMS normalisation's gain over the first ``upto`` samples (unity before ``MIN_GAIN_SECONDS``):
        fixed by the window's own end, so it does not depend on how far the stream has arrived."""
        k = min(upto // HOP, len(self.energy) - 1)
        if k * HOP < MIN_GAIN_SECONDS * SAMPLE_RATE or self.energy[k] <= 0:
            return 1.0
        rms = np.sqrt(self.energy[k] / (k * HOP))
        return float(min(10 ** (TARGET_DBFS / 20) / rms, 10 ** (MAX_GAIN_DB / 20)))

    def push(self, samples: np.ndarray) -> np.ndarray:
        """Add samples (S,) in [-1, 1]; returns the frames committed by them, (T_new, D) float32."""
        x = np.asarray(samples, np.float32).ravel()
        if not np.isfinite(x).all():
            raise ParameterError("audio samples contain NaN or infinite values")
        self.buffer = np.concatenate([self.buffer, x])
        self.received += len(x)
        self.tail = np.concatenate([self.tail, x.astype(np.float64)])
        whole = len(self.tail) // HOP
        if whole:
            sums = np.cumsum(np.square(self.tail[:whole * HOP]).reshape(whole, HOP).sum(1))
            self.energy.extend((self.energy[-1] + sums).tolist())
            self.tail = self.tail[whole * HOP:]
        out = []
        while self.available() - self.done >= self.hop:
            out.append(self._window(self.done + self.hop))
        return self._stack(out)

    def flush(self) -> np.ndarray:
        """End of stream: the remaining frames (no more future will come)."""
        out = []
        last = 1 + self.received // HOP
        while self.done < last:
            out.append(self._window(min(self.done + self.hop, last), final=True))
        return self._stack(out)

    def available(self) -> int:
        """Frames whose look-ahead has arrived: t with (t + ahead) · HOP + HOP/2 ≤ received."""
        return max(0, (self.received - HOP // 2) // HOP - self.ahead + 1)

    def _stack(self, parts: list) -> np.ndarray:
        if not parts:
            return np.zeros((0, front_ends.feature_dim(self.front_end, len(self.encoder.get("layers", [5])))), np.float32)
        return np.concatenate(parts)

    def _window(self, end: int, final: bool = False) -> np.ndarray:
        """Commit frames done … end − 1 from one window of the front end."""
        first = max(0, self.done - self.past)
        last = end + self.ahead                              # frames of look-ahead (fewer at the stream's end)
        a = (first - self.offset) * HOP
        b = min(len(self.buffer), (last - self.offset) * HOP + HOP // 2)
        audio = self.buffer[a:b] * self.gain(self.offset * HOP + b)
        audio = np.clip(audio, -1, 1)
        if front_ends.uses_whisper(self.front_end):
            feats = self._whisper(audio)
        else:
            feats = front_ends.frame_features(audio, self.front_end)
        block = feats[self.done - first:end - first]
        if len(block) < end - self.done:                     # the stream ended inside the window's last frame
            block = np.concatenate([block, np.repeat(block[-1:], end - self.done - len(block), 0)])
        self.done = end
        keep = max(0, self.done - self.past - self.offset)   # samples no future window needs
        self.buffer, self.offset = self.buffer[keep * HOP:], self.offset + keep
        return self._normalise(block.astype(np.float32))

    def _whisper(self, audio: np.ndarray) -> np.ndarray:
        """Encoder states of one window on the frame axis (1 + len // HOP, 384): Whisper's clamp at the loudest
        mel power of the stream so far, the window padded (as Whisper pads its 30 s) to ``pad`` frames."""
        from pipeline.audio import whisper_encoder as we
        n = 1 + len(audio) // HOP
        logs = we.log10_mel(audio, n)
        self.peak = max(self.peak, float(logs.max()))
        width = max(self.pad, 2 * -(-n // 2))
        mel = np.full((we.N_MELS, width), self.peak - 8.0, np.float32)
        mel[:, :n] = logs
        layers = tuple(self.encoder.get("layers", we.FINAL))
        if layers == we.FINAL:
            return we.to_frame_axis(we.encode_mel(we.whisper_scale(mel, self.peak)), n)
        from pipeline.audio.whisper_layers import encode_layers
        states = encode_layers(we.whisper_scale(mel, self.peak)[None], upto=max(layers))[:, 0]
        return np.concatenate([we.to_frame_axis(states[k], n) for k in layers], axis=1)

    def _normalise(self, block: np.ndarray) -> np.ndarray:
        if not self.utterance_norm:
            return block
        x = block.astype(np.float64)
        self.n, self.sum, self.sum2 = self.n + len(x), self.sum + x.sum(0), self.sum2 + (x ** 2).sum(0)
        mean = self.sum / self.n
        std = np.sqrt(np.maximum(self.sum2 / self.n - mean ** 2, 0))
        cols = front_ends.normalised_columns(self.front_end, x.shape[1])
        x[:, cols] = (x[:, cols] - mean[cols]) / np.maximum(std[cols], 1e-6)
        return x.astype(np.float32)


def causal_features(samples: np.ndarray, front_end: str, encoder: dict | None = None,
                    past_s: float = STREAM["past_s"], ahead_s: float = STREAM["ahead_s"],
                    hop_s: float = STREAM["hop_s"], utterance_norm: bool = False, pad_s: float = STREAM["pad_s"],
                    piece_s: float = 0.02) -> np.ndarray:
    """The frames (1 + S // 160, D) a live stream of ``samples`` (raw, not normalised) would give, pushed
    in pieces of ``piece_s`` seconds: what ``bench/live.py`` compares with the offline front end."""
    sf = StreamingFeatures(front_end, encoder, past_s, ahead_s, hop_s, utterance_norm, pad_s)
    step = max(1, int(piece_s * SAMPLE_RATE))
    parts = [sf.push(samples[a:a + step]) for a in range(0, len(samples), step)]
    parts.append(sf.flush())
    return np.concatenate(parts)[:1 + len(samples) // HOP]
