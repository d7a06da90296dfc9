"""Video re-timing (paper 000 §3.3): DP optimality and constraints, speech/blink/motion signals,
ping-pong extension and half-way interpolation of repeated frames."""
import itertools

import numpy as np
import pytest

from pipeline.errors import ParameterError
from pipeline.video.repeats import interpolate_repeats
from stages.synthesize.retime import blink_flags, extend_by_ping_pong, eye_area, motion_speed, retime
from stages.synthesize.speech_flags import speech_flags


# ---------------------------------------------------------------- retime

def assert_valid(mapping, n, m):
    mapping = np.asarray(mapping)
    assert mapping.shape == (n,)
    assert mapping.min() >= 0 and mapping.max() < m
    steps = np.diff(mapping)
    assert set(steps.tolist()) <= {0, 1}, "monotonic, advancing by 0 or 1"
    assert not np.any((steps[1:] == 0) & (steps[:-1] == 0)), "a target frame shown at most twice"


def path_cost(A, V, mapping, alpha_s, alpha_u):
    """Independent cost of a mapping, summed frame by frame from the paper's G and repeat terms."""
    cost = 0.0
    for i, j in enumerate(mapping):
        if not A[i]:
            cost += V[j]
        if i >= 2 and A[i - 2] and (i < 3 or not A[i - 3]):      # A(-1) = 0
            cost -= alpha_u * V[j]
        if i > 0 and mapping[i - 1] == j:
            cost += alpha_s * V[j]
    return cost


def all_mappings(n, m):
    for start in range(m):
        for steps in itertools.product((0, 1), repeat=n - 1):
            if any(a == 0 and b == 0 for a, b in zip(steps, steps[1:])):
                continue
            mapping = start + np.concatenate([[0], np.cumsum(steps)]).astype(int)
            if mapping[-1] < m:
                yield mapping


def test_retime_is_optimal_on_all_tiny_cases():
    rng = np.random.default_rng(0)
    for _ in range(300):
        n = int(rng.integers(1, 7))
        m = int(rng.integers((n + 1) // 2, 7)) or 1
        A = rng.random(n) < 0.5
        V = np.round(rng.random(m), 1) if rng.random() < 0.5 else rng.random(m) * 3
        alpha_s, alpha_u = rng.uniform(0, 3, size=2)
        mapping = retime(A, V, alpha_s, alpha_u)
        assert_valid(mapping, n, m)
        best = min(path_cost(A, V, c, alpha_s, alpha_u) for c in all_mappings(n, m))
        assert path_cost(A, V, mapping, alpha_s, alpha_u) == pytest.approx(best, abs=1e-9)


def test_retime_constraints_on_random_inputs():
    rng = np.random.default_rng(1)
    for n, m in [(300, 200), (200, 300), (400, 200), (1, 1), (2, 1), (50, 50)]:
        A = rng.random(n) < 0.6
        mapping = retime(A, rng.random(m))
        assert_valid(mapping, n, m)
        assert mapping.dtype.kind == "i"
    assert_valid(retime(np.ones(20, bool), rng.random(10)), 20, 10)   # N = 2M: every frame twice


def test_retime_equal_lengths_all_speech_plays_at_normal_speed():
    n = 120
    np.testing.assert_array_equal(retime(np.ones(n, bool), np.ones(n)), np.arange(n))
    mapping = retime(np.ones(n, bool), np.random.default_rng(2).random(n) + 0.1)
    assert_valid(mapping, n, n)


def test_silence_lands_on_a_still_stretch_of_the_target():
    V = np.ones(200)
    V[100:140] = 0.01                                # the speaker keeps still for 40 frames
    A = np.ones(150, bool)
    A[60:100] = False                                # the source pauses for 40 frames
    mapping = retime(A, V)
    assert_valid(mapping, 150, 200)
    still = (mapping[60:100] >= 100) & (mapping[60:100] < 140)
    assert still.mean() >= 0.9
    moving = (mapping[A] < 100) | (mapping[A] >= 140)
    assert moving.mean() >= 0.9


def test_repeats_fall_in_low_motion_frames_without_blinks():
    V = np.ones(100)
    V[30:70] = 0.05                                  # calm section
    V[45:48] += 1.0                                  # α_B · B(j): a blink inside it
    mapping = retime(np.ones(120, bool), V)          # 20 more output frames than target frames
    assert_valid(mapping, 120, 100)
    repeated = mapping[1:][np.diff(mapping) == 0]
    assert len(repeated) >= 20
    assert np.all((repeated >= 30) & (repeated < 70))
    assert not np.any((repeated >= 45) & (repeated < 48))


def test_retime_rejects_a_target_shorter_than_half_the_output():
    with pytest.raises(ParameterError, match="extend_by_ping_pong"):
        retime(np.ones(21, bool), np.ones(10))


def test_retime_of_a_long_clip_is_a_valid_path():
    """2000 output frames over 1500 target frames: monotone, steps of 0 or 1, no frame shown
    three times in a row (speed is measured in bench/retime.py, not here)."""
    rng = np.random.default_rng(3)
    A, V = rng.random(2000) < 0.7, rng.random(1500)
    m = retime(A, V)
    steps = np.diff(m)
    assert len(m) == 2000 and set(np.unique(steps)) <= {0, 1}
    assert not np.any((steps[1:] == 0) & (steps[:-1] == 0))


# ---------------------------------------------------------------- ping-pong

def test_ping_pong_indices():
    np.testing.assert_array_equal(extend_by_ping_pong(4, 10), [0, 1, 2, 3, 2, 1, 0, 1, 2, 3])
    np.testing.assert_array_equal(extend_by_ping_pong(5, 3), np.arange(5))
    np.testing.assert_array_equal(extend_by_ping_pong(1, 4), np.zeros(4))
    idx = extend_by_ping_pong(30, 100)
    assert len(idx) == 100 and set(np.abs(np.diff(idx)).tolist()) == {1}
    V = np.random.default_rng(4).random(30)
    assert_valid(retime(np.ones(100, bool), V[idx]), 100, len(idx))   # 100 > 2 · 30 works now
    with pytest.raises(ParameterError):
        extend_by_ping_pong(0, 5)


# ---------------------------------------------------------------- speech flags

def tone(seconds, sr, amplitude, freq=220.0):
    t = np.arange(int(round(seconds * sr))) / sr
    return amplitude * np.sin(2 * np.pi * freq * t)


def test_speech_flags_join_short_gaps_and_keep_pauses():
    sr, fps = 16000, 25
    parts = [np.zeros(sr),                            # 0.0–1.0 silence
             tone(1.0, sr, 0.3),                      # 1.0–2.0 speech
             np.zeros(int(0.4 * sr)),                 # 2.0–2.4 gap < 0.5 s: joined
             tone(0.8, sr, 0.05),                     # 2.4–3.2 quieter speech (−16 dB)
             np.zeros(sr),                            # 3.2–4.2 a pause: stays
             tone(0.4, sr, 0.2),                      # 4.2–4.6 speech
             np.zeros(int(0.2 * sr)),                 # 4.6–4.8 short gap: joined
             tone(0.4, sr, 0.2),                      # 4.8–5.2 speech
             np.zeros(int(0.6 * sr)),
             tone(0.03, sr, 0.3),                     # 5.8 a click: removed
             np.zeros(int(1.17 * sr))]
    x = np.concatenate(parts)
    x = x + 1e-4 * np.random.default_rng(5).standard_normal(x.size)   # −70 dB noise floor
    n = int(7.0 * fps)
    flags = speech_flags(x, sr, fps, n)
    t = np.arange(n) / fps
    expected = ((t >= 0.9) & (t <= 3.3)) | ((t >= 4.1) & (t <= 5.3))
    edges = np.array([0.9, 3.3, 4.1, 5.3])
    far = np.min(np.abs(t[:, None] - edges), axis=1) > 1.5 / fps
    np.testing.assert_array_equal(flags[far], expected[far])
    assert not flags[(t > 3.5) & (t < 3.9)].any()
    assert flags.dtype == bool and flags.shape == (n,)
    stereo = speech_flags(np.stack([x, x], axis=1), sr, fps, n)
    np.testing.assert_array_equal(stereo, flags)


def test_pauses_are_found_above_a_room_noise_floor():
    sr, fps = 16000, 25
    rng = np.random.default_rng(9)
    x = np.concatenate([tone(1.5, sr, 0.3), np.zeros(sr), tone(1.5, sr, 0.3)])
    x = x + 0.3 / np.sqrt(2) * 10 ** (-30 / 20) * rng.standard_normal(x.size)   # noise at −30 dB
    t = np.arange(100) / fps
    flags = speech_flags(x, sr, fps, 100)
    assert not flags[(t > 1.7) & (t < 2.3)].any()
    assert flags[(t < 1.3) | (t > 2.7)].all()
    assert speech_flags(x, sr, fps, 100, noise_margin_db=None).all()          # −35 dB alone: no pause


def test_silent_audio_has_no_speech():
    assert not speech_flags(np.zeros(32000), 16000, 30, 60).any()
    assert not speech_flags(np.zeros(0), 16000, 30, 10).any()
    assert speech_flags(np.zeros(16000), 16000, 30, 0).shape == (0,)


# ---------------------------------------------------------------- target signals

def synthetic_face(eye_height=5.0, iod=100.0):
    """68 points: a face whose outer eye corners are ``iod`` apart, eyes as hexagons."""
    lm = np.random.default_rng(6).uniform(0, iod, size=(68, 2))
    s = iod / 100.0
    eye = np.array([[0, 0], [10, -1], [20, -1], [30, 0], [20, 1], [10, 1]], float)
    eye[:, 1] *= eye_height
    lm[36:42] = eye * s
    lm[42:48] = (eye + [70, 0]) * s
    return lm


def test_blink_flags_open_and_closed_eyes():
    opened, closed = synthetic_face(5.0), synthetic_face(1.0)           # areas 0.02 and 0.004
    lm = np.stack([opened, closed, opened, np.full((68, 2), np.nan)])
    np.testing.assert_array_equal(blink_flags(lm), [False, True, False, False])
    np.testing.assert_allclose(eye_area(lm[:3]), [0.02, 0.004, 0.02])
    np.testing.assert_allclose(eye_area(3.0 * lm[:3] + 40.0), eye_area(lm[:3]))
    np.testing.assert_array_equal(blink_flags(lm, threshold=0.025), [True, True, True, False])


def test_motion_speed_static_known_and_scale_invariant():
    face0 = synthetic_face()
    static = np.repeat(face0[None], 10, axis=0)
    np.testing.assert_array_equal(motion_speed(static), np.zeros(10))
    shift = np.arange(10)[:, None, None] * np.array([3.0, 4.0])         # 5 px per frame
    moving = static + shift
    np.testing.assert_allclose(motion_speed(moving), 0.05)              # IOD = 100 px
    np.testing.assert_allclose(motion_speed(2.5 * moving + 7.0), motion_speed(moving))
    jitter = moving + np.random.default_rng(7).normal(0, 1, moving.shape)
    np.testing.assert_allclose(motion_speed(0.5 * jitter - 3.0), motion_speed(jitter))


def test_motion_speed_of_invalid_frames_is_the_median():
    lm = np.repeat(synthetic_face()[None], 12, axis=0)
    lm += (np.arange(12) ** 2)[:, None, None] * np.array([1.0, 0.0])   # accelerating
    lm[5] = np.nan
    v = motion_speed(lm)
    assert np.isfinite(v).all()
    assert v[5] == pytest.approx(np.median(np.delete(v, 5)))
    assert v[4] == pytest.approx((4 ** 2 - 3 ** 2) / 100)               # only the step into frame 4
    with pytest.raises(ParameterError):
        motion_speed(np.full((3, 68, 2), np.nan))
    with pytest.raises(ParameterError):
        motion_speed(np.zeros((3, 5, 2)))


# ---------------------------------------------------------------- repeated-frame interpolation

def square_at(x0, size=16, shape=(64, 96)):
    """A textured bright square with its left edge at column x0, on a dark background."""
    texture = np.random.default_rng(8).integers(150, 256, size=(size, size, 3), dtype=np.uint8)
    img = np.full(shape + (3,), 20, np.uint8)
    img[24:24 + size, x0:x0 + size] = texture
    return img


def square_frames(n, step=4):
    return [square_at(20 + step * j) for j in range(n)]


def centroid_x(img):
    g = img.astype(float).sum(axis=2)
    g = np.clip(g - 60.0, 0, None)                    # background (20 per channel) to 0
    return (g.sum(axis=0) * np.arange(g.shape[1])).sum() / g.sum()


def test_repeated_frame_is_interpolated_half_way():
    frames = square_frames(6)
    mapping = np.array([0, 1, 1, 2, 3, 4, 4, 5, 5])
    calls = []

    def get(j):
        calls.append(j)
        return frames[j]

    out = list(interpolate_repeats(get, mapping))
    assert len(out) == len(mapping) and sorted(set(calls)) == calls       # each frame fetched once
    for i in [0, 1, 3, 4, 5, 7]:
        np.testing.assert_array_equal(out[i], frames[mapping[i]])
        assert out[i] is not frames[mapping[i]]
    for i in [2, 6]:                                  # repeats of frames 1 and 4
        middle = 0.5 * (centroid_x(frames[mapping[i]]) + centroid_x(frames[mapping[i] + 1]))
        assert abs(centroid_x(out[i]) - middle) < 1.0
        truth = square_at(20 + 4 * mapping[i] + 2).astype(float)     # the square really half-way
        blend = 0.5 * (frames[mapping[i]].astype(float) + frames[mapping[i] + 1])
        assert np.abs(out[i] - truth).mean() < 0.5 * np.abs(blend - truth).mean()   # no ghosting
        assert out[i].dtype == np.uint8 and out[i].shape == frames[0].shape
    np.testing.assert_array_equal(out[8], frames[5])  # a repeat at the very end stays a copy
    listed = list(interpolate_repeats(frames, mapping))
    for a, b in zip(listed, out):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("k", [1, 2])
def test_half_warp_is_the_per_pixel_formula(k):
    """The half-way warp (one 2-channel map on a cached grid) samples image(x − ½·F(x)) with F the flow
    upsampled and scaled by k: the same bytes as building gx − ½F and gy − ½F pixel by pixel."""
    import cv2
    from pipeline.video.repeats import _warp_half
    rng = np.random.default_rng(k)
    image = rng.integers(0, 256, (60, 80, 3), np.uint8)
    flow = rng.normal(0, 3, (60 // k, 80 // k, 2)).astype(np.float32)
    up = flow if k == 1 else cv2.resize(flow, (80, 60), interpolation=cv2.INTER_LINEAR) * np.float32(k)
    gx, gy = np.meshgrid(np.arange(80, dtype=np.float32), np.arange(60, dtype=np.float32))
    want = cv2.remap(image, gx - 0.5 * up[..., 0], gy - 0.5 * up[..., 1], cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)
    assert np.array_equal(_warp_half(image, flow, k), want)
    assert not np.array_equal(want, image)            # the flow moved pixels: the comparison means something
