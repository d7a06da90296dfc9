"""bench/floors.py's pure parts: Rhubarb's mouth cues sampled per video frame, the energy floor, the lag convention."""
import wave

import numpy as np

from bench import floors

FPS = 25.0


def test_cues_are_sampled_at_each_frame_time_with_the_shape_map():
    # frames at 0, 0.04, 0.08, …: frame 5 is t = 0.20, the first of the D cue; frame 9 (0.36) the last
    cues = [dict(start=0.0, end=0.2, value="X"), dict(start=0.2, end=0.4, value="D"),
            dict(start=0.4, end=0.48, value="A"), dict(start=0.48, end=0.6, value="C"),
            dict(start=0.6, end=0.64, value="F")]
    got = floors.cues_to_frames(cues, 18, FPS)
    want = [0.0] * 5 + [1.0] * 5 + [0.0] * 2 + [0.6] * 3 + [0.3] + [0.0] * 2    # past the last cue: rest
    np.testing.assert_allclose(got, want)


def test_the_shapes_open_in_rhubarbs_order():
    o = floors.SHAPE_OPENING
    assert set(o) == set("ABCDEFGHX")
    assert o["X"] == o["A"] == 0.0 and o["D"] == 1.0
    assert o["A"] < o["B"] < o["C"] < o["D"]            # closed, clenched teeth, open, wide open
    assert o["C"] <= o["H"] < o["D"]                    # L: at least as open as C, less than D
    assert o["G"] < o["C"] and o["F"] < o["E"] < o["C"]


def write_wav(path, x, rate=16000):
    with wave.open(str(path), "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(rate)
        w.writeframes((np.clip(x, -1, 1) * 32767).astype("<i2").tobytes())


def test_loud_bursts_open_the_energy_floor_and_silence_closes_it(tmp_path):
    rate, seconds = 16000, 3.0
    t = np.arange(int(rate * seconds)) / rate
    loud = ((t % 1.0) >= 0.5)                                 # 0.5 s silent, 0.5 s a 200 Hz tone, three times
    x = np.where(loud, 0.5 * np.sin(2 * np.pi * 200 * t), 0.0) + 1e-4 * np.random.default_rng(0).standard_normal(len(t))
    write_wav(tmp_path / "a.wav", x, rate)
    n = int(seconds * FPS)
    opening = floors.energy_opening(tmp_path / "a.wav", n, FPS)
    phase = (np.arange(n) / FPS) % 1.0
    inner = phase > 0.6                        # loud, away from the attack
    quiet = (phase > 0.3) & (phase < 0.44)     # silent, away from the release and the next onset (RMS window ±40 ms)
    assert opening.shape == (n,)
    assert opening[inner].min() > 0.8 and opening[quiet].max() < 0.1


def test_the_lag_convention_is_the_yardsticks():
    rng = np.random.default_rng(1)
    truth = rng.standard_normal(200)
    early = np.roll(truth, -3)                 # the prediction 3 frames early: truth[t + 3] == pred[t]
    r = floors.lag_corrs(truth, early)
    assert r["lag"] == 3 and r["corr_best"] > 0.99 > r["corr"]
    truth[[10, 50]] = np.nan                   # untracked frames are dropped, as the yardstick does
    assert np.isfinite(floors.lag_corrs(truth, truth)["corr"])
