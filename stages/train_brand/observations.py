"""Facial and vocal observations for Voice Puppetry (paper 002 §4.1, §4.3), per video, at one
model frame rate (``brand.rate``; the paper's 29.97 Hz NTSC, 25 Hz for GRID).

Face: the frontalized landmarks the paper's tracker would follow — the 18 lip points of the
mouth PCA (``pipeline.face.dlib_face.LIP_POINTS``), the jaw line 3–13 and the brows 17–26: P = 39 points,
canonical texture pixels (pose removed by the frontalize stage). Frames are resampled to the
model rate by linear interpolation of the frame times (identity when fps = rate); a model frame
is valid when both video frames around it have a valid pose and landmarks.

Voice: ``pipeline.audio.vocal_features`` of the video's 16 kHz audio track (ingest store), on the
same model frames (the audio starts at the first video frame).
"""
from __future__ import annotations

import numpy as np
from tqdm import tqdm

from pipeline.face.dlib_face import LIP_POINTS
from pipeline.io.store import open_group
from pipeline.audio.vocal_features import vocal_features

FACE_POINTS = list(LIP_POINTS) + list(range(3, 14)) + list(range(17, 27))
LIP_INDEX = list(range(len(LIP_POINTS)))          # the lips are the first 18 of FACE_POINTS


def resample(values: np.ndarray, ok: np.ndarray, frame_time: np.ndarray, n_out: int, rate: float):
    """Linear interpolation of (T, ...) per-frame values at t = k / rate, k < n_out → values, valid.

    Times past the last frame hold it; valid where both bracketing frames are valid.
    """
    t = np.arange(n_out) / rate
    hi = np.clip(np.searchsorted(frame_time, t, side="right"), 1, len(frame_time) - 1)
    lo = hi - 1
    w = np.clip((t - frame_time[lo]) / np.maximum(frame_time[hi] - frame_time[lo], 1e-9), 0.0, 1.0)
    w = w.reshape(-1, *([1] * (values.ndim - 1)))
    filled = np.where(ok.reshape(-1, *([1] * (values.ndim - 1))), values, 0.0)
    out = (1 - w) * filled[lo] + w * filled[hi]
    wf = w.reshape(-1)
    return out, (ok[lo] | (wf == 1.0)) & (ok[hi] | (wf == 0.0))


def load_videos(ingest_path: str, landmarks_path: str, frontalize_path: str, pca_path: str,
                rate: float, features: str, encoder: dict | None = None) -> tuple[list[dict], dict]:
    """Per video (not excluded): name, split, fps, points (n, P, 2) and ok (n,) at the model rate,
    voice (n, A), and the store's frame-rate truth for evaluation: frame_coeffs (T, k), frame_ok (T,),
    samples (S,) float32. Also the mouth PCA basis and attributes of the pca store."""
    src, lmg, fr, pca = (open_group(p) for p in (ingest_path, landmarks_path, frontalize_path, pca_path))
    flm = fr["frontal_landmarks"]
    ok_all = np.asarray(fr["pose_valid"][...]) & np.asarray(lmg["valid"][...])
    ftime = np.asarray(src["frame_time"][...])
    coeffs, cvalid = np.asarray(pca["coeffs"][...], np.float32), np.asarray(pca["valid"][...])
    audio = src["audio"]
    out = []
    videos = [v for v in pca.attrs["videos"] if not v.get("excluded") and v["n_frames"]]
    for v in tqdm(videos, desc="face + voice", unit="video", leave=False):
        f0, n = v["first_frame"], v["n_frames"]
        pts = np.asarray(flm[f0:f0 + n], np.float64)[:, FACE_POINTS]
        samples = np.asarray(audio[v["first_sample"]:v["first_sample"] + v["n_samples"]], np.float32) / 32768.0
        n_model = int(np.floor(min(v["n_samples"] / 16000.0, ftime[f0 + n - 1] + 0.5 / v["fps"]) * rate + 0.5))
        points, ok = resample(pts, ok_all[f0:f0 + n], ftime[f0:f0 + n], n_model, rate)
        out.append(dict(name=v["name"], split=v["split"], fps=float(v["fps"]), points=points, ok=ok,
                        voice=vocal_features(samples, features, rate, n_model, v["name"], encoder),
                        frame_coeffs=coeffs[f0:f0 + n], frame_ok=cvalid[f0:f0 + n], samples=samples))
    basis = {k: np.asarray(pca[k][...], np.float64) for k in ("mean", "components")}
    return out, dict(basis=basis, attrs=dict(pca.attrs))


def face_pca(train: list[dict], dims: int) -> dict:
    """PCA of the training face shapes (valid model frames): mean (2P,), components (dims, 2P),
    explained variance ratio of every component kept."""
    x = np.concatenate([v["points"][v["ok"]].reshape(int(v["ok"].sum()), -1) for v in train])
    mean = x.mean(0)
    _, s, vt = np.linalg.svd(x - mean, full_matrices=False)
    var = s ** 2
    return dict(mean=mean, components=vt[:dims], explained=var[:dims] / var.sum())


def observations(v: dict, pca: dict, rate: float) -> tuple[np.ndarray, np.ndarray]:
    """Position (D PCA coordinates) and velocity (per second) of one video: (n, 2D) and the frames
    where both are defined (the frame and the one before valid)."""
    y = (v["points"].reshape(len(v["points"]), -1) - pca["mean"]) @ pca["components"].T
    vel = np.zeros_like(y)
    vel[1:] = (y[1:] - y[:-1]) * rate
    ok = v["ok"].copy()
    ok[1:] &= v["ok"][:-1]
    ok[0] = False
    return np.concatenate([y, vel], 1), ok


def segments(ok: np.ndarray, min_length: int = 3) -> list[slice]:
    """Runs of consecutive valid frames at least ``min_length`` long."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], ok.astype(np.int8), [0]])))
    return [slice(a, b) for a, b in zip(edges[::2], edges[1::2]) if b - a >= min_length]
