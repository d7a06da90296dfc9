"""Per-frame self-check of the composite: is the mouth in the output where, and what, it should be?

dlib's 68-point predictor re-reads every output frame inside the target's face box; its 20 mouth
points (48–67) are compared with the synthesized mouth — the candidates' weighted landmarks in
the texture, taken through the frame's pose onto the frame. A render-back that went wrong (a
smeared blob, a mouth in the wrong place, a lipless ring) moves dlib's points far from them; an
over-sharpened or scribbled mouth multiplies the mouth box's Laplacian energy (compared with the
sharpest real mouths of the target: the 90th percentile over sampled target frames). Frames that fail
fall back to the target frame, cross-faded over ``fade`` frames on each side
(``fallback_weights``).
"""
from __future__ import annotations

import cv2
import numpy as np

from pipeline.face.canonical import Surface, TextureWindow
from pipeline.face.dlib_face import MOUTH, interocular, predict_landmarks
from pipeline.face.geometry import project

CHIN = np.arange(6, 11)                     # the jawline's lowest five points: they follow the mouth
NOSE_AND_CHIN = np.r_[27:36, CHIN]
LOWER_LIP = np.array([56, 57, 58, 65, 66, 67])


def to_frame(uv: np.ndarray, surface: Surface, window: TextureWindow, rvec, tvec, K: np.ndarray) -> np.ndarray:
    """Texture-pixel points (K, 2) on the extended face surface → frame pixels (K, 2) at a pose."""
    xy = window.to_mm(np.asarray(uv, np.float64))
    return project(np.column_stack([xy, surface.z(xy[:, 0], xy[:, 1])]), rvec, tvec, K)


def face_box(lm: np.ndarray) -> np.ndarray:
    """A dlib-like face box [x0, y0, x1, y1] from 68 frame landmarks (jawline and brows)."""
    pts = lm[:27]
    return np.r_[pts.min(0), pts.max(0)]


def laplacian_energy(gray: np.ndarray, box) -> float:
    """Mean squared Laplacian of ``gray`` (H, W) uint8 inside ``box`` = [x0, y0, x1, y1]."""
    h, w = gray.shape
    x0, y0 = max(int(box[0]), 0), max(int(box[1]), 0)
    x1, y1 = min(int(np.ceil(box[2])), w), min(int(np.ceil(box[3])), h)
    if x1 - x0 < 3 or y1 - y0 < 3:
        return float("nan")
    lap = cv2.Laplacian(gray[y0:y1, x0:x1].astype(np.float32), cv2.CV_32F)
    return float(np.mean(lap ** 2))


def mouth_box(lm: np.ndarray) -> np.ndarray:
    """[x0, y0, x1, y1] around the mouth (48–67) of 68 frame landmarks, 30 % margin each side."""
    m = lm[MOUTH]
    pad = 0.3 * (m.max(0) - m.min(0))
    return np.r_[m.min(0) - pad, m.max(0) + pad]


def mouth_energy(rgb: np.ndarray, lm: np.ndarray) -> float:
    """Laplacian energy of the mouth box of a frame (H, W, 3) RGB with 68 landmarks (68, 2) px."""
    return laplacian_energy(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), mouth_box(lm))


def check_frame(result: np.ndarray, expected: np.ndarray, reference_energy: float, target: np.ndarray | None = None,
                target_expected: np.ndarray | None = None) -> dict:
    """Measure one composited frame.

    result : (H, W, 3) uint8 RGB — the output frame.
    expected : (68, 2) frame px — where the output's landmarks should be: the target's own
        landmarks with the mouth (48–67) replaced by the synthesized one.
    reference_energy : the mouth box's Laplacian energy in the sharpest real frames of the
        target (an open mouth with teeth has more edges than a closed one, so the frame under
        the output is no reference).
    target, target_expected : the untouched target frame the output was composited into (H, W, 3) and
        where its own landmarks are by the same geometry (``expected`` with the target's own mouth, (68, 2)
        frame px). Given, the check is differential: dlib re-reads both frames inside one box, and what it
        sees change from the target to the output is compared with what was meant to change. dlib's points
        depend on the box it is handed; on a face the frame cuts (forehead or chin at the edge) or turned
        three-quarters, the box made from the landmarks is not the detector's, and dlib reads even the
        untouched frame 0.1–0.3 IOD away from its tracked points (bench/tight_crops.py's failing clips:
        62–91 % of untouched frames would fail). Its bias is the same on both frames and cancels.

    Returns dict(error: mean distance of dlib's mouth points on ``result`` to ``expected``'s, in
    inter-ocular distances; face_error: the same for the nose (27–35) and chin (6–10), the rest of
    the rendered lower face; sharpness: the mouth box's Laplacian energy in ``result`` over
    ``reference_energy``).
    """
    # only the face box, grown by half its size on each side (the predictor's samples stay well
    # inside), is converted to grey and searched: the same points as on the whole frame
    box = face_box(expected if target_expected is None else target_expected)
    reach = 0.5 * (box[2:] - box[:2])
    h, w = result.shape[:2]
    x0, y0 = np.maximum(np.floor(box[:2] - reach).astype(int), 0)
    x1, y1 = np.minimum(np.ceil(box[2:] + reach).astype(int), [w, h])
    origin = np.array([x0, y0], np.float64)
    inner = np.r_[box[:2] - origin, box[2:] - origin]

    def read(rgb):
        grey = cv2.cvtColor(np.ascontiguousarray(rgb[y0:y1, x0:x1]), cv2.COLOR_RGB2GRAY)
        return grey, predict_landmarks(grey, inner) + origin

    gray, found = read(result)
    if target is not None and target_expected is not None:
        found = found - read(target)[1] + target_expected       # dlib's change, put on the target's points
    iod = float(interocular(expected))
    err = float(np.linalg.norm(found[MOUTH] - expected[MOUTH], axis=1).mean() / max(iod, 1e-6))
    face_err = float(np.linalg.norm(found[NOSE_AND_CHIN] - expected[NOSE_AND_CHIN], axis=1).mean() / max(iod, 1e-6))
    mouth = mouth_box(expected)
    sharp = laplacian_energy(gray, np.r_[mouth[:2] - origin, mouth[2:] - origin])
    return dict(error=err, face_error=face_err, sharpness=sharp / max(reference_energy, 1e-6))


def passes(check: dict, max_error: float, max_sharpness: float, max_face_error: float = np.inf) -> bool:
    return bool(check["error"] <= max_error and check["sharpness"] <= max_sharpness
                and check.get("face_error", 0.0) <= max_face_error)


def fallback_weights(ok: np.ndarray, fade: int) -> np.ndarray:
    """Weight (N,) of the composited frame per output frame: 0 at a failed frame, rising linearly
    to 1 over ``fade`` frames on either side (the rest is the target frame)."""
    ok = np.asarray(ok, bool)
    n = len(ok)
    bad = np.flatnonzero(~ok)
    if not len(bad):
        return np.ones(n)
    dist = np.abs(np.arange(n)[:, None] - bad[None, :]).min(1)
    return np.clip(dist / (fade + 1), 0.0, 1.0)
