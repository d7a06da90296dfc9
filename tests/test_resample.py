"""Bit-exact resampling (``pipeline.resample``): OpenCV's fixed-point maps built in NumPy."""
import cv2
import numpy as np
import pytest

from pipeline import resample


def image():
    rng = np.random.default_rng(1)
    return cv2.GaussianBlur((rng.random((60, 80, 3)) * 255).astype(np.uint8), (0, 0), 1.5)


def test_integer_positions_copy_pixels_and_half_pixels_average():
    img = image()
    gx, gy = np.meshgrid(np.arange(80.0), np.arange(60.0))
    assert np.array_equal(resample.remap(img, gx, gy), img)
    half = resample.remap(img, gx[:, :-1] + 0.5, gy[:, :-1])
    expect = (img[:, :-1].astype(int) + img[:, 1:]) / 2
    assert np.abs(half - expect).max() <= 1


def test_fixed_point_maps_round_to_a_32nd_of_a_pixel():
    xy, frac = resample.fixed_point_maps(np.array([[2.0, 2.49, -0.02]]), np.array([[3.0, 3.5, 0.0]]))
    assert xy.tolist() == [[[2, 3], [2, 3], [-1, 0]]]
    assert frac.tolist() == [[0, 16 * 32 + 16, 31]]          # 2.49 → 2 + 16/32 (x), 3.5 → 3 + 16/32 (y); −0.02 → −1 + 31/32


def test_matches_opencv_float_maps_and_warp_affine_within_one_level():
    img = image()
    gx, gy = np.meshgrid(np.arange(80.0), np.arange(60.0))
    mx, my = 0.9 * gx + 3.3 + np.sin(gy / 7), 1.05 * gy - 2.1
    ours = resample.remap(img, mx, my).astype(int)
    theirs = cv2.remap(img, mx.astype(np.float32), my.astype(np.float32), cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_REPLICATE).astype(int)
    assert np.abs(ours - theirs).max() <= 1
    m = np.array([[0.8, 0.1, 4.0], [-0.05, 0.9, -2.0]])
    ours = resample.warp_affine(img, m, (70, 50), cv2.BORDER_REFLECT).astype(int)
    theirs = cv2.warpAffine(img, m, (70, 50), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT).astype(int)
    assert np.abs(ours - theirs)[2:-2, 2:-2].max() <= 1


def test_only_8_bit_images():
    with pytest.raises(TypeError, match="uint8"):
        resample.remap(image().astype(np.float32), np.zeros((2, 2)), np.zeros((2, 2)))


def test_cubic_copies_pixels_at_integer_positions_and_its_weights_sum_to_one():
    img = image()
    gx, gy = np.meshgrid(np.arange(80.0), np.arange(60.0))
    assert np.array_equal(resample.remap(img, gx, gy, interpolation="cubic"), img)
    assert (resample.CUBIC_TABLE.sum(axis=1) == 1 << resample.CUBIC_BITS).all()
    assert resample.CUBIC_TABLE[0].tolist() == [0, 1 << resample.CUBIC_BITS, 0, 0]


@pytest.mark.parametrize("border", [cv2.BORDER_REPLICATE, cv2.BORDER_REFLECT])
def test_cubic_matches_opencv_bicubic_within_one_level(border):
    img = image()
    gx, gy = np.meshgrid(np.arange(90.0), np.arange(70.0))
    mx, my = 0.9 * gx - 4.3 + np.sin(gy / 7), 1.05 * gy - 5.1        # reaches past every edge
    ours = resample.remap(img, mx, my, border, interpolation="cubic").astype(int)
    xy, frac = resample.fixed_point_maps(mx, my)                     # the same 1/32-px positions
    theirs = cv2.remap(img, xy, frac, cv2.INTER_CUBIC, borderMode=border).astype(int)
    assert np.abs(ours - theirs).max() <= 1
    assert np.abs(ours - theirs).mean() < 0.05


def test_cubic_on_a_grid_in_two_passes_equals_the_general_remap():
    img = image()
    xs, ys = np.arange(75) * 0.93 + 1.37, np.arange(66) * 1.04 - 3.11
    grid = resample.sample_grid_cubic(img, xs, ys)
    general = resample.remap_cubic(img, np.broadcast_to(xs, (66, 75)), np.broadcast_to(ys[:, None], (66, 75)))
    assert np.array_equal(grid, general)
    assert np.array_equal(resample.sample_grid_cubic(img[..., 0], xs, ys), grid[..., 0])


def test_cubic_keeps_more_detail_than_bilinear_at_half_pixel_shifts():
    rng = np.random.default_rng(3)
    img = cv2.GaussianBlur((rng.random((80, 80)) * 255).astype(np.uint8), (0, 0), 0.8)
    gx, gy = np.meshgrid(np.arange(80.0) + 0.5, np.arange(80.0) + 0.5)
    energy = {m: cv2.Laplacian(resample.remap(img, gx, gy, interpolation=m), cv2.CV_32F)[4:-4, 4:-4].var()
              for m in ("linear", "cubic")}
    original = cv2.Laplacian(img, cv2.CV_32F)[4:-4, 4:-4].var()
    assert energy["linear"] < 0.5 * original < energy["cubic"]


def test_unknown_interpolation_and_border_are_refused():
    with pytest.raises(ValueError, match="interpolation"):
        resample.remap(image(), np.zeros((2, 2)), np.zeros((2, 2)), interpolation="nearest")
    with pytest.raises(ValueError, match="border"):
        resample.remap(image(), np.zeros((2, 2)), np.zeros((2, 2)), cv2.BORDER_CONSTANT, interpolation="cubic")
