"""The recording's own audio–video offset (stages/train/offsets.py): found by the lag at which audio
features best predict the mouth, and undone on the targets."""
import numpy as np
import pytest

from stages.train import offsets


def recording(lag: int, n_segments=4, m=600, d=24, seed=0, noise=0.3):
    """Segments of (x, y, ok): y is a linear map of smooth features x, delayed by ``lag`` steps (the video late)."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(d, 3))
    xs, ys, oks = [], [], []
    kernel = np.hanning(9) / np.hanning(9).sum()
    for _ in range(n_segments):
        raw = rng.normal(size=(m + 60, d))
        x = np.stack([np.convolve(raw[:, j], kernel, "same") for j in range(d)], 1)
        y_true = x @ A + noise * rng.normal(size=(m + 60, 3))
        y = np.roll(y_true, lag, axis=0)                   # what the camera shows at t happened at t - lag
        xs.append(x[30:30 + m])
        ys.append(y[30:30 + m])
        oks.append(np.ones(m, bool))
    return xs, ys, oks


@pytest.mark.parametrize("lag", [-8, 0, 6, 12])
def test_a_known_offset_is_found(lag):
    est = offsets.estimate(*recording(lag), synced=0)
    assert est["reliable"] and est["lag"] == est["best"] == lag


def test_the_offset_is_counted_from_the_lag_of_footage_in_sync():
    """Footage in sync has its mouth ``SYNCED_LAG`` steps ahead of its sound: only the rest is undone."""
    est = offsets.estimate(*recording(offsets.SYNCED_LAG + 4))
    assert est["best"] == offsets.SYNCED_LAG + 4 and est["lag"] == 4
    assert offsets.estimate(*recording(offsets.SYNCED_LAG))["lag"] == 0
    near = offsets.estimate(*recording(offsets.SYNCED_LAG + offsets.LAG_STEP))     # one step from sync: left alone
    assert near["best"] == offsets.SYNCED_LAG + offsets.LAG_STEP and near["lag"] == 0 and near["reliable"]


def test_shift_aligns_the_targets_and_marks_the_rows_it_cannot_fill():
    xs, ys, oks = recording(6, n_segments=1)
    y, ok = offsets.shift(ys[0], oks[0], 6)
    assert np.array_equal(y[:-6], ys[0][6:]) and ok[:-6].all() and not ok[-6:].any()
    y, ok = offsets.shift(ys[0], oks[0], -4)
    assert np.array_equal(y[4:], ys[0][:-4]) and not ok[:4].any()


def test_footage_whose_offset_cannot_be_estimated_is_not_shifted():
    xs, ys, oks = recording(0)
    still = [np.zeros_like(y) for y in ys]                                   # a mouth that never moves
    est = offsets.estimate(xs, still, oks)
    assert est == dict(lag=0, errors={}, reliable=False, reason="no visible mouth motion")
    rng = np.random.default_rng(3)
    unrelated = [rng.normal(size=y.shape) for y in ys]                       # a mouth that ignores the sound
    est = offsets.estimate(xs, unrelated, oks)
    assert est["lag"] == 0 and not est["reliable"] and est["reason"]
    assert offsets.estimate(xs[:1], ys[:1], oks[:1])["reason"].startswith("one segment")


def test_recording_of_a_segment():
    assert offsets.recording_of("sky_drive2_s002") == "sky_drive2"
    assert offsets.recording_of("obama_03") == "obama_03"
    assert offsets.recording_of("a_sb_s010") == "a_sb"
