"""Rendering one frame: piecewise-affine mesh warp of the template, painted mouth and eyelids."""
from __future__ import annotations

import cv2
import numpy as np

from pipeline import resample
from stages.synthetic_speaker import articulation, face_template

MIN_TRIANGLE_AREA = 0.5
"""Mesh triangles smaller than this (px^2) in the frame are not rasterised."""

# Landmark index groups of the dlib/iBUG 68-point convention.
RIGHT_EYE = np.arange(36, 42)  # subject's right eye = image left
LEFT_EYE = np.arange(42, 48)
UPPER_INNER_LIP = np.array([60, 61, 62, 63, 64])
LOWER_INNER_LIP = np.array([64, 65, 66, 67, 60])


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
    # Cramer's rule in element-wise float64: LAPACK's solve picks CPU-specific kernels (FMA or not),
    # and the corpus must be the same bytes on any x86-64 CPU
    t = target[triangles].astype(np.float64)                  # (K, 3, 2)
    (x0, y0), (x1, y1), (x2, y2) = t[:, 0].T, t[:, 1].T, t[:, 2].T
    det = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)       # the determinant of [x y 1] rows
    areas = 0.5 * np.abs(det)
    small = areas < MIN_TRIANGLE_AREA
    det = np.where(small, 1.0, det)
    # inverse of H = [[x0 y0 1], [x1 y1 1], [x2 y2 1]] (adjugate / det), rows of H⁻¹ times source
    inv = np.stack([np.stack([y1 - y2, y2 - y0, y0 - y1], -1),
                    np.stack([x2 - x1, x0 - x2, x1 - x0], -1),
                    np.stack([x1 * y2 - x2 * y1, x2 * y0 - x0 * y2, x0 * y1 - x1 * y0], -1)], 1) / det[:, None, None]
    inv[small] = np.eye(3)
    src = source[triangles].astype(np.float64)                # (K, 3, 2)
    affines = (inv[:, :, 0, None] * src[:, None, 0] + inv[:, :, 1, None] * src[:, None, 1]
               + inv[:, :, 2, None] * src[:, None, 2])
    return affines, areas


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
    center = landmarks[articulation.INNER_LIP].mean(axis=0)
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
    inner = landmarks[articulation.INNER_LIP]
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
        # blurred as 8-bit: OpenCV's float filters round differently with and without AVX/FMA (its
        # 8-bit ones do not), and the corpus must be the same bytes on any x86-64 CPU
        lid8 = cv2.dilate(np.round(lid * 255).astype(np.uint8), np.ones((5, 5), np.uint8))
        lid = cv2.GaussianBlur(lid8, (0, 0), 1.0).astype(np.float32) / 255.0
        region = blend(region, colour, strength * np.clip(lid, 0.0, 1.0))
        lash = polyline_alpha(shape, lash_line(points), low)
        region = blend(region, np.array([85.0, 60.0, 50.0]), 0.6 * strength * lash)
        frame[low[1]:high[1], low[0]:high[0]] = np.clip(region + 0.5, 0, 255).astype(np.uint8)


def render_frame(template: face_template.FaceTemplate, landmarks: np.ndarray, closure: float,
                 pose: np.ndarray) -> np.ndarray:
    """Warp the template onto the frame's landmarks and paint mouth and eyelids.

    Parameters
    ----------
    template : FaceTemplate
    landmarks : ndarray, (68, 2)
        This frame's landmarks (px), from :func:`articulation.frame_landmarks`.
    closure : float
        Eyelid closure 0..1.
    pose : ndarray, (6,)

    Returns
    -------
    ndarray, (H, W, 3) uint8 RGB
    """
    target = articulation.frame_mesh_points(template, landmarks, pose)
    map_x, map_y = piecewise_affine_maps(template.mesh_points, target, template.triangles,
                                         template.image.shape[:2])
    frame = resample.remap(template.image, map_x, map_y, cv2.BORDER_REFLECT)
    paint_mouth(frame, landmarks, template.face_width)
    paint_closed_eyes(frame, landmarks, closure, template.eyelid_rgb)
    return frame
