"""MFCC features (paper 000 §3.1) against an independent librosa computation."""
import librosa
import numpy as np
import pytest

from pipeline.audio import audio_features as af
from pipeline.errors import ParameterError


def known_signal(seconds=1.5, sr=16000):
    t = np.arange(int(seconds * sr)) / sr
    x = 0.3 * np.sin(2 * np.pi * 220 * t) + 0.2 * np.sin(2 * np.pi * (300 + 900 * t) * t)
    x[int(0.5 * sr):int(0.7 * sr)] = 0.0                    # a pause
    return (x * (0.5 + 0.5 * np.sin(2 * np.pi * 3 * t))).astype(np.float32)


def test_mfcc_matches_librosa_reference():
    x = known_signal()
    ours = af.mfcc_features(x)
    mel = librosa.feature.melspectrogram(y=x.astype(np.float64), sr=16000, n_fft=512, win_length=400, hop_length=160,
                                         window="hann", center=True, pad_mode="constant", power=2.0, n_mels=40,
                                         htk=True, norm=None)
    ref = librosa.feature.mfcc(S=np.log(mel + af.EPS), n_mfcc=13, dct_type=2, norm="ortho").T
    assert ours.shape == (1 + len(x) // 160, 28)
    assert ref.shape[0] == ours.shape[0]
    np.testing.assert_allclose(ours[:, :13], ref, rtol=1e-3, atol=2e-3)


def test_mel_filterbank_matches_librosa_htk():
    ref = librosa.filters.mel(sr=16000, n_fft=512, n_mels=40, htk=True, norm=None)
    np.testing.assert_allclose(af.mel_filterbank(), ref, atol=1e-6)


def test_log_energy_and_deltas():
    x = known_signal()
    f = af.mfcc_features(x)
    # log mean energy follows the pause: much lower inside it than around it
    assert f[60, 13] < f[30, 13] - 10
    ref_delta = librosa.feature.delta(f[:, :14].T, width=5, order=1, mode="interp").T
    np.testing.assert_allclose(f[3:-3, 14:], ref_delta[3:-3], rtol=1e-3, atol=1e-3)


def test_frame_t_is_centred_at_t_over_100():
    x = np.zeros(16000, np.float32)
    x[8000 - 2:8000 + 2] = 1.0                              # a click at 0.5 s
    c0 = af.mfcc_features(x)[:, 0]                          # Hann-weighted: peaks where the click is central
    assert int(np.argmax(c0)) == 50


def test_rms_normalize_target_and_silence():
    x = known_signal() * 0.01
    y = af.rms_normalize(x, -23.0)
    assert 20 * np.log10(np.sqrt(np.mean(y.astype(np.float64) ** 2))) == pytest.approx(-23.0, abs=0.1)
    assert np.all(af.rms_normalize(np.zeros(1000, np.float32)) == 0)


def test_wrong_rate_or_shape_is_a_parameter_error():
    with pytest.raises(ParameterError, match="16000 Hz"):
        af.mfcc_features(np.zeros(100, np.float32), sample_rate=44100)
    with pytest.raises(ParameterError, match="mono"):
        af.mfcc_features(np.zeros((2, 100), np.float32))


def test_cmvn_removes_a_per_dimension_channel_offset_and_gain():
    from pipeline.audio.audio_features import cmvn
    rng = np.random.default_rng(0)
    x = rng.normal(size=(500, 28)) * rng.uniform(0.5, 3, 28) + rng.normal(size=28) * 5
    y = cmvn(x)
    np.testing.assert_allclose(y.mean(0), 0, atol=1e-5)
    np.testing.assert_allclose(y.std(0), 1, atol=1e-4)
    other_channel = x * rng.uniform(0.5, 2.0, 28) + rng.normal(size=28) * 3     # e.g. a different microphone
    np.testing.assert_allclose(cmvn(other_channel), y, atol=1e-4)
