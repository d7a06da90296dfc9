"""Composite pieces (paper 000 §3.4) without I/O: layers, jaw correction, pyramid blend, render-back."""
import cv2
import numpy as np
import pytest
import skimage.data

from pipeline.face.geometry import intrinsics
from stages.composite.layers import chin_spline, jaw_band, jaw_correction, layer_masks, pyramid_blend, synth_alpha
from stages.composite.render import inverse_map, render, texture_footprint
from stages.frontalize.chin_extension import extend_depth, face_depth_on_grid
from pipeline.face.canonical import Surface, TextureWindow
from stages.frontalize.warp import frontal_texture
from tests.helpers.splat import render as splat

WINDOW = TextureWindow(-80.0, 20.0, 160 / 128, 128)       # params.yaml: texture_x_mm, texture_y_mm, size


@pytest.fixture(scope="module")
def geometry(face3d):
    step = 2.0
    xs, ys = np.arange(-110, 111, step), np.arange(-80, 221, step)
    d, known = face_depth_on_grid(face3d, xs, ys)
    return Surface(extend_depth(np.nan_to_num(d), known), xs[0], ys[0], step)


@pytest.fixture(scope="module")
def landmarks_uv(face3d):
    return WINDOW.to_pixels(face3d[:, :2])


def test_pyramid_blend_reproduces_its_inputs_where_alpha_is_0_or_1():
    rng = np.random.default_rng(0)
    front = rng.integers(0, 256, (96, 120, 3)).astype(np.uint8)
    back = cv2.GaussianBlur(rng.integers(0, 256, (96, 120, 3)).astype(np.uint8), (0, 0), 3)
    ones, zeros = np.ones((96, 120), np.float32), np.zeros((96, 120), np.float32)
    assert np.abs(pyramid_blend(front, back, ones).astype(int) - front).max() <= 1
    assert np.abs(pyramid_blend(front, back, zeros).astype(int) - back).max() <= 1
    step = zeros.copy()
    step[:, 60:] = 1
    out = pyramid_blend(front, back, step).astype(int)
    assert np.abs(out[:, :30] - back[:, :30]).mean() < 3         # far from the seam: untouched
    assert np.abs(out[:, 90:] - front[:, 90:]).mean() < 3


def test_pyramid_blend_equals_blending_the_two_pyramids():
    """Burt & Adelson as written — both images decomposed, each level mixed by the alpha pyramid,
    collapsed — gives the same image as the blend's difference-only decomposition."""
    rng = np.random.default_rng(1)
    h, w = 101, 137                                           # odd sizes: pyrUp's dstsize matters
    front = rng.integers(0, 256, (h, w, 3)).astype(np.uint8)
    back = cv2.GaussianBlur(rng.integers(0, 256, (h, w, 3)).astype(np.uint8), (0, 0), 2)
    alpha = cv2.GaussianBlur((rng.random((h, w)) > 0.5).astype(np.float32), (0, 0), 4)
    levels = 4
    gf, gb, ga = [front.astype(np.float32)], [back.astype(np.float32)], [alpha]
    for _ in range(levels):
        gf.append(cv2.pyrDown(gf[-1]))
        gb.append(cv2.pyrDown(gb[-1]))
        ga.append(cv2.pyrDown(ga[-1]))
    out = ga[-1][..., None] * gf[-1] + (1 - ga[-1][..., None]) * gb[-1]
    for lvl in range(levels - 1, -1, -1):
        size = (gf[lvl].shape[1], gf[lvl].shape[0])
        lf = gf[lvl] - cv2.pyrUp(gf[lvl + 1], dstsize=size)
        lb = gb[lvl] - cv2.pyrUp(gb[lvl + 1], dstsize=size)
        out = cv2.pyrUp(out, dstsize=size) + ga[lvl][..., None] * lf + (1 - ga[lvl][..., None]) * lb
    reference = np.clip(out + 0.5, 0, 255).astype(np.uint8)
    assert np.abs(pyramid_blend(front, back, alpha, levels).astype(int) - reference).max() <= 1


def test_layer_alpha_is_continuous_across_the_chin(landmarks_uv):
    mouth, neck = layer_masks(landmarks_uv, 128, feather=2.0)
    no_shirt = np.zeros_like(mouth)
    a = synth_alpha(mouth, neck, no_shirt)
    chin = chin_spline(landmarks_uv[2:15])
    u = int(round(landmarks_uv[8, 0]))
    v_chin = int(round(chin[len(chin) // 2, 1]))
    column = a[int(landmarks_uv[57, 1]):v_chin + 5, u]
    assert column.min() > 0.97, column.min()                  # no seam where the two layers meet
    assert a[int(landmarks_uv[30, 1]) - 4, u] < 0.05          # the nose and eyes are never replaced
    depth = 0.3 * (chin[:, 1].max() - landmarks_uv[30, 1])
    assert a[int(chin[:, 1].max() + depth) + 4:, u].max() < 0.05   # the neck layer stops below the chin
    shirt = np.zeros_like(mouth)
    shirt[v_chin + 6:] = 1                                     # the target's shirt is in front of the neck
    a2 = synth_alpha(mouth, neck, shirt)
    assert a2[v_chin + 8:, u].max() < 0.05
    assert a2[int(landmarks_uv[57, 1]), u] > 0.97


def test_jaw_correction_moves_the_synthesized_jaw_onto_the_target(landmarks_uv):
    face = cv2.resize(skimage.data.astronaut()[60:260, 140:340], (128, 128))
    shift = np.float32([[1, 0, 0], [0, 1, 3]])                 # synthesized chin 3 px too low
    synth = cv2.warpAffine(face, shift, (128, 128), borderMode=cv2.BORDER_REFLECT)
    band = jaw_band(landmarks_uv, 128, 6.0)
    fixed = jaw_correction(synth, face, band)
    near, far = band > 0.6, band < 1e-3
    err = lambda img, m: np.abs(img.astype(float) - face.astype(float))[m].mean()
    assert err(fixed, near) < 0.5 * err(synth, near), (err(fixed, near), err(synth, near))
    assert np.abs(fixed.astype(int) - synth)[far].mean() < 1.0   # away from the jawline: untouched


def test_render_back_inverts_the_frontal_warp(geometry):
    photo = cv2.GaussianBlur(skimage.data.astronaut()[40:340, 100:320], (0, 0), 2.0)   # detail the texture can hold
    K = intrinsics(320, 400, 1.5)
    rvec, tvec = np.radians([6.0, -14.0, 4.0]), np.array([0.0, -40.0, 650.0])
    frame = splat(geometry, photo, rvec, tvec, K)
    points = WINDOW.grid_points(geometry)
    texture = frontal_texture(frame, points, rvec, tvec, K)
    box = texture_footprint(points, rvec, tvec, K, frame.shape)
    x0, y0, x1, y1 = box

    def back_error(r):
        mu, mv = inverse_map(box, geometry, WINDOW, r, tvec, K)
        img, cover = render(texture, mu, mv)
        inside = cv2.erode((cover > 0.99).astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)
        inside &= frame[y0:y1, x0:x1].any(-1)
        return np.abs(img.astype(float) - frame[y0:y1, x0:x1])[inside].mean(), inside.mean()

    err, covered = back_error(rvec)
    wrong, _ = back_error(np.zeros(3))
    assert covered > 0.5
    assert err < 8.0, err                                      # ≈ 6: two resamplings of a splatted render
    assert err < 0.3 * wrong, (err, wrong)


def test_render_map_shows_the_visible_sheet_where_the_surface_folds():
    """A 30 mm step in depth (a lip standing out) seen from below: the surface folds in the view, and
    its rays meet it up to three times. The map must give every pixel the point nearest the camera;
    Newton's method alone (the map before) converges to a hidden sheet on part of the fold."""
    from pipeline.face.geometry import project
    from stages.composite.render import facing, first_hit, fold_region
    step = 2.0
    xs, ys = np.arange(-110, 111, step), np.arange(-80, 221, step)
    gy = np.broadcast_to(ys[:, None], (len(ys), len(xs)))
    depth = -30.0 * np.clip((gy - 78.0) / 4.0, 0.0, 1.0)          # below y = 80 mm 30 mm nearer: slope 7.5
    surface = Surface(depth, xs[0], ys[0], step)
    K = intrinsics(720, 576, 1.5)
    rvec, tvec = np.array([-0.3, 0.0, 0.0]), np.array([0.0, -60.0, 600.0])     # pitched: the ramp seen from below
    xy_ramp = np.array([[0.0, 80.0]])
    assert facing(xy_ramp, surface, rvec, tvec, K)[0] < 0                                # the ramp is seen from behind
    box = texture_footprint(WINDOW.grid_points(surface).reshape(-1, 3), rvec, tvec, K, (576, 720))
    mu, mv = inverse_map(box, surface, WINDOW, rvec, tvec, K, step=4)
    x0, y0, x1, y1 = box
    py, px = np.mgrid[y0:y1:4, x0:x1:4]
    pix = np.column_stack([px.ravel(), py.ravel()]).astype(np.float64)
    folded = fold_region(pix, surface, WINDOW, rvec, tvec, K, reach=8.0)
    assert 0 < folded.sum() < len(pix)
    xy, hit = first_hit(pix, surface, rvec, tvec, K)
    assert hit.all()
    z = surface.z(xy[:, 0], xy[:, 1])
    assert np.abs(project(np.column_stack([xy, z]), rvec, tvec, K) - pix).max() < 0.01   # on the ray
    # nearest: no other point of the ray between the camera and the hit lies behind the surface
    R = cv2.Rodrigues(rvec)[0]
    cam_depth = np.column_stack([xy, z]) @ R[2] + tvec[2]
    rays = np.column_stack([pix, np.ones(len(pix))]) @ np.linalg.inv(K).T
    for frac in np.linspace(0.9, 0.999, 12):
        X = (rays * (frac * cam_depth)[:, None] - tvec) @ R
        above = X[:, 2] - surface.z(X[:, 0], X[:, 1])
        assert (above < 0).all() or (above > 0).all()         # all on the camera's side
    # the rendered map is that of the visible points (texture px) on the folded pixels
    uv_map = np.column_stack([mu[py - y0, px - x0].ravel(), mv[py - y0, px - x0].ravel()])
    uv_hit = WINDOW.to_pixels(xy)
    inside = folded & (uv_hit >= 0).all(1) & (uv_hit <= WINDOW.size - 1).all(1)
    assert inside.sum() > 10
    assert np.abs(uv_map[inside] - uv_hit[inside]).max() < 0.05


def test_render_map_upsampling_is_aligned_with_its_samples():
    """A coarse map sampled every `step` px, upsampled: an affine function is reproduced at every
    pixel (bilinear is exact on it). Pixel-centre resizing (cv2.resize) shifted it by 1.5 px at step 4."""
    from stages.composite.render import upsample_grid
    step, h, w = 4, 37, 50
    ys, xs = np.arange(0, h + step, step), np.arange(0, w + step, step)
    gx, gy = np.meshgrid(xs, ys)
    coarse = np.dstack([0.3 * gx + 0.1 * gy + 2.0, -0.2 * gx + 0.5 * gy]).astype(np.float32)
    u, v = upsample_grid(coarse, step, (h, w))
    fy, fx = np.mgrid[0:h, 0:w]
    assert u.shape == v.shape == (h, w)
    assert np.abs(u - (0.3 * fx + 0.1 * fy + 2.0)).max() < 1e-3
    assert np.abs(v - (-0.2 * fx + 0.5 * fy)).max() < 1e-3


@pytest.mark.parametrize("footprint, T", [(118, 128), (266, 192), (400, 352), (1400, 512), (3000, 512)])
def test_ray_map_step_is_a_power_of_two_within_the_texture_spacing(footprint, T):
    """The ray map's step keeps solved samples ≤ RAY_MAP_SPACING texture px apart (at least 4 frame px) and is a
    power of two: remap reads coordinates in 1/32 px, so at step 6 the upsampled map of an affine function is off
    by up to 6/64 px, at a power of two it is exact."""
    from stages.composite.render import upsample_grid
    from stages.composite.target_geometry import RAY_MAP_SPACING, ray_map_step
    step = ray_map_step(footprint, T)
    assert step >= 4 and step & (step - 1) == 0
    assert step == 4 or step * T / footprint <= RAY_MAP_SPACING
    assert 2 * step * T / footprint > RAY_MAP_SPACING                 # the largest such step

    def affine_error(step, h=97, w=97):
        ys, xs = np.arange(0, h + step, step), np.arange(0, w + step, step)
        gx, gy = np.meshgrid(xs, ys)
        u, _ = upsample_grid(np.dstack([0.3 * gx + 2.0, 0.5 * gy]).astype(np.float32), step, (h, w))
        return np.abs(u - (0.3 * np.mgrid[0:h, 0:w][1] + 2.0)).max()
    assert affine_error(step) < 1e-3
    assert affine_error(6) > 0.01                                   # why not any step


def test_geometry_cache_reuses_frames_and_stays_within_its_budget(monkeypatch):
    """One computation per target frame while it stays cached; least recently used frames leave first once
    the byte budget is reached."""
    from stages.composite import target_geometry as tg
    calls = []

    def fake(tgt, j, T, p, shape):
        calls.append(j)
        a = np.zeros((T, T), np.float32)                    # 4·T² bytes per array, 5 arrays
        return tg.TargetGeometry(np.zeros((T, T, 3), np.uint8)[:0], a, a, None, None, None, a, (0, 0, 1, 1), a, a)

    monkeypatch.setattr(tg, "target_geometry", fake)
    one = 5 * 4 * 16 * 16
    cache = tg.GeometryCache(budget_bytes=3 * one)
    for j in (0, 1, 0, 2, 0, 3, 1):
        cache.get(None, j, 16, None, (32, 32, 3))
    assert calls == [0, 1, 2, 3, 1]                         # 0 kept (recently used), 1 evicted by 3, then re-made
    assert cache.used <= 3 * one and len(cache.items) == 3
    assert cache.hits == 2 and cache.misses == 5


def test_jaw_correction_of_a_large_texture_uses_the_flow_of_a_smaller_copy(landmarks_uv):
    """At 512 px the flow is found at 128 px (``flow_max``, its default) and scaled up: the jaw still lands on
    the target."""
    face = cv2.resize(skimage.data.astronaut()[60:260, 140:340], (512, 512), interpolation=cv2.INTER_CUBIC)
    shift = np.float32([[1, 0, 0], [0, 1, 12]])                # synthesized chin 12 px (3 at 128) too low
    synth = cv2.warpAffine(face, shift, (512, 512), borderMode=cv2.BORDER_REFLECT)
    band = jaw_band(4 * landmarks_uv, 512, 24.0)
    fixed = jaw_correction(synth, face, band)
    near, far = band > 0.6, band < 1e-3
    err = lambda img, m: np.abs(img.astype(float) - face.astype(float))[m].mean()
    assert err(fixed, near) < 0.5 * err(synth, near), (err(fixed, near), err(synth, near))
    assert np.abs(fixed.astype(int) - synth)[far].mean() < 1.0
