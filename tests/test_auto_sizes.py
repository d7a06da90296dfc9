"""Crop and texture sizes follow the face's size in the footage (``ingest.crop_size: auto``,
``frontalize.texture_size: auto``), and speak frontalizes a target the way the model's bank was."""
import numpy as np
import pytest
import zarr

from lipsynth.speak import same_window, with_texture_window
from pipeline.params import Frontalize, Params
from stages.frontalize.frontalize import auto_texture_size, crop_interocular, texture_window
from stages.ingest.crop import auto_crop_size


def test_crop_keeps_the_footage_resolution_within_bounds():
    assert auto_crop_size([124, 120, 130], 2.0, 448) == 240          # GRID s1 at 360×288: 248 px of source → 240
    assert auto_crop_size([215, 215], 2.0, 448) == 416               # a 720p face: 430 px → 416, not halved to 224
    assert auto_crop_size([300], 2.0, 448) == 448                    # capped
    assert auto_crop_size([60], 2.0, 448) == 224                     # never below the former fixed size
    assert auto_crop_size([], 2.0, 448) == 224                       # no face seen yet: ingest names the video later
    assert auto_crop_size([124, 120, 10_000, 122, 124], 2.0, 448) == 240      # the median ignores one bad detection


def test_texture_is_as_fine_as_the_crop_and_bounded():
    p = Frontalize()
    assert auto_texture_size(62.0, p) == 128                         # 360×288: 110 px for 160 mm → the minimum
    assert auto_texture_size(119.0, p) == 208                        # 160 mm × 119 / 90 = 211.6 → 208
    assert auto_texture_size(200.0, p) == 352                        # a 1080-line face: 355.6 → 352
    assert auto_texture_size(400.0, p) == 512                        # capped at max_texture_size
    assert auto_texture_size(200.0, Frontalize(max_texture_size=256)) == 256
    assert auto_texture_size(float("nan"), p) == 128
    wide = Frontalize(texture_x_mm=[-40, 40])                       # half the window → half the pixels
    assert auto_texture_size(119.0, wide) == 128 and auto_texture_size(240.0, wide) == 208


def test_crop_interocular_reads_source_pixels_through_each_videos_crop_scale():
    g = zarr.open_group(zarr.storage.MemoryStore(), mode="w")
    lm = np.zeros((20, 68, 2), np.float32)
    lm[:10, 45, 0], lm[10:, 45, 0] = 120.0, 300.0                    # source-px eye distances of two videos
    valid = np.ones(20, bool)
    valid[3] = False
    lm[3, 45, 0] = 5000.0                                            # an invalid frame must not count
    g.create_array("landmarks", data=lm)
    g.create_array("valid", data=valid)
    videos = [dict(first_frame=0, n_frames=10, crop=[0, 0, 2.0]), dict(first_frame=10, n_frames=10, crop=[0, 0, 2.5])]
    d = crop_interocular(g, videos)                                  # 120 / 2 = 60 and 300 / 2.5 = 120 crop px
    assert 60.0 <= d <= 120.0
    assert crop_interocular(g, videos[:1]) == pytest.approx(60.0)
    assert crop_interocular(g, videos[1:]) == pytest.approx(120.0)


def test_speak_frontalizes_with_the_models_window_of_any_size():
    for size in (128, 208, 224, 256):
        bank = dict(x0=-80.0, y0=20.0, mm_per_px=160.0 / size, size=size)
        p = with_texture_window(Params(), bank)
        w = texture_window(p.frontalize)
        assert same_window(bank, dict(x0=w.x0, y0=w.y0, mm_per_px=w.mm_per_px, size=w.size))
    assert not same_window(dict(x0=-80.0, y0=20.0, mm_per_px=1.25, size=128),
                           dict(x0=-80.0, y0=20.0, mm_per_px=160 / 144, size=144))
