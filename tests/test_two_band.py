"""synthesize.detail: two_band / aligned — the Viterbi over detail sources, the cross-fade plan, the
warps, and the detail measures that judge them (pure functions, no stores)."""
import cv2
import numpy as np
import pytest

from pipeline.errors import ParameterError
from pipeline.measures.lipsync_measures import detail_energy, detail_flicker
from stages.synthesize import two_band as tb


def test_next_rows_follow_frame_ids_and_never_a_bank_frame():
    ids = np.array([10, 11, 13, 12, -1, -2])
    assert tb.next_rows(ids).tolist() == [1, 3, -1, 2, -1, -1]


def test_the_path_follows_a_run_of_consecutive_frames_when_switching_costs_more():
    # pool rows 0..9 = frames 0..9 of one video; row 10 = a bank frame. At each output frame the
    # nearest row jumps about, but the run 2, 3, 4, 5 is always second best by a small margin.
    n, p = 4, 11
    costs = np.full((n, p), 9.0)
    for i in range(n):
        costs[i, 2 + i] = 1.3                    # the run
        costs[i, 10] = 1.0 if i % 2 else 9.0     # a bank frame, nearest every other frame
        costs[i, 7 - i] = 1.0                    # a different video frame, nearest each time
    ids = np.r_[np.arange(10), -1]
    assert tb.detail_sources(costs, ids, k=3, switch_cost=2.0, hold_cost=1.0).tolist() == [2, 3, 4, 5]
    # free switches: the nearest row at every frame
    assert tb.detail_sources(costs, ids, k=3, switch_cost=0.0, hold_cost=0.0).tolist() == [7, 6, 5, 4] or \
        tb.detail_sources(costs, ids, k=3, switch_cost=0.0, hold_cost=0.0).tolist() == [7, 10, 5, 10]


def test_the_path_is_the_exact_viterbi_optimum_on_small_random_problems():
    rng = np.random.default_rng(0)
    ids = np.array([0, 1, 2, 3, 10, 11, -1])
    nxt = tb.next_rows(ids)

    def cost(path, c, s, h):
        tot = c[0, path[0]]
        for i in range(1, len(path)):
            a, b = path[i - 1], path[i]
            tot += c[i, b] + (0 if nxt[a] == b else h if a == b else s)
        return tot

    import itertools
    for _ in range(5):
        c = rng.uniform(0, 3, (4, len(ids)))
        got = tb.detail_sources(c, ids, k=len(ids), switch_cost=1.5, hold_cost=0.7, reach=len(ids), beam=len(ids) ** 2)
        best = min(cost(pth, c, 1.5, 0.7) for pth in itertools.product(range(len(ids)), repeat=4))
        assert cost(got, c, 1.5, 0.7) == pytest.approx(best)


def test_a_run_may_not_continue_into_a_frame_outside_the_reach():
    costs = np.array([[0.0, 5.0, 5.0], [5.0, 50.0, 0.0]])       # frame 1 of the run is far from the wanted shape
    ids = np.array([0, 1, 2])
    assert tb.detail_sources(costs, ids, k=1, switch_cost=100.0, hold_cost=100.0, reach=2).tolist() == [0, 2]


def test_bad_costs_are_refused():
    with pytest.raises(ParameterError, match="pool rows"):
        tb.detail_sources(np.zeros((3, 4)), np.arange(5))
    with pytest.raises(ParameterError, match="k ≥ 1"):
        tb.detail_sources(np.zeros((3, 4)), np.arange(4), k=0)


def test_a_switch_is_cross_faded_and_weights_sum_to_one():
    ids = np.arange(20)
    sources = np.array([2, 3, 4, 12, 13, 14, 15, 16])         # a switch at output frame 3
    plan = tb.crossfade_plan(sources, ids, fade=3)
    assert plan[:3] == [[(2, 1.0)], [(3, 1.0)], [(4, 1.0)]]
    assert [r for r, _ in plan[3]] == [5, 12] and [r for r, _ in plan[5]] == [7, 14]
    old = [dict(p).get(r, 0.0) for p, r in zip(plan[3:6], (5, 6, 7))]
    assert old == pytest.approx([0.75, 0.5, 0.25])               # falls linearly
    assert plan[6] == [(15, 1.0)]
    assert all(sum(w for _, w in p) == pytest.approx(1.0) for p in plan)


def blobs(size=96, shift=(0.0, 0.0), seed=1):
    """A textured test image: smooth blobs plus fine stripes, translated by ``shift`` (x, y) px."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:size, 0:size].astype(np.float64)
    x, y = x - shift[0], y - shift[1]
    img = 128 + 40 * np.sin(x / 7.0) * np.cos(y / 9.0) + 30 * np.sin(0.9 * x + 0.5 * y)
    for cx, cy in rng.uniform(20, size - 20, (4, 2)):
        img += 40 * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / 60)
    return np.clip(img, 0, 255).astype(np.uint8)


def test_the_landmark_field_moves_points_onto_their_targets_and_leaves_far_pixels():
    src = np.array([[40.0, 40.0], [56.0, 40.0]])
    dst = src + [0.0, 5.0]                                      # both points 5 px down
    mx, my = tb.displacement_field(src, dst, 96, sigma=8.0, points=np.arange(2))
    assert my[45, 40] == pytest.approx(40.0, abs=0.6) and mx[45, 40] == pytest.approx(40.0, abs=0.3)
    assert my[90, 5] == pytest.approx(90.0, abs=0.05) and mx[90, 5] == pytest.approx(5.0, abs=0.05)


def test_aligned_i420_candidates_move_like_rgb_ones():
    rgb = np.dstack([blobs(), blobs(seed=2), blobs(seed=3)])
    i420 = cv2.cvtColor(rgb, cv2.COLOR_RGB2YUV_I420)
    src = np.array([[[40.0, 50.0], [56.0, 50.0]]])
    dst = src[0] + [3.0, 4.0]
    a = tb.align_candidates(rgb[None], src, dst, 10.0)[0]
    b = cv2.cvtColor(tb.align_candidates(i420[None], src, dst, 10.0)[0], cv2.COLOR_YUV2RGB_I420)
    ref = cv2.cvtColor(cv2.cvtColor(a, cv2.COLOR_RGB2YUV_I420), cv2.COLOR_YUV2RGB_I420)
    assert np.abs(b.astype(int) - ref.astype(int))[20:76, 20:76].mean() < 3.0
    assert np.abs(a.astype(int) - rgb.astype(int))[40:60, 40:60].mean() > 5      # it did move


def test_two_band_keeps_the_medians_low_band_and_takes_the_sources_detail():
    sharp = np.dstack([blobs()] * 3)
    soft = cv2.GaussianBlur(sharp, (0, 0), 3.0)
    lm = np.tile([48.0, 48.0], (68, 1)) + np.random.default_rng(0).normal(0, 10, (68, 2))
    out = tb.two_band(soft, lm, [(sharp, lm, 1.0)], band_sigma=2.0, warp_sigma=8.0)
    low_soft, _ = tb.split_bands(soft, 2.0)
    _, high_sharp = tb.split_bands(sharp, 2.0)
    assert np.abs(out - (low_soft + high_sharp))[8:-8, 8:-8].mean() < 1.5       # aligned already: flow ≈ 0
    box = (8, 8, 88, 88)
    assert detail_energy(out[None, ..., 0], box, 1.0) > 3 * detail_energy(soft[None, ..., 0], box, 1.0)


def test_detail_measures_see_detail_and_not_motion():
    box = (20, 20, 76, 76)
    moving = np.stack([blobs(shift=(0.7 * t, 0.4 * t)) for t in range(6)])
    noisy = np.stack([np.clip(blobs().astype(int) + np.random.default_rng(t).normal(0, 6, (96, 96)), 0, 255)
                      .astype(np.uint8) for t in range(6)])
    soft = np.stack([cv2.GaussianBlur(f, (0, 0), 2.0) for f in moving])
    assert detail_flicker(moving, box, 1.5) < 0.5 * detail_flicker(noisy, box, 1.5)     # motion is not flicker
    assert detail_energy(soft, box, 1.5) < 0.3 * detail_energy(moving, box, 1.5)         # blur loses the band


def test_a_large_candidate_is_aligned_through_the_flow_of_smaller_copies():
    """Above ``flow_max`` the flow runs on area-averaged copies and the two warps are composed into one
    resampling: a 384 px candidate moved by a smooth field lands on the target about as well as with the
    flow at full size, and far better than with the landmarks alone (which here know nothing of the motion)."""
    size = 384
    target = np.dstack([cv2.resize(blobs(seed=s), (size, size), interpolation=cv2.INTER_CUBIC) for s in (1, 2, 3)])
    gy, gx = np.mgrid[0:size, 0:size].astype(np.float32)
    bend = 4.0 * np.sin(gx / size * np.pi) * np.sin(gy / size * np.pi)            # ≤ 4 px, smooth
    candidate = cv2.remap(target, gx - bend, gy + 0.5 * bend, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    lm = np.tile([size / 2, size / 2], (68, 1)) + np.random.default_rng(1).normal(0, 30, (68, 2))
    err = lambda im: np.abs(im.astype(float) - target)[40:-40, 40:-40].mean()
    small = tb.align_to(candidate, lm, target, lm, sigma=24.0, flow_max=192)
    full = tb.align_to(candidate, lm, target, lm, sigma=24.0, flow_max=384)
    none = tb.align_to(candidate, lm, target, lm, sigma=24.0, flow=False)
    assert err(full) < 0.1 * err(none), (err(full), err(none))
    assert err(small) < 0.25 * err(none), (err(small), err(none))     # within 2 grey levels (of ≈ 7.5 unaligned)


@pytest.mark.parametrize("sigma", [5.5, 8.0])
def test_the_wide_band_split_at_half_size_matches_the_full_size_blur(sigma):
    assert sigma >= tb.HALF_SIZE_SIGMA                                               # the half-size path
    img = np.dstack([cv2.resize(blobs(seed=s), (256, 256), interpolation=cv2.INTER_CUBIC) for s in (1, 2, 3)])
    low, high = tb.split_bands(img, sigma)
    ref = cv2.GaussianBlur(img.astype(np.float32), (0, 0), sigma)
    np.testing.assert_allclose(low + high, img, atol=1e-3)
    assert np.abs(low - ref)[16:-16, 16:-16].max() < 1.0
    assert np.abs(low - ref)[16:-16, 16:-16].mean() < 0.02 * high.std()


def test_a_cross_fade_keeps_the_detail_energy_of_its_sources():
    """Half-way through a switch, the blend of two frames' (uncorrelated) details keeps their energy instead of
    losing half of it; the same frame blended with itself is left as it is."""
    rng = np.random.default_rng(4)
    grain = lambda: np.clip(128 + rng.normal(0, 20, (96, 96, 3)), 0, 255).astype(np.uint8)
    a, b = grain(), grain()
    median = np.full((96, 96, 3), 128, np.uint8)
    lm = np.tile([48.0, 48.0], (68, 1)) + np.random.default_rng(0).normal(0, 10, (68, 2))
    energy = lambda im: np.mean(np.square(im.astype(float) - 128)[8:-8, 8:-8])
    one = tb.two_band(median, lm, [(a, lm, 1.0)], band_sigma=2.0, warp_sigma=8.0, flow=False)
    half = tb.two_band(median, lm, [(a, lm, 0.5), (b, lm, 0.5)], band_sigma=2.0, warp_sigma=8.0, flow=False)
    assert energy(half) == pytest.approx(energy(one), rel=0.1), (energy(half), energy(one))    # a plain sum: ½
    same = tb.two_band(median, lm, [(a, lm, 0.5), (a, lm, 0.5)], band_sigma=2.0, warp_sigma=8.0, flow=False)
    assert np.abs(same.astype(int) - one).max() <= 1


def test_auto_takes_two_bands_for_large_textures_only():
    from stages.synthesize.texture_pool import TWO_BAND_FROM, detail_method
    assert detail_method("auto", 128) == "median"                  # GRID s1, the synthetic speaker
    assert detail_method("auto", 192) == "two_band"                # GRID s4 720×576
    assert detail_method("auto", TWO_BAND_FROM) == "two_band" and detail_method("auto", TWO_BAND_FROM - 16) == "median"
    assert detail_method("median", 512) == "median" and detail_method("two_band", 128) == "two_band"


def test_the_two_band_median_runs_only_as_fine_as_its_low_band_shows():
    from pipeline.params import Synthesize
    from stages.synthesize.texture_pool import median_size
    p = Synthesize()                                               # detail_band_px 2, median_max_size 256
    assert median_size(192, "median", p) == 192 and median_size(512, "median", p) == 256
    assert median_size(192, "two_band", p) == 128 and median_size(512, "two_band", p) == 128
    assert median_size(112, "two_band", p) == 112                  # never larger than the texture
    assert median_size(512, "two_band", Synthesize(detail_band_px=1.0)) == 256   # a narrower band needs a finer median


def test_detail_from_a_differently_coloured_frame_brings_no_colour():
    """A source whose colour differs from the median's (white teeth where the median shows red lips) adds
    brightness detail only: every output pixel keeps the median's chroma."""
    white = (np.indices((96, 96))[1] // 3 % 2).astype(bool)                             # fine 6 px stripes
    teeth = np.where(white[..., None], np.uint8([235, 235, 235]), np.uint8([170, 40, 60]))   # teeth between lips
    red = np.zeros((96, 96, 3), np.uint8)
    red[...] = (170, 40, 60)                                                            # flat lipstick red
    lm = np.tile([48.0, 48.0], (68, 1)) + np.random.default_rng(0).normal(0, 10, (68, 2))
    out = tb.two_band(red, lm, [(teeth, lm, 1.0)], band_sigma=2.0, warp_sigma=8.0, flow=False).astype(float)
    core = out[8:-8, 8:-8]
    assert core[..., 1].std() > 20                                                      # the detail is there
    d = core - core.mean(-1, keepdims=True)                                            # chroma: channel − mean
    ref = np.array([170, 40, 60], float) - np.mean([170, 40, 60])
    clipped = (core <= 0.5) | (core >= 254.5)
    assert np.abs(d - ref)[~clipped.any(-1)].max() < 1.5, np.abs(d - ref).max()
