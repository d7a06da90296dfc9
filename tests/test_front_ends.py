"""Audio front ends (issue 13): pocketsphinx phone indicators, their combination with MFCC, and
models that refuse another front end's frames."""
import json

import numpy as np
import pytest

from pipeline.audio import front_ends
from pipeline.errors import ParameterError
from pipeline.models.mouth_prediction import load_audio, predict_mouth
from pipeline.audio.phone_features import PHONES, phone_indicators, recognize_phones
from tests.conftest import shared


def grid_words(name):
    """GRID alignment: (start s, end s, word) at 25 kHz sample units."""
    rows = [line.split() for line in shared("grid_s1", "align", f"{name}.align").read_text().splitlines() if line.strip()]
    return [(int(a) / 25000, int(b) / 25000, w) for a, b, w in rows]


@pytest.mark.parametrize("name", ["bgaa6n", "lrae3s"])
@pytest.mark.real
def test_phones_fall_inside_words_and_silence_outside(name):
    """Against GRID's word alignment: frames inside words are mostly recognised as phones, frames
    in the alignment's leading / trailing silence mostly as silence."""
    samples = load_audio(shared("grid_s1", "video", f"{name}.mp4"))
    ind = phone_indicators(samples)
    assert ind.shape == (1 + len(samples) // 160, len(PHONES))
    assert (ind.sum(1) == 1).all()                               # exactly one class per frame
    t = np.arange(len(ind)) / 100.0
    words = grid_words(name)
    in_word = np.zeros(len(ind), bool)
    for a, b, w in words:
        if w not in ("sil", "sp"):
            in_word |= (t >= a + 0.03) & (t < b - 0.03)
    edge_sil = (t < words[0][1] - 0.05) | (t > words[-1][0] + 0.05)
    speech = ind[:, 0] == 0
    assert speech[in_word].mean() > 0.9, speech[in_word].mean()
    assert (~speech[edge_sil]).mean() > 0.8, (~speech[edge_sil]).mean()
    # and the speech holds several different phones, not one class
    assert len(np.unique(ind[speech].argmax(1))) >= 10


@pytest.mark.real
def test_phones_of_a_clip_do_not_depend_on_what_was_decoded_before():
    """The phonetic store must be deterministic: a worker decodes videos in any order."""
    a = load_audio(shared("hdtf", "RD_Radio36_000.wav"))       # 16 s of another voice and channel
    b = load_audio(shared("grid_s1", "video", "lrae3s.mp4"))
    first = recognize_phones(b)
    recognize_phones(a)
    assert recognize_phones(b) == first


def test_silence_and_noise_give_silence_not_a_crash():
    assert recognize_phones(np.zeros(16000, np.float32)) == []
    silent = phone_indicators(np.zeros(16000, np.float32))
    assert silent.shape == (101, 40) and (silent[:, 0] == 1).all()
    noise = phone_indicators(0.05 * np.random.default_rng(0).standard_normal(32000).astype(np.float32))
    assert np.isfinite(noise).all() and (noise.sum(1) == 1).all()
    assert phone_indicators(np.zeros(16000, np.float32), n_frames=50).shape == (50, 40)


def test_combined_front_end_widths_and_utterance_norm():
    rng = np.random.default_rng(0)
    mfcc, phones = rng.normal(3.0, 2.0, (120, 28)).astype(np.float32), np.eye(40, dtype=np.float32)[rng.integers(0, 40, 118)]
    x = front_ends.combine("mfcc+phonetic", mfcc, phones)
    assert x.shape == (118, 68) == (118, front_ends.feature_dim("mfcc+phonetic"))
    assert front_ends.feature_dim("mfcc") == 28 and front_ends.feature_dim("phonetic") == 40
    n = front_ends.utterance_norm(x, "mfcc+phonetic")
    assert np.allclose(n[:, :28].mean(0), 0, atol=1e-5) and np.allclose(n[:, :28].std(0), 1, atol=1e-3)
    assert np.array_equal(n[:, 28:], x[:, 28:])                # indicators untouched
    with pytest.raises(ParameterError, match="choose one of mfcc, phonetic, mfcc\\+phonetic"):
        front_ends.feature_dim("lpc")
    with pytest.raises(ParameterError, match="needs MFCC and phone indicators"):
        front_ends.combine("mfcc+phonetic", mfcc, None)


def test_a_model_given_another_front_ends_frames_says_so(tmp_path):
    """A folder whose config claims one front end but whose normalisation has another width."""
    from pipeline.models import delayed_lstm
    from pipeline.models.model_folder import save_model
    from stages.pca.pca import fit_pca
    net = delayed_lstm.DelayedLSTM(28, 8, 20)
    basis = fit_pca(np.random.default_rng(0).normal(size=(100, 36)), 20)
    save_model(tmp_path, net, dict(model="lstm", delay=20, hidden=8, layers=1, n_features=28, n_components=20,
                                   feature_rate=100.0, features="mfcc", params={}), np.zeros(28, np.float32),
               np.ones(28, np.float32), basis, dict(lip_points=list(range(18)), iod_px=72.0))
    samples = 0.1 * np.random.default_rng(1).standard_normal(16000).astype(np.float32)
    assert predict_mouth(samples, tmp_path, 25)["coeffs"].shape == (25, 20)
    cfg = json.loads((tmp_path / "config.json").read_text())
    (tmp_path / "config.json").write_text(json.dumps(dict(cfg, features="mfcc+phonetic")))
    with pytest.raises(ParameterError, match="expects 28-D input frames but its front end 'mfcc\\+phonetic' gives 68-D"):
        predict_mouth(samples, tmp_path, 25)


def test_vtlp_moves_a_formant_by_the_warp_factor():
    from pipeline.audio import audio_features as af
    assert np.allclose(af.vtlp_warp([0, 1000, 8000], 1.0), [0, 1000, 8000])
    f = np.linspace(0, 8000, 200)
    for a in (0.85, 1.15):
        w = af.vtlp_warp(f, a)
        assert w[0] == 0 and w[-1] == pytest.approx(8000) and (np.diff(w) > 0).all()   # monotone, ends fixed
        assert af.vtlp_warp(1000, a) == pytest.approx(1000 * a)
    t = np.arange(16000) / 16000
    tone = (0.3 * np.sin(2 * np.pi * 1000 * t)).astype(np.float32)
    assert np.array_equal(af.mfcc_features(tone, warp=1.0), af.mfcc_features(tone))
    peak = lambda a: int(np.median(af.log_mel(tone, a)[0].argmax(1)))
    centres = af.mel_to_hz(np.linspace(0, af.hz_to_mel(8000), 42))[1:-1]
    assert abs(centres[peak(1.15)] - 1150) < abs(centres[peak(1.15)] - 1000)   # the tone now reads as ~1150 Hz
    assert peak(0.85) < peak(1.0) < peak(1.15)


def test_lstm_trains_on_augmented_copies():
    """Training sequences with K variants of x: one drawn per epoch, same shapes out."""
    from pipeline.params import Train
    from stages.train import lstm
    rng = np.random.default_rng(0)
    seqs = []
    for _ in range(4):
        y = rng.normal(size=(300, 3)).astype(np.float32)
        x = np.stack([np.repeat(y, 2, 1) * s for s in (1.0, 0.9, 1.1)]).astype(np.float32)   # (3, 300, 6)
        seqs.append((x, y, np.ones(300, bool)))
    p = Train(hidden=16, steps=180, val_every=6, batch_size=4, bptt=50, lr=0.01)      # 30 epochs of 6 steps
    model, hist, _ = lstm.train(seqs, [(s[0][0], s[1], s[2]) for s in seqs], p, 0, "cpu")
    assert hist[-1]["val_loss"] < 0.3 * hist[0]["val_loss"], hist


def test_speak_names_the_front_end_that_suits_another_voice():
    from lipsynth.speak import front_end_advice
    assert "train.features: whisper" in front_end_advice(dict(features="mfcc", params=dict(vtlp_warps=[])))
    assert "train.features: whisper" in front_end_advice(dict(features="mfcc+phonetic"))
    assert "train.features: whisper" not in front_end_advice(dict(features="whisper"))
    assert "phone indicators" in front_end_advice(dict(features="phonetic", params=dict(vtlp_warps=[])))


def test_pitch_shift_keeps_formants_and_timing():
    from pipeline.audio import audio_features as af
    t = np.arange(32000) / 16000

    def voice(f0):      # harmonics of f0 under one fixed formant envelope (peaks at 700 and 1800 Hz), on 0.5–1.5 s
        env = lambda f: np.exp(-((f - 700) / 150) ** 2) + 0.5 * np.exp(-((f - 1800) / 200) ** 2)
        x = sum(env(k * f0) * np.sin(2 * np.pi * k * f0 * t) for k in range(1, int(3500 / f0)))
        return (0.3 * x * ((t > 0.5) & (t < 1.5))).astype(np.float32)

    low = voice(110.0)
    assert np.array_equal(af.pitch_shifted_mfcc(low, 0.0), af.mfcc_features(low))
    up = af.pitch_shifted_mfcc(low, 4.0)
    assert up.shape == af.mfcc_features(low).shape
    # timing kept: the energy rises and falls at the same 10 ms frames
    on = lambda m: np.flatnonzero(m[:, 13] > m[:, 13].max() - 3)[[0, -1]]
    assert np.abs(on(up) - on(af.mfcc_features(low))).max() <= 1
    # formants kept: closer to the same envelope sung 4 semitones higher than to the audio merely sped up
    from scipy.signal import resample_poly
    truth = af.mfcc_features(voice(110.0 * 2 ** (4 / 12)))
    sped = af.mfcc_features(resample_poly(low, 50, 63).astype(np.float32))   # played ×1.26 faster: formants move too
    mid = slice(60, 110)                                                     # 0.6–1.1 s: voiced in all three
    d = lambda a, b: np.abs(a[mid, 1:13] - b[mid, 1:13]).mean()
    assert d(up, truth) < 0.6 * d(sped, truth), (d(up, truth), d(sped, truth))     # measured 3.5 vs 7.9


def test_the_mouth_rests_in_silence_and_nowhere_else():
    """Digital silence moves the LSTM's mouth to its rest shape (inside the stretch, cross-faded);
    speech and room-noise pauses keep the model's own prediction."""
    from pipeline.audio.audio_features import SILENCE_DBFS, silent_frames
    from pipeline.models.mouth_prediction import rest_in_silence
    rng = np.random.default_rng(0)
    sr = 16000
    t = np.arange(sr) / sr
    speech = (0.2 * np.sin(2 * np.pi * 180 * t) * (0.6 + 0.4 * np.sin(2 * np.pi * 3 * t))).astype(np.float32)
    room = 0.001 * rng.standard_normal(sr).astype(np.float32)                # a pause with room noise at −60 dBFS
    samples = np.concatenate([speech, np.zeros(sr, np.float32), speech, room, speech])
    n = 1 + len(samples) // 160
    c100 = rng.standard_normal((n, 20)).astype(np.float32)
    rest = np.full(20, 5.0, np.float32)
    out = rest_in_silence(c100, samples, rest)
    assert np.allclose(out[120:180], rest)                                # the middle of the silent second
    assert np.array_equal(out[:95], c100[:95]) and np.array_equal(out[205:], c100[205:])   # speech and the noisy pause
    assert 0 < np.abs(out[103] - c100[103]).max() < np.abs(rest - c100[103]).max()         # a ramp, not a jump
    pauses = silent_frames(samples, n)                                    # relative to the peak: both pauses
    assert pauses[120:180].all() and pauses[320:380].all() and not pauses[20:80].any()
    assert not silent_frames(samples, n, SILENCE_DBFS, None)[320:380].any()
