"""The pretrained speech front end (pipeline.audio.whisper_encoder): weights, log-mel, windows, seams."""
from __future__ import annotations


import numpy as np
import pytest

from pipeline.audio import front_ends, whisper_encoder as we
from pipeline.errors import ParameterError
from tests.conftest import shared

SR = 16000


def speech_like(seconds: float, seed: int = 0) -> np.ndarray:
    """Syllable-rate amplitude-modulated harmonic tones with moving pitch: a voice-like test signal."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * SR)) / SR
    f0 = 120 + 30 * np.sin(2 * np.pi * 0.7 * t)
    phase = 2 * np.pi * np.cumsum(f0) / SR
    voice = sum(np.sin(k * phase) / k for k in range(1, 12))
    env = np.clip(np.sin(2 * np.pi * 4 * t + rng.uniform(0, 6)), 0, None) ** 2
    return (0.1 * voice * env + 0.003 * rng.standard_normal(len(t))).astype(np.float32)


def test_weights_are_the_pinned_files():
    we.check_weights(we.weights_folder())            # the installed package's files hash to the pinned digests


def test_altered_or_missing_weight_file_is_one_clear_error(tmp_path):
    src = we.weights_folder()
    (tmp_path / "model.bin").symlink_to(src / "model.bin")
    text = (src / "config.json").read_text()
    (tmp_path / "config.json").write_text(text.replace("50257", "50258", 1))
    with pytest.raises(we.WeightsError, match=r"config\.json: SHA-256 is not the pinned"):
        we.check_weights(tmp_path)
    (tmp_path / "config.json").unlink()
    with pytest.raises(we.WeightsError, match=r"config\.json: whisper encoder weight file missing"):
        we.check_weights(tmp_path)


def test_log_mel_puts_a_tone_in_its_band_and_floors_at_max_minus_8():
    t = np.arange(SR * 2) / SR
    tone = (0.5 * np.sin(2 * np.pi * 1000 * t)).astype(np.float32)
    mel = we.log_mel(tone, 300)
    assert mel.shape == (80, 300)
    import librosa
    centres = librosa.mel_frequencies(n_mels=82, fmax=8000)[1:-1]
    assert abs(centres[int(np.argmax(mel[:, 50:150].mean(1)))] - 1000) < 80
    assert mel.max() - mel.min() <= 2.0 + 1e-5           # (x + 4) / 4 of a range clamped to 8
    assert np.allclose(mel[:, 250:], mel.min())          # zero padding past the 2 s sits on the floor


def test_windows_cover_the_audio_and_crossfade_weights_sum_to_one():
    starts = we.window_starts(2600, 1000, 200)
    assert starts[0] == 0 and starts[-1] + 1000 >= 2600 and np.all(np.diff(starts) == 800)
    n, ov = 500, 100
    acc = np.zeros(starts[-1] // 2 + n)
    for i, s in enumerate(starts):
        acc[s // 2:s // 2 + n] += we.crossfade_weights(n, ov, i == 0, i == len(starts) - 1)
    assert np.allclose(acc, 1.0)                        # overlapping ramps add up: no gain change at a seam
    with pytest.raises(ParameterError):
        we.window_starts(100, 100, 100)


def test_long_audio_has_no_seam_at_window_edges():
    x = speech_like(26.0)
    f = we.whisper_features(x, window_s=10.0, overlap_s=2.0)
    assert f.shape == (1 + len(x) // 160, we.STATE_DIM) and np.isfinite(f).all()
    step = np.linalg.norm(np.diff(f, axis=0), axis=1)
    # window k covers [8k, 8k + 10) s: the ramps end at 10, 18 s and start at 8, 16 s
    seams = [int(s * 100) for s in (8, 10, 16, 18)]
    at_seams = max(step[s - 2:s + 2].max() for s in seams)
    assert at_seams < np.percentile(step, 99) * 1.5, "a window edge shows as a jump in the features"


def test_bad_audio_gives_finite_features_or_one_clear_error():
    for x in (np.zeros(SR * 2, np.float32), 0.3 * np.random.default_rng(1).standard_normal(SR // 3).astype(np.float32)):
        f = front_ends.frame_features(x, "whisper")
        assert f.shape == (1 + len(x) // 160, 384) and np.isfinite(f).all()
    x = speech_like(1.0)
    x[100] = np.nan
    with pytest.raises(ParameterError, match="NaN"):
        we.whisper_features(x)


@pytest.mark.real
def test_encoder_transcribes_a_grid_clip():
    """The log-mel and the weights are Whisper's own: its decoder reads a GRID sentence from our input."""
    clip = shared("grid_s1", "video", "bgaa6n.mp4")
    if not clip.exists():
        pytest.skip(f"real footage not found: {clip}")
    import ctranslate2
    from pipeline.models.mouth_prediction import load_audio
    mel = we.log_mel(load_audio(clip), 3000)
    r = we.load_encoder(1).generate(ctranslate2.StorageView.from_array(mel[None]), [[50257, 50362]], max_length=30)
    text = "".join(r[0].sequences[0]).replace("Ġ", " ").lower()
    assert "green" in text and "now" in text, text          # "bin green at a six now"
