"""The animated 3D head (the product of paper 001 §5): the speaker's dense textured head mesh
(``pipeline.face.head_mesh``) moved per frame by predicted landmarks, rendered off screen with pyvista.

Motion: each driving point (Karras: jaw, nose, lips — 42 points; other families: the 18 lip points)
moves its handle vertex by (predicted − rest) in the canonical plane; a pre-factorised bi-Laplacian
solve (``pipeline.face.bilaplacian``) spreads that smoothly over the skin and holds the brows, eyes,
nose bridge and forehead outline still; a moved vertex takes the surface depth at its new (x, y)
("depth from the surface"). The upper teeth follow the upper inner lip, the lower teeth the jaw; while
the predicted inner lips touch (gap below ``TEETH_SHUT_MM``) both rows sink ``TEETH_HIDDEN_MM`` deeper,
behind the mouth cavity, so the sliver between the lips shows the dark cavity and not a pale line of
teeth; they come forward as the lips part (fully at ``TEETH_OPEN_MM``).

Rendering needs an off-screen OpenGL: EGL (Mesa) with ``OFF_SCREEN=True`` and
``VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow`` (set here before pyvista is imported). Normals are
recomputed every frame (smooth shading), the skin is textured with the head texture (linear
interpolation), two lights. The three-quarter view's copy of the texture has its fine detail faded where
that view squeezes the far cheek (``head_texture.turned_view_texture``: a frontal smile line there would
show as a hard dark fold beside the nose); the front view's is the texture itself.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from pipeline.face.bilaplacian import BiLaplacian
from pipeline.face.canonical import Surface
from pipeline.face.head_mesh import TEETH_DEPTH_MM, HeadMesh, anchor_vertices, handle_vertices
from pipeline.face.head_texture import turned_view_texture

CHIN = 8
TEETH_SHUT_MM, TEETH_OPEN_MM = 1.5, 3.0    #: inner-lip gap (mm): teeth hidden below the first, shown from the second
TEETH_HIDDEN_MM = 25.0                     #: how much deeper hidden teeth sit (mm; the cavity is 8–22 mm deep)


@dataclass
class HeadMotion:
    """Per-frame positions of every part (mm): skin (T, N, 3), upper_teeth (T, Nu, 3), lower_teeth (T, Nl, 3),
    in the head's own frame; the whole head turns by ``rotation`` (T, 3, 3) about ``pivot`` (3,) mm (None: still)."""

    skin: np.ndarray
    upper_teeth: np.ndarray
    lower_teeth: np.ndarray
    rotation: np.ndarray | None = None
    pivot: np.ndarray | None = None

    def posed(self, points: np.ndarray, t=None) -> np.ndarray:
        """Points in the head's frame → turned with the head: (N, 3) at frame ``t``, or (T, N, 3) at all frames."""
        if self.rotation is None:
            return points
        r = self.rotation if t is None else self.rotation[t]
        sub = "tij,tnj->tni" if t is None else "ij,nj->ni"
        return np.einsum(sub, r, points - self.pivot) + self.pivot


def with_footage(motion: HeadMotion, mesh: HeadMesh, surface: Surface, landmarks_mm: np.ndarray,
                 closure: np.ndarray | None = None, rotation: np.ndarray | None = None) -> HeadMotion:
    """``motion`` with blinks (``closure`` (T,) in [0, 1]) and a turning head (``rotation`` (T, 3, 3)).

    Parameters
    ----------
    motion : HeadMotion
        The speaking head (``animate``).
    mesh : HeadMesh
        The rest head.
    surface : Surface
        The face surface (depth of moved skin vertices).
    landmarks_mm : ndarray
        (68, 2) the rest landmarks (mm).
    closure, rotation : ndarray or None
        From ``pipeline.face.head_motion.footage_tracks``; None leaves the eyes open / the head still.
    """
    from pipeline.face.head_motion import blink_offsets, pivot
    skin = motion.skin
    if closure is not None:
        xy = skin[..., :2].copy()
        xy[..., 1] += np.asarray(closure)[:, None] * blink_offsets(mesh.skin.vertices[:, :2], landmarks_mm)[None]
        skin = np.concatenate([xy, surface.z(xy[..., 0], xy[..., 1])[..., None]], axis=-1)
    piv = None if rotation is None else pivot(landmarks_mm, float(surface.z(*landmarks_mm[30])))
    return HeadMotion(skin, motion.upper_teeth, motion.lower_teeth, rotation, piv)


def animate(mesh: HeadMesh, surface: Surface, head_landmarks: np.ndarray, point_ids, moved: np.ndarray,
            deformer: BiLaplacian | None = None) -> HeadMotion:
    """Move the rest head by predicted points.

    Parameters
    ----------
    mesh : HeadMesh
        The rest head.
    surface : Surface
        The extended face surface f* (mm); the skin's depth follows it.
    head_landmarks : ndarray
        (68, 2) mm, the rest positions of all points (mouth shut).
    point_ids : sequence of int
        (P,) 68-point indices of the driving points.
    moved : ndarray
        (T, P, 2) their predicted positions (mm).
    deformer : BiLaplacian, optional
        Built by ``deformer_for`` (built here when None).

    Returns
    -------
    HeadMotion
        Every part's vertices per frame (mm).
    """
    ids = [int(i) for i in point_ids]
    deformer = deformer or deformer_for(mesh, head_landmarks, ids)
    d = np.asarray(moved, np.float64) - head_landmarks[ids][None]                 # (T, P, 2)
    xy = mesh.skin.vertices[None, :, :2] + deformer(d)
    z = surface.z(xy[..., 0], xy[..., 1])[..., None]
    upper = d[:, [ids.index(i) for i in (61, 62, 63)]].mean(1)
    lower = d[:, ids.index(CHIN)] if CHIN in ids else 0.7 * d[:, [ids.index(i) for i in (65, 66, 67)]].mean(1)

    depth = TEETH_DEPTH_MM + TEETH_HIDDEN_MM * teeth_hidden(ids, np.asarray(moved, np.float64))[:, None]

    def teeth(part, offset):        # carried by the offset, TEETH_DEPTH_MM behind the skin there (deeper when hidden)
        txy = part.vertices[None, :, :2] + offset[:, None]
        return np.concatenate([txy, (surface.z(txy[..., 0], txy[..., 1]) + depth)[..., None]], axis=-1)

    return HeadMotion(np.concatenate([xy, z], axis=-1), teeth(mesh.upper_teeth, upper), teeth(mesh.lower_teeth, lower))


def teeth_hidden(point_ids, moved: np.ndarray) -> np.ndarray:
    """(T,) in [0, 1]: how hidden the teeth are — 1 while the predicted inner lips touch, 0 once they part.

    Parameters
    ----------
    point_ids : list of int
        (P,) 68-point indices of the driving points (the inner lips 61–63 and 65–67 among them).
    moved : ndarray
        (T, P, 2) their predicted positions (mm, y down).

    Returns
    -------
    ndarray
        (T,) 1 for a gap ≤ ``TEETH_SHUT_MM``, 0 for ≥ ``TEETH_OPEN_MM``, linear between; the gap is the mean
        vertical distance of the inner-lip pairs 61/67, 62/66, 63/65. Without the lower inner lip: zeros.
    """
    ids = [int(i) for i in point_ids]
    if not all(i in ids for i in (61, 62, 63, 65, 66, 67)):
        return np.zeros(len(moved))
    up, lo = [ids.index(i) for i in (61, 62, 63)], [ids.index(i) for i in (67, 66, 65)]
    gap = (moved[:, lo, 1] - moved[:, up, 1]).mean(1)
    return np.clip((TEETH_OPEN_MM - gap) / (TEETH_OPEN_MM - TEETH_SHUT_MM), 0.0, 1.0)


def deformer_for(mesh: HeadMesh, head_landmarks: np.ndarray, point_ids) -> BiLaplacian:
    """The factorised bi-Laplacian for driving points ``point_ids`` (handles on their side of the mouth cut)."""
    ids = [int(i) for i in point_ids]
    handles = handle_vertices(mesh, head_landmarks[ids], ids)
    anchors = np.setdiff1d(anchor_vertices(mesh, head_landmarks, ids), handles)
    return BiLaplacian(len(mesh.skin.vertices), mesh.skin.triangles, handles, anchors)


class HeadRenderer:
    """Front and three-quarter views of the head side by side; ``render(motion, t)`` → (size, 2·size, 3) uint8."""

    def __init__(self, mesh: HeadMesh, texture: np.ndarray, size: int = 512, yaw_deg: float = 35.0):
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
        import pyvista as pv
        pv.OFF_SCREEN = True
        from pipeline.face.head_mesh import CAVITY_RGB, TEETH_RGB

        def poly(part):
            faces = np.column_stack([np.full(len(part.triangles), 3), part.triangles]).ravel()
            m = pv.PolyData(part.vertices.astype(np.float64), faces)
            if part.uv is not None:
                m.active_texture_coordinates = part.uv.astype(np.float32)
            return m.compute_normals(split_vertices=False, consistent_normals=False, auto_orient_normals=False)

        self.skin, self.cavity = poly(mesh.skin), poly(mesh.cavity)
        self.cavity_rest = mesh.cavity.vertices.astype(np.float64)
        self.upper, self.lower = poly(mesh.upper_teeth), poly(mesh.lower_teeth)
        def pv_texture(image):
            t = pv.Texture(np.ascontiguousarray(image))       # pyvista puts image row 0 at v = 1
            t.interpolate = True
            return t

        skin = mesh.skin                   # the turned view's texture: detail faded where it squeezes the far cheek
        textures = (pv_texture(texture), pv_texture(turned_view_texture(texture, skin.vertices, skin.triangles,
                                                                        skin.uv, yaw_deg)))
        self.plotter = pv.Plotter(off_screen=True, shape=(1, 2), window_size=(2 * size, size), border=False,
                                  lighting="none")
        # no anti-aliasing: on a software OpenGL (llvmpipe, no GPU) pyvista's default 8× MSAA costs ~3× the
        # render and FXAA ~3.5× (measured at 512 px: none 31 ms, MSAA-2 66, FXAA 114), for edges that differ
        # by a pixel's shade at full size
        self.plotter.disable_anti_aliasing()
        v = mesh.skin.vertices
        centre = np.array([v[:, 0].mean(), v[:, 1].mean(), np.median(v[:, 2])])
        dist = 3.3 * np.ptp(v[:, 1])
        for col, yaw in enumerate((0.0, yaw_deg)):
            self.plotter.subplot(0, col)
            self.plotter.set_background("black")
            self.plotter.add_mesh(self.skin, texture=textures[col], smooth_shading=True, ambient=0.25, diffuse=0.8,
                                  specular=0.08, specular_power=12)
            self.plotter.add_mesh(self.cavity, color=CAVITY_RGB, smooth_shading=True, ambient=0.3, diffuse=0.6)
            for teeth in (self.upper, self.lower):
                self.plotter.add_mesh(teeth, color=TEETH_RGB, smooth_shading=True, ambient=0.45, diffuse=0.6,
                                      specular=0.15)
            a = np.radians(yaw)
            eye = centre + dist * np.array([np.sin(a), 0.0, -np.cos(a)])      # the camera looks along +z
            self.plotter.camera_position = [tuple(eye), tuple(centre), (0.0, -1.0, 0.0)]
            self.plotter.camera.view_angle = 22.0
        for position, intensity in (([-250.0, -300.0, -600.0], 0.75), ([350.0, -50.0, -400.0], 0.35)):   # key, fill
            self.plotter.add_light(pv.Light(position=tuple(centre + position), focal_point=tuple(centre),
                                            intensity=intensity))

    def render(self, motion: HeadMotion, t: int) -> np.ndarray:
        """Frame ``t`` of ``motion``: (size, 2·size, 3) uint8 RGB."""
        self.skin.points = motion.posed(motion.skin[t], t)
        self.upper.points = motion.posed(motion.upper_teeth[t], t)
        self.lower.points = motion.posed(motion.lower_teeth[t], t)
        turned = motion.rotation is not None
        if turned:
            self.cavity.points = motion.posed(self.cavity_rest, t)
        for m in (self.skin, self.upper, self.lower) + ((self.cavity,) if turned else ()):
            m.compute_normals(inplace=True, split_vertices=False, consistent_normals=False, auto_orient_normals=False)
        self.plotter.render()
        return np.asarray(self.plotter.screenshot(return_img=True))[..., :3]

    def close(self) -> None:
        self.plotter.close()
