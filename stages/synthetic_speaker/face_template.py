"""The still photo prepared for animation: crop, landmarks, rest face, mesh.

``skimage.data.astronaut()`` is cropped and scaled so the dlib face box has a
fixed size in the frame, the smiling teeth are inpainted away, and a Delaunay
mesh is built over the 68 landmarks plus head-ring, neck and frame-border points.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import dlib
import numpy as np
import skimage.data
from scipy.spatial import Delaunay

from pipeline import resample
from pipeline.face import dlib_face

FACE_WIDTH_AT_360 = 120.0
"""Width (px) of the dlib face box in a 360-px-wide frame."""

# Landmark index groups of the dlib/iBUG 68-point convention.
NOSE = np.arange(27, 36)
LOWER_OUTER_LIP = np.arange(55, 60)
# (upper, lower) inner-lip landmark pairs that meet when the lips close
INNER_LIP_PAIRS = ((61, 67), (62, 66), (63, 65))
# chin landmark -> fraction of the lower-lip movement it follows when the mouth closes
CHIN_FOLLOW = {5: 0.2, 6: 0.5, 7: 0.8, 8: 1.0, 9: 0.8, 10: 0.5, 11: 0.2}


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
    found = dlib_face.detect_faces(image, 0)
    if len(found) != 1:
        raise RuntimeError(f"expected one face in the template photo, found {len(found)}")
    box = found[0][0]
    landmarks = dlib_face.predict_landmarks(image, box).astype(np.float64)
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
    # bilinear and bit-exact (pipeline.resample): OpenCV's own warps round differently with and without
    # AVX2, and the corpus must be the same bytes on any x86-64 CPU
    image = resample.warp_affine(photo, affine, (width, height), cv2.BORDER_REFLECT)
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
