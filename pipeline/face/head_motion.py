"""Blinks and head motion for the 3D head, taken from the person's own footage.

The frontalize store keeps, per frame of the person's videos, the tracked head pose (rvec, model to
camera) and the frontal landmarks. ``footage_tracks`` replays them at the output frame rate, the videos
one after another (ping-pong when the audio is longer than the footage):

- **blinks**: the eyes' closure per frame from the eye landmarks (eye aspect ratio, Soukupová & Čech
  2016: (|37−41| + |38−40|) / 2|36−39|, both eyes) against the footage's open-eye level (its median);
  so the blinks come when, as often and as long as the person's own. ``blink_offsets`` turns a closure
  into skin motion: the upper lid slides down over the eye (the eye's skin rows compress onto the lower
  lid, the lid fold above stretches), tapered to nothing at the eye corners;
- **head motion**: the tracked rotation relative to the footage's median pose, lightly smoothed (tracking
  jitter), applied rigidly to the whole head about a neck pivot (``pivot``).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.errors import LipsynthError

EYES = ((36, 37, 38, 39, 41, 40), (42, 43, 44, 45, 47, 46))   # corner, upper, upper, corner, lower, lower
LID_FOLD_MM = 6.0            #: skin above the upper lid that stretches as it closes (mm)
CLOSED_AT = 0.55             #: eye aspect ratio / its open level at which the eye counts as fully closed


@dataclass
class FootageTracks:
    """Per output frame: closure (T,) in [0, 1] (1: eyes shut) and rotation (T, 3, 3) relative to rest."""

    closure: np.ndarray
    rotation: np.ndarray


def eye_aspect(landmarks: np.ndarray) -> np.ndarray:
    """(F, 68, 2) landmarks → (F,) eye aspect ratio, mean of both eyes (unitless; ~0.3 open, ~0.1 shut)."""
    out = []
    for c0, u1, u2, c1, l1, l2 in EYES:
        lm = landmarks
        h = np.linalg.norm(lm[:, u1] - lm[:, l1], axis=-1) + np.linalg.norm(lm[:, u2] - lm[:, l2], axis=-1)
        out.append(h / np.maximum(2 * np.linalg.norm(lm[:, c0] - lm[:, c1], axis=-1), 1e-9))
    return np.mean(out, axis=0)


def closure_of(ear: np.ndarray) -> np.ndarray:
    """(F,) eye aspect ratio → (F,) closure in [0, 1]: 0 at the footage's median (open) level, 1 at
    ``CLOSED_AT`` of it; half-closures below a fifth are tracking noise and read as 0."""
    open_level = np.median(ear)
    c = np.clip((open_level - ear) / max(open_level * (1 - CLOSED_AT), 1e-9), 0.0, 1.0)
    return np.where(c < 0.2, 0.0, c)


def rotation_matrices(rvec: np.ndarray) -> np.ndarray:
    """(F, 3) Rodrigues vectors (rad) → (F, 3, 3) rotation matrices."""
    from scipy.spatial.transform import Rotation
    return Rotation.from_rotvec(np.asarray(rvec, np.float64)).as_matrix()


def _runs(store) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """The store's videos as (ear (n,), rvec (n, 3), fps), invalid frames filled from their neighbours."""
    import zarr
    if not Path(store).exists():
        raise LipsynthError(f"{store}: no footage store for blinks and head motion (the frontalize stage writes it; "
                            "without it: render_mesh.blinks and .head_motion false, or no --footage)")
    g = zarr.open_group(str(store), mode="r")
    pose, valid, lm = (np.asarray(g[k][...]) for k in ("pose", "pose_valid", "frontal_landmarks"))
    out = []
    for v in g.attrs["videos"]:
        if v.get("excluded"):
            continue
        sl = slice(v["first_frame"], v["first_frame"] + v["n_frames"])
        ok = valid[sl]
        if ok.mean() < 0.5:
            continue
        out.append((eye_aspect(_fill(lm[sl].reshape(len(ok), -1), ok).reshape(-1, 68, 2)), _fill(pose[sl, :3], ok),
                    float(v.get("fps", 25.0))))
    if not out:
        raise LipsynthError(f"{store}: no video with a tracked pose in at least half of its frames")
    return out


def _fill(a: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """(n, C) values with the rows where ``ok`` is False interpolated from the valid ones (per column)."""
    t = np.arange(len(ok))
    return np.stack([np.interp(t, t[ok], a[ok, j]) for j in range(a.shape[1])], 1)


def footage_tracks(store, n_frames: int, fps: float, smooth_frames: float = 1.5) -> FootageTracks:
    """The footage's blinks and head rotations for ``n_frames`` output frames at ``fps``.

    Parameters
    ----------
    store : str or Path
        The frontalize store (``store/frontalize.zarr``: pose, pose_valid, frontal_landmarks, videos).
    n_frames : int
        Output frames T.
    fps : float
        Output frame rate (frames/s); the footage is resampled to it.
    smooth_frames : float
        Gaussian smoothing of the rotation (footage frames; tracking jitter).

    Returns
    -------
    FootageTracks
        closure (T,), rotation (T, 3, 3) relative to the footage's median pose.
    """
    from scipy.ndimage import gaussian_filter1d
    closure, rvec = [], []
    for ear, rv, src_fps in _runs(store):
        t_out = np.arange(0, len(ear) / src_fps, 1 / fps)
        idx = np.minimum((t_out * src_fps).round().astype(int), len(ear) - 1)
        closure.append(closure_of(ear)[idx])
        rvec.append(gaussian_filter1d(rv, smooth_frames, axis=0, mode="nearest")[idx])
    closure, rvec = np.concatenate(closure), np.concatenate(rvec)
    ref = rotation_matrices(np.median(rvec, axis=0)[None])[0]
    period = np.arange(n_frames) % max(2 * len(closure) - 2, 1)
    pick = np.where(period < len(closure), period, 2 * len(closure) - 2 - period)       # ping-pong
    rel = rotation_matrices(rvec[pick]) @ ref.T
    return FootageTracks(closure[pick], rel)


def blink_offsets(vertices_xy: np.ndarray, landmarks_mm: np.ndarray) -> np.ndarray:
    """(N,) downward shift (mm, +y) of each skin vertex for fully shut eyes (closure 1); scale by the closure.

    Parameters
    ----------
    vertices_xy : ndarray
        (N, 2) rest skin vertices (mm).
    landmarks_mm : ndarray
        (68, 2) the rest landmarks (mm; eyes open).
    """
    dy = np.zeros(len(vertices_xy))
    x, y = vertices_xy[:, 0], vertices_xy[:, 1]
    for c0, u1, u2, c1, l1, l2 in EYES:
        lm = landmarks_mm
        xs = lm[[c0, u1, u2, c1], 0]
        inside = (x > xs[0]) & (x < xs[3])
        up = np.interp(x, xs, lm[[c0, u1, u2, c1], 1])
        lo = np.interp(x, lm[[c0, l1, l2, c1], 0], lm[[c0, l1, l2, c1], 1])
        w = np.where(inside, np.sin(np.pi * np.clip((x - xs[0]) / (xs[3] - xs[0]), 0, 1)), 0.0)
        h = np.maximum(lo - up, 0)
        fold = inside & (y >= up - LID_FOLD_MM) & (y < up)
        eye = inside & (y >= up) & (y <= lo)
        dy[fold] = (w * h * (y - (up - LID_FOLD_MM)) / LID_FOLD_MM)[fold]
        dy[eye] = (w * (lo - y))[eye]
    return dy


def pivot(landmarks_mm: np.ndarray, surface_z: float) -> np.ndarray:
    """(3,) mm: the point the head turns about — under the ears, ~95 mm behind the nose tip, at mouth height."""
    return np.array([landmarks_mm[[0, 16], 0].mean(), landmarks_mm[[48, 54], 1].mean(), surface_z + 95.0])
