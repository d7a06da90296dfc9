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


def test_a_model_with_a_skip_map_adds_it_and_survives_its_folder(tmp_path):
    import torch
    from pipeline.models.delayed_lstm import DelayedLSTM, predict_sequence
    from pipeline.models.model_folder import load_model, save_model
    torch.manual_seed(0)
    plain, skip = DelayedLSTM(6, 5, 3), DelayedLSTM(6, 5, 3, skip=True)
    state = dict(plain.state_dict(), **{"skip.weight": torch.randn(3, 6)})
    skip.load_state_dict(state)
    x = np.random.default_rng(0).normal(size=(40, 6)).astype(np.float32)
    expected = predict_sequence(plain, x, 0, "cpu") + x @ state["skip.weight"].numpy().T
    np.testing.assert_allclose(predict_sequence(skip, x, 0, "cpu"), expected, atol=1e-5)
    basis = dict(mean=np.zeros(36), components=np.eye(36)[:3])
    save_model(tmp_path, skip, dict(model="lstm", delay=0, hidden=5, layers=1, skip=True, n_features=6, n_components=3),
               np.zeros(6, np.float32), np.ones(6, np.float32), basis, dict(lip_points=list(range(18)), iod_px=60.0))
    loaded, cfg, _ = load_model(tmp_path)
    assert cfg["skip"] and loaded.skip is not None
    np.testing.assert_allclose(predict_sequence(loaded, x, 0, "cpu"), expected, atol=1e-5)


def test_inputs_are_aligned_with_their_targets_like_the_hidden_states():
    from stages.train.adapt import input_states
    x = np.arange(10, dtype=np.float32)[:, None]
    np.testing.assert_array_equal(input_states(x, 0)[:, 0], np.arange(10))
    np.testing.assert_array_equal(input_states(x, 3)[:, 0], [3, 4, 5, 6, 7, 8, 9, 0, 0, 0])   # output t → shape t − 3
