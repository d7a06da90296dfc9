"""Karras et al. 2017 input features (§3.2) and network (§3.1, Table 1)."""
import numpy as np
import pytest
import torch

from pipeline.audio import speech_autocorrelation as ac
from pipeline.errors import BadInputError
from pipeline.models.karras_network import KarrasNetwork, multiply_adds

SR = ac.SAMPLE_RATE


def test_autocorrelation_of_a_sinusoid_peaks_at_its_period():
    n = np.arange(ac.FRAME)
    frame = np.sin(2 * np.pi * n / 20.0)                         # period 20 samples (800 Hz)
    r = ac.frame_autocorrelation(frame)
    assert r.shape == (32,) and np.argmax(r[5:]) + 5 == 20 and r[10] < 0
    w = np.hanning(ac.FRAME + 2)[1:-1]
    assert r[0] == pytest.approx(np.sum((frame - frame.mean()) ** 2 * w ** 2))
    assert np.allclose(ac.frame_autocorrelation(frame + 3.0), r)          # DC removed


def test_windows_are_centred_520_ms_and_zero_padded():
    x = np.zeros(2 * SR)
    x[SR] = 1.0                                                             # a click at 1.0 s
    f = ac.autocorrelation_features(x, np.array([1.0, 1.0 + 0.26 - 0.004, 0.1]))
    assert f.shape == (3, 64, 32) and f.dtype == np.float32
    energy = f[..., 0]
    assert set(np.flatnonzero(energy[0] > 0)) <= {30, 31, 32, 33}           # the centre frames
    assert np.flatnonzero(energy[1] > 0).max() <= 1                         # the first frames, 256 ms later
    assert (energy[2] == 0).all()                                           # before the click: silence/padding
    assert ac.HALF * 2 == int(0.52 * SR)


def test_normalisation_and_bad_input():
    assert np.abs(ac.normalise_track(np.array([0.1, -0.25, 0.2]))).max() == 1.0
    with pytest.raises(BadInputError, match="quiet.wav.*silent"):
        ac.autocorrelation_features(np.zeros(SR), np.array([0.5]), "quiet.wav")
    with pytest.raises(BadInputError, match="blip.wav.*too short"):
        ac.autocorrelation_features(np.ones(4000), np.array([0.1]), "blip.wav")


def test_network_is_table_1():
    m = KarrasNetwork(15066)
    assert sum(p.numel() for p in m.parameters()) == pytest.approx(3.7e6, rel=0.02)   # "3.7 million" (§3.1)
    assert 50e6 < multiply_adds(m) < 80e6
    shapes = []
    hook = lambda mod, inp, out: shapes.append(tuple(out.shape[1:]))
    for conv in list(m.formant) + list(m.articulation):
        conv.register_forward_hook(hook)
    y = m(torch.randn(4, 1, 64, 32), torch.zeros(4, 16))
    assert y.shape == (4, 15066)
    assert shapes == [(72, 64, 16), (108, 64, 8), (162, 64, 4), (243, 64, 2), (256, 64, 1),
                      (256, 32, 1), (256, 16, 1), (256, 8, 1), (256, 4, 1), (256, 1, 1)]


def test_emotion_changes_the_output_and_pca_initialises_the_last_layer():
    torch.manual_seed(0)
    m = KarrasNetwork(6, emotion_dim=4)
    x = torch.randn(2, 1, 64, 32)
    assert not torch.allclose(m(x, torch.zeros(2, 4)), m(x, torch.ones(2, 4)))
    mean, comps = np.arange(6.0), np.eye(6)[:3]                 # 3 components (< 150): zero-padded
    m.init_output_from_pca(mean, comps)
    with torch.no_grad():
        m.fc150.weight.zero_()
        m.fc150.bias.copy_(torch.arange(150.0))
    out = m(x, torch.zeros(2, 4))
    assert torch.allclose(out, torch.tensor(mean + np.arange(3.0) @ comps, dtype=torch.float32).expand(2, 6))


def test_training_noise_is_shared_within_a_pair():
    torch.manual_seed(1)
    m = KarrasNetwork(5)
    x = torch.randn(1, 1, 64, 32).repeat(4, 1, 1, 1)
    e = torch.zeros(4, 16)
    y = m(x, e, noise=True)
    assert torch.allclose(y[0], y[1]) and torch.allclose(y[2], y[3]) and not torch.allclose(y[0], y[2])
    assert not torch.allclose(y[0], m(x, e)[0])
