"""synthesize.texture: candidates, Eq. 12 σ, weighted median, teeth proxy (paper 000 §3.2)."""

import cv2
import numpy as np
import pytest
import skimage.data

from pipeline.face.dlib_face import LIP_POINTS
from stages.synthesize import teeth as th
from stages.synthesize import texture as tx

LIP18 = np.array(LIP_POINTS) - 48          # rows of the 18 shape points inside the 20 lip points
SKIN, LIP, CAVITY, TOOTH, GAP = (205, 160, 135), (170, 60, 70), (45, 20, 25), (235, 232, 220), (120, 110, 100)


def mouth_face(top=4.0, bottom=4.0, upper=True, lower=True, blur=0.0, du=0.0, T=128):
    """Synthetic frontal lower face: textured skin, red lips, dark cavity, white teeth with gaps.

    top / bottom: inner-lip opening above / below the corner line (v = 70), px. Returns
    (rgb (T, T, 3) uint8, lip (20, 2) float32 = dlib points 48–67)."""
    cu, cv = 64.0 + du, 70.0
    xs = np.array([-16, -8, 0, 8, 16], float)
    outer = np.concatenate([[[cu - 24, cv]], np.c_[cu + xs, cv - top - 5 - (xs == 0)],
                            [[cu + 24, cv]], np.c_[cu - xs, cv + bottom + 6 + (xs == 0)]])
    inner = np.concatenate([[[cu - 20, cv]], np.c_[cu + xs[1:4], np.full(3, cv - top)],
                            [[cu + 20, cv]], np.c_[cu - xs[1:4], np.full(3, cv + bottom)]])
    lip = np.concatenate([outer, inner]).astype(np.float32)
    rng = np.random.default_rng(7)
    img = (np.array(SKIN) + rng.normal(0, 4, (T, T, 1))).clip(0, 255).astype(np.uint8)
    cv2.fillPoly(img, [np.round(outer * 16).astype(np.int32)], LIP, shift=4)
    inside = np.zeros((T, T), np.uint8)
    cv2.fillPoly(inside, [np.round(inner * 16).astype(np.int32)], 1, shift=4)
    img[inside > 0] = CAVITY
    v, u = np.mgrid[:T, :T]
    band = np.zeros((T, T), bool)
    if upper:
        band |= v <= cv - top + 3.5
    if lower:
        band |= v >= cv + bottom - 3.5
    teeth = band & (inside > 0)
    img[teeth] = TOOTH
    img[teeth & (np.round(u - du) % 5 == 0)] = GAP
    if blur > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur)
    return img, lip


def lap_var(rgb, mask):
    grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float32)
    return float(cv2.Laplacian(grey, cv2.CV_32F)[mask].var())


def slow_weighted_median(images, w):
    n = len(images)
    flat = images.reshape(n, -1)
    out = np.empty(flat.shape[1], np.uint8)
    for p in range(flat.shape[1]):
        order = np.argsort(flat[:, p], kind="stable")
        cum = np.cumsum(w[order])
        out[p] = flat[order[np.argmax(cum >= 0.5 * w.sum())], p]
    return out.reshape(images.shape[1:])


# ----------------------------------------------------------------------------- candidates, σ

def test_select_candidates_are_the_n_nearest_in_order():
    rng = np.random.default_rng(0)
    shapes = rng.normal(0, 3, (1000, 18, 2)).astype(np.float32)
    target = rng.normal(0, 3, (18, 2))
    idx, d2 = tx.select_candidates(target.reshape(-1), shapes, 25)
    ref = ((shapes.reshape(1000, -1) - target.reshape(-1)) ** 2).sum(1)
    np.testing.assert_allclose(d2, ref, rtol=1e-5)
    np.testing.assert_array_equal(idx, np.argsort(ref)[:25])
    assert len(tx.select_candidates(target, shapes[:10], 25)[0]) == 10


@pytest.mark.parametrize("alpha", [0.5, 0.9, 0.99])
def test_solve_sigma_meets_eq12_and_weights_fall_with_distance(alpha):
    rng = np.random.default_rng(1)
    d2 = np.concatenate([[0.0, 0.0], rng.gamma(2.0, 30.0, 4000), [1e9, 1e15]])
    idx = np.argsort(d2)[:50]
    sigma = tx.solve_sigma(d2, idx, alpha)
    assert abs(tx.candidate_share(d2, idx, sigma) - alpha) < 1e-3
    sigma_shifted = tx.solve_sigma(d2 + 1e6, idx, alpha)          # only differences matter
    assert abs(tx.candidate_share(d2, idx, sigma_shifted) - alpha) < 1e-3
    w = tx.weights(d2[idx], sigma)
    assert abs(w.sum() - 1) < 1e-12 and np.all(np.diff(w) <= 0) and w[-1] < w[0]
    # the weight of every frame follows Eq. 11: ratio of two weights = exp(−Δd²/2σ²)
    np.testing.assert_allclose(w[10] / w[0], np.exp(-(d2[idx][10] - d2[idx][0]) / (2 * sigma ** 2)))


def test_solve_sigma_degenerate_cases():
    assert tx.solve_sigma(np.full(100, 4.0), np.arange(10), 0.9) == 1.0           # all equal
    d2 = np.arange(100.0)
    s_all = tx.solve_sigma(d2, np.arange(100), 0.9)                                # n = M: share ≡ 1
    assert np.isfinite(s_all) and np.ptp(tx.weights(d2, s_all)) < 1e-3           # ~uniform
    ties = np.r_[np.zeros(20), np.arange(1.0, 81)]                                 # 10 of 20 tied minima
    s = tx.solve_sigma(ties, np.arange(10), 0.9)
    assert np.isfinite(s) and s > 0 and tx.candidate_share(ties, np.arange(10), s) == pytest.approx(0.5, abs=1e-3)


def test_weighted_lip_points_is_the_weighted_mean():
    rng = np.random.default_rng(2)
    pts = rng.normal(size=(7, 20, 2))
    w = rng.random(7)
    np.testing.assert_allclose(tx.weighted_lip_points(pts, w), np.average(pts, axis=0, weights=w))
    np.testing.assert_allclose(tx.weighted_lip_points(pts, np.eye(7)[3]), pts[3])


# ----------------------------------------------------------------------------- weighted median

@pytest.mark.parametrize("n,levels", [(2, 256), (5, 256), (7, 4), (50, 256), (50, 3), (256, 256)])
def test_weighted_median_matches_slow_reference(n, levels):
    rng = np.random.default_rng(n + levels)
    images = rng.integers(0, levels, (n, 6, 5, 3)).astype(np.uint8)
    w = rng.random(n) * (rng.random(n) > 0.2)           # some zero weights
    w[0] += 0.1
    ref = slow_weighted_median(images, w)
    np.testing.assert_array_equal(tx.weighted_median(images, w), ref)
    np.testing.assert_array_equal(tx.weighted_median(images, w, block=7), ref)      # blocks + a remainder


def test_weighted_median_degenerate_cases():
    rng = np.random.default_rng(3)
    images = rng.integers(0, 256, (9, 16, 16, 3)).astype(np.uint8)
    w = np.full(9, 1e-6)
    w[4] = 1.0
    np.testing.assert_array_equal(tx.weighted_median(images, w), images[4])
    np.testing.assert_array_equal(tx.weighted_median(images, np.ones(9)), np.median(images, 0).astype(np.uint8))
    np.testing.assert_array_equal(tx.weighted_median(images[:1], [2.0]), images[0])
    for k in (2, 4):                          # cumulative weight hits exactly half: the lower value
        np.testing.assert_array_equal(tx.weighted_median(images[:k], np.ones(k)), np.sort(images[:k], 0)[k // 2 - 1])
    with pytest.raises(ValueError):
        tx.weighted_median(images.astype(np.float32), np.ones(9))


# ----------------------------------------------------------------------------- Eq. 13–14, masks

def test_overlay_and_high_pass_neutral_values():
    rng = np.random.default_rng(4)
    img = rng.random((20, 20, 3)).astype(np.float32)
    np.testing.assert_allclose(th.overlay(img, np.full_like(img, 0.5)), img, atol=1e-6)
    assert np.all(th.overlay(img, np.full_like(img, 0.7)) >= img)       # H > 0.5 brightens
    assert np.all(th.overlay(img, np.full_like(img, 0.3)) <= img)
    np.testing.assert_allclose(th.high_pass(np.full((20, 20, 3), 0.3, np.float32), 2.0, 5.0), 0.5, atol=1e-6)
    h = th.high_pass(img, 1.0, 100.0)
    assert h.min() >= 0 and h.max() <= 1 and h.dtype == np.float32


def test_teeth_mask_finds_a_white_band_inside_the_inner_lip_only():
    img, lip = mouth_face(upper=False, lower=False)
    img[66:71, :] = TOOTH                     # white band across the whole face, through the mouth
    img[72:74, 50:80] = (250, 100, 100)       # bright but saturated (tongue/lip): not teeth
    mask = th.teeth_mask(img, lip)
    inside = np.zeros(mask.shape, np.uint8)
    cv2.fillPoly(inside, [np.round(lip[12:] * 16).astype(np.int32)], 1, shift=4)
    band = np.zeros(mask.shape, bool)
    band[66:71] = True
    assert mask[band & (cv2.erode(inside, np.ones((3, 3), np.uint8)) > 0)].all()
    assert not mask[inside == 0].any()        # not the band on skin/lips, not the low-S skin
    assert not mask[(inside > 0) & ~band].any()  # not the dark cavity, not the bright red
    full = np.zeros((68, 2), np.float32)
    full[48:] = lip
    np.testing.assert_array_equal(th.teeth_mask(img, full), mask)


# ----------------------------------------------------------------------------- enhancement

def test_enhance_teeth_adds_detail_in_the_teeth_and_nothing_far_away():
    sharp, lip = mouth_face()
    median = cv2.GaussianBlur(sharp, (0, 0), 1.5)
    out = th.enhance_teeth(median, lip, sharp, lip, sharp, lip, (0.0, 0.0))
    teeth = th.teeth_mask(median, lip)
    assert teeth.sum() > 100
    assert lap_var(out, teeth) > 2 * lap_var(median, teeth)
    err = lambda im: np.abs(im.astype(float) - sharp)[teeth].mean()
    assert err(out) < 0.8 * err(median)
    np.testing.assert_array_equal(out[:40], median[:40])          # outer lip top is at v ≈ 60
    np.testing.assert_array_equal(out[105:], median[105:])
    np.testing.assert_array_equal(out[:, :15], median[:, :15])
    closed, lip_c = mouth_face(top=0.5, bottom=0.5, upper=False, lower=False)   # no teeth: only unsharp
    out_c = th.enhance_teeth(closed, lip_c, sharp, lip, sharp, lip, unsharp_amount=0.0)
    np.testing.assert_array_equal(out_c, closed)


def test_lower_proxy_follows_the_jaw():
    proxy, proxy_lip = mouth_face(top=4, bottom=4, du=2.0)
    truth, lip = mouth_face(top=4, bottom=7)          # jaw 3 px lower, mouth 2 px to the left
    median = cv2.GaussianBlur(truth, (0, 0), 1.5)
    np.testing.assert_allclose(th.jaw_shift(lip, proxy_lip), (-2.0, 3.0), atol=1e-5)
    lower = th.teeth_mask(median, lip) & (th.upper_weight(lip, truth.shape) < 0.5)
    err = lambda shift: np.abs(th.enhance_teeth(median, lip, truth, lip, proxy, proxy_lip, shift,
                                                unsharp_amount=0.0).astype(float) - truth)[lower].mean()
    assert err(None) == err((-2.0, 3.0))
    assert err(None) < 0.85 * err((0.0, 0.0)) and err(None) < 0.85 * err((2.0, -3.0))


def test_pick_teeth_proxies_prefers_open_sharp_visible_teeth():
    frames = [mouth_face(0.5, 0.5, False, False),        # 0 closed
              mouth_face(3, 3),                          # 1 slightly open, teeth
              mouth_face(5, 5),                          # 2 open, teeth: the best
              mouth_face(6, 6, False, False),            # 3 most open, no teeth
              mouth_face(5, 5, blur=1.2),                # 4 open, teeth, blurred
              mouth_face(5, 5)]                          # 5 copy of 2 (used with yaw)
    imgs = np.stack([f[0] for f in frames])
    lm = np.zeros((len(frames), 68, 2), np.float32)
    lm[:, 48:] = [f[1] for f in frames]
    ok = np.ones(len(frames), bool)
    ok[5] = False
    assert th.pick_teeth_proxies(imgs, lm, ok) == (2, 2)
    calls = []
    getter = lambda ix: calls.append(ix) or imgs[ix]
    assert th.pick_teeth_proxies(getter, lm, ok, top_k=4) == (2, 2) and len(calls[0]) == 4
    yaw = np.array([0, 0, 0.5, 0, 0, 0])
    assert th.pick_teeth_proxies(imgs, lm, np.ones(6, bool), yaw=yaw) == (5, 5)
    assert th.pick_teeth_proxies(imgs, lm, ok, upper=1) == (1, 2)
    assert th.pick_teeth_proxies(None, lm, ok, upper=1, lower=4) == (1, 4)


# ----------------------------------------------------------------------------- a real photo

ASTRO_LIP = np.array([[201, 139], [209, 139], [218, 139], [224, 141], [230, 140], [237, 140], [245, 141],
                      [237, 151], [229, 155], [222, 156], [216, 155], [208, 150], [204, 141], [218, 143],
                      [223, 144], [229, 143], [242, 142], [229, 150], [223, 151], [217, 150]], np.float32)
"""dlib 68-point predictor (pipeline.face.dlib_face) on skimage's astronaut, points 48–67 (a smile with teeth)."""


@pytest.fixture(scope="module")
def astronaut_mouth():
    """(128, 128, 3) crop of the astronaut's lower face and its (20, 2) lip points."""
    u0, v0 = 159, 83
    return np.ascontiguousarray(skimage.data.astronaut()[v0:v0 + 128, u0:u0 + 128]), ASTRO_LIP - (u0, v0)


def test_real_photo_teeth_mask_and_enhancement(astronaut_mouth):
    sharp, lip = astronaut_mouth
    teeth = th.teeth_mask(sharp, lip)
    assert teeth.sum() > 60 and (teeth & (th.upper_weight(lip, teeth.shape) > 0.5)).sum() > 30
    median = cv2.GaussianBlur(sharp, (0, 0), 1.2)
    out = th.enhance_teeth(median, lip, sharp, lip, sharp, lip, (0.0, 0.0))
    region = th.teeth_mask(median, lip)
    assert lap_var(out, region) > 1.5 * lap_var(median, region)
    err = lambda im: np.abs(im.astype(float) - sharp)[region].mean()
    assert err(out) < err(median)


def test_synthesize_texture_end_to_end_on_shifted_real_frames(astronaut_mouth):
    base, lip = astronaut_mouth
    rng = np.random.default_rng(5)
    M, n = 300, 20
    offs = rng.uniform(-3, 3, (M, 2))
    frames = np.stack([cv2.warpAffine(base, np.float32([[1, 0, du], [0, 1, dv]]), (128, 128),
                                      borderMode=cv2.BORDER_REFLECT) for du, dv in offs])
    lm = np.zeros((M, 68, 2), np.float32)
    lm[:, 48:] = lip + offs[:, None].astype(np.float32)
    shapes = lm[:, 48:][:, LIP18]
    up, lo = th.pick_teeth_proxies(frames, lm, np.ones(M, bool), top_k=16)
    proxies = th.proxies_from_frames(lambda ix: frames[ix], lm, up, lo)
    got = []
    rgb, info = tx.synthesize_texture(lip[LIP18], shapes, lambda ix: got.append(ix) or frames[ix], lm,
                                      n=n, alpha=0.9, proxies=proxies)
    dist = np.hypot(*offs.T)
    assert set(info["indices"]) == set(np.argsort(dist)[:n]) and list(got[0]) == list(info["indices"])
    assert abs(info["share"] - 0.9) < 1e-3 and info["sigma"] > 0
    assert abs(info["weights"].sum() - 1) < 1e-9 and np.all(np.diff(info["weights"]) <= 0)
    np.testing.assert_allclose(info["lip_points"], info["landmarks"][48:68])
    assert np.abs(info["lip_points"] - lip).max() < 1.0      # the weighted jaw sits on the target
    assert rgb.shape == (128, 128, 3) and rgb.dtype == np.uint8
    mouth = th._polygon(lip[:12], rgb.shape).astype(bool)
    assert np.abs(rgb.astype(float) - base)[mouth].mean() < 20
    i420 = np.stack([cv2.cvtColor(f, cv2.COLOR_RGB2YUV_I420) for f in frames])      # the store's format
    rgb_yuv, info_yuv = tx.synthesize_texture(lip[LIP18], shapes, lambda ix: i420[ix], lm, n=n, proxies=proxies)
    np.testing.assert_array_equal(info_yuv["indices"], info["indices"])
    assert th.pick_teeth_proxies(lambda ix: i420[ix], lm, np.ones(M, bool), top_k=16) == (up, lo)
    proxies_yuv = th.proxies_from_frames(lambda ix: i420[ix], lm, up, lo)
    assert np.abs(proxies_yuv["upper"] - proxies["upper"]).mean() < 0.01
    assert rgb_yuv.shape == rgb.shape and np.abs(rgb_yuv.astype(float) - rgb)[mouth].mean() < 6


@pytest.mark.real
@pytest.mark.slow
def test_teeth_detail_on_real_frontal_textures(grid_preprocessed):
    """Teeth proxy on frontal textures of real GRID footage: where the weighted median of other
    frames shows teeth, the proxies' high frequencies add detail there (§3.2.3).

    GRID's median teeth are pinker than its real teeth (S ≈ 0.5–0.6 against 0.39–0.46 on the
    widest-open frame), so the default S ≤ 0.45 finds none on this frame; the test sets
    s_max = 0.6, which marks the interior's bright part (teeth) and still rejects the cavity by V.
    """
    import zarr
    store = grid_preprocessed / "frontalize.zarr"
    from pipeline.io.store import i420_to_rgb
    g = zarr.open_group(store, mode="r")
    k = min(600, g["texture"].shape[0])
    lm = g["frontal_landmarks"][:k]
    ok = np.flatnonzero(g["pose_valid"][:k] & np.isfinite(lm).all((1, 2)))
    rgb = np.stack([i420_to_rgb(t) for t in g["texture"][:k][ok]])
    lm = lm[ok]
    up, lo = th.pick_teeth_proxies(rgb, lm, np.ones(len(ok), bool), top_k=32)
    proxies = th.proxies_from_frames(lambda ix: rgb[ix], lm, up, lo)
    j = int(np.argmax(lm[:, 66, 1] - lm[:, 62, 1]))
    assert th.teeth_mask(rgb[j], lm[j, LIP_POINTS]).sum() > 20, "the widest-open real frame shows teeth"
    others = np.flatnonzero(np.abs(np.arange(len(ok)) - j) > 50)          # not j's own neighbours
    pinkish = dict(s_max=0.6)
    out, info = tx.synthesize_texture(lm[j, LIP_POINTS], lm[others][:, LIP_POINTS],
                                      lambda ix: rgb[others[ix]], lm[others], proxies=proxies, params=pinkish)
    plain, _ = tx.synthesize_texture(lm[j, LIP_POINTS], lm[others][:, LIP_POINTS],
                                     lambda ix: rgb[others[ix]], lm[others], params=pinkish)
    assert abs(info["share"] - 0.9) < 1e-3
    teeth = th.teeth_mask(plain, info["lip_points"], s_max=0.6)
    assert teeth.sum() > 20, "the median of other frames shows teeth: the test's precondition failed"
    assert np.abs(out.astype(int) - plain)[~th._polygon(th._lip20(info["lip_points"])[th.OUTER],
                                                         plain.shape[:2], grow_px=12).astype(bool)].max() == 0
    assert lap_var(out, teeth) > 1.5 * lap_var(plain, teeth)


def test_median_at_half_size_is_the_full_size_median_upsampled(astronaut_mouth):
    """``synthesize.median_max_size``: candidates area-averaged to half size give a median that, upsampled,
    matches the full-size median's low band (its shape and shading), at a quarter of the values sorted."""
    from pipeline.io.store import i420_to_rgb, resize_i420, rgb_to_i420
    from stages.synthesize.texture_pool import median_pool
    base, lip = astronaut_mouth
    big = cv2.resize(base, (256, 256), interpolation=cv2.INTER_CUBIC)
    rng = np.random.default_rng(2)
    offs = rng.uniform(-4, 4, (40, 2))
    i420 = np.stack([rgb_to_i420(cv2.warpAffine(big, np.float32([[1, 0, du], [0, 1, dv]]), (256, 256),
                                                borderMode=cv2.BORDER_REFLECT)) for du, dv in offs])
    small, scale = median_pool(i420, 128)
    assert small.shape == (40, 192, 128) and scale == 0.5
    same, one = median_pool(i420, 256)
    assert same is i420 and one == 1.0
    # each plane area-averaged: the small texture is the big one's RGB resized (up to I420 rounding)
    ref = cv2.resize(i420_to_rgb(i420[0]), (128, 128), interpolation=cv2.INTER_AREA).astype(float)
    assert np.abs(i420_to_rgb(small[0]) - ref).mean() < 2.0
    with pytest.raises(ValueError):
        resize_i420(i420[0], 126)
    lm = np.zeros((40, 68, 2), np.float32)
    lm[:, 48:] = 2 * lip + offs[:, None].astype(np.float32)
    shapes = lm[:, 48:][:, LIP18]
    plain = dict(unsharp_amount=0.0)
    full, info = tx.synthesize_texture(2 * lip[LIP18], shapes, lambda ix: i420[ix], lm, n=20, params=plain)
    half, info_half = tx.synthesize_texture(2 * lip[LIP18], shapes, lambda ix: small[ix], lm, n=20, params=plain,
                                            size=256)
    assert half.shape == full.shape == (256, 256, 3)
    np.testing.assert_array_equal(info_half["indices"], info["indices"])
    low = lambda im: cv2.GaussianBlur(im.astype(np.float32), (0, 0), 4.0)
    assert np.abs(low(half) - low(full)).mean() < 2.0
    assert np.abs(half.astype(float) - full).mean() > 0.2      # not the full-size median itself: detail is lost
