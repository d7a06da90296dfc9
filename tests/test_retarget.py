"""Predicted shapes re-targeted onto another person's mouth (stages/synthesize/synthesize.retarget)."""
import numpy as np

from stages.synthesize.synthesize import retarget


def shapes(n, spread, seed, centre=(60.0, 80.0)):
    rng = np.random.default_rng(seed)
    base = np.stack([np.linspace(-20, 20, 18), np.sin(np.arange(18))], 1) + np.asarray(centre)
    return base[None] + spread * rng.normal(size=(n, 1, 1)) * np.linspace(0.2, 1.0, 18)[None, :, None]


def rms(d):
    return float(np.sqrt(np.mean(np.sum((d - d.mean(0)) ** 2, axis=-1))))


def test_without_a_spread_gain_the_displacements_keep_their_size():
    lips, target = shapes(200, 1.0, 0), shapes(300, 3.0, 1, centre=(64.0, 90.0))
    model_mean = lips.mean(0)
    out = retarget(lips, model_mean, target, max_spread_gain=1.0)
    width = lambda s: np.linalg.norm(s[6] - s[0])
    scale = width(target.mean(0)) / width(model_mean)
    assert np.allclose(out, target.mean(0) + (lips - model_mean) * scale)


def test_a_damped_prediction_is_widened_to_the_targets_own_motion_within_the_cap():
    """A read speaker's model predicts a natural talker's opening at a third of its spread."""
    lips, target = shapes(200, 1.0, 0), shapes(300, 3.0, 1, centre=(64.0, 90.0))
    model_mean = lips.mean(0)
    plain = retarget(lips, model_mean, target)
    wide = retarget(lips, model_mean, target, max_spread_gain=5.0)
    gain = rms(target) / rms(plain)
    assert 2.0 < gain < 5.0
    assert abs(rms(wide) - gain * rms(plain)) < 1e-9
    assert np.allclose(wide.mean(0), plain.mean(0))                   # the mean mouth stays where it was
    capped = retarget(lips, model_mean, target, max_spread_gain=2.0)
    assert abs(rms(capped) - 2.0 * rms(plain)) < 1e-9
    lively = retarget(shapes(200, 9.0, 0), model_mean, target, max_spread_gain=5.0)
    assert np.allclose(lively, retarget(shapes(200, 9.0, 0), model_mean, target))   # never narrowed


def test_the_pool_speakers_own_prediction_is_widened_around_its_mean_and_keeps_its_correlation():
    """The same-speaker path (no re-targeting): a damped prediction of the pool's own person (an LSTM
    regressing to the mean) is widened to the pool's spread, within the cap, never narrowed."""
    from stages.synthesize.synthesize import widen
    lips, pool = shapes(200, 1.0, 0), shapes(300, 2.5, 1)
    wide = widen(lips, pool, 5.0)
    assert abs(rms(wide) - rms(pool)) < 1e-9
    assert np.allclose(wide.mean(0), lips.mean(0))
    opening = lambda s: s[:, 9, 1] - s[:, 3, 1]
    assert np.corrcoef(opening(wide), opening(lips))[0, 1] > 1 - 1e-12      # affine: what the model knows is kept
    assert abs(rms(widen(lips, pool, 1.5)) - 1.5 * rms(lips)) < 1e-9
    assert np.allclose(widen(shapes(200, 9.0, 0), pool, 5.0), shapes(200, 9.0, 0))
