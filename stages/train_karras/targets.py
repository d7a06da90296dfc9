"""Training targets for the Karras network (paper 001 §3, issue: "Karras predicts the whole face").

Per video frame: the frontalized landmarks of the lower face that the frontal texture window
covers — jaw line 2–14, nose 27–35, outer and inner lips 48–67 (42 points, canonical texture px,
pose removed by the frontalize stage) → an 84-D vector, so the jaw moves with the lips. Frames
without a valid pose or landmarks are left out. The model's shared predict output (the 18 lip
points of the mouth PCA) is read back from these points (``lip_index``).
"""
from __future__ import annotations

import numpy as np

from pipeline.errors import LipsynthError
from pipeline.face.dlib_face import LIP_POINTS
from pipeline.io.store import open_group

FACE_POINTS = list(range(2, 15)) + list(range(27, 36)) + list(range(48, 68))
LIP_INDEX = [FACE_POINTS.index(p) for p in LIP_POINTS]


def load_targets(ingest_path: str, landmarks_path: str, frontalize_path: str) -> list[dict]:
    """Per video (not excluded): name, split, fps, frame_time (T,) s, targets (T, 84) px, ok (T,),
    samples (S,) float32 16 kHz mono (the audio starts at the first frame)."""
    src, lmg, fr = (open_group(p) for p in (ingest_path, landmarks_path, frontalize_path))
    layout = fr["frontal_landmarks"].shape[1:]
    if tuple(layout) != (68, 2):
        raise LipsynthError(f"{frontalize_path}: frontal landmarks have layout {tuple(layout)}, the Karras targets "
                            "need dlib's 68 points (jaw 2–14, nose 27–35, lips 48–67)")
    ok_all = np.asarray(fr["pose_valid"][...]) & np.asarray(lmg["valid"][...])
    ftime = np.asarray(src["frame_time"][...])
    out = []
    for v in fr.attrs["videos"]:
        if v.get("excluded") or not v["n_frames"]:
            continue
        f0, n = v["first_frame"], v["n_frames"]
        pts = np.asarray(fr["frontal_landmarks"][f0:f0 + n], np.float32)[:, FACE_POINTS].reshape(n, -1)
        samples = np.asarray(src["audio"][v["first_sample"]:v["first_sample"] + v["n_samples"]], np.float32) / 32768.0
        out.append(dict(name=v["name"], split=v["split"], fps=float(v["fps"]), frame_time=ftime[f0:f0 + n],
                        targets=pts, ok=ok_all[f0:f0 + n], samples=samples))
    return out


def training_pairs(videos: list[dict]) -> np.ndarray:
    """(n, 2) int: (video index, frame index) of every frame whose successor in the same video is
    also valid — the temporal pairs of §4.3 start there."""
    rows = []
    for i, v in enumerate(videos):
        ok = v["ok"]
        start = np.flatnonzero(ok[:-1] & ok[1:])
        rows.append(np.column_stack([np.full(len(start), i), start]))
    return np.concatenate(rows) if rows else np.zeros((0, 2), int)
