"""Personalization's read-out candidate (stages/train/adapt.py): ridge toward the base, α by cross-validation."""
import numpy as np

from stages.train.adapt import choose_alpha, ridge_readout


def linear_data(rng, n=400, h=12, k=4, noise=0.05):
    H = rng.normal(size=(n, h))
    W, b = rng.normal(size=(k, h)), rng.normal(size=k)
    return H, H @ W.T + b + noise * rng.normal(size=(n, k)), W, b


def test_weak_ridge_is_least_squares_and_strong_ridge_keeps_the_base():
    rng = np.random.default_rng(0)
    H, Y, W, b = linear_data(rng)
    W0, b0 = np.zeros_like(W), np.zeros_like(b)
    W1, b1 = ridge_readout(H, Y, W0, b0, 1e-9)
    np.testing.assert_allclose(W1, W, atol=0.02)
    np.testing.assert_allclose(b1, b, atol=0.02)
    W0 = rng.normal(size=W.shape)
    W2, _ = ridge_readout(H, Y, W0, b0, 1e9)
    np.testing.assert_allclose(W2, W0, atol=1e-4)                # shrunk to the base's weights, not to zero


def test_the_bias_follows_the_person_even_under_strong_shrinkage():
    rng = np.random.default_rng(1)
    H, Y, W, b = linear_data(rng)
    Y = Y + 5.0                                                  # the person's mean shape is elsewhere
    _, b2 = ridge_readout(H, Y, W, b, 10.0 * len(H))
    np.testing.assert_allclose(b2, b + 5.0, atol=0.3)


def test_cross_validation_prefers_weak_shrinkage_when_the_base_is_wrong_and_strong_when_it_is_right():
    rng = np.random.default_rng(2)
    H, Y, W, b = linear_data(rng, noise=0.5)
    Hs, Ys = np.array_split(H, 5), np.array_split(Y, 5)
    wrong, _ = choose_alpha(Hs, Ys, rng.normal(size=W.shape), np.zeros_like(b))
    right, errors = choose_alpha(Hs, Ys, W, b)
    assert wrong <= 1e-2 and right >= 1.0, (wrong, right, errors)
    assert set(errors) and all(np.isfinite(list(errors.values())))
