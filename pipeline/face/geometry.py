"""Camera geometry shared by the stages: intrinsics, projection, rigid pose (PnP).

Conventions: camera coordinates x right, y down, z forward (OpenCV/COLMAP). A pose is
``(rvec, tvec)``: a model point X maps to R(rvec) X + tvec in camera coordinates, then to
pixels by K. Units of the model are millimetres; pixels are source-frame pixels.
"""
from __future__ import annotations

import cv2
import numpy as np


def intrinsics(width: int, height: int, focal_factor: float) -> np.ndarray:
    """(3, 3) pinhole K with focal = focal_factor × max(width, height), centred principal point."""
    f = focal_factor * max(width, height)
    return np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]], np.float64)


def rotation(rvec) -> np.ndarray:
    return cv2.Rodrigues(np.asarray(rvec, np.float64).reshape(3))[0]


def project(points: np.ndarray, rvec, tvec, K: np.ndarray) -> np.ndarray:
    """Project (..., 3) model points → (..., 2) pixels."""
    cam = points @ rotation(rvec).T + np.asarray(tvec, np.float64).reshape(3)
    uv = cam @ K.T
    return uv[..., :2] / uv[..., 2:3]


def solve_pose(model: np.ndarray, image: np.ndarray, K: np.ndarray, guess=None) -> tuple[np.ndarray, np.ndarray, float]:
    """Rigid pose of (P, 3) ``model`` points seen at (P, 2) ``image`` pixels.

    SQPnP (global) followed by Levenberg–Marquardt refinement, or LM from ``guess``.
    Returns rvec (3,), tvec (3,), RMS reprojection error (pixels).
    """
    model = np.ascontiguousarray(model, np.float64)
    image = np.ascontiguousarray(image, np.float64)
    if guess is None:
        _, rvec, tvec = cv2.solvePnP(model, image, K, None, flags=cv2.SOLVEPNP_SQPNP)
    else:
        rvec, tvec = (np.asarray(g, np.float64).reshape(3, 1).copy() for g in guess)
    rvec, tvec = cv2.solvePnPRefineLM(model, image, K, None, rvec, tvec)
    err = np.sqrt(np.mean(np.sum((project(model, rvec, tvec, K) - image) ** 2, axis=1)))
    return rvec.reshape(3), tvec.reshape(3), float(err)


def euler_degrees(rvec) -> np.ndarray:
    """(yaw, pitch, roll) in degrees of a model-to-camera rotation (y-up-free convention: yaw about y)."""
    R = rotation(rvec)
    pitch = np.degrees(np.arctan2(R[2, 1], R[2, 2]))
    yaw = np.degrees(np.arcsin(-np.clip(R[2, 0], -1, 1)))
    roll = np.degrees(np.arctan2(R[1, 0], R[0, 0]))
    return np.array([yaw, pitch, roll])


def rotation_angle_deg(R1: np.ndarray, R2: np.ndarray) -> float:
    """Angle (degrees) of the rotation taking R1 to R2."""
    c = (np.trace(R1.T @ R2) - 1) / 2
    return float(np.degrees(np.arccos(np.clip(c, -1, 1))))
