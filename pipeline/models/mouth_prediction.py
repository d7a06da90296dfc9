"""Mouth shapes for new audio from a trained model folder: the interface every model family answers.

``predict_mouth(load_audio(path), model_dir, fps)`` is what ``synthesize``, ``lipsynth speak``
and ``lipsynth predict-mouth`` call, whatever family the folder holds: ``lstm`` (below) or
``brand`` (Voice Puppetry, ``pipeline.models.voice_puppet``: Viterbi on its own voice features, the
closed-form trajectory at ``fps``) or ``ensemble`` (the mean of its members' outputs,
``pipeline.models.model_ensemble``) or ``karras`` (Karras et al., ``pipeline.models.karras_inference``:
autocorrelation windows at the frame times, two inferences 4 ms apart, a constant or interpolated
emotion vector — ``emotion``; its output also has ``face_points``, the whole lower face). The audio is any file PyAV reads (wav, mp3, m4a, the audio
of a video...), any rate and channel count: it is mixed to mono, resampled to 16 kHz, RMS-normalised and turned into the model's
front end (``pipeline.audio.front_ends``: the paper's 28-D MFCC, pocketsphinx phone indicators, or both). The LSTM runs over them (in chunks that carry its state, if asked — the
result equals one pass) and its 100 Hz output is sampled at the video frame times
t_k = k / fps, k < round(duration · fps).

Output (dict): coeffs (T, 20) PCA coefficients, lip_points (T, 18, 2) canonical texture pixels,
frame_time (T,) s, fps, pca_fingerprint.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.audio import audio_features
from pipeline.audio import front_ends
from pipeline.io import media
from pipeline.errors import BadInputError, ParameterError
from pipeline.models import model_ensemble, mouth_retrieval
from pipeline.models.model_folder import ModelFolder, check_model, read_config
from pipeline.models.mouth_pca import reconstruct

MIN_SECONDS = 0.5


def load_audio(path) -> np.ndarray:
    """Mono 16 kHz RMS-normalised samples of any audio (or video) file."""
    samples, _ = media.read_audio(path, audio_features.SAMPLE_RATE)
    if len(samples) < MIN_SECONDS * audio_features.SAMPLE_RATE:
        raise BadInputError(path, f"audio too short ({len(samples) / audio_features.SAMPLE_RATE:.2f} s < {MIN_SECONDS} s)")
    return audio_features.rms_normalize(samples)


def frame_count(n_samples: int, fps: float, sample_rate: int = audio_features.SAMPLE_RATE) -> int:
    """Frames of a video at ``fps`` lasting as long as the audio: round(duration · fps)."""
    return int(np.floor(n_samples / sample_rate * fps + 0.5))


def to_frames(c100: np.ndarray, frame_time: np.ndarray, rate: float = 100.0) -> np.ndarray:
    """Linear interpolation of (m, k) 100 Hz values at frame times (s) → (T, k)."""
    t = np.arange(len(c100)) / rate
    return np.stack([np.interp(frame_time, t, c100[:, j]) for j in range(c100.shape[1])], axis=1)


def rest_in_silence(c100: np.ndarray, samples: np.ndarray, rest: np.ndarray, ramp: int = 5) -> np.ndarray:
    """(m, k) 100-Hz coefficients with the silent stretches of ``samples`` (below ``SILENCE_DBFS``:
    digital silence or faint hiss, ``audio_features.silent_frames``) moved to the model's rest mouth,
    cross-faded over ``ramp`` frames inside each stretch. A front end reads nothing there, and
    silence unlike the training pauses must not open the mouth; ordinary pauses (room noise) are left
    to the model, which learnt them (gating them too lowered other voices' correlation 0.26 → 0.16)."""
    quiet = audio_features.silent_frames(samples, len(c100), audio_features.SILENCE_DBFS, None).astype(np.float64)
    if not quiet.any():
        return c100
    kernel = np.ones(2 * ramp + 1) / (2 * ramp + 1)
    g = (quiet * np.convolve(quiet, kernel, mode="same"))[:, None]      # ramps inside the quiet stretch only
    return ((1 - g) * c100 + g * rest[None]).astype(np.float32)


def check_model_folder(model_dir) -> dict:
    """Check a model folder of any family, ensembles included (raises ModelError naming what is
    wrong); its config."""
    if read_config(model_dir)["model"] == "ensemble":
        return model_ensemble.check(model_dir)
    return check_model(model_dir)


def open_model(model_dir) -> ModelFolder:
    """A model folder of any family opened once: its config read, its model(s) loaded and checked
    (``check_model_folder``; raises ModelError naming what is wrong). Pass the record on: the functions
    taking a model folder read its config and speaker from it. A record given is returned as it is."""
    if isinstance(model_dir, ModelFolder):
        return model_dir
    folder = Path(model_dir)
    return ModelFolder(folder, check_model_folder(folder))


def check_emotion(model_dir, emotion) -> None:
    """Refuse (ParameterError) an ``--emotion`` the model folder cannot take, before any long work."""
    if emotion is None:
        return
    family = read_config(model_dir)["model"]
    if family != "karras":
        raise ParameterError(f"--emotion {emotion}: only Karras models take an emotion; {model_dir} is a {family} model")
    from pipeline.models.karras_inference import parse_emotion
    with np.load(f"{model_dir}/arrays.npz") as z:
        parse_emotion(emotion, z["emotion_candidates"])


def predict_mouth(samples: np.ndarray, model_dir, fps: float, chunk_seconds: float | None = None,
                  device: str = "auto", source: str = "audio", emotion=None) -> dict:
    """Mouth shapes at ``fps`` for 16 kHz mono ``samples`` (see module doc for the output keys)."""
    from pipeline.models.delayed_lstm import pick_device, predict_sequence
    from pipeline.models.model_folder import load_model, load_puppet
    if not 1 <= fps <= 240:
        raise ParameterError(f"--fps {fps}: expected a video frame rate between 1 and 240")
    family = read_config(model_dir)["model"]
    check_emotion(model_dir, emotion)
    if family == "ensemble":
        return model_ensemble.average([predict_mouth(samples, m, fps, chunk_seconds, device, source)
                                       for m in model_ensemble.member_folders(model_dir)])
    if family == "karras":
        from pipeline.models import karras_inference
        from pipeline.models.model_folder import load_karras
        dev = pick_device(device)
        model = load_karras(model_dir, dev)
        out = karras_inference.predict(samples, model, fps, emotion, source=source, device=dev)
        cfg = model["config"]
        return dict(out, pca_fingerprint=cfg["pca_fingerprint"], iod_px=cfg.get("iod_px"),
                    mean_shape=model["pca_mean"].reshape(-1, 2).astype(np.float32),
                    face_mean=model["face_mean"].reshape(-1, 2).astype(np.float32), face_point_ids=cfg["face_points"])
    if family == "brand":
        from pipeline.models import voice_puppet
        puppet = load_puppet(model_dir)
        out = voice_puppet.predict(samples, puppet, fps, source=source)
        cfg = puppet["config"]
        return dict(out, pca_fingerprint=cfg["pca_fingerprint"], iod_px=cfg.get("iod_px"),
                    mean_shape=puppet["pca_mean"].reshape(-1, 2).astype(np.float32))
    dev = pick_device(device)
    model, config, arrays = load_model(model_dir, dev)
    features = config.get("features", "mfcc")
    x = front_ends.frame_features(samples, features, config.get("encoder"))
    front_ends.check_width(x, features, len(arrays["feature_mean"]), str(model_dir))
    if config.get("feature_norm", "corpus") == "utterance":
        x = front_ends.utterance_norm(x, features)
    x = (x - arrays["feature_mean"]) / arrays["feature_std"]
    chunk = int(chunk_seconds * 100) if chunk_seconds else None
    c100 = predict_sequence(model, x.astype(np.float32), config["delay"], dev, chunk)
    if "retrieval_keys" in arrays:             # a personalized model kept the person's own shapes (mouth_retrieval)
        r = config["retrieval"]
        c100 = mouth_retrieval.retrieve(mouth_retrieval.keys(c100, r["context"], r["step"]), arrays["retrieval_keys"],
                                        arrays["retrieval_values"], r["k"], r["smooth"], r["step"]).astype(np.float32)
    if "rest_coeffs" in arrays:
        c100 = rest_in_silence(c100, samples, arrays["rest_coeffs"])
    n = frame_count(len(samples), fps)
    t = np.arange(n) / fps
    coeffs = to_frames(c100, t).astype(np.float32)
    basis = dict(mean=arrays["pca_mean"], components=arrays["pca_components"])
    return dict(coeffs=coeffs, lip_points=reconstruct(coeffs, basis).astype(np.float32), frame_time=t,
                fps=fps, pca_fingerprint=config["pca_fingerprint"], coeffs_100hz=c100,
                iod_px=config.get("iod_px"), mean_shape=basis["mean"].reshape(-1, 2).astype(np.float32))
