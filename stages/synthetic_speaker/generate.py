"""Deterministic synthetic talking-head corpus (the "synthetic speaker").

A real photo (``skimage.data.astronaut()``) is animated with a piecewise-affine
mesh warp driven by a small landmark model (mouth opening / width / rounding,
blinks, head pose), and a matching speech-like soundtrack is produced by a
source-filter formant synthesiser over a random sequence of phone-like units.
The mouth moves *before* the sound (``MOUTH_LEAD_S``), with co-articulation, so
audio -> mouth is learnable but not a function of instantaneous loudness.

Outputs, for video ``i`` in ``out_dir``:

``speaker_XX.mp4``
    H.264 yuv420p video (crf 18) + AAC mono audio, muxed with PyAV.
``speaker_XX.truth.npz``
    Ground truth, see :func:`truth_arrays`.

Everything is a pure function of ``(seed, i)`` and the frame/audio settings;
video ``i`` does not depend on ``n_videos``.

Run ``python -m stages.synthetic_speaker.generate --help``.
"""
from __future__ import annotations

import argparse
import logging
import os
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import av
import av.codec.context
import cv2
import dlib
import numpy as np
import skimage.data
from scipy.ndimage import gaussian_filter1d
from scipy.signal import butter, lfilter, sosfilt
from scipy.spatial import Delaunay
from tqdm import tqdm

from pipeline import face
from pipeline.errors import LipsynthError, ParameterError
from pipeline.params import require, section

log = logging.getLogger("lipsynth.synthetic_speaker")

# ----------------------------------------------------------------------------
# Constants
# ----------------------------------------------------------------------------

MOUTH_LEAD_S = 0.08
"""The mouth shows the articulation of the sound heard this many seconds later."""

MOUTH_NAMES = ("open", "width", "round")
"""Mouth parameters: opening 0..1, spreading -1..1 (negative = narrow), rounding 0..1."""

POSE_NAMES = ("yaw_deg", "pitch_deg", "roll_deg", "tx_px", "ty_px", "scale")

FACE_WIDTH_AT_360 = 120.0
"""Width (px) of the dlib face box in a 360-px-wide frame."""

CONTROL_RATE = 1000
"""Sampling rate (Hz) of articulatory control tracks."""

COARTICULATION_SIGMA_S = 0.035
"""Gaussian time constant (s) of the dominance-weighted mouth smoothing."""

MIN_TRIANGLE_AREA = 0.5
"""Mesh triangles smaller than this (px^2) in the frame are not rasterised."""

FILTER_BLOCK = 80
"""Audio samples per block with constant formant-filter coefficients."""

VIDEO_OPTIONS = {"crf": "18", "preset": "medium", "threads": "1"}
AUDIO_BIT_RATE = 64000
AAC_SAMPLE_RATES = (8000, 11025, 12000, 16000, 22050, 24000, 32000, 44100, 48000)

HOG_MIN_FACE_PX = 80
"""dlib's frontal HOG detector (upsample 0) misses faces narrower than about this."""

# Landmark index groups of the dlib/iBUG 68-point convention.
NOSE = np.arange(27, 36)
RIGHT_EYE = np.arange(36, 42)  # subject's right eye = image left
LEFT_EYE = np.arange(42, 48)
OUTER_LIP = np.arange(48, 60)
INNER_LIP = np.arange(60, 68)
UPPER_INNER_LIP = np.array([60, 61, 62, 63, 64])
LOWER_INNER_LIP = np.array([64, 65, 66, 67, 60])
# (upper lid, lower lid) landmark pairs that meet when the eye closes
EYELID_PAIRS = ((37, 41), (38, 40), (43, 47), (44, 46))
LOWER_OUTER_LIP = np.arange(55, 60)
# (upper, lower) inner-lip landmark pairs that meet when the lips close
INNER_LIP_PAIRS = ((61, 67), (62, 66), (63, 65))
# chin landmark -> fraction of the lower-lip movement it follows when the mouth closes
CHIN_FOLLOW = {5: 0.2, 6: 0.5, 7: 0.8, 8: 1.0, 9: 0.8, 10: 0.5, 11: 0.2}


@dataclass(frozen=True)
class PhoneType:
    """One phone-like unit of the synthetic language.

    Attributes
    ----------
    kind : str
        "vowel", "nasal", "fricative", "stop" or "silence".
    mouth : tuple of float
        Target (open, width, round); bilabial closures use a negative opening so
        that the smoothed trajectory reaches full closure.
    dominance : float
        Co-articulation weight: how strongly the unit imposes its mouth target.
    formants : tuple of float
        F1, F2, F3 targets (Hz).
    voicing : float
        Glottal source amplitude (0 = voiceless).
    noise_band : tuple of float or None
        Frication / burst noise pass band (Hz).
    noise_amp : float
        Frication (or burst) noise amplitude.
    duration : tuple of float
        Min and max duration (s).
    """

    kind: str
    mouth: tuple
    dominance: float
    formants: tuple
    voicing: float
    noise_band: tuple | None
    noise_amp: float
    duration: tuple


PHONES = {
    "sil": PhoneType("silence", (0.0, 0.0, 0.0), 1.0, (500, 1500, 2500), 0.0, None, 0.0, (0.3, 1.0)),
    "a": PhoneType("vowel", (0.95, 0.15, 0.0), 1.0, (730, 1090, 2440), 1.0, None, 0.0, (0.08, 0.15)),
    "e": PhoneType("vowel", (0.55, 0.50, 0.0), 1.0, (530, 1840, 2480), 0.9, None, 0.0, (0.07, 0.13)),
    "i": PhoneType("vowel", (0.22, 0.90, 0.0), 1.0, (290, 2250, 3000), 0.8, None, 0.0, (0.07, 0.12)),
    "o": PhoneType("vowel", (0.60, -0.35, 0.6), 1.0, (570, 840, 2410), 0.9, None, 0.0, (0.08, 0.14)),
    "u": PhoneType("vowel", (0.20, -0.60, 1.0), 1.0, (320, 870, 2240), 0.8, None, 0.0, (0.07, 0.12)),
    "m": PhoneType("nasal", (-0.30, 0.0, 0.0), 3.0, (250, 1100, 2300), 0.35, None, 0.0, (0.05, 0.09)),
    "n": PhoneType("nasal", (0.18, 0.20, 0.0), 0.4, (250, 1500, 2500), 0.35, None, 0.0, (0.05, 0.08)),
    "f": PhoneType("fricative", (0.06, 0.10, 0.0), 2.0, (400, 1300, 2500), 0.0, (1500, 7500), 0.04, (0.08, 0.12)),
    "s": PhoneType("fricative", (0.10, 0.50, 0.0), 1.0, (400, 1700, 2600), 0.0, (4500, 7800), 0.09, (0.08, 0.13)),
    "sh": PhoneType("fricative", (0.15, -0.20, 0.8), 1.5, (400, 1800, 2500), 0.0, (1900, 4200), 0.1, (0.08, 0.13)),
    "p": PhoneType("stop", (-0.30, 0.0, 0.0), 3.0, (400, 900, 2300), 0.0, (400, 2500), 0.25, (0.07, 0.11)),
    "b": PhoneType("stop", (-0.30, 0.0, 0.0), 3.0, (300, 900, 2300), 0.15, (400, 2000), 0.15, (0.06, 0.09)),
    "t": PhoneType("stop", (0.15, 0.30, 0.0), 0.4, (400, 1700, 2600), 0.0, (3000, 7500), 0.25, (0.06, 0.10)),
    "k": PhoneType("stop", (0.30, 0.10, 0.0), 0.4, (400, 1900, 2400), 0.0, (1200, 3200), 0.25, (0.07, 0.11)),
}

VOWELS = ("a", "e", "i", "o", "u")
VOWEL_WEIGHTS = (0.28, 0.22, 0.20, 0.15, 0.15)
ONSETS = ("m", "n", "f", "s", "sh", "p", "b", "t", "k")
CODAS = ("m", "n", "s", "t", "k")
PHONE_DTYPE = np.dtype([("label", "U3"), ("start", "f8"), ("end", "f8")])

STOP_CLOSURE_FRACTION = 0.6
"""Fraction of a stop's duration spent in silent (or voice-bar) closure."""

FORMANT_BANDWIDTHS = (90.0, 110.0, 170.0)
FIXED_HIGHER_FORMANTS = ((3400.0, 250.0), (4400.0, 300.0))

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
# Face template: photo, landmarks, mesh
# ----------------------------------------------------------------------------

@dataclass(frozen=True)
class FaceTemplate:
    """The still photo prepared for animation, in frame coordinates.

    Attributes
    ----------
    image : ndarray, (H, W, 3) uint8
        Cropped, scaled RGB photo (the warp source).
    mesh_points : ndarray, (N, 2) float64
        Mesh vertices in ``image`` (px): 68 detected landmarks, then head-ring,
        neck and frame-border points.
    triangles : ndarray, (K, 3) int
        Delaunay triangles over ``mesh_points``.
    neutral : ndarray, (68, 2) float64
        Landmarks of the rest face (lips together, eyes open), px.
    depth : ndarray, (68,) float64
        Depth (px, towards the camera) of each landmark for head rotation.
    ring_count, neck_count : int
        How many head-ring and neck points follow the 68 landmarks.
    center : ndarray, (2,)
        Face-box centre (px), the pivot of the head pose.
    face_width : float
        Width of the detected face box (px).
    eyelid_rgb : ndarray, (2, 3) float
        Eyelid skin colour for the right and left eye.
    """

    image: np.ndarray
    mesh_points: np.ndarray
    triangles: np.ndarray
    neutral: np.ndarray
    depth: np.ndarray
    ring_count: int
    neck_count: int
    center: np.ndarray
    face_width: float
    eyelid_rgb: np.ndarray


def detect_face(image: np.ndarray) -> tuple[dlib.rectangle, np.ndarray]:
    """Detect the single face of an RGB image and its 68 landmarks.

    Parameters
    ----------
    image : ndarray, (H, W, 3) uint8

    Returns
    -------
    box : dlib.rectangle
        HOG face box (upsample 0).
    landmarks : ndarray, (68, 2) float64
        Landmark pixel coordinates (x, y).
    """
    found = face.detect_faces(image, 0)
    if len(found) != 1:
        raise RuntimeError(f"expected one face in the template photo, found {len(found)}")
    box = found[0][0]
    landmarks = face.predict_landmarks(image, box).astype(np.float64)
    return dlib.rectangle(*(int(round(v)) for v in box)), landmarks


def crop_affine(box: dlib.rectangle, width: int, height: int) -> np.ndarray:
    """Affine (2, 3) taking photo pixels to frame pixels.

    The face box becomes ``FACE_WIDTH_AT_360 * width / 360`` px wide (limited by
    the height), centred horizontally, slightly below mid-height so that hair,
    neck and shoulders are visible.
    """
    face_width = FACE_WIDTH_AT_360 * min(width / 360.0, height / 288.0)
    scale = face_width / box.width()
    box_center = np.array([(box.left() + box.right()) / 2, (box.top() + box.bottom()) / 2])
    frame_center = np.array([0.5 * width, 0.52 * height])
    offset = frame_center - scale * box_center
    return np.array([[scale, 0.0, offset[0]], [0.0, scale, offset[1]]])


def apply_affine(affine: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a (2, 3) affine to (..., 2) points."""
    return points @ affine[:, :2].T + affine[:, 2]


def closed_mouth(landmarks: np.ndarray) -> np.ndarray:
    """Rest landmarks: the photo's smiling open mouth with the lips brought together.

    The upper inner lip moves down 35 % of the lip gap, the lower lip (inner and
    outer) and the chin move up the remaining 65 %.

    Parameters
    ----------
    landmarks : ndarray, (68, 2)
        Detected landmarks (px).

    Returns
    -------
    ndarray, (68, 2)
    """
    rest = landmarks.copy()
    for upper, lower in INNER_LIP_PAIRS:
        gap = landmarks[lower, 1] - landmarks[upper, 1]
        rest[upper, 1] += 0.35 * gap
        rest[lower, 1] -= 0.65 * gap
    lower_lip_lift = 0.65 * (landmarks[66, 1] - landmarks[62, 1])
    rest[LOWER_OUTER_LIP, 1] -= lower_lip_lift
    for index, follow in CHIN_FOLLOW.items():
        rest[index, 1] -= follow * lower_lip_lift
    return rest


def landmark_depth(landmarks: np.ndarray, center: np.ndarray, face_width: float) -> np.ndarray:
    """Approximate depth of each landmark: an ellipsoidal head plus a nose.

    Returns
    -------
    ndarray, (68,)
        Depth in px (positive towards the camera) relative to the head centre.
    """
    u = (landmarks[:, 0] - center[0]) / (0.62 * face_width)
    v = (landmarks[:, 1] - center[1]) / (0.80 * face_width)
    depth = 0.55 * face_width * np.sqrt(np.clip(1.0 - u**2 - v**2, 0.0, None))
    nose_bulge = np.array([0.05, 0.10, 0.16, 0.22, 0.10, 0.13, 0.15, 0.13, 0.10])
    depth[NOSE] += nose_bulge * face_width
    return depth


def head_ring_points(center: np.ndarray, face_width: float, width: int, height: int) -> np.ndarray:
    """Points on an ellipse just outside hair and ears; they move with the head.

    Returns
    -------
    ndarray, (R, 2)
        Only the points at least 4 px inside the frame.
    """
    angles = np.deg2rad(np.linspace(-25.0, 205.0, 13))
    ring_center = center + np.array([0.0, -0.15 * face_width])
    points = ring_center + np.stack([0.95 * face_width * np.cos(angles),
                                     -1.05 * face_width * np.sin(angles)], axis=1)
    inside = ((points[:, 0] >= 4) & (points[:, 0] <= width - 5)
              & (points[:, 1] >= 4) & (points[:, 1] <= height - 5))
    return points[inside]


def neck_points(landmarks: np.ndarray, face_width: float) -> np.ndarray:
    """Points below the jaw that follow part of the head translation.

    Returns
    -------
    ndarray, (5, 2)
    """
    chin = landmarks[8]
    offsets = np.array([[-0.55, 0.05], [-0.3, 0.3], [0.0, 0.32], [0.3, 0.3], [0.55, 0.05]])
    return chin + offsets * face_width


def border_points(width: int, height: int, per_side: int = 7) -> np.ndarray:
    """Fixed points along the frame border (slightly outside so edges are covered).

    Returns
    -------
    ndarray, (B, 2)
    """
    xs = np.linspace(-1.0, width, per_side)
    ys = np.linspace(-1.0, height, per_side)
    top = np.stack([xs, np.full_like(xs, -1.0)], axis=1)
    bottom = np.stack([xs, np.full_like(xs, float(height))], axis=1)
    left = np.stack([np.full_like(ys[1:-1], -1.0), ys[1:-1]], axis=1)
    right = np.stack([np.full_like(ys[1:-1], float(width)), ys[1:-1]], axis=1)
    return np.concatenate([top, bottom, left, right])


def eyelid_colours(image: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
    """Median skin colour between each eyebrow and upper eyelid.

    Returns
    -------
    ndarray, (2, 3) float
        RGB colour for the right and left eye.
    """
    colours = []
    for brow, lid in (((19, 20), (37, 38)), ((23, 24), (43, 44))):
        x = landmarks[list(lid), 0].mean()
        y = 0.4 * landmarks[list(brow), 1].mean() + 0.6 * landmarks[list(lid), 1].mean()
        x0, y0 = int(round(x)), int(round(y))
        patch = image[y0 - 1:y0 + 2, x0 - 3:x0 + 4].reshape(-1, 3)
        colours.append(np.median(patch, axis=0))
    return np.array(colours, dtype=np.float64)


def remove_teeth(image: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
    """Inpaint the photo's smiling teeth and dark mouth corners with lip texture.

    The mouth interior is painted per frame, so the template must show lips
    only: the inner-lip polygon (widened to the outer lip corners) and the
    bright/dark non-lip pixels just around it are filled from the surrounding lips.

    Parameters
    ----------
    image : ndarray, (H, W, 3) uint8 RGB
    landmarks : ndarray, (68, 2)

    Returns
    -------
    ndarray, (H, W, 3) uint8
    """
    cavity_outline = landmarks[[48, 61, 62, 63, 54, 65, 66, 67]]
    cavity = np.zeros(image.shape[:2], dtype=np.uint8)
    cv2.fillPoly(cavity, [np.round(cavity_outline * 16).astype(np.int32)], 255, cv2.LINE_AA, 4)
    cavity = cavity > 64
    near_cavity = cv2.dilate(cavity.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    hsv = cv2.cvtColor(image, cv2.COLOR_RGB2HSV).astype(np.int32)
    teeth_or_dark = ((hsv[..., 1] < 55) & (hsv[..., 2] > 210)) | (hsv[..., 2] < 165)
    mask = (cavity | (near_cavity & teeth_or_dark)).astype(np.uint8) * 255
    return cv2.inpaint(image, mask, 2, cv2.INPAINT_TELEA)


def build_template(width: int, height: int) -> FaceTemplate:
    """Prepare the astronaut photo as an animatable face for ``width`` x ``height`` frames."""
    photo = skimage.data.astronaut()
    box, photo_landmarks = detect_face(photo)
    affine = crop_affine(box, width, height)
    image = cv2.warpAffine(photo, affine, (width, height), flags=cv2.INTER_CUBIC,
                           borderMode=cv2.BORDER_REFLECT)
    landmarks = apply_affine(affine, photo_landmarks)
    image = remove_teeth(image, landmarks)
    corners = apply_affine(affine, np.array([[box.left(), box.top()], [box.right(), box.bottom()]]))
    center = corners.mean(axis=0)
    face_width = float(corners[1, 0] - corners[0, 0])
    ring = head_ring_points(center, face_width, width, height)
    neck = neck_points(landmarks, face_width)
    mesh_points = np.concatenate([landmarks, ring, neck, border_points(width, height)])
    return FaceTemplate(
        image=image,
        mesh_points=mesh_points,
        triangles=Delaunay(mesh_points).simplices.astype(np.int64),
        neutral=closed_mouth(landmarks),
        depth=landmark_depth(landmarks, center, face_width),
        ring_count=len(ring),
        neck_count=len(neck),
        center=center,
        face_width=face_width,
        eyelid_rgb=eyelid_colours(image, landmarks),
    )


# ----------------------------------------------------------------------------
# Timeline of phone-like units
# ----------------------------------------------------------------------------

def sample_syllable(rng: np.random.Generator) -> list[str]:
    """A random (C)V(C) syllable as a list of phone labels."""
    syllable = []
    if rng.random() < 0.8:
        syllable.append(str(rng.choice(ONSETS)))
    syllable.append(str(rng.choice(VOWELS, p=VOWEL_WEIGHTS)))
    if rng.random() < 0.3:
        syllable.append(str(rng.choice(CODAS)))
    return syllable


def sample_word(rng: np.random.Generator) -> list[tuple[str, float, bool]]:
    """A random word of 1-3 syllables, first syllable stressed.

    Returns
    -------
    list of (label, duration_s, stressed)
    """
    word = []
    for syllable_index in range(int(rng.integers(1, 4))):
        stressed = syllable_index == 0
        for label in sample_syllable(rng):
            low, high = PHONES[label].duration
            duration = rng.uniform(low, high)
            is_stressed_vowel = stressed and PHONES[label].kind == "vowel"
            word.append((label, duration * (1.3 if is_stressed_vowel else 1.0), is_stressed_vowel))
    return word


def sample_phrase(rng: np.random.Generator, max_seconds: float) -> list[tuple[str, float, bool]]:
    """Connected words (2-6) that fit in ``max_seconds``; the last vowel is lengthened.

    Returns
    -------
    list of (label, duration_s, stressed); empty if not even one word fits.
    """
    phrase: list[tuple[str, float, bool]] = []
    for _ in range(int(rng.integers(2, 7))):
        word = sample_word(rng)
        if sum(d for _, d, _ in phrase + word) * 1.2 > max_seconds:
            break
        phrase += word
    for position in range(len(phrase) - 1, -1, -1):
        label, duration, stressed = phrase[position]
        if PHONES[label].kind == "vowel":
            phrase[position] = (label, duration * 1.4, stressed)
            break
    return phrase


def sample_phone_sequence(rng: np.random.Generator, seconds: float) -> tuple[np.ndarray, np.ndarray]:
    """Random utterance: silence, phrases separated by 0.3-1 s pauses, silence.

    Parameters
    ----------
    rng : numpy Generator
    seconds : float
        Total duration; the sequence tiles ``[0, seconds]`` exactly.

    Returns
    -------
    phones : structured ndarray, (P,) of ``PHONE_DTYPE``
        Label, start and end time (s) of each unit, "sil" for silence.
    stressed : ndarray, (P,) bool
        Stressed vowels (carry a pitch accent).
    """
    pause_range = PHONES["sil"].duration
    units = [("sil", rng.uniform(0.3, 0.6), False)]
    elapsed = units[0][1]
    while True:
        phrase = sample_phrase(rng, seconds - elapsed - 0.3)
        if not phrase:
            break
        units += phrase
        elapsed += sum(d for _, d, _ in phrase)
        pause = rng.uniform(*pause_range)
        units.append(("sil", pause, False))
        elapsed += pause
        if elapsed >= seconds - 0.6:
            break
    if units[-1][0] != "sil":
        units.append(("sil", 0.0, False))
    bounds = np.concatenate([[0.0], np.cumsum([d for _, d, _ in units])])
    bounds = np.minimum(bounds, seconds)
    bounds[-1] = seconds
    phones = np.zeros(len(units), dtype=PHONE_DTYPE)
    phones["label"] = [label for label, _, _ in units]
    phones["start"], phones["end"] = bounds[:-1], bounds[1:]
    keep = phones["end"] > phones["start"]
    return phones[keep], np.array([s for _, _, s in units], dtype=bool)[keep]


def phone_index_at(phones: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Index of the phone covering each time (s); clamps outside the timeline."""
    index = np.searchsorted(phones["start"], times, side="right") - 1
    return np.clip(index, 0, len(phones) - 1)


def speech_activity(phones: np.ndarray, times: np.ndarray) -> np.ndarray:
    """True where ``times`` (s) fall inside a non-silence unit."""
    return phones["label"][phone_index_at(phones, times)] != "sil"


# ----------------------------------------------------------------------------
# Articulation: mouth, blinks, head pose
# ----------------------------------------------------------------------------

def mouth_targets(phones: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Per-phone mouth targets (with small token-to-token variation) and dominances.

    Returns
    -------
    targets : ndarray, (P, 3)
        (open, width, round) per phone.
    dominance : ndarray, (P,)
    """
    targets = np.array([PHONES[label].mouth for label in phones["label"]], dtype=np.float64)
    dominance = np.array([PHONES[label].dominance for label in phones["label"]])
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
    control_times = np.arange(int(np.ceil((end + 1.0) * CONTROL_RATE))) / CONTROL_RATE
    index = phone_index_at(phones, control_times)
    weights = dominance[index]
    sigma = COARTICULATION_SIGMA_S * CONTROL_RATE
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


def frame_landmarks(template: FaceTemplate, mouth: np.ndarray, closure: float,
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


def frame_mesh_points(template: FaceTemplate, landmarks: np.ndarray, pose: np.ndarray) -> np.ndarray:
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


# ----------------------------------------------------------------------------
# Rendering
# ----------------------------------------------------------------------------

def triangle_affines(source: np.ndarray, target: np.ndarray, triangles: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Per-triangle affine maps from target (frame) to source (template) pixels.

    Returns
    -------
    affines : ndarray, (K, 3, 2)
        ``[x, y, 1] @ affines[k]`` is the source position of target pixel (x, y).
    areas : ndarray, (K,)
        Target triangle areas (px^2); triangles under ``MIN_TRIANGLE_AREA`` get
        an arbitrary affine and must not be rasterised.
    """
    homogeneous = np.concatenate([target[triangles], np.ones((len(triangles), 3, 1))], axis=2)
    areas = 0.5 * np.abs(np.linalg.det(homogeneous))
    homogeneous[areas < MIN_TRIANGLE_AREA] = np.eye(3)
    return np.linalg.solve(homogeneous, source[triangles]), areas


def piecewise_affine_maps(source: np.ndarray, target: np.ndarray, triangles: np.ndarray,
                          shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Dense ``cv2.remap`` maps of the triangle-mesh warp taking ``source`` to ``target``.

    Parameters
    ----------
    source, target : ndarray, (N, 2)
        Mesh vertices in the template and in the frame (px).
    triangles : ndarray, (K, 3)
    shape : (H, W)

    Returns
    -------
    map_x, map_y : ndarray, (H, W) float32
        Source coordinates of every frame pixel.
    """
    height, width = shape
    affines, areas = triangle_affines(source, target, triangles)
    owner = np.full(shape, -1, dtype=np.int32)
    fixed_point = np.round(target * 16).astype(np.int32)
    # Smallest first: pixels on shared edges go to the better-conditioned larger
    # triangle, so collapsed lips and eyelids never sample through a sliver.
    for k in np.argsort(areas, kind="stable"):
        if areas[k] < MIN_TRIANGLE_AREA:
            continue
        cv2.fillConvexPoly(owner, fixed_point[triangles[k]], int(k), lineType=cv2.LINE_8, shift=4)
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float32)
    identity = np.array([[1, 0], [0, 1], [0, 0]], dtype=np.float64)
    table = np.concatenate([affines, identity[None]]).astype(np.float32)
    pixel_affine = table[owner]  # owner -1 -> identity (last row)
    map_x = xs * pixel_affine[..., 0, 0] + ys * pixel_affine[..., 1, 0] + pixel_affine[..., 2, 0]
    map_y = xs * pixel_affine[..., 0, 1] + ys * pixel_affine[..., 1, 1] + pixel_affine[..., 2, 1]
    return map_x, map_y


def catmull_rom_closed(points: np.ndarray, steps: int = 4) -> np.ndarray:
    """Closed Catmull-Rom curve through ``points`` (M, 2); returns (M * steps, 2)."""
    p0, p1 = np.roll(points, 1, axis=0), points
    p2, p3 = np.roll(points, -1, axis=0), np.roll(points, -2, axis=0)
    t = (np.arange(steps) / steps)[:, None, None]
    curve = 0.5 * ((2 * p1) + (-p0 + p2) * t + (2 * p0 - 5 * p1 + 4 * p2 - p3) * t**2
                   + (-p0 + 3 * p1 - 3 * p2 + p3) * t**3)
    return curve.transpose(1, 0, 2).reshape(-1, 2)


def polygon_alpha(shape: tuple[int, int], polygon: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """Anti-aliased coverage (H, W) float32 in [0, 1] of a polygon given in frame px."""
    mask = np.zeros(shape, dtype=np.uint8)
    fixed_point = np.round((polygon - origin) * 16).astype(np.int32)
    cv2.fillPoly(mask, [fixed_point], 255, lineType=cv2.LINE_AA, shift=4)
    return mask.astype(np.float32) / 255.0


def blend(region: np.ndarray, colour: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """``region * (1 - alpha) + colour * alpha`` for (h, w, 3) float region, alpha (h, w)."""
    return region * (1.0 - alpha[..., None]) + colour * alpha[..., None]


def lip_curve(landmarks: np.ndarray, indices, xs: np.ndarray) -> np.ndarray:
    """y (px) of the piecewise-linear lip line through ``landmarks[indices]`` at columns ``xs``."""
    points = landmarks[list(indices)]
    order = np.argsort(points[:, 0], kind="stable")
    return np.interp(xs, points[order, 0], points[order, 1])


def teeth_alpha(xs: np.ndarray, ys: np.ndarray, landmarks: np.ndarray, gap: float,
                face_width: float) -> np.ndarray:
    """Coverage (h, w) of the upper teeth (below the upper lip) and lower teeth (above the lower lip).

    Upper teeth span the central 85 % of the mouth width, lower teeth the
    central 60 %; both get shorter towards the corners and fade in as the lips
    part by more than about a pixel.
    """
    corners = landmarks[[60, 64], 0]
    center = 0.5 * (corners[0] + corners[1])
    half_width = max(0.5 * (corners[1] - corners[0]), 1.0)
    lateral = np.clip(np.abs(xs - center) / half_width, 0.0, 1.0)
    taper = np.sqrt(np.clip(1.0 - lateral**2, 0.0, 1.0))
    upper_height = min(0.5 * gap, 0.05 * face_width) * taper
    lower_height = min(0.15 * gap, 0.02 * face_width) * taper
    upper = np.clip(lip_curve(landmarks, UPPER_INNER_LIP, xs) + upper_height - ys + 0.5, 0.0, 1.0)
    lower = np.clip(ys - lip_curve(landmarks, LOWER_INNER_LIP, xs) + lower_height + 0.5, 0.0, 1.0)
    upper *= np.clip((0.85 - lateral) / 0.15, 0.0, 1.0)
    lower *= np.clip((0.6 - lateral) / 0.2, 0.0, 1.0)
    parted = np.clip(gap / 2.0 - 0.5, 0.0, 1.0)
    return np.maximum(upper, lower) * parted


def lip_gap(landmarks: np.ndarray) -> float:
    """Mean vertical distance (px) between the inner lips at landmarks 61-63 / 67-65."""
    return float(np.mean(landmarks[[67, 66, 65], 1] - landmarks[[61, 62, 63], 1]))


def mouth_interior(xs: np.ndarray, ys: np.ndarray, landmarks: np.ndarray, face_width: float) -> np.ndarray:
    """Colour (h, w, 3) of the open mouth at pixel centres ``xs, ys`` (h, w).

    Dark reddish cavity, darker towards the corners, a tongue low in the mouth
    and light low-saturation teeth (see :func:`teeth_alpha`).
    """
    gap = lip_gap(landmarks)
    center = landmarks[INNER_LIP].mean(axis=0)
    half_width = max(0.5 * (landmarks[64, 0] - landmarks[60, 0]), 1.0)
    lateral = np.clip(np.abs(xs - center[0]) / half_width, 0.0, 1.0)
    shade = (1.0 - 0.5 * lateral**2)[..., None]
    interior = np.array([72.0, 22.0, 28.0]) * (0.5 + 0.5 * shade)
    tongue = np.exp(-((xs - center[0]) / (0.5 * half_width)) ** 2
                    - ((ys - landmarks[66, 1] + 0.2 * gap) / max(0.25 * gap, 0.5)) ** 2)
    interior = blend(interior, np.array([125.0, 55.0, 60.0]), 0.7 * tongue * min(gap / 12.0, 1.0))
    separation = np.cos(np.pi * (xs - center[0]) / (0.045 * face_width)) ** 16
    teeth = np.array([228.0, 220.0, 206.0]) * shade * (1.0 - 0.1 * separation)[..., None]
    return blend(interior, teeth, teeth_alpha(xs, ys, landmarks, gap, face_width))


def polyline_alpha(shape: tuple[int, int], points: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """Anti-aliased 1-px polyline coverage (H, W) float in [0, 1] of frame-px ``points``."""
    mask = np.zeros(shape, dtype=np.uint8)
    cv2.polylines(mask, [np.round((points - origin) * 16).astype(np.int32)], False, 255,
                  thickness=1, lineType=cv2.LINE_AA, shift=4)
    return mask / 255.0


def paint_mouth(frame: np.ndarray, landmarks: np.ndarray, face_width: float) -> None:
    """Paint the mouth interior inside the inner-lip polygon, and the lip seam (in place).

    Parameters
    ----------
    frame : ndarray, (H, W, 3) uint8 RGB
    landmarks : ndarray, (68, 2)
    face_width : float
        Face width (px), sets the teeth size.
    """
    inner = landmarks[INNER_LIP]
    low = np.floor(inner.min(axis=0) - 3).astype(int).clip(0)
    high = np.minimum(np.ceil(inner.max(axis=0) + 4).astype(int), [frame.shape[1], frame.shape[0]])
    shape = (high[1] - low[1], high[0] - low[0])
    ys, xs = np.mgrid[low[1]:high[1], low[0]:high[0]].astype(np.float64)
    region = frame[low[1]:high[1], low[0]:high[0]].astype(np.float64)
    cavity = np.clip(lip_gap(landmarks), 0.0, 1.0) * polygon_alpha(shape, catmull_rom_closed(inner), low)
    region = blend(region, mouth_interior(xs, ys, landmarks, face_width), cavity)
    seam_x = np.arange(landmarks[60, 0], landmarks[64, 0] + 0.5, 1.0)
    seam = np.stack([seam_x, lip_curve(landmarks, UPPER_INNER_LIP, seam_x)], axis=1)
    region = blend(region, np.array([110.0, 50.0, 55.0]), 0.35 * polyline_alpha(shape, seam, low))
    frame[low[1]:high[1], low[0]:high[0]] = np.clip(region + 0.5, 0, 255).astype(np.uint8)


def lash_line(eye: np.ndarray) -> np.ndarray:
    """Smooth arc (M, 2) from corner to corner through the middle of the closing lids.

    Parameters
    ----------
    eye : ndarray, (6, 2)
        The eye's landmarks in iBUG order (corner, two upper, corner, two lower).
    """
    through = np.stack([eye[0], 0.5 * (eye[1] + eye[5]), 0.5 * (eye[2] + eye[4]), eye[3]])
    coefficients = np.polyfit(through[:, 0], through[:, 1], 2)
    xs = np.linspace(eye[0, 0], eye[3, 0], 12)
    return np.stack([xs, np.polyval(coefficients, xs)], axis=1)


def paint_closed_eyes(frame: np.ndarray, landmarks: np.ndarray, closure: float,
                      eyelid_rgb: np.ndarray) -> None:
    """Cover each eye with feathered eyelid skin and a soft lash line, in proportion to ``closure``.

    Parameters
    ----------
    frame : ndarray, (H, W, 3) uint8 RGB
        Modified in place.
    landmarks : ndarray, (68, 2)
    closure : float
        0 = open (nothing painted), 1 = closed.
    eyelid_rgb : ndarray, (2, 3)
        Skin colour for the right and left eyelid.
    """
    strength = float(np.clip((closure - 0.2) / 0.6, 0.0, 1.0))
    if strength <= 0.0:
        return
    for eye, colour in ((RIGHT_EYE, eyelid_rgb[0]), (LEFT_EYE, eyelid_rgb[1])):
        points = landmarks[eye]
        low = np.floor(points.min(axis=0) - 4).astype(int).clip(0)
        high = np.ceil(points.max(axis=0) + 5).astype(int)
        shape = (high[1] - low[1], high[0] - low[0])
        region = frame[low[1]:high[1], low[0]:high[0]].astype(np.float64)
        lid = polygon_alpha(shape, catmull_rom_closed(points), low)
        lid = cv2.GaussianBlur(cv2.dilate(lid, np.ones((5, 5), np.uint8)), (0, 0), 1.0)
        region = blend(region, colour, strength * np.clip(lid, 0.0, 1.0))
        lash = polyline_alpha(shape, lash_line(points), low)
        region = blend(region, np.array([85.0, 60.0, 50.0]), 0.6 * strength * lash)
        frame[low[1]:high[1], low[0]:high[0]] = np.clip(region + 0.5, 0, 255).astype(np.uint8)


def render_frame(template: FaceTemplate, landmarks: np.ndarray, closure: float,
                 pose: np.ndarray) -> np.ndarray:
    """Warp the template onto the frame's landmarks and paint mouth and eyelids.

    Parameters
    ----------
    template : FaceTemplate
    landmarks : ndarray, (68, 2)
        This frame's landmarks (px), from :func:`frame_landmarks`.
    closure : float
        Eyelid closure 0..1.
    pose : ndarray, (6,)

    Returns
    -------
    ndarray, (H, W, 3) uint8 RGB
    """
    target = frame_mesh_points(template, landmarks, pose)
    map_x, map_y = piecewise_affine_maps(template.mesh_points, target, template.triangles,
                                         template.image.shape[:2])
    frame = cv2.remap(template.image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    paint_mouth(frame, landmarks, template.face_width)
    paint_closed_eyes(frame, landmarks, closure, template.eyelid_rgb)
    return frame


# ----------------------------------------------------------------------------
# Audio: source-filter formant synthesis
# ----------------------------------------------------------------------------

def stop_phases(phones: np.ndarray, index: np.ndarray, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closure and 12-ms burst masks of a stop, for control samples inside phone ``index``.

    Returns
    -------
    closure, burst : ndarray, (n,) bool
        Closure: the first ``STOP_CLOSURE_FRACTION`` of the unit; burst: the
        12 ms after it. The rest of the unit is the release (aspiration or voicing).
    """
    start, end = phones["start"][index], phones["end"][index]
    release = start + STOP_CLOSURE_FRACTION * (end - start)
    return times < release, (times >= release) & (times < release + 0.012)


def control_tracks(phones: np.ndarray, n_control: int) -> dict[str, np.ndarray]:
    """Step-wise synthesis controls at ``CONTROL_RATE``.

    Returns
    -------
    dict of ndarray
        ``formants`` (n, 3) Hz; ``voicing`` (n,) glottal amplitude; ``aspiration``
        (n,) noise into the vocal tract; one ``noise:<label>`` (n,) frication/burst
        amplitude per unit with a noise band.
    """
    times = np.arange(n_control) / CONTROL_RATE
    index = phone_index_at(phones, times)
    labels = phones["label"][index]
    tracks = {
        "formants": np.array([PHONES[label].formants for label in labels], dtype=np.float64),
        "voicing": np.array([PHONES[label].voicing for label in labels]),
        "aspiration": np.zeros(n_control),
    }
    for label, phone in PHONES.items():
        if phone.noise_band is not None:
            tracks["noise:" + label] = np.where(labels == label, phone.noise_amp, 0.0)
    closure, burst = stop_phases(phones, index, times)
    for label in ("p", "b", "t", "k"):
        stop = labels == label
        release = stop & ~closure & ~burst
        tracks["noise:" + label] = np.where(stop & burst, PHONES[label].noise_amp, 0.0)
        if label == "b":
            tracks["voicing"][release] = 0.6
        else:
            tracks["voicing"][stop] = 0.0
            tracks["aspiration"][release] = 0.12
    return tracks


def pitch_contour(phones: np.ndarray, stressed: np.ndarray, rng: np.random.Generator,
                  n_control: int) -> np.ndarray:
    """Fundamental frequency (Hz) at ``CONTROL_RATE``.

    Per phrase: declination from ~130 to ~105 Hz, a pitch accent on each stressed
    vowel, a slow wobble, and 1 % jitter every 5 ms.
    """
    times = np.arange(n_control) / CONTROL_RATE
    f0 = np.full(n_control, 110.0)
    speech = phones["label"] != "sil"
    edges = np.flatnonzero(np.diff(np.concatenate([[0], speech.astype(int), [0]])))
    for first, last in zip(edges[::2], edges[1::2] - 1):
        start, end = phones["start"][first], phones["end"][last]
        inside = (times >= start - 0.05) & (times <= end + 0.05)
        fraction = np.clip((times[inside] - start) / (end - start), 0, 1)
        f_start, f_end = rng.uniform(122, 140), rng.uniform(98, 110)
        f0[inside] = f_start + (f_end - f_start) * fraction
    for center in 0.5 * (phones["start"][stressed] + phones["end"][stressed]):
        f0 += rng.uniform(8, 18) * np.exp(-0.5 * ((times - center) / 0.07) ** 2)
    f0 += 2.0 * np.sin(2 * np.pi * rng.uniform(2, 4) * times + rng.uniform(0, 2 * np.pi))
    jitter = np.repeat(rng.normal(0, 0.01, size=n_control // 5 + 1), 5)[:n_control]
    return f0 * (1.0 + jitter)


def glottal_source(f0: np.ndarray, sample_rate: int) -> np.ndarray:
    """Differentiated Rosenberg glottal pulse train (includes lip radiation).

    Parameters
    ----------
    f0 : ndarray, (N,)
        Fundamental frequency per sample (Hz).

    Returns
    -------
    ndarray, (N,)
        Roughly unit-peak excitation.
    """
    phase = np.mod(np.cumsum(f0 / sample_rate), 1.0)
    rise, fall = 0.4, 0.16
    flow = np.where(phase < rise, 0.5 * (1 - np.cos(np.pi * phase / rise)),
                    np.where(phase < rise + fall, np.cos(0.5 * np.pi * (phase - rise) / fall), 0.0))
    derivative = np.diff(flow, prepend=0.0)
    return derivative / (np.abs(derivative).max() + 1e-12)


def resonator_coefficients(freq: float, bandwidth: float, sample_rate: int) -> tuple[float, float, float]:
    """Klatt resonator ``y[n] = a x[n] + b y[n-1] + c y[n-2]`` with unit DC gain."""
    c = -np.exp(-2 * np.pi * bandwidth / sample_rate)
    b = 2 * np.exp(-np.pi * bandwidth / sample_rate) * np.cos(2 * np.pi * freq / sample_rate)
    return 1.0 - b - c, b, c


def time_varying_resonator(signal: np.ndarray, freqs: np.ndarray, bandwidth: float,
                           sample_rate: int) -> np.ndarray:
    """Second-order resonator whose centre frequency changes every ``FILTER_BLOCK`` samples.

    Parameters
    ----------
    signal : ndarray, (N,)
    freqs : ndarray, (ceil(N / FILTER_BLOCK),)
        Centre frequency (Hz) per block.
    bandwidth : float
        Hz.

    Returns
    -------
    ndarray, (N,)
    """
    output = np.empty_like(signal)
    previous, before_previous = 0.0, 0.0
    for block, freq in enumerate(freqs):
        piece = slice(block * FILTER_BLOCK, (block + 1) * FILTER_BLOCK)
        a, b, c = resonator_coefficients(freq, bandwidth, sample_rate)
        state = [b * previous + c * before_previous, c * previous]
        output[piece], _ = lfilter([a], [1.0, -b, -c], signal[piece], zi=state)
        previous = output[piece][-1]
        before_previous = output[piece][-2] if output[piece].size > 1 else previous
    return output


def vocal_tract(excitation: np.ndarray, formants: np.ndarray, sample_rate: int) -> np.ndarray:
    """Cascade of F1-F3 (time-varying) and two fixed higher formants.

    Parameters
    ----------
    excitation : ndarray, (N,)
    formants : ndarray, (ceil(N / FILTER_BLOCK), 3)
        F1-F3 per block (Hz).
    """
    signal = excitation
    for j, bandwidth in enumerate(FORMANT_BANDWIDTHS):
        signal = time_varying_resonator(signal, formants[:, j], bandwidth, sample_rate)
    for freq, bandwidth in FIXED_HIGHER_FORMANTS:
        a, b, c = resonator_coefficients(freq, bandwidth, sample_rate)
        signal = lfilter([a], [1.0, -b, -c], signal)
    return signal


def band_noise(rng: np.random.Generator, band: tuple, n_samples: int, sample_rate: int) -> np.ndarray:
    """Unit-RMS white noise band-passed to ``band`` (Hz)."""
    high = min(band[1], 0.95 * sample_rate / 2)
    sos = butter(4, [band[0], high], btype="bandpass", fs=sample_rate, output="sos")
    noise = sosfilt(sos, rng.standard_normal(n_samples))
    return noise / (noise.std() + 1e-12)


def to_audio_rate(track: np.ndarray, sigma_s: float, n_samples: int, sample_rate: int) -> np.ndarray:
    """Smooth a ``CONTROL_RATE`` track (Gaussian, ``sigma_s`` seconds) and resample it to (n_samples,)."""
    smooth = gaussian_filter1d(track, sigma_s * CONTROL_RATE, axis=0, mode="nearest")
    control_times = np.arange(len(track)) / CONTROL_RATE
    return np.interp(np.arange(n_samples) / sample_rate, control_times, smooth)


def block_formants(formants: np.ndarray, n_samples: int, sample_rate: int) -> np.ndarray:
    """F1-F3 (Hz) per ``FILTER_BLOCK``, from step targets at ``CONTROL_RATE`` smoothed over 18 ms.

    Returns
    -------
    ndarray, (ceil(n_samples / FILTER_BLOCK), 3)
    """
    smooth = gaussian_filter1d(formants, 0.018 * CONTROL_RATE, axis=0, mode="nearest")
    control_times = np.arange(len(formants)) / CONTROL_RATE
    block_times = (np.arange(int(np.ceil(n_samples / FILTER_BLOCK))) + 0.5) * FILTER_BLOCK / sample_rate
    return np.stack([np.interp(block_times, control_times, smooth[:, j]) for j in range(3)], axis=1)


def frication(tracks: dict, rng: np.random.Generator, n_samples: int, sample_rate: int) -> np.ndarray:
    """Sum of band-passed noises gated by the fricative and stop-burst amplitude tracks."""
    noise = np.zeros(n_samples)
    for label, phone in PHONES.items():
        if phone.noise_band is None or not tracks["noise:" + label].any():
            continue
        sigma_s = 0.002 if phone.kind == "stop" else 0.008
        envelope = to_audio_rate(tracks["noise:" + label], sigma_s, n_samples, sample_rate)
        noise += envelope * band_noise(rng, phone.noise_band, n_samples, sample_rate)
    return noise


def synthesize_speech(phones: np.ndarray, stressed: np.ndarray, rng: np.random.Generator,
                      sample_rate: int, n_samples: int) -> np.ndarray:
    """Speech-like audio for a phone sequence.

    Voiced units: glottal pulses (with pitch contour and jitter) through the
    formant cascade; fricatives and stop bursts: band-passed noise; stops:
    closure, burst and aspiration. Peak-normalised to 0.7.

    Parameters
    ----------
    phones : structured ndarray, (P,)
    stressed : ndarray, (P,) bool
    rng : numpy Generator
    sample_rate : int
        Hz.
    n_samples : int

    Returns
    -------
    ndarray, (n_samples,) float32
        Mono waveform in [-1, 1].
    """
    n_control = int(np.ceil(n_samples / sample_rate * CONTROL_RATE)) + 1
    tracks = control_tracks(phones, n_control)
    f0 = to_audio_rate(pitch_contour(phones, stressed, rng, n_control), 0.002, n_samples, sample_rate)
    voicing = to_audio_rate(tracks["voicing"], 0.006, n_samples, sample_rate)
    aspiration = to_audio_rate(tracks["aspiration"], 0.003, n_samples, sample_rate)
    excitation = voicing * glottal_source(f0, sample_rate) + 0.4 * aspiration * rng.standard_normal(n_samples)
    speech = vocal_tract(excitation, block_formants(tracks["formants"], n_samples, sample_rate), sample_rate)
    speech /= np.abs(speech).max() + 1e-12
    speech += frication(tracks, rng, n_samples, sample_rate)
    speech += 3e-4 * rng.standard_normal(n_samples)
    return (0.7 * speech / np.abs(speech).max()).astype(np.float32)


# ----------------------------------------------------------------------------
# One video
# ----------------------------------------------------------------------------

@dataclass(frozen=True)
class VideoScript:
    """Everything about one clip except the rendered pixels.

    Attributes
    ----------
    phones : structured ndarray, (P,) of ``PHONE_DTYPE``
    stressed : ndarray, (P,) bool
    mouth : ndarray, (T, 3) float32
    closure : ndarray, (T,) float
    pose : ndarray, (T, 6) float32
    landmarks : ndarray, (T, 68, 2) float32
    audio : ndarray, (N,) float32
    """

    phones: np.ndarray
    stressed: np.ndarray
    mouth: np.ndarray
    closure: np.ndarray
    pose: np.ndarray
    landmarks: np.ndarray
    audio: np.ndarray


def video_rng(seed: int, video_index: int, stream: str) -> np.random.Generator:
    """Independent random stream per (seed, video, purpose)."""
    stream_id = {"phones": 0, "mouth": 1, "blinks": 2, "pose": 3, "audio": 4}[stream]
    return np.random.default_rng([seed, video_index, stream_id])


def script_video(template: FaceTemplate, seed: int, video_index: int, seconds: float,
                 fps: int, sample_rate: int) -> VideoScript:
    """Sample the phone sequence, articulation, pose, landmarks and audio of one clip."""
    n_frames = int(round(seconds * fps))
    frame_times = np.arange(n_frames) / fps
    phones, stressed = sample_phone_sequence(video_rng(seed, video_index, "phones"), seconds)
    targets, dominance = mouth_targets(phones, video_rng(seed, video_index, "mouth"))
    mouth = mouth_trajectory(phones, targets, dominance, frame_times)
    closure = blink_closure(video_rng(seed, video_index, "blinks"), frame_times)
    pose = head_pose_track(video_rng(seed, video_index, "pose"), frame_times, template.face_width)
    landmarks = np.stack([frame_landmarks(template, mouth[t], closure[t], pose[t].astype(np.float64))
                          for t in range(n_frames)]).astype(np.float32)
    audio = synthesize_speech(phones, stressed, video_rng(seed, video_index, "audio"),
                              sample_rate, int(round(seconds * sample_rate)))
    return VideoScript(phones, stressed, mouth, closure, pose, landmarks, audio)


def render_frames(template: FaceTemplate, script: VideoScript):
    """Yield the RGB frames (H, W, 3) uint8 of a scripted clip."""
    for t in range(len(script.mouth)):
        yield render_frame(template, script.landmarks[t].astype(np.float64), float(script.closure[t]),
                           script.pose[t].astype(np.float64))


def truth_arrays(script: VideoScript, fps: int, sample_rate: int) -> dict[str, np.ndarray]:
    """Ground-truth arrays saved in ``speaker_XX.truth.npz``.

    Returns
    -------
    dict
        ``landmarks`` (T, 68, 2) float32 px (x, y), dlib/iBUG order;
        ``pose`` (T, 6) float32 (yaw, pitch, roll deg, tx, ty px, scale);
        ``pose_names`` (6,) str; ``blink`` (T,) bool (eyes more than half closed);
        ``mouth`` (T, 3) float32 (open 0..1, width -1..1, round 0..1);
        ``mouth_names`` (3,) str; ``phones`` (P,) structured (label U3, start f8 s,
        end f8 s) tiling the clip, "sil" = silence; ``voiced`` (T,) bool, speech
        (non-silence unit) at the frame time; ``fps``, ``sample_rate`` and
        ``mouth_lead_s`` scalars.
    """
    frame_times = np.arange(len(script.mouth)) / fps
    return {
        "landmarks": script.landmarks.astype(np.float32),
        "pose": script.pose.astype(np.float32),
        "pose_names": np.array(POSE_NAMES),
        "blink": script.closure >= 0.5,
        "mouth": script.mouth.astype(np.float32),
        "mouth_names": np.array(MOUTH_NAMES),
        "phones": script.phones,
        "voiced": speech_activity(script.phones, frame_times),
        "fps": np.array(fps),
        "sample_rate": np.array(sample_rate),
        "mouth_lead_s": np.array(MOUTH_LEAD_S),
    }


def write_mp4(path: Path, frames, audio: np.ndarray, fps: int, sample_rate: int,
              width: int, height: int) -> None:
    """Encode frames (H.264 yuv420p, crf 18, 1 thread) and mono AAC audio into an MP4.

    Audio is fed in step with the video (``sample_rate / fps`` samples per frame)
    so the muxer interleaves the streams.

    Parameters
    ----------
    path : Path
    frames : iterable of ndarray, (H, W, 3) uint8 RGB
    audio : ndarray, (N,) float32
    fps, sample_rate, width, height : int
    """
    with av.open(str(path), mode="w", format="mp4", options={"fflags": "+bitexact"}) as container:
        video = container.add_stream("libx264", rate=fps, options=dict(VIDEO_OPTIONS))
        video.width, video.height, video.pix_fmt = width, height, "yuv420p"
        video.codec_context.thread_count = 1
        video.codec_context.flags |= av.codec.context.Flags.bitexact
        sound = container.add_stream("aac", rate=sample_rate, layout="mono")
        sound.bit_rate = AUDIO_BIT_RATE
        sound.codec_context.flags |= av.codec.context.Flags.bitexact
        audio_written = 0
        for index, rgb in enumerate(frames):
            frame = av.VideoFrame.from_ndarray(rgb, format="rgb24")
            frame.pts = index
            container.mux(video.encode(frame))
            audio_until = min(int(round((index + 1) * sample_rate / fps)), len(audio))
            if audio_until > audio_written:
                chunk = av.AudioFrame.from_ndarray(audio[None, audio_written:audio_until],
                                                   format="fltp", layout="mono")
                chunk.sample_rate, chunk.pts = sample_rate, audio_written
                container.mux(sound.encode(chunk))
                audio_written = audio_until
        container.mux(video.encode(None))
        container.mux(sound.encode(None))


def generate_video(template: FaceTemplate, settings: dict, video_index: int, directory: Path) -> None:
    """Script, render and write ``speaker_XX.mp4`` and ``speaker_XX.truth.npz`` into ``directory``."""
    script = script_video(template, settings["seed"], video_index, settings["seconds_per_video"],
                          settings["fps"], settings["sample_rate"])
    stem = directory / f"speaker_{video_index:02d}"
    write_mp4(stem.with_suffix(".mp4"), render_frames(template, script), script.audio,
              settings["fps"], settings["sample_rate"], settings["width"], settings["height"])
    np.savez_compressed(stem.with_suffix(".truth.npz"),
                        **truth_arrays(script, settings["fps"], settings["sample_rate"]))


# ----------------------------------------------------------------------------
# Corpus and entry point
# ----------------------------------------------------------------------------

def validated_settings(params: dict) -> dict:
    """Check the ``synthetic_speaker`` params section and return typed settings."""
    where = "synthetic_speaker"
    settings = {
        "seed": require(params, "seed", int, where),
        "n_videos": require(params, "n_videos", int, where),
        "seconds_per_video": float(require(params, "seconds_per_video", (int, float), where)),
        "fps": require(params, "fps", int, where),
        "width": require(params, "width", int, where),
        "height": require(params, "height", int, where),
        "sample_rate": require(params, "sample_rate", int, where),
        "out_dir": str(require(params, "out_dir", str, where)),
    }
    checks = (
        ("n_videos", settings["n_videos"] >= 1, ">= 1"),
        ("seconds_per_video", settings["seconds_per_video"] >= 1.0, ">= 1"),
        ("fps", settings["fps"] > 0, "> 0"),
        ("width", settings["width"] >= 160 and settings["width"] % 2 == 0, "even and >= 160"),
        ("height", settings["height"] >= 128 and settings["height"] % 2 == 0, "even and >= 128"),
        ("sample_rate", settings["sample_rate"] in AAC_SAMPLE_RATES, f"one of {AAC_SAMPLE_RATES}"),
    )
    for key, ok, rule in checks:
        if not ok:
            raise ParameterError(f"{where}.{key}={settings[key]!r}: must be {rule}")
    return settings


def replace_directory(source: Path, destination: Path) -> None:
    """Move ``source`` onto ``destination``, removing an existing ``destination`` first.

    The old directory is renamed aside before the new one is moved in, so a
    complete corpus is always either at ``destination`` or at the aside name.
    """
    aside = destination.with_name(f".{destination.name}.old-{os.getpid()}")
    if destination.exists():
        os.replace(destination, aside)
    os.replace(source, destination)
    shutil.rmtree(aside, ignore_errors=True)


def generate_corpus(settings: dict) -> Path:
    """Generate all clips into a temporary sibling directory, then move it onto ``out_dir``.

    Returns
    -------
    Path
        The output directory.
    """
    out_dir = Path(settings["out_dir"])
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    staging = out_dir.with_name(f".{out_dir.name}.tmp-{os.getpid()}")
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir()
    try:
        template = build_template(settings["width"], settings["height"])
        log.info("template face %.0f px wide, %d mesh points, %d triangles",
                 template.face_width, len(template.mesh_points), len(template.triangles))
        if template.face_width < HOG_MIN_FACE_PX:
            log.warning("face is only %.0f px wide: dlib's HOG detector will miss it "
                        "(use frames of at least 240 x 192)", template.face_width)
        for video_index in tqdm(range(settings["n_videos"]), desc="synthetic speaker", unit="video"):
            generate_video(template, settings, video_index, staging)
        replace_directory(staging, out_dir)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return out_dir


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """Command-line arguments."""
    parser = argparse.ArgumentParser(
        prog="python -m stages.synthetic_speaker.generate",
        description=(
            "Generate a deterministic synthetic talking-head corpus: n_videos clips of the "
            "astronaut photo animated to speak a random phone-like language, written as "
            "OUT/speaker_XX.mp4 (H.264 + AAC) and OUT/speaker_XX.truth.npz (per-frame 68 "
            "landmarks, head pose, blinks, mouth parameters, phone timings, speech activity). "
            "Settings come from the 'synthetic_speaker' section of params.yaml (or the file "
            "named by $LIPSYNTH_PARAMS): seed, n_videos, seconds_per_video, fps, width, "
            "height, sample_rate, out_dir. The output directory is replaced atomically."),
        epilog=(
            "truth.npz keys: landmarks (T,68,2) float32 px, dlib/iBUG order; pose (T,6) "
            "yaw/pitch/roll deg, tx/ty px, scale; blink (T,) bool; mouth (T,3) open 0..1, "
            "width -1..1, round 0..1; phones (P,) label/start/end s ('sil' = silence); "
            "voiced (T,) bool speech activity; fps; sample_rate; mouth_lead_s. The mouth "
            f"anticipates the sound by {MOUTH_LEAD_S * 1000:.0f} ms."),
    )
    parser.add_argument("--out", metavar="DIR", help="output directory (overrides out_dir)")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    """Entry point: read params, generate the corpus, report the time taken."""
    args = parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        settings = validated_settings(section("synthetic_speaker"))
        if args.out:
            settings["out_dir"] = args.out
        started = time.perf_counter()
        out_dir = generate_corpus(settings)
    except LipsynthError as error:
        log.error("%s", error)
        return 2
    log.info("wrote %d videos to %s in %.1f s", settings["n_videos"], out_dir,
             time.perf_counter() - started)
    return 0


if __name__ == "__main__":
    sys.exit(main())
