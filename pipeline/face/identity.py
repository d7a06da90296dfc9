"""Who is in a video: dlib's face-recognition ResNet descriptors (128-D) of sampled frames.

A model folder records its speaker's descriptor (``pipeline/models/speaker_bank``); ``lipsynth speak``
computes the target's and compares: two faces of one person are usually less than 0.6 apart
(dlib's threshold on LFW; Euclidean distance of unit-scale descriptors), two people more.

Frames come from the ingest store (I420 face-region crops) with the landmarks stage's 68 points,
which are in frame pixels: ``crop`` = (x0, y0, s) maps crop pixel q to frame pixel (x0, y0) + s·q.
"""
from __future__ import annotations

import functools
import os

import numpy as np


@functools.lru_cache(maxsize=1)
def recogniser():
    import dlib
    from pipeline.face.dlib_face import predictor_path
    return dlib.face_recognition_model_v1(os.path.join(os.path.dirname(predictor_path()),
                                                       "dlib_face_recognition_resnet_model_v1.dat"))


def face_descriptor(rgb: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
    """128-D descriptor (float32) of the face whose 68 landmarks (68, 2) px are given in ``rgb`` (H, W, 3)."""
    import dlib
    pts = [dlib.point(int(round(x)), int(round(y))) for x, y in landmarks]
    x0, y0 = np.floor(landmarks.min(0)).astype(int)
    x1, y1 = np.ceil(landmarks.max(0)).astype(int)
    shape = dlib.full_object_detection(dlib.rectangle(int(x0), int(y0), int(x1), int(y1)), pts)
    return np.asarray(recogniser().compute_face_descriptor(np.ascontiguousarray(rgb), shape), np.float32)


def crop_landmarks(landmarks: np.ndarray, crop) -> np.ndarray:
    """Frame-pixel landmarks (..., 68, 2) → pixels of the ingest crop ``crop`` = (x0, y0, s)."""
    x0, y0, s = crop
    return (np.asarray(landmarks, np.float64) - [x0, y0]) / s


def sampled_frames(valid: np.ndarray, n_frames: int = 20) -> np.ndarray:
    """Indices of up to ``n_frames`` evenly spaced valid frames (valid : (N,) bool)."""
    idx = np.flatnonzero(valid)
    if not len(idx):
        return idx
    return idx[np.unique(np.linspace(0, len(idx) - 1, min(n_frames, len(idx))).round().astype(int))]


def video_descriptor(crops, landmarks: np.ndarray, valid: np.ndarray, crop, n_frames: int = 20) -> np.ndarray | None:
    """Per-frame descriptors (F, 128) of up to ``n_frames`` evenly spaced valid frames of one video.

    crops : indexable (N, 3S/2, S) I420 crops; landmarks : (N, 68, 2) frame px; valid : (N,) bool.
    None when no frame is valid.
    """
    idx = sampled_frames(valid, n_frames)
    return frame_descriptors(crops, idx, np.asarray(landmarks)[idx], crop) if len(idx) else None


def frame_descriptors(crops, frames, landmarks: np.ndarray, crop) -> np.ndarray:
    """Descriptors (F, 128) of ``frames`` (F,) indices into crops (N, 3S/2, S) I420, with their
    landmarks (F, 68, 2) frame px."""
    from pipeline.io.store import i420_to_rgb
    if not len(frames):
        return np.zeros((0, 128), np.float32)
    return np.stack([face_descriptor(i420_to_rgb(np.asarray(crops[i])), crop_landmarks(lm, crop))
                     for i, lm in zip(frames, landmarks)])


def stored_descriptors(job: dict) -> np.ndarray:
    """A worker task: ``frame_descriptors`` of ``job["frames"]`` read from the ingest store ``job["ingest"]``
    (crops) with ``job["landmarks"]`` (F, 68, 2) frame px and ``job["crop"]``."""
    import zarr
    crops = zarr.open_group(job["ingest"], mode="r")["crops"]
    return frame_descriptors(crops, job["frames"], np.asarray(job["landmarks"]), job["crop"])


def identity(descriptors: np.ndarray) -> np.ndarray:
    """One descriptor for many frames of a person (F, 128) → (128,): the element-wise median."""
    return np.median(np.asarray(descriptors, np.float32), axis=0)


def distance(a: np.ndarray, b: np.ndarray) -> float:
    """Euclidean distance of two descriptors (same person ≲ 0.6)."""
    return float(np.linalg.norm(np.asarray(a, np.float64) - np.asarray(b, np.float64)))
