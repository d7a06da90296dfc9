"""The dense 3D head of the speaker (paper 001's product): a textured face mesh with an open mouth.

Built only from what the model folder keeps of its speaker — the extended face surface f*(x, y)
(frontalize, Eqs. 7–8 of paper 000), the whole-face texture and its landmarks
(``pipeline.face.head_texture``):

- **skin**: a regular grid every ``step_mm`` over the face outline (jaw contour closed by an arc over
  the forehead), depth from the surface, texture coordinates from the head texture (full resolution,
  interpolated by the renderer: no blocks);
- **the mouth cut**: the grid row nearest the inner-lip line (corner 60 → 64 through the inner-lip
  midpoints) is snapped onto it and split in two copies, the cells along it triangulated so the cut
  follows grid edges; triangles above use the upper copy, below the lower — the lips can part;
- **mouth cavity**: a dark bowl 8–22 mm behind the lips, larger than any opening;
- **teeth**: two pale strips 4 mm behind the lips, the upper one hidden by the upper lip, the lower one
  moving with the jaw.

Model mm, x right, y down, z away from the camera (nose tip nearest).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipeline.face.canonical import Surface
from pipeline.face.head_texture import HeadWindow

JAW = list(range(17))
UPPER_LIP = [49, 50, 51, 52, 53, 61, 62, 63]       # points on the upper side of the mouth cut
LOWER_LIP = [55, 56, 57, 58, 59, 65, 66, 67]       # ... on the lower side
INNER_LIP_OPENING = [60, 61, 62, 63, 64, 65, 66, 67]
STILL = [17, 18, 19, 20, 21, 22, 23, 24, 25, 26, 27, 28, 36, 37, 38, 39, 40, 41, 42, 43, 44, 45, 46, 47]  # brows, nose bridge, eyes
CAVITY_RGB, TEETH_RGB = (0.16, 0.04, 0.05), (0.93, 0.90, 0.82)
TEETH_DEPTH_MM = 5.0               #: the teeth sit this far behind the skin surface wherever they move
JAW_INSET_MM = 3.0                 #: the outline runs this far inside the tracked jaw contour's sides (mm)


@dataclass
class Part:
    """One rigid-topology piece: vertices (N, 3) mm, triangles (F, 3), and per-vertex texture coordinates or None."""

    vertices: np.ndarray
    triangles: np.ndarray
    uv: np.ndarray | None = None


@dataclass
class HeadMesh:
    """The skin (textured, cut at the mouth), the cavity and two teeth strips, at rest."""

    skin: Part
    side: np.ndarray               # (N,) skin vertex: -1 above the mouth cut, +1 below, 0 elsewhere
    cavity: Part
    upper_teeth: Part
    lower_teeth: Part
    slit: np.ndarray = field(repr=False)   # (S, 2) mm: the inner-lip line, corner to corner


def smooth_surface(surface: Surface, sigma_mm: float = 4.0) -> Surface:
    """The surface with its facets rounded off (Gaussian, ``sigma_mm``): f* is linear between the 68
    landmarks, whose creases a lit mesh shows as seams."""
    from scipy.ndimage import gaussian_filter
    return Surface(gaussian_filter(surface.depth, sigma_mm / surface.step, mode="nearest"), surface.x0, surface.y0,
                   surface.step)


def face_outline(landmarks_mm: np.ndarray, forehead_mm: float = 45.0, n_arc: int = 24,
                 inset_mm: float = JAW_INSET_MM) -> np.ndarray:
    """(17 + n_arc, 2) polygon (mm): the jaw contour 0 → 16, then an elliptic arc back over the forehead
    that rises ``forehead_mm`` above the brows.

    The jaw contour's sides are brought ``inset_mm`` towards the nose tip (fading to none at the chin, point 8):
    the tracked contour sits on the silhouette, where the texture holds background as much as skin.
    """
    jaw = landmarks_mm[JAW].astype(np.float64).copy()
    toward = landmarks_mm[30] - jaw
    toward /= np.maximum(np.linalg.norm(toward, axis=1, keepdims=True), 1e-9)
    jaw += inset_mm * np.minimum(1.0, np.abs(np.arange(17) - 8) / 4.0)[:, None] * toward
    c = (jaw[0] + jaw[16]) / 2
    a = np.linalg.norm(jaw[16] - jaw[0]) / 2
    b = c[1] - (landmarks_mm[17:27, 1].min() - forehead_mm)
    t = np.linspace(0, np.pi, n_arc + 2)[1:-1]
    arc = np.column_stack([c[0] + a * np.cos(t), c[1] - b * np.sin(t)])
    return np.concatenate([jaw, arc])


def mouth_slit(landmarks_mm: np.ndarray) -> np.ndarray:
    """(5, 2) mm: the inner-lip line — corner 60, the midpoints of 61/67, 62/66, 63/65, corner 64."""
    lm = landmarks_mm
    return np.array([lm[60], (lm[61] + lm[67]) / 2, (lm[62] + lm[66]) / 2, (lm[63] + lm[65]) / 2, lm[64]])


def inside(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Even–odd point-in-polygon test: (N, 2) points, (M, 2) polygon → (N,) bool."""
    x, y = points[:, 0, None], points[:, 1, None]
    x0, y0 = polygon[:, 0], polygon[:, 1]
    x1, y1 = np.roll(x0, -1), np.roll(y0, -1)
    crosses = ((y0 > y) != (y1 > y)) & (x < (x1 - x0) * (y - y0) / np.where(y1 != y0, y1 - y0, 1e-12) + x0)
    return crosses.sum(1) % 2 == 1


def _grid_part(surface: Surface, xs: np.ndarray, ys: np.ndarray, depth_behind=0.0) -> Part:
    """A plain triangulated grid on the surface, pushed ``depth_behind`` mm (scalar or (len(ys), len(xs))) back."""
    gx, gy = np.meshgrid(xs, ys)
    z = surface.z(gx, gy) + depth_behind
    w = len(xs)
    r, c = np.meshgrid(np.arange(len(ys) - 1), np.arange(w - 1), indexing="ij")
    a = (r * w + c).ravel()
    tris = np.concatenate([np.column_stack([a, a + w, a + 1]), np.column_stack([a + 1, a + w, a + w + 1])])
    return Part(np.column_stack([gx.ravel(), gy.ravel(), z.ravel()]), tris)


def head_mesh(surface: Surface, window: HeadWindow, landmarks_mm: np.ndarray, step_mm: float = 2.0) -> HeadMesh:
    """The rest head of a speaker.

    Parameters
    ----------
    surface : Surface
        The extended face surface f* (mm).
    window : HeadWindow
        The head texture's window.
    landmarks_mm : ndarray
        (68, 2) the head texture's landmarks (mm; mouth shut).
    step_mm : float
        Grid spacing (mm); 2 mm gives about 6,000 skin vertices on an adult face.
    """
    outline = face_outline(landmarks_mm)
    slit = mouth_slit(landmarks_mm)
    x0 = np.floor(outline[:, 0].min() / step_mm) * step_mm
    y0 = np.floor(outline[:, 1].min() / step_mm) * step_mm
    xs = np.arange(x0, outline[:, 0].max() + step_mm, step_mm)
    ys = np.arange(y0, outline[:, 1].max() + step_mm, step_mm)
    W, H = len(xs), len(ys)
    gx, gy = np.meshgrid(xs, ys)
    gx, gy = gx.copy(), gy.copy()
    # the cut: in the columns spanning the mouth, the row nearest the inner-lip line, 1 row per column at most
    cols = np.flatnonzero((xs >= slit[0, 0] - step_mm / 2) & (xs <= slit[-1, 0] + step_mm / 2))
    k = np.full(W, -1)
    for c in cols:
        want = int(round((np.interp(xs[c], slit[:, 0], slit[:, 1]) - y0) / step_mm))
        k[c] = want if c == cols[0] else int(np.clip(want, k[c - 1] - 1, k[c - 1] + 1))
        gy[k[c], c] = np.interp(np.clip(xs[c], slit[0, 0], slit[-1, 0]), slit[:, 0], slit[:, 1])
    gx[k[cols[0]], cols[0]], gy[k[cols[0]], cols[0]] = slit[0]       # the corners are shared by both lips
    gx[k[cols[-1]], cols[-1]], gy[k[cols[-1]], cols[-1]] = slit[-1]
    verts = np.column_stack([gx.ravel(), gy.ravel()])
    # cells → triangles; where the cut steps down to the right it follows the other diagonal
    tris = []
    for r in range(H - 1):
        for c in range(W - 1):
            a = r * W + c
            if k[c] >= 0 and k[c + 1] == k[c] + 1 and r == k[c]:
                tris += [(a, a + W + 1, a + 1), (a, a + W, a + W + 1)]
            else:
                tris += [(a, a + W, a + 1), (a + 1, a + W, a + W + 1)]
    tris = np.array(tris, np.int64)
    keep = inside(verts, outline)[tris].all(1)
    tris = tris[keep]
    # split the cut's inner vertices: triangles with a vertex below the cut take the lower copies
    row, col = np.divmod(np.arange(H * W), W)
    cut = [k[c] * W + c for c in cols[1:-1]]
    below_v = (k[col] >= 0) & (row > k[col])
    above_v = (k[col] >= 0) & (row < k[col])
    remap = np.arange(H * W)
    remap[cut] = H * W + np.arange(len(cut))
    below_t = below_v[tris].any(1)
    tris[below_t] = remap[tris[below_t]]
    verts = np.concatenate([verts, verts[cut]])
    side = np.concatenate([np.where(above_v, -1, np.where(below_v, 1, 0)), np.ones(len(cut), int)])
    side[cut] = -1
    # drop vertices no triangle uses
    used = np.zeros(len(verts), bool)
    used[tris.ravel()] = True
    new = np.cumsum(used) - 1
    verts, side, tris = verts[used], side[used], new[tris]
    verts = _snap_border(verts, tris, outline, slit, step_mm)
    skin = Part(np.column_stack([verts, surface.z(verts[:, 0], verts[:, 1])]), tris, window.to_uv(verts))
    # the cavity: a bowl behind the mouth, 8 mm deep at its rim, 22 mm at its centre
    mw = slit[-1, 0] - slit[0, 0]
    cx, cy = slit[:, 0].mean(), slit[2, 1]
    cxs = np.linspace(slit[0, 0] - 4, slit[-1, 0] + 4, 25)
    cys = np.linspace(cy - 12, cy + 30, 25)
    bx, by = np.meshgrid(cxs, cys)
    bowl = 8 + 14 * np.clip(1 - ((bx - cx) / (mw / 2 + 4)) ** 2 - ((by - cy - 9) / 21) ** 2, 0, 1)
    cavity = _grid_part(surface, cxs, cys, bowl)
    # the teeth: strips TEETH_DEPTH_MM behind the skin, 0.6 of the mouth wide; the upper ones reach
    # 1.5 mm below the line of the shut lips (they show once the mouth opens), the lower ones start 1 mm under it
    txs = np.linspace(cx - 0.3 * mw, cx + 0.3 * mw, 13)
    upper = _grid_part(surface, txs, np.linspace(cy - 10, cy + 1.5, 5), TEETH_DEPTH_MM)
    lower = _grid_part(surface, txs, np.linspace(cy + 1.0, cy + 10, 5), TEETH_DEPTH_MM)
    return HeadMesh(skin, side, cavity, upper, lower, slit)


def _snap_border(verts: np.ndarray, tris: np.ndarray, outline: np.ndarray, slit: np.ndarray, step: float) -> np.ndarray:
    """Move the mesh's outer border vertices onto the outline polygon (a smooth silhouette, not grid stairs);
    the mouth cut's vertices stay."""
    edges = np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1)
    e, n = np.unique(edges, axis=0, return_counts=True)
    border = np.unique(e[n == 1])
    border = border[_distance_to_polyline(verts[border], slit) > step]
    a, b = outline, np.roll(outline, -1, axis=0)                       # the closed outline's segments
    p = verts[border][:, None]
    t = np.clip(((p - a) * (b - a)).sum(-1) / np.maximum(((b - a) ** 2).sum(-1), 1e-12), 0, 1)
    q = a + t[..., None] * (b - a)                                     # (B, M, 2) nearest point per segment
    best = np.argmin(((q - p) ** 2).sum(-1), axis=1)
    out = verts.copy()
    out[border] = q[np.arange(len(border)), best]
    return out


def _distance_to_polyline(points: np.ndarray, line: np.ndarray) -> np.ndarray:
    a, b = line[:-1], line[1:]
    p = points[:, None]
    t = np.clip(((p - a) * (b - a)).sum(-1) / np.maximum(((b - a) ** 2).sum(-1), 1e-12), 0, 1)
    return np.sqrt((((a + t[..., None] * (b - a)) - p) ** 2).sum(-1)).min(1)


def handle_vertices(mesh: HeadMesh, points_mm: np.ndarray, point_ids) -> np.ndarray:
    """(P,) the skin vertex that carries each driving point: the nearest one on the point's side of the cut.

    points_mm : (P, 2) rest positions; point_ids : their 68-point indices (upper-lip points take a vertex
    above the cut, lower-lip points one below).
    """
    xy = mesh.skin.vertices[:, :2]
    out = np.empty(len(point_ids), np.int64)
    for i, (p, pid) in enumerate(zip(points_mm, point_ids)):
        d = np.linalg.norm(xy - p, axis=1)
        if pid in UPPER_LIP:
            d[mesh.side > 0] = np.inf
        elif pid in LOWER_LIP:
            d[mesh.side < 0] = np.inf
        out[i] = int(np.argmin(d))
    return out


def anchor_vertices(mesh: HeadMesh, landmarks_mm: np.ndarray, driven_ids) -> np.ndarray:
    """Skin vertices held still: those nearest the brows, eyes and nose bridge that are not driven, and the
    upper outline (above the eyes' line)."""
    xy = mesh.skin.vertices[:, :2]
    ids = [i for i in STILL if i not in set(driven_ids)]
    nearest = [int(np.argmin(np.linalg.norm(xy - landmarks_mm[i], axis=1))) for i in ids]
    t = mesh.skin.triangles
    edges = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    e, n = np.unique(edges, axis=0, return_counts=True)
    border = np.unique(e[n == 1])
    top = border[xy[border, 1] < landmarks_mm[[36, 45], 1].mean()]
    return np.unique(np.concatenate([np.array(nearest, np.int64), top]))
