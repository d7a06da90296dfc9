"""The animated face mesh (``pipeline.face.face_mesh``): surface grid, thin-plate deformation, colours, EGL render."""
import numpy as np
import pytest

from pipeline.face import face_mesh as fm
from pipeline.face.canonical import Surface

X, Y = (-60.0, 60.0), (0.0, 120.0)


def dome():
    """A smooth surface: z = (x² + y²) / 400 mm on a 2 mm grid."""
    xs, ys = np.arange(-110, 111, 2.0), np.arange(-80, 221, 2.0)
    gx, gy = np.meshgrid(xs, ys)
    return Surface((gx ** 2 + (gy - 60) ** 2) / 400.0, -110.0, -80.0, 2.0)


def lips(open_mm: float) -> np.ndarray:
    """18 lip points (mm) around (0, 70) in dlib order: outer 12 on an ellipse from the left corner over
    the upper lip, inner 6 (61–63 left to right, 65–67 right to left) opening by ``open_mm``."""
    a = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    outer = np.column_stack([-25 * np.cos(a), 70 - (8 + open_mm / 2) * np.sin(a)])
    inner = np.array([[-10, 70 - open_mm / 2], [0, 70 - open_mm / 2], [10, 70 - open_mm / 2],
                      [10, 70 + open_mm / 2], [0, 70 + open_mm / 2], [-10, 70 + open_mm / 2]], float)
    return np.concatenate([outer, inner])


def test_mesh_is_a_triangulated_grid_on_the_surface():
    s = dome()
    v, t = fm.lower_face_mesh(s, X, Y, 3.0)
    assert v.shape == (41 * 41, 3) and t.shape == (2 * 40 * 40, 3)
    assert np.allclose(v[:, 2], (v[:, 0] ** 2 + (v[:, 1] - 60) ** 2) / 400.0, atol=0.05)
    assert t.min() == 0 and t.max() == len(v) - 1
    a, b = v[t[:, 1], :2] - v[t[:, 0], :2], v[t[:, 2], :2] - v[t[:, 0], :2]
    area = 0.5 * np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    assert np.allclose(area, 4.5)                  # every triangle is half a 3 mm cell: no gaps, no overlaps


def test_deformation_moves_the_lips_keeps_anchors_and_stays_on_the_surface():
    s = dome()
    v, _ = fm.lower_face_mesh(s, X, Y, 3.0)
    rest, moved = lips(1.0), np.stack([lips(1.0), lips(12.0)])
    anchors = fm.border_anchors(X, Y)
    P = fm.animate(v, s, rest, moved, anchors)
    assert np.allclose(P[0], v, atol=1e-6)                           # no displacement → the rest mesh
    below = np.argmin(np.linalg.norm(v[:, :2] - [0, 76], axis=1))    # skin just under the lower lip moves down
    above = np.argmin(np.linalg.norm(v[:, :2] - [0, 64], axis=1))    # ... and above the upper lip moves up
    assert P[1, below, 1] - v[below, 1] > 2 and P[1, above, 1] - v[above, 1] < -2
    corner = np.argmin(np.linalg.norm(v[:, :2] - [X[0], Y[0]], axis=1))
    assert np.linalg.norm(P[1, corner] - v[corner]) < 1e-3            # border anchors hold
    z = (P[1, :, 0] ** 2 + (P[1, :, 1] - 60) ** 2) / 400.0
    assert np.allclose(P[1, :, 2], z, atol=0.05)                     # depth from the surface


def test_colours_mark_lips_and_mouth_opening():
    pts = np.array([[0.0, 70.0, 0.0], [0.0, 62.0, 0.0], [0.0, 20.0, 0.0]])
    c = fm.vertex_colours(pts, lips(6.0))
    assert tuple(c[0]) == fm.MOUTH and tuple(c[1]) == fm.LIP and tuple(c[2]) == fm.SKIN
    assert tuple(fm.vertex_colours(pts, lips(0.0))[0]) != fm.MOUTH    # a closed mouth shows no opening


def test_coincident_driving_points_do_not_break_the_spline():
    s = dome()
    v, _ = fm.lower_face_mesh(s, X, Y, 3.0)
    P = fm.animate(v, s, lips(0.0), lips(12.0)[None], fm.border_anchors(X, Y))   # closed rest: inner points coincide
    assert np.isfinite(P).all() and np.abs(P[0] - v).max() < 20


def test_offscreen_render_shows_an_open_mouth(monkeypatch):
    pytest.importorskip("pyvista")
    monkeypatch.setenv("OFF_SCREEN", "True")
    s = dome()
    v, t = fm.lower_face_mesh(s, X, Y, 1.5)
    r = fm.MeshRenderer(v, t, 120)
    try:
        shut = r.render(v, lips(3.0))
        P = fm.animate(v, s, lips(3.0), lips(12.0)[None], fm.border_anchors(X, Y))[0]
        open_ = r.render(P, lips(12.0))
    finally:
        r.close()
    assert shut.shape == (120, 240, 3) and shut[20:100, 10:110].mean() > 80      # the face is drawn, lit
    mouth = lambda img: float(img[62:80, 45:75].sum(-1).mean())                # the mouth's middle, front view
    assert mouth(open_) < 0.6 * mouth(shut)
