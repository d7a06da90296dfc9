"""dlib face detector (HOG) and 68-point iBUG shape predictor, loaded once per process."""
from __future__ import annotations

import functools
import importlib.util
import os

import numpy as np


def predictor_path() -> str:
    """Path of ``shape_predictor_68_face_landmarks.dat`` shipped by face-recognition-models.

    Located with ``find_spec`` so that ``pkg_resources`` is never imported.
    """
    spec = importlib.util.find_spec("face_recognition_models")
    if spec is None or spec.origin is None:
        raise ImportError("face-recognition-models is not installed (pip install face-recognition-models)")
    return os.path.join(os.path.dirname(spec.origin), "models", "shape_predictor_68_face_landmarks.dat")


@functools.lru_cache(maxsize=1)
def detector():
    import dlib
    return dlib.get_frontal_face_detector()


@functools.lru_cache(maxsize=1)
def predictor():
    import dlib
    return dlib.shape_predictor(predictor_path())


def detect_faces(gray: np.ndarray, upsample: int = 0) -> list[tuple[np.ndarray, float]]:
    """HOG detections as ``(box, score)``, box = [x0, y0, x1, y1] in pixels, best first."""
    dets, scores, _ = detector().run(np.ascontiguousarray(gray), upsample, 0.0)
    out = [(np.array([d.left(), d.top(), d.right(), d.bottom()], float), float(s)) for d, s in zip(dets, scores)]
    return sorted(out, key=lambda ds: -ds[1])


def detect_face(gray: np.ndarray, max_upsample: int = 1) -> tuple[np.ndarray, float] | None:
    """Best face box and score, trying the cheap un-upsampled pyramid first (faces ≥ 80 px),
    then up to ``max_upsample`` doublings for smaller faces. None if there is no face."""
    for up in range(max_upsample + 1):
        dets = detect_faces(gray, up)
        if dets:
            return dets[0]
    return None


def predict_landmarks(gray: np.ndarray, box) -> np.ndarray:
    """68 landmarks (68, 2) float32 pixel coordinates inside ``box`` = [x0, y0, x1, y1]."""
    import dlib
    r = dlib.rectangle(int(round(box[0])), int(round(box[1])), int(round(box[2])), int(round(box[3])))
    s = predictor()(np.ascontiguousarray(gray), r)
    return np.array([(p.x, p.y) for p in s.parts()], np.float32)


# ---------------------------------------------------------------- iBUG 68-point index sets
# "Right" and "left" are the subject's: the subject's right eye (36–41) is on the image's left.
JAW = slice(0, 17)
BROWS = slice(17, 27)
NOSE = slice(27, 36)
EYES = slice(36, 48)
RIGHT_EYE = slice(36, 42)               # subject's right eye = image left
LEFT_EYE = slice(42, 48)                # subject's left eye = image right
MOUTH = slice(48, 68)                   # outer lip 48–59, inner lip 60–67
RIGHT_EYE_OUTER, LEFT_EYE_OUTER = 36, 45
OUTER_LIP = slice(48, 60)
INNER_LIP = slice(60, 68)

# The paper's 18 lip fiducials (paper 000 §3.1): outer lip 48–59 and inner lip 61–63, 65–67 (the
# inner corners 60 and 64 duplicate the outer corners' motion and are left out).
LIP_POINTS = list(range(48, 60)) + [61, 62, 63, 65, 66, 67]
INNER_TOP, INNER_BOTTOM = 62, 66        # inner-lip midpoints: their distance is the mouth opening

# The canonical face is scaled so that the outer eye corners are IOD_MM apart (a typical adult
# outer-canthal width); the frontal texture window is given in these millimetres.
IOD_MM = 90.0


def interocular(lm: np.ndarray) -> np.ndarray:
    """Outer-eye-corner distance of (..., 68, 2) landmarks → (...), same units as ``lm``."""
    return np.linalg.norm(lm[..., LEFT_EYE_OUTER, :] - lm[..., RIGHT_EYE_OUTER, :], axis=-1)
