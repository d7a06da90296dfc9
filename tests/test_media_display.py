"""Frames as players show them: display rotation (phone video), sample aspect ratio (anamorphic),
variable frame rate (phones, screen recorders)."""
from fractions import Fraction

import numpy as np
import pytest

from pipeline.errors import BadInputError
from pipeline.io import media
from tests.helpers.media import face_frames, make_anamorphic_clip, make_clip, make_vfr_clip, set_display_rotation


def marked_frames(n=6, size=(96, 64)):
    """Frames with a white block in the top-left corner: where it lands tells the orientation."""
    frames = np.zeros((n, size[1], size[0], 3), np.uint8)
    frames[:, :16, :24] = 255
    return frames


def corner_of(img: np.ndarray) -> str:
    g = img if img.ndim == 2 else img.mean(-1)
    h, w = g.shape
    quads = {"top-left": g[:h // 2, :w // 2], "top-right": g[:h // 2, w // 2:],
             "bottom-left": g[h // 2:, :w // 2], "bottom-right": g[h // 2:, w // 2:]}
    return max(quads, key=lambda k: quads[k].mean())


@pytest.mark.parametrize("degrees, corner", [(90, "top-right"), (180, "bottom-right"), (270, "bottom-left")])
def test_a_rotated_clip_is_decoded_upright_in_every_format(tmp_path, degrees, corner):
    clip = tmp_path / "phone.mp4"
    make_clip(clip, n_frames=6, frames=marked_frames())
    set_display_rotation(clip, degrees)
    info = media.probe(clip)
    assert (info.width, info.height) == ((64, 96) if degrees % 180 else (96, 64))
    _, rgb = next(media.iter_frames(clip))
    _, grey = next(media.iter_frames(clip, "gray"))
    _, (y, u, v) = next(media.iter_frames(clip, "yuv"))
    assert rgb.shape[:2] == grey.shape == y.shape == (info.height, info.width)
    assert u.shape == v.shape == ((info.height + 1) // 2, (info.width + 1) // 2)
    assert corner_of(rgb) == corner_of(grey) == corner_of(y) == corner, degrees


def test_an_unrotated_clip_is_untouched(tmp_path):
    clip = tmp_path / "plain.mp4"
    frames = marked_frames()
    make_clip(clip, n_frames=6, frames=frames)
    _, rgb = next(media.iter_frames(clip))
    assert rgb.shape == frames.shape[1:] and corner_of(rgb) == "top-left"


def test_an_anamorphic_clip_is_resampled_to_square_pixels(tmp_path):
    clip = tmp_path / "dv.mp4"
    frames = face_frames(4, size=(320, 256))
    make_anamorphic_clip(clip, frames, sar=Fraction(2, 1))
    info = media.probe(clip)
    assert (info.width, info.height) == (320, 256)
    _, rgb = next(media.iter_frames(clip))
    _, (y, u, _) = next(media.iter_frames(clip, "yuv"))
    assert rgb.shape == (256, 320, 3) and y.shape == (256, 320) and u.shape == (128, 160)
    assert np.abs(rgb.astype(float) - frames[0]).mean() < 12          # the face as it was drawn, not squeezed


def test_a_rotation_that_is_not_a_quarter_turn_is_one_clear_error(tmp_path):
    import struct
    clip = tmp_path / "tilted.mp4"
    make_clip(clip, n_frames=4, frames=marked_frames(4))
    data = bytearray(clip.read_bytes())
    i = data.find(b"tkhd")
    c, s = int(0x10000 * np.cos(np.radians(45))), int(0x10000 * np.sin(np.radians(45)))
    data[i + 44:i + 80] = struct.pack(">9i", c, s, 0, -s, c, 0, 0, 0, 0x40000000)
    clip.write_bytes(bytes(data))
    with pytest.raises(BadInputError, match="display rotation of -?45° .*multiples of 90°") as e:
        media.probe(clip)
    assert str(clip) in str(e.value)


def test_constant_rate_passes_a_jittered_constant_rate_stream_unchanged():
    rng = np.random.default_rng(1)
    times = 0.5 + np.arange(40) / 25 + rng.uniform(-0.018, 0.018, 40)   # jitter below half a frame
    out = list(media.constant_rate(zip(times, range(40)), 25.0))
    assert [i for _, i in out] == list(range(40))
    np.testing.assert_allclose([t for t, _ in out], times[0] + np.arange(40) / 25, atol=1e-12)


def test_constant_rate_repeats_over_gaps_and_drops_crowded_frames():
    times = [0.0, 0.04, 0.2, 0.21, 0.22, 0.24]      # a 160 ms gap, then three frames within one period
    out = list(media.constant_rate(zip(times, range(6)), 25.0))
    assert [i for _, i in out] == [0, 1, 1, 1, 1, 4, 5]
    assert list(media.constant_rate(iter([]), 25.0)) == []


def test_a_variable_frame_rate_clip_is_decoded_on_its_average_rate(tmp_path):
    rng = np.random.default_rng(0)
    times = np.concatenate([[0], np.cumsum(rng.choice([0.033, 0.040, 0.066], 59, p=[.4, .4, .2]))])
    clip = make_vfr_clip(tmp_path / "vfr.mp4", times)
    info = media.probe(clip)
    out = list(media.iter_frames(clip, "gray"))
    slots = np.array([t for t, _ in out])
    np.testing.assert_allclose(np.diff(slots), 1 / info.fps, rtol=1e-9)       # evenly spaced
    assert abs(len(out) - info.n_frames) <= 1
    shown = np.array([int(round((g.mean() - 16) / 4 * 255 / 219)) for _, g in out])   # limited-range Y → index
    expected = [int(np.flatnonzero(times <= s + 0.5 / info.fps).max()) for s in slots]
    np.testing.assert_array_equal(shown, expected)
    assert len(set(shown)) < len(times)                       # crowded frames were dropped
    assert (np.diff(shown) == 0).any()                        # gaps were filled by repeats


def test_threaded_decoding_gives_every_frame_in_order_with_the_same_pixels(tmp_path, monkeypatch):
    """Frame threading holds frames back inside the decoder (one per thread) and returns them at the flush: the
    decoded clip must still be every frame, in order, at its time, with the pixels one thread gives."""
    rng = np.random.default_rng(0)
    frames = face_frames(37, (96, 64))
    frames[:, :8, :8] = rng.integers(0, 255, (37, 8, 8, 3), dtype=np.uint8)      # each frame distinct
    clip = make_clip(tmp_path / "clip.mp4", n_frames=37, frames=frames, audio=False)
    decoded = {}
    for threads in (1, media.DECODE_THREADS, 4):
        monkeypatch.setattr(media, "DECODE_THREADS", threads)
        decoded[threads] = list(media.iter_frames(clip, "rgb24"))
    one = decoded.pop(1)
    assert len(one) == 37
    for threads, got in decoded.items():
        assert [t for t, _ in got] == [t for t, _ in one], threads
        assert all(np.array_equal(a, b) for (_, a), (_, b) in zip(got, one)), threads
