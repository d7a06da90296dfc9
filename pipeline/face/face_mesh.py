"""An animated 3D face from predicted landmarks (the product of paper 001 §5): the speaker's lower-face
mesh, deformed per frame by landmark displacements, rendered off screen with pyvista.

Mesh: the extended face surface f*(x, y) of the frontalize stage (Eqs. 7–8 of paper 000, a depth
map on the canonical grid; model mm, x right, y down, z away from the camera — the nose tip is
at z ≈ −29 mm) sampled every ``step_mm`` over the lower face → a regular triangulated grid of a
few thousand vertices.

Motion: the predicted points (e.g. the 18 lip points, in canonical texture px → mm) minus their
rest positions are spread over the mesh by a thin-plate spline (``scipy.interpolate.RBFInterpolator``)
that also holds fixed anchors (eyes, nose bridge and a ring at the mesh border) still; a displaced
vertex takes the surface depth at its new (x, y) — "depth from the surface".

Rendering needs an off-screen OpenGL: EGL (Mesa) with ``OFF_SCREEN=True`` and
``VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow`` (set here before pyvista is imported).
"""
from __future__ import annotations

import os

import numpy as np
from scipy.interpolate import RBFInterpolator

from pipeline.face.canonical import Surface

ANCHOR_LANDMARKS = (27, 28, 36, 39, 42, 45)      # nose bridge and eye corners: they do not move with speech
# the 18 lip points (pipeline.face.dlib_face.LIP_POINTS order: outer 48–59, inner 61–63, 65–67) as polygons
OUTER_LIP = list(range(12))
INNER_LIP = [0, 12, 13, 14, 6, 15, 16, 17]        # 48 (corner), 61, 62, 63, 54 (corner), 65, 66, 67
SKIN, LIP, MOUTH = (0.86, 0.70, 0.60), (0.75, 0.42, 0.42), (0.12, 0.03, 0.03)


def lower_face_mesh(surface: Surface, x_mm=(-75.0, 75.0), y_mm=(-10.0, 170.0), step_mm: float = 3.0):
    """Regular grid over the lower face on the surface → vertices (N, 3) mm and triangles (F, 3)."""
    xs = np.arange(x_mm[0], x_mm[1] + 1e-9, step_mm)
    ys = np.arange(y_mm[0], y_mm[1] + 1e-9, step_mm)
    gx, gy = np.meshgrid(xs, ys)
    verts = np.column_stack([gx.ravel(), gy.ravel(), surface.z(gx, gy).ravel()])
    w = len(xs)
    r, c = np.meshgrid(np.arange(len(ys) - 1), np.arange(w - 1), indexing="ij")
    a = (r * w + c).ravel()
    tris = np.concatenate([np.column_stack([a, a + 1, a + w]), np.column_stack([a + 1, a + w + 1, a + w])])
    return verts, tris


def border_anchors(x_mm, y_mm, n: int = 12) -> np.ndarray:
    """(4n, 2) points on the mesh border (mm): the deformation fades to zero there."""
    t = np.linspace(0, 1, n, endpoint=False)
    (x0, x1), (y0, y1) = x_mm, y_mm
    return np.concatenate([np.column_stack([x0 + t * (x1 - x0), np.full(n, y0)]),
                           np.column_stack([np.full(n, x1), y0 + t * (y1 - y0)]),
                           np.column_stack([x1 - t * (x1 - x0), np.full(n, y1)]),
                           np.column_stack([np.full(n, x0), y1 - t * (y1 - y0)])])


def animate(vertices: np.ndarray, surface: Surface, rest: np.ndarray, moved: np.ndarray, anchors: np.ndarray,
            smoothing: float = 1e-3) -> np.ndarray:
    """Per-frame vertex positions (T, N, 3).

    Parameters
    ----------
    vertices : (N, 3) rest mesh (mm); rest : (P, 2) rest positions of the driving points (mm);
    moved : (T, P, 2) their positions per frame (mm); anchors : (A, 2) points held still (mm).
    smoothing : the spline's regularisation (mm²-scale); > 0 keeps it solvable when driving points
        coincide (the inner lips of a closed rest mouth).
    """
    T, P = moved.shape[:2]
    src = np.concatenate([rest, anchors])
    disp = np.zeros((len(src), T * 2))
    disp[:P] = (moved - rest[None]).transpose(1, 0, 2).reshape(P, T * 2)
    tps = RBFInterpolator(src, disp, kernel="thin_plate_spline", smoothing=smoothing)
    d = tps(vertices[:, :2]).reshape(len(vertices), T, 2).transpose(1, 0, 2)        # (T, N, 2)
    xy = vertices[None, :, :2] + d
    return np.concatenate([xy, surface.z(xy[..., 0], xy[..., 1])[..., None]], axis=-1)


def inside(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Even–odd point-in-polygon test: (N, 2) points, (M, 2) polygon → (N,) bool."""
    x, y = points[:, 0, None], points[:, 1, None]
    x0, y0 = polygon[:, 0], polygon[:, 1]
    x1, y1 = np.roll(x0, -1), np.roll(y0, -1)
    crosses = ((y0 > y) != (y1 > y)) & (x < (x1 - x0) * (y - y0) / np.where(y1 != y0, y1 - y0, 1e-12) + x0)
    return crosses.sum(1) % 2 == 1


def vertex_colours(points: np.ndarray, lips_mm: np.ndarray) -> np.ndarray:
    """(N, 3) RGB in [0, 1] for one frame: mouth opening (inside the inner lip) dark, lips red, skin."""
    xy = points[:, :2]
    out = np.tile(np.array(SKIN), (len(points), 1))
    out[inside(xy, lips_mm[OUTER_LIP])] = LIP
    out[inside(xy, lips_mm[INNER_LIP])] = MOUTH
    return out


class MeshRenderer:
    """Front and three-quarter views of one mesh side by side; ``render(points)`` → (H, 2W, 3) uint8."""

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray, size: int = 360, yaw_deg: float = 35.0):
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
        import pyvista as pv
        pv.OFF_SCREEN = True
        faces = np.column_stack([np.full(len(triangles), 3), triangles]).ravel()
        self.mesh = pv.PolyData(vertices.astype(np.float64), faces)
        self.mesh.point_data["colour"] = np.tile((255 * np.array(SKIN)).astype(np.uint8), (len(vertices), 1))
        self.plotter = pv.Plotter(off_screen=True, shape=(1, 2), window_size=(2 * size, size), border=False)
        centre = vertices.mean(0)
        dist = 1.9 * np.ptp(vertices[:, 1])
        for col, yaw in enumerate((0.0, yaw_deg)):
            self.plotter.subplot(0, col)
            self.plotter.set_background("black")
            self.plotter.add_mesh(self.mesh, scalars="colour", rgb=True, smooth_shading=True, specular=0.2)
            a = np.radians(yaw)
            eye = centre + dist * np.array([np.sin(a), 0.0, -np.cos(a)])      # the camera looks along +z
            self.plotter.camera_position = [tuple(eye), tuple(centre), (0.0, -1.0, 0.0)]
        self.rest = vertices.copy()

    def render(self, points: np.ndarray, lips_mm: np.ndarray | None = None) -> np.ndarray:
        """One frame: mesh vertices (N, 3) mm, and the 18 lip points (mm) to colour lips and mouth."""
        self.mesh.points = points
        if lips_mm is not None:
            self.mesh.point_data["colour"] = (255 * vertex_colours(points, lips_mm)).astype(np.uint8)
        self.mesh.compute_normals(inplace=True)
        self.plotter.render()
        return np.asarray(self.plotter.screenshot(return_img=True))[..., :3]

    def close(self) -> None:
        self.plotter.close()
