"""Inference with a trained Karras et al. network (paper 001 §5): face points for any audio.

For each output frame k at t_k = k / fps the network runs twice, on the 520 ms autocorrelation
windows centred at t_k − 2 ms and t_k + 2 ms (§5: "evaluated twice … 4 ms apart in time, and the
predictions are averaged"), with one constant emotion vector (§5.1): a mined candidate by index,
or an interpolation between two candidates.

Output of ``predict`` (dict): face_points (T, P, 2) canonical texture px (the lower-face points the
model was trained on), coeffs (T, k) the lip points projected on the model's mouth PCA, lip_points
(T, 18, 2) their PCA reconstruction, frame_time (T,) s, fps, emotion (E,).
"""
from __future__ import annotations

import numpy as np

from pipeline.errors import ParameterError
from pipeline.audio.speech_autocorrelation import padded_track, windows

ENSEMBLE_OFFSETS_S = (-0.002, 0.002)        # two inferences 4 ms apart, centred on the frame time


def parse_emotion(spec, candidates: np.ndarray, default: int = 0) -> np.ndarray:
    """An emotion vector (E,) from ``spec``: None (the default candidate), ``K`` (candidate index) or
    ``K1:K2:t`` (linear interpolation (1 − t)·c[K1] + t·c[K2], t in [0, 1]).

    Raises ParameterError naming the spec and the valid range.
    """
    n = len(candidates)
    if spec is None or spec == "":
        return np.asarray(candidates[default], np.float32)
    text = str(spec)
    parts = text.split(":")

    def index(p: str) -> int:
        try:
            k = int(p)
        except ValueError:
            raise ParameterError(f"--emotion {text}: {p!r} is not a candidate index (0…{n - 1})") from None
        if not 0 <= k < n:
            raise ParameterError(f"--emotion {text}: candidate {k} does not exist (the model has {n}: 0…{n - 1}; "
                                 "list them with `lipsynth emotions`)")
        return k

    if len(parts) == 1:
        return np.asarray(candidates[index(parts[0])], np.float32)
    if len(parts) != 3:
        raise ParameterError(f"--emotion {text}: expected K or K1:K2:t (e.g. 0:3:0.5)")
    a, b = index(parts[0]), index(parts[1])
    try:
        t = float(parts[2])
    except ValueError:
        raise ParameterError(f"--emotion {text}: t = {parts[2]!r} is not a number in [0, 1]") from None
    if not 0.0 <= t <= 1.0:
        raise ParameterError(f"--emotion {text}: t = {t} is outside [0, 1]")
    return ((1 - t) * candidates[a] + t * candidates[b]).astype(np.float32)


def face_points_at(net, padded: np.ndarray, times: np.ndarray, emotion: np.ndarray, batch: int = 256,
                   device: str = "cpu", ensemble: bool = True) -> np.ndarray:
    """Network output (T, D) at ``times`` (s) of a ``padded_track`` for one emotion vector (E,):
    the mean of the two 4 ms-apart inferences (or one inference at t when ``ensemble`` is False)."""
    import torch
    offsets = ENSEMBLE_OFFSETS_S if ensemble else (0.0,)
    e = torch.as_tensor(np.asarray(emotion, np.float32), device=device)
    out = []
    net.eval()
    with torch.no_grad():
        for i in range(0, len(times), batch):
            t = np.asarray(times[i:i + batch], np.float64)
            acc = 0.0
            for d in offsets:
                x = torch.as_tensor(windows(padded, t + d)[:, None], device=device)
                acc = acc + net(x, e.expand(len(t), -1)).cpu().numpy()
            out.append(acc / len(offsets))
    return np.concatenate(out) if out else np.zeros((0, net.out.out_features), np.float32)


def predict(samples: np.ndarray, model: dict, fps: float, emotion=None, source: str = "audio",
            device: str = "cpu", ensemble: bool = True) -> dict:
    """Face points, mouth PCA coefficients and lip points at ``fps`` for 16 kHz mono ``samples``.

    ``model`` is ``pipeline.models.model_folder.load_karras``'s dict; ``emotion`` as in ``parse_emotion``.
    """
    from pipeline.models.mouth_pca import reconstruct
    cfg = model["config"]
    e = parse_emotion(emotion, model["emotion_candidates"], cfg.get("default_emotion", 0))
    padded = padded_track(samples, source)
    n = int(np.floor(len(samples) / 16000 * fps + 0.5))
    t = np.arange(n) / fps
    y = face_points_at(model["net"].to(device), padded, t, e, device=device, ensemble=ensemble)
    face = y.reshape(n, -1, 2).astype(np.float32)
    lips = face[:, model["lip_index"]].reshape(n, -1)
    basis = dict(mean=model["pca_mean"], components=model["pca_components"])
    coeffs = ((lips - basis["mean"]) @ basis["components"].T).astype(np.float32)
    return dict(face_points=face, coeffs=coeffs, lip_points=reconstruct(coeffs, basis).astype(np.float32),
                frame_time=t, fps=fps, emotion=e)
