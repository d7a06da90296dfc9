"""Personalization's choice (stages/train/selection.py): folds over segments, a score that follows the lips,
a change from the base only beyond noise."""
import numpy as np
import pytest

from stages.train import selection


def test_fold_plan_covers_every_segment_once_in_contiguous_blocks():
    for n, k in [(2, 5), (6, 5), (11, 5), (5, 5), (30, 4)]:
        plan = selection.fold_plan(n, k)
        assert len(plan) == min(n, k)
        assert np.array_equal(np.concatenate(plan), np.arange(n))           # once each, in time order
        assert all(np.all(np.diff(b) == 1) for b in plan)                   # contiguous
        sizes = [len(b) for b in plan]
        assert max(sizes) - min(sizes) <= 1
    with pytest.raises(ValueError, match="1 segment"):
        selection.fold_plan(1, 5)


def test_utility_prefers_following_the_lips_over_a_slightly_lower_error():
    """The news anchor of issue 47: readout (ratio 0.92, corr 0.39) was kept over encoder_readout
    (0.97, 0.65) by mouth error alone."""
    assert selection.utility(0.65, 0.97) > selection.utility(0.39, 0.92)
    assert selection.utility(float("nan"), 0.9) == pytest.approx(0.1)       # no correlation counts as 0
    assert selection.utility(0.5, 1.0) == pytest.approx(0.5)


def test_a_gain_within_noise_does_not_replace_the_base():
    assert not selection.beats([0.3, -0.25, 0.02, -0.01, 0.01])             # mean 0.014, SE 0.09
    assert selection.beats([0.10, 0.12, 0.08, 0.11, 0.09])
    assert not selection.beats([-0.1, -0.1, -0.1])
    assert not selection.beats([0.5])                                       # one fold: no spread, no change


def test_choose_keeps_the_base_unless_a_candidate_beats_it_on_the_folds():
    base = [0.30, 0.50, 0.20, 0.40, 0.35]
    noisy = [0.60, 0.20, 0.45, 0.30, 0.38]            # higher mean (0.386 vs 0.35), but not fold by fold
    steady = [0.36, 0.55, 0.27, 0.44, 0.41]           # +0.056 on every fold
    better = [0.45, 0.66, 0.33, 0.58, 0.49]           # +0.13 on every fold
    name, table = selection.choose(dict(base=base, noisy=noisy))
    assert name == "base" and not table["noisy"]["beats_base"] and table["noisy"]["mean"] > table["base"]["mean"]
    name, table = selection.choose(dict(base=base, noisy=noisy, steady=steady, better=better))
    assert name == "better" and table["steady"]["beats_base"]
    assert table["better"]["gain"] == pytest.approx(np.mean(np.subtract(better, base)))
