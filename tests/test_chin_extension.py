"""Eq. 7–8 solver on analytic surfaces."""
import numpy as np

from stages.frontalize.chin_extension import extend_depth, face_depth_on_grid


def grid(h=90, w=70):
    y, x = np.mgrid[0:h, 0:w].astype(float)
    return x, y


def test_fills_hole_of_surface_with_zero_boundary_gradient():
    x, y = grid()
    h, w = x.shape
    f = 10 * np.cos(np.pi * x / (w - 1)) * np.cos(np.pi * y / (h - 1))   # ∇f = 0 on the boundary
    hole = (x - 35) ** 2 + (y - 45) ** 2 < 12 ** 2
    g = extend_depth(f, ~hole)
    assert np.abs(g - f)[hole].max() < 0.01 * 10          # the hole is recovered to 1 % of the amplitude
    assert np.abs(g - f)[~hole].max() < 0.01


def test_extension_is_flat_at_the_border_and_smooth():
    x, y = grid()
    f = 30 - 0.02 * ((x - 35) ** 2 + (y - 40) ** 2)       # a dome known only in the centre
    known = (x - 35) ** 2 + (y - 40) ** 2 < 15 ** 2
    g = extend_depth(f, known)
    np.testing.assert_allclose(g[known], f[known], atol=0.05)
    gy, gx = np.gradient(g)
    border_slope = np.r_[np.abs(gx[:, 0]), np.abs(gx[:, -1]), np.abs(gy[0]), np.abs(gy[-1])]
    inner_slope = np.hypot(gx, gy)[known].max()
    assert border_slope.max() < 0.1 * inner_slope
    assert np.all(np.isfinite(g))
    # the extension continues the dome downward (it does not jump back up to the face level)
    assert g[0, 0] < f[known].min()


def test_constant_stays_constant():
    x, _ = grid()
    known = np.zeros_like(x, bool)
    known[30:50, 20:40] = True
    g = extend_depth(np.full(x.shape, 7.0), known)
    np.testing.assert_allclose(g, 7.0, atol=1e-6)


def test_face_depth_interpolates_inside_hull_only():
    pts = np.array([[0, 0, 1.0], [10, 0, 2.0], [0, 10, 3.0], [10, 10, 4.0]] + [[5, 5, 2.5]] * 64)
    d, known = face_depth_on_grid(pts, np.arange(-2, 13.0), np.arange(-2, 13.0))
    assert known[2:13, 2:13].all() and not known[0].any()
    assert abs(d[2 + 5, 2 + 5] - 2.5) < 1e-9
