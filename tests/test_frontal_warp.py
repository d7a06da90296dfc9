"""Frontal warp: a face rendered at a known pose, frontalized, matches the frontal render."""
import numpy as np
import pytest
import skimage.data

from pipeline.face.geometry import intrinsics, project
from stages.frontalize.chin_extension import extend_depth, face_depth_on_grid
from pipeline.face.canonical import Surface, TextureWindow, frontal_landmarks
from stages.frontalize.warp import frontal_texture
from tests.helpers.splat import render


@pytest.fixture(scope="module")
def scene(face3d):
    step = 2.0
    xs, ys = np.arange(-110, 111, step), np.arange(-80, 221, step)
    d, known = face_depth_on_grid(face3d, xs, ys)
    surface = Surface(extend_depth(np.nan_to_num(d), known), xs[0], ys[0], step)
    photo = skimage.data.astronaut()[40:340, 100:320]       # any real texture, 1 px per mm
    return surface, photo


def test_frontal_warp_undoes_pose(scene, face3d):
    surface, photo = scene
    K = intrinsics(320, 400, 1.5)
    win = TextureWindow(-60.0, 20.0, 1.0, 120)
    points = win.grid_points(surface)
    t = np.array([0.0, -40.0, 650.0])
    frontal = frontal_texture(render(surface, photo, np.zeros(3), t, K), points, np.zeros(3), t, K).astype(float)
    rvec = np.radians([8.0, -12.0, 5.0])                    # pitch, yaw, roll
    turned = render(surface, photo, rvec, t, K)
    corrected = frontal_texture(turned, points, rvec, t, K).astype(float)
    naive = frontal_texture(turned, points, np.zeros(3), t, K).astype(float)
    err, err_naive = np.abs(corrected - frontal).mean(), np.abs(naive - frontal).mean()
    assert err < 6.0, err
    assert err < 0.3 * err_naive, (err, err_naive)


def test_frontal_landmarks_invert_projection(scene, face3d):
    surface, _ = scene
    K = intrinsics(320, 400, 1.5)
    rvec, tvec = np.radians([5.0, 15.0, -4.0]), np.array([5.0, -30.0, 700.0])
    xy = face3d[:, :2]
    on_surface = np.column_stack([xy, surface.z(xy[:, 0], xy[:, 1])])
    pixels = project(on_surface, rvec, tvec, K)
    back = frontal_landmarks(pixels, xy + 3.0, surface, rvec, tvec, K)
    err = np.linalg.norm(back - xy, axis=1)
    assert err[27:].max() < 0.05          # nose, eyes, mouth land back on their model points
    assert np.median(err[:27]) < 0.5      # jaw and brows, on the hull rim where rays graze: close


def test_surface_slopes_are_those_of_its_bilinear_depth(scene):
    """z_slopes gives z's own values and its finite-difference slopes inside a patch, and 0 across
    the border where the depth continues flat (a wrong slope would send Newton astray)."""
    surface, _ = scene
    rng = np.random.default_rng(0)
    x, y = rng.uniform(-100, 100, 500), rng.uniform(-70, 210, 500)
    z, zx, zy = surface.z_slopes(x, y)
    np.testing.assert_allclose(z, surface.z(x, y), atol=1e-9)
    h = 1e-4                                           # inside one 2-mm patch for almost every point
    fdx = (surface.z(x + h, y) - surface.z(x - h, y)) / (2 * h)
    fdy = (surface.z(x, y + h) - surface.z(x, y - h)) / (2 * h)
    assert np.mean(np.abs(zx - fdx) < 1e-5) > 0.99 and np.mean(np.abs(zy - fdy) < 1e-5) > 0.99
    z, zx, zy = surface.z_slopes(np.array([-500.0, 0.0]), np.array([0.0, 900.0]))
    assert zx[0] == 0 and zy[1] == 0
    assert z[0] == surface.z(np.array([-500.0]), np.array([0.0]))[0]


def test_frontal_landmarks_converge_where_a_few_iterations_would_not(scene):
    """Dense rays from a rough (affine) start, as the render-back map solves them: every ray
    that meets the surface ends on it to a thousandth of a pixel."""
    surface, _ = scene
    K = intrinsics(320, 400, 1.5)
    rvec, tvec = np.radians([10.0, -20.0, 6.0]), np.array([0.0, -40.0, 650.0])
    gx, gy = np.meshgrid(np.linspace(-50, 50, 40), np.linspace(0, 130, 40))
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    pixels = project(np.column_stack([xy, surface.z(xy[:, 0], xy[:, 1])]), rvec, tvec, K)
    start = xy + np.random.default_rng(1).normal(0, 8, xy.shape)
    back = frontal_landmarks(pixels, start, surface, rvec, tvec, K, iterations=8)
    hit = project(np.column_stack([back, surface.z(back[:, 0], back[:, 1])]), rvec, tvec, K)
    assert np.percentile(np.linalg.norm(hit - pixels, axis=1), 99) < 1e-3


def test_inpainting_fills_only_the_mask_as_full_resolution_telea_would():
    """Half-resolution Telea: pixels outside the mask are untouched, and a hole in steep smooth
    shading is filled as OpenCV's full-resolution Telea fills it (a fill shifted by one pixel
    would differ by 1.8 levels on average here; the half-resolution one by 1.3)."""
    import cv2
    from stages.frontalize.warp import inpaint
    T = 128
    yy, xx = np.mgrid[0:T, 0:T].astype(np.float32)
    texture = np.dstack([10 + 1.9 * yy, 20 + 1.7 * xx, 250 - 0.9 * (xx + yy)]).clip(0, 255).astype(np.uint8)
    mask = ((xx - 80) ** 2 + (yy - 90) ** 2 < 20 ** 2) | ((yy > 120) & (xx < 30))
    holed = texture.copy()
    holed[mask] = 0
    out = inpaint(holed, mask, 3.0)
    assert np.array_equal(out[~mask], texture[~mask])
    full = cv2.inpaint(holed, mask.astype(np.uint8), 3.0, cv2.INPAINT_TELEA)
    assert np.abs(out.astype(int) - full)[mask].mean() < 1.5


def test_inpainting_radius_still_acts_at_half_resolution():
    """frontalize.inpaint_radius must change the fill (DVC reruns frontalize when it is edited):
    at half resolution it acts in steps of 2 px — 3 and 5 px differ, 3 and 4 px are the same."""
    from stages.frontalize.warp import inpaint
    rng = np.random.default_rng(2)
    texture = rng.integers(0, 256, (128, 128, 3)).astype(np.uint8)
    mask = np.zeros((128, 128), bool)
    mask[70:110, 20:100] = True
    r3, r4, r5 = (inpaint(texture, mask, r) for r in (3.0, 4.0, 5.0))
    assert np.array_equal(r3, r4) and not np.array_equal(r3, r5)
