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
