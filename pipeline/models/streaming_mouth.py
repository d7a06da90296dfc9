"""Mouth shapes as the audio arrives: the causal front end, the LSTM stepped with its state carried, and
the video frames whose shape is now known (``lipsynth live``).

``predict_mouth`` runs a whole file; ``StreamingMouth`` gives the same model's shapes piece by piece:
``push(samples)`` returns the frames k (at ``fps``) whose 100-Hz coefficients around k / fps exist, each
as (k, coeffs (20,), lip_points (18, 2) canonical texture px). The LSTM's target delay d holds a frame
back d steps more (the network hears d steps of the future). Digital silence moves the mouth to the
model's rest shape (``rest_coeffs``), as offline. A model folder with a live LSTM (``live.pt``, taught by
``bench/live_student.py`` to read the causal front end's states as the LSTM reads the offline ones) runs
it in place of its own when the stream settings are the ones it was taught with.

Only LSTM model folders stream (Voice Puppetry's Viterbi and Karras' windows need the future); a
personalized model that kept its retrieval candidate streams its parametric read-out (a Viterbi path
needs the future too) — ``retrieval`` says so.
"""
from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import torch

from pipeline.audio import audio_features
from pipeline.audio.streaming_features import RATE, STREAM, StreamingFeatures
from pipeline.errors import ParameterError
from pipeline.models.model_folder import load_model, read_config, read_state_dict
from pipeline.models.mouth_pca import reconstruct

log = logging.getLogger("lipsynth.live")


def load_student(model, model_dir, stream: dict) -> bool:
    """Put the model folder's live LSTM (``live.pt``: taught by ``bench/live_student.py`` to hear through the
    causal front end with these ``stream`` settings) into ``model``; False (the offline LSTM, with a
    warning) when the folder has none or it was taught with other settings."""
    folder = Path(model_dir)
    if not (folder / "live.pt").is_file() or not (folder / "live.json").is_file():
        log.warning("%s has no live LSTM (live.pt; bench/live_student.py makes it): the offline LSTM hears the "
                    "live front end's short windows — expect weaker lip sync", model_dir)
        return False
    if (folder / "MANIFEST.json").is_file():             # a shipped folder: every file hash-checked first
        from pipeline.models.base_model import verify
        verify(folder)
    taught = json.loads((folder / "live.json").read_text())["stream"]
    if any(abs(taught[k] - stream[k]) > 1e-9 for k in taught):
        log.warning("%s: its live LSTM was taught with %s, this stream is %s: using the offline LSTM", model_dir,
                    taught, stream)
        return False
    model.lstm.load_state_dict(read_state_dict(folder / "live.pt"))
    log.info("live LSTM of %s (taught with the live front end: %s)", model_dir, taught)
    return True


class StreamingMouth:
    """Push 16 kHz mono samples (raw, any level); get [(k, coeffs, lip_points), …] for new frames."""

    def __init__(self, model_dir, fps: float, past_s: float = STREAM["past_s"], ahead_s: float = STREAM["ahead_s"],
                 hop_s: float = STREAM["hop_s"], pad_s: float = STREAM["pad_s"], device: str = "cpu",
                 use_student: bool = True):
        config = read_config(model_dir)
        if config["model"] != "lstm":
            raise ParameterError(f"{model_dir}: a {config['model']} model cannot run live (its inference needs the "
                                 f"whole audio); use an LSTM model folder (models/base or a personalized one)")
        if not 1 <= fps <= 240:
            raise ParameterError(f"fps {fps}: expected a video frame rate between 1 and 240")
        self.model, self.config, arrays = load_model(model_dir, torch.device(device))
        self.student = use_student and load_student(self.model, model_dir, dict(past_s=past_s, ahead_s=ahead_s,
                                                                                 hop_s=hop_s, pad_s=pad_s))
        self.model.eval()
        self.device = torch.device(device)
        self.delay = int(config["delay"])
        self.fps = float(fps)
        self.mean, self.std = arrays["feature_mean"], arrays["feature_std"]
        self.basis = dict(mean=arrays["pca_mean"], components=arrays["pca_components"])
        self.rest = arrays["rest_coeffs"] if "rest_coeffs" in arrays else None
        self.retrieval = "retrieval_keys" in arrays
        self.features = StreamingFeatures(config.get("features", "mfcc"), config.get("encoder"), past_s, ahead_s,
                                          hop_s, config.get("feature_norm", "corpus") == "utterance", pad_s)
        self.state = None
        self.fed = 0                     # 100-Hz steps fed to the LSTM
        self.c100: list[np.ndarray] = []  # committed coefficients, step i = shape at i / 100 s
        self.quiet = np.zeros(0, bool)   # per committed feature frame: digital silence
        self.next_frame = 0
        self.samples = np.zeros(0, np.float32)     # raw audio not yet judged for silence
        self.samples_offset = 0                    # its first frame (× 160 samples)

    @property
    def mean_shape(self) -> np.ndarray:
        return self.basis["mean"].reshape(-1, 2).astype(np.float32)

    def push(self, samples: np.ndarray) -> list[tuple[int, np.ndarray, np.ndarray]]:
        self._track_silence(samples)
        return self._step(self.features.push(samples), final=False)

    def flush(self) -> list[tuple[int, np.ndarray, np.ndarray]]:
        """End of stream: every remaining frame up to the audio's duration."""
        return self._step(self.features.flush(), final=True)

    def _track_silence(self, samples: np.ndarray) -> None:
        """Judge the 10-ms frames 150 ms behind the newest audio: digital silence or not (``quiet``)."""
        hop = audio_features.HOP
        self.samples = np.concatenate([self.samples, np.asarray(samples, np.float32).ravel()])
        upto = self.samples_offset + len(self.samples) // hop - 16     # frames with 15 frames of audio after them
        if upto <= len(self.quiet):
            return
        q = audio_features.silent_frames(self.samples, None, audio_features.SILENCE_DBFS, None)
        self.quiet = np.concatenate([self.quiet, q[len(self.quiet) - self.samples_offset:upto - self.samples_offset]])
        keep = max(0, len(self.quiet) - 32 - self.samples_offset)      # the stretch rule looks back 150 ms
        self.samples = self.samples[keep * hop:]
        self.samples_offset += keep

    @torch.no_grad()
    def _step(self, x: np.ndarray, final: bool) -> list:
        if len(x):
            xn = ((x - self.mean) / self.std).astype(np.float32)
            y, self.state = self.model(torch.from_numpy(xn[None]).to(self.device), self.state)
            y = y[0].cpu().numpy()
            self.fed += len(x)
            start = max(0, self.delay - (self.fed - len(x)))       # the first d outputs precede step 0
            self.c100.extend(y[start:])
        if final and self.delay:
            y, self.state = self.model(torch.zeros((1, self.delay, x.shape[1] if len(x) else len(self.mean)),
                                                   device=self.device), self.state)
            self.c100.extend(y[0].cpu().numpy())
        return self._frames(final)

    def _frames(self, final: bool) -> list:
        n = len(self.c100)
        duration_frames = (self.features.received / audio_features.SAMPLE_RATE) * self.fps
        out = []
        while True:
            k = self.next_frame
            t = k / self.fps * RATE
            if final:
                if k >= int(np.floor(duration_frames + 0.5)):
                    break
            elif int(np.ceil(t)) >= n:
                break
            i0 = min(int(np.floor(t)), n - 1)
            i1 = min(i0 + 1, n - 1)
            f = t - np.floor(t)
            c = (1 - f) * self.c100[i0] + f * self.c100[i1]
            if self.rest is not None and i0 < len(self.quiet) and self.quiet[i0]:
                c = self.rest
            c = np.asarray(c, np.float32)
            out.append((k, c, reconstruct(c[None], self.basis)[0].astype(np.float32)))
            self.next_frame += 1
        return out


def stream_mouth(samples: np.ndarray, model_dir, fps: float, past_s: float = STREAM["past_s"],
                 ahead_s: float = STREAM["ahead_s"], hop_s: float = STREAM["hop_s"], pad_s: float = STREAM["pad_s"],
                 piece_s: float = 0.02, use_student: bool = True) -> np.ndarray:
    """Lip points (T, 18, 2) of a live stream of ``samples`` pushed in ``piece_s`` pieces (the bench's
    comparison with ``predict_mouth``)."""
    sm = StreamingMouth(model_dir, fps, past_s, ahead_s, hop_s, pad_s, use_student=use_student)
    step = max(1, int(piece_s * audio_features.SAMPLE_RATE))
    frames = []
    for a in range(0, len(samples), step):
        frames += sm.push(samples[a:a + step])
    frames += sm.flush()
    return np.stack([f[2] for f in frames])
