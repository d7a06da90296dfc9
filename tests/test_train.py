"""pca + train + predict-mouth: pure pieces on toy data (the synthetic-speaker run is in test_dvc_pipeline)."""
import json

import numpy as np
import pytest
import torch

from pipeline.errors import BadInputError
from pipeline.models import delayed_lstm
from pipeline.models.model_folder import ModelError, load_model, save_model
from pipeline.models.mouth_pca import fingerprint, project, reconstruct
from pipeline.models.mouth_prediction import frame_count, load_audio, predict_mouth
from pipeline.params import Train
from pipeline.models.mouth_pca import resample_to_100hz
from stages.pca.pca import fit_pca
from stages.train import lstm
from pipeline.measures.mouth_metrics import lagged_correlation
from tests.helpers.media import write_wav

P = Train(hidden=16, layers=1, batch_size=20, bptt=50, lr=0.01, steps=540, val_every=9)   # 60 epochs of 9 steps


def test_pca_round_trip_and_variance_order():
    rng = np.random.default_rng(0)
    latent = rng.normal(size=(500, 5)) * np.array([5, 4, 3, 2, 1])
    x = latent @ rng.normal(size=(5, 36)) + rng.normal(size=36)
    basis = fit_pca(x, 20)
    np.testing.assert_allclose(reconstruct(project(x, basis), basis).reshape(500, 36), x, atol=1e-8)
    ev = basis["explained_variance"]
    assert np.all(np.diff(ev) <= 1e-9) and basis["explained_variance_ratio"][:5].sum() > 0.999
    assert fingerprint(basis) == fingerprint({k: v.copy() for k, v in basis.items()})


def test_resample_to_100hz_is_linear_and_respects_gaps():
    t = np.arange(10) / 25.0
    c = np.column_stack([t * 3.0, -t])
    ok = np.ones(10, bool)
    ok[5] = False
    out, v = resample_to_100hz(c, ok, t, 37)
    np.testing.assert_allclose(out[:16, 0], np.arange(16) / 100 * 3.0, atol=1e-6)
    assert not v[17:24].any()                  # steps touching the invalid frame (0.20 s) are invalid
    assert v[:16].all() and v[24:37].all()


def toy_sequences(k, n_seq=30, length=300, seed=0):
    """Inputs are white noise; the target is the input k steps in the future."""
    rng = np.random.default_rng(seed)
    seqs = []
    for _ in range(n_seq):
        x = rng.normal(size=(length + k, 3)).astype(np.float32)
        seqs.append((x[:length], x[k:k + length, :2].copy(), np.ones(length, bool)))
    return seqs


@pytest.mark.slow
def test_target_delay_is_needed_to_see_the_future():
    k = 5
    train, val = toy_sequences(k), toy_sequences(k, 6, seed=1)
    loss = {}
    for d in (0, 3, 5, 8):
        model, hist, kept = lstm.train(train, val, P, d, torch.device("cpu"), seed=0)
        assert kept == hist[-1]["step"] == 540
        loss[d] = hist[-1]["val_loss"]
    assert loss[5] < 0.3 * loss[0] and loss[8] < 0.3 * loss[0]        # delay ≥ k: the future is visible
    assert loss[3] > 2 * loss[5]                                      # delay < k: still blind to part of it
    assert loss[0] > 1.5                                              # ≈ 2 (two unit-variance targets)


def test_delayed_pairs_alignment():
    x = np.arange(6, dtype=np.float32)[:, None]
    xd, yd, md = lstm.delayed_pairs(x, x * 10, np.ones(6, bool), 2)
    assert len(xd) == 8 and np.all(yd[md, 0] == np.arange(6) * 10) and not md[:2].any()


@pytest.fixture(scope="module")
def model_dir(tmp_path_factory):
    rng = np.random.default_rng(0)
    folder = tmp_path_factory.mktemp("model")
    net = delayed_lstm.DelayedLSTM(28, 12, 20)
    basis = fit_pca(rng.normal(size=(200, 36)), 20)
    save_model(folder, net, dict(model="lstm", delay=20, hidden=12, layers=1, n_features=28, n_components=20,
                                 feature_rate=100.0, params={}), np.zeros(28, np.float32), np.ones(28, np.float32),
               basis, dict(lip_points=list(range(18)), iod_px=72.0))
    return folder


def test_chunked_inference_equals_one_pass(model_dir):
    model, config, _ = load_model(model_dir)
    x = np.random.default_rng(1).normal(size=(437, 28)).astype(np.float32)
    one = delayed_lstm.predict_sequence(model, x, config["delay"], "cpu")
    for chunk in (1, 37, 100):
        np.testing.assert_allclose(delayed_lstm.predict_sequence(model, x, config["delay"], "cpu", chunk), one, atol=1e-5)
    assert one.shape == (437, 20)


@pytest.mark.parametrize("fps,seconds,frames", [(29.97, 3.0, 90), (30000 / 1001, 10.0, 300), (25, 3.0, 75),
                                                (30, 1.7, 51)])
def test_frame_counts(model_dir, fps, seconds, frames):
    samples = np.random.default_rng(0).normal(size=int(seconds * 16000)).astype(np.float32) * 0.1
    assert frame_count(len(samples), fps) == frames
    out = predict_mouth(samples, model_dir, fps)
    assert out["coeffs"].shape == (frames, 20) and out["lip_points"].shape == (frames, 18, 2)
    assert np.allclose(out["frame_time"][1], 1 / fps)


def tone_wav(path, seconds, rate, channels, silent=False):
    """A WAV of a 200 Hz tone switched on and off at 2 Hz (or silence)."""
    t = np.arange(int(seconds * rate)) / rate
    x = np.zeros_like(t) if silent else 0.3 * np.sin(2 * np.pi * 200 * t) * (np.sin(2 * np.pi * 2 * t) > 0)
    return write_wav(path, x, rate, channels)


@pytest.mark.parametrize("rate,channels", [(8000, 1), (22050, 2), (44100, 6), (48000, 2)])
def test_any_rate_and_channel_count(tmp_path, model_dir, rate, channels):
    samples = load_audio(tone_wav(tmp_path / "a.wav", 2.0, rate, channels))
    assert abs(len(samples) - 32000) <= 2
    out = predict_mouth(samples, model_dir, 25)
    assert len(out["coeffs"]) == 50 and np.isfinite(out["coeffs"]).all()


def test_silent_and_short_audio(tmp_path, model_dir):
    silent = load_audio(tone_wav(tmp_path / "s.wav", 1.0, 16000, 1, silent=True))
    assert np.all(silent == 0)
    assert np.isfinite(predict_mouth(silent, model_dir, 25)["coeffs"]).all()
    with pytest.raises(BadInputError, match=r"short.wav: audio too short \(0.30 s"):
        load_audio(tone_wav(tmp_path / "short.wav", 0.3, 16000, 1))


def test_mismatched_model_folders_fail_loudly(tmp_path, model_dir):
    with pytest.raises(ModelError, match="trained on PCA basis"):
        load_model(model_dir, expect_fingerprint="0123456789abcdef")
    broken = tmp_path / "broken"
    broken.mkdir()
    for f in ("weights.pt", "arrays.npz"):
        (broken / f).write_bytes((model_dir / f).read_bytes())
    cfg = json.loads((model_dir / "config.json").read_text())
    (broken / "config.json").write_text(json.dumps(dict(cfg, pca_fingerprint="feedfacefeedface")))
    with pytest.raises(ModelError, match="does not match config.json"):
        load_model(broken)
    (broken / "config.json").write_text(json.dumps(dict(cfg, hidden=30)))
    with pytest.raises(ModelError, match="weights.pt does not fit"):
        load_model(broken)
    with pytest.raises(ModelError, match="missing weights.pt"):
        load_model(tmp_path)


def test_lagged_correlation_finds_the_shift():
    rng = np.random.default_rng(0)
    true = np.convolve(rng.normal(size=300), np.ones(5) / 5, "same")
    pred = np.roll(true, 3)
    corr = lagged_correlation(pred, true, 5)
    assert max(corr, key=corr.get) == 3
