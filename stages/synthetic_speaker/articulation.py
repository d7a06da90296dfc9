"""Articulation: co-articulated mouth, blinks, head pose, and the landmarks of one frame.

The mouth shows the articulation of the sound heard ``MOUTH_LEAD_S`` later.
Mouth parameters drive blend shapes on the rest face; blinks close the lids;
the head pose rotates the landmarks (with depth) about the face centre.
"""
from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter1d

from stages.synthetic_speaker import face_template, language

MOUTH_LEAD_S = 0.08
"""The mouth shows the articulation of the sound heard this many seconds later."""

MOUTH_NAMES = ("open", "width", "round")
"""Mouth parameters: opening 0..1, spreading -1..1 (negative = narrow), rounding 0..1."""

POSE_NAMES = ("yaw_deg", "pitch_deg", "roll_deg", "tx_px", "ty_px", "scale")

COARTICULATION_SIGMA_S = 0.035
"""Gaussian time constant (s) of the dominance-weighted mouth smoothing."""

# Landmark index groups of the dlib/iBUG 68-point convention.
OUTER_LIP = np.arange(48, 60)
INNER_LIP = np.arange(60, 68)
# (upper lid, lower lid) landmark pairs that meet when the eye closes
EYELID_PAIRS = ((37, 41), (38, 40), (43, 47), (44, 46))

# Mouth blend-shape bases: landmark displacement per unit parameter, in units of
# the face-box width. Each row: landmark index, dx, dy.
OPEN_BASIS = (
    (4, 0.0, 0.01), (5, 0.0, 0.03), (6, 0.0, 0.07), (7, 0.0, 0.11), (8, 0.0, 0.14),
    (9, 0.0, 0.11), (10, 0.0, 0.07), (11, 0.0, 0.03), (12, 0.0, 0.01),
    (48, 0.025, 0.05), (54, -0.025, 0.05), (60, 0.025, 0.05), (64, -0.025, 0.05),
    (49, 0.0, -0.004), (50, 0.0, -0.006), (51, 0.0, -0.006), (52, 0.0, -0.006), (53, 0.0, -0.004),
    (61, 0.0, -0.012), (62, 0.0, -0.012), (63, 0.0, -0.012),
    (55, 0.0, 0.07), (56, 0.0, 0.125), (57, 0.0, 0.14), (58, 0.0, 0.125), (59, 0.0, 0.07),
    (65, 0.0, 0.13), (66, 0.0, 0.15), (67, 0.0, 0.13),
)
WIDTH_BASIS = (
    (48, -0.05, 0.0), (60, -0.05, 0.0), (54, 0.05, 0.0), (64, 0.05, 0.0),
    (49, -0.025, 0.0), (59, -0.025, 0.0), (61, -0.02, 0.0), (67, -0.02, 0.0),
    (53, 0.025, 0.0), (55, 0.025, 0.0), (63, 0.02, 0.0), (65, 0.02, 0.0),
    (50, -0.01, 0.004), (52, 0.01, 0.004), (51, 0.0, 0.004),
    (58, -0.01, -0.004), (56, 0.01, -0.004), (57, 0.0, -0.004),
)
ROUND_BASIS = (
    (48, 0.07, 0.03), (60, 0.075, 0.03), (54, -0.07, 0.03), (64, -0.075, 0.03),
    (49, 0.045, -0.01), (59, 0.045, 0.01), (61, 0.045, -0.008), (67, 0.045, 0.008),
    (53, -0.045, -0.01), (55, -0.045, 0.01), (63, -0.045, -0.008), (65, -0.045, 0.008),
    (50, 0.012, -0.014), (51, 0.0, -0.015), (52, -0.012, -0.014),
    (58, 0.012, 0.014), (57, 0.0, 0.015), (56, -0.012, 0.014),
    (62, 0.0, -0.01), (66, 0.0, 0.006),
)
LIP_PROTRUSION = 0.08
"""Forward lip movement (face widths) at full rounding, used by the head rotation."""


# ----------------------------------------------------------------------------
# Over time: mouth, blinks, head pose
# ----------------------------------------------------------------------------

def mouth_targets(phones: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Per-phone mouth targets (with small token-to-token variation) and dominances.

    Returns
    -------
    targets : ndarray, (P, 3)
        (open, width, round) per phone.
    dominance : ndarray, (P,)
    """
    targets = np.array([language.PHONES[label].mouth for label in phones["label"]], dtype=np.float64)
    dominance = np.array([language.PHONES[label].dominance for label in phones["label"]])
    speech = phones["label"] != "sil"
    targets[speech] += rng.normal(0.0, 0.05, size=(speech.sum(), 3))
    return targets, dominance


def mouth_trajectory(phones: np.ndarray, targets: np.ndarray, dominance: np.ndarray,
                     frame_times: np.ndarray, lead_s: float = MOUTH_LEAD_S) -> np.ndarray:
    """Co-articulated mouth parameters at the given video times.

    The step sequence of phone targets is smoothed with a dominance-weighted
    Gaussian (weighted mean of nearby targets) and read ``lead_s`` ahead, so the
    mouth anticipates the sound.

    Parameters
    ----------
    phones : structured ndarray, (P,)
    targets : ndarray, (P, 3)
    dominance : ndarray, (P,)
    frame_times : ndarray, (T,)
        Video times (s).
    lead_s : float
        Anticipation (s).

    Returns
    -------
    ndarray, (T, 3) float32
        (open in [0, 1], width in [-1, 1], round in [0, 1]).
    """
    end = phones["end"][-1]
    control_times = np.arange(int(np.ceil((end + 1.0) * language.CONTROL_RATE))) / language.CONTROL_RATE
    index = language.phone_index_at(phones, control_times)
    weights = dominance[index]
    sigma = COARTICULATION_SIGMA_S * language.CONTROL_RATE
    numerator = gaussian_filter1d(weights[:, None] * targets[index], sigma, axis=0, mode="nearest")
    denominator = gaussian_filter1d(weights, sigma, mode="nearest")
    smooth = numerator / denominator[:, None]
    sampled = np.stack([np.interp(frame_times + lead_s, control_times, smooth[:, j])
                        for j in range(3)], axis=1)
    low, high = np.array([0.0, -1.0, 0.0]), np.array([1.0, 1.0, 1.0])
    return np.clip(sampled, low, high).astype(np.float32)


def blink_closure(rng: np.random.Generator, frame_times: np.ndarray) -> np.ndarray:
    """Eyelid closure per frame: blinks of 100-200 ms every 2-6 s.

    Returns
    -------
    ndarray, (T,) float
        0 = open, 1 = fully closed.
    """
    closure = np.zeros_like(frame_times)
    start = rng.uniform(0.5, 3.0)
    while start < frame_times[-1] + 1.0:
        duration = rng.uniform(0.10, 0.20)
        phase = (frame_times - start) / duration
        inside = (phase > 0) & (phase < 1)
        closure[inside] = np.maximum(closure[inside],
                                     np.clip(1.6 * np.sin(np.pi * phase[inside]), 0.0, 1.0))
        start += duration + rng.uniform(2.0, 6.0)
    return closure


def head_pose_track(rng: np.random.Generator, frame_times: np.ndarray, face_width: float) -> np.ndarray:
    """Smooth head pose: each channel is a sum of three slow random sinusoids.

    Returns
    -------
    ndarray, (T, 6) float32
        yaw, pitch, roll (degrees), tx, ty (px, face-centre shift) and scale.
    """
    std = np.array([2.5, 1.5, 1.2, 0.035 * face_width, 0.025 * face_width, 0.012])
    pose = np.zeros((len(frame_times), 6))
    for channel in range(6):
        freqs = rng.uniform(0.05, 0.45, size=3)
        phases = rng.uniform(0.0, 2 * np.pi, size=3)
        amps = rng.uniform(0.5, 1.0, size=3)
        waves = amps * np.sin(2 * np.pi * freqs * frame_times[:, None] + phases)
        pose[:, channel] = waves.sum(axis=1) / np.sqrt(0.5 * np.sum(amps**2)) * std[channel]
    pose[:, 5] += 1.0
    return pose.astype(np.float32)


# ----------------------------------------------------------------------------
# Geometry: landmarks of one frame
# ----------------------------------------------------------------------------

def basis_array(rows: tuple) -> np.ndarray:
    """(68, 2) displacement field from ``(index, dx, dy)`` rows."""
    basis = np.zeros((68, 2))
    for index, dx, dy in rows:
        basis[index] = (dx, dy)
    return basis


MOUTH_BASES = np.stack([basis_array(OPEN_BASIS), basis_array(WIDTH_BASIS), basis_array(ROUND_BASIS)])


def deform_mouth(landmarks: np.ndarray, mouth: np.ndarray, face_width: float) -> np.ndarray:
    """Add the mouth blend shapes: ``landmarks + face_width * sum_j mouth_j * basis_j``.

    Parameters
    ----------
    landmarks : ndarray, (68, 2)
    mouth : ndarray, (3,)
        (open, width, round).
    face_width : float
        Face-box width (px); bases are in face widths.
    """
    return landmarks + face_width * np.tensordot(mouth, MOUTH_BASES, axes=1)


def close_eyelids(landmarks: np.ndarray, closure: float) -> np.ndarray:
    """Move upper lids 85 % and lower lids 15 % of the way to each other."""
    moved = landmarks.copy()
    for upper, lower in EYELID_PAIRS:
        gap = landmarks[lower] - landmarks[upper]
        moved[upper] = landmarks[upper] + 0.85 * closure * gap
        moved[lower] = landmarks[lower] - 0.15 * closure * gap
    return moved


def rotation_matrix(yaw_deg: float, pitch_deg: float, roll_deg: float) -> np.ndarray:
    """(3, 3) rotation ``Rz(roll) @ Ry(yaw) @ Rx(pitch)`` in image axes (x right, y down, z to camera)."""
    yaw, pitch, roll = np.deg2rad([yaw_deg, pitch_deg, roll_deg])
    rx = np.array([[1, 0, 0], [0, np.cos(pitch), -np.sin(pitch)], [0, np.sin(pitch), np.cos(pitch)]])
    ry = np.array([[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]])
    rz = np.array([[np.cos(roll), -np.sin(roll), 0], [np.sin(roll), np.cos(roll), 0], [0, 0, 1]])
    return rz @ ry @ rx


def apply_head_pose(points: np.ndarray, depth: np.ndarray, pose: np.ndarray,
                    center: np.ndarray) -> np.ndarray:
    """Rotate points (with depth) about the head centre, scale and translate (weak perspective).

    Parameters
    ----------
    points : ndarray, (N, 2)
        Frontal positions (px).
    depth : ndarray, (N,)
        Depth (px) towards the camera.
    pose : ndarray, (6,)
        yaw, pitch, roll (deg), tx, ty (px), scale.
    center : ndarray, (2,)
        Pivot (px).

    Returns
    -------
    ndarray, (N, 2)
    """
    local = np.column_stack([points - center, depth])
    rotated = local @ rotation_matrix(*pose[:3]).T
    return pose[5] * rotated[:, :2] + center + pose[3:5]


def frame_landmarks(template: face_template.FaceTemplate, mouth: np.ndarray, closure: float,
                    pose: np.ndarray) -> np.ndarray:
    """The 68 landmarks of one frame: rest face + mouth + blink, then head pose.

    Returns
    -------
    ndarray, (68, 2) float64
        Pixel coordinates.
    """
    shaped = close_eyelids(deform_mouth(template.neutral, mouth, template.face_width), closure)
    depth = template.depth.copy()
    depth[OUTER_LIP] += LIP_PROTRUSION * template.face_width * mouth[2]
    depth[INNER_LIP] += LIP_PROTRUSION * template.face_width * mouth[2]
    return apply_head_pose(shaped, depth, pose, template.center)


def frame_mesh_points(template: face_template.FaceTemplate, landmarks: np.ndarray,
                      pose: np.ndarray) -> np.ndarray:
    """All mesh vertices of one frame: landmarks, head ring (full pose), neck (40 % shift), border.

    Returns
    -------
    ndarray, (N, 2)
    """
    ring_end = 68 + template.ring_count
    neck_end = ring_end + template.neck_count
    ring = template.mesh_points[68:ring_end]
    ring = apply_head_pose(ring, np.zeros(len(ring)), pose, template.center)
    neck = template.mesh_points[ring_end:neck_end] + 0.4 * pose[3:5]
    return np.concatenate([landmarks, ring, neck, template.mesh_points[neck_end:]])
