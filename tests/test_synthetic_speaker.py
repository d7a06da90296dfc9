"""Properties of the synthetic talking-head corpus (stages/synthetic_speaker/)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import av
import dlib
import numpy as np
import pytest

from pipeline.face import dlib_face
from scipy.ndimage import uniform_filter1d

from stages.synthetic_speaker import articulation, face_template, language, render
from stages.synthetic_speaker import generate as gen
from stages.registry import stage

ROOT = Path(__file__).resolve().parents[1]
WIDTH, HEIGHT, FPS, RATE = 360, 288, 25, 16000
SECONDS = 4.0
BILABIALS = ("m", "b", "p")


@pytest.fixture(scope="module")
def template():
    return face_template.build_template(WIDTH, HEIGHT)


@pytest.fixture(scope="module")
def script(template):
    return gen.script_video(template, seed=7, video_index=0, seconds=SECONDS, fps=FPS, sample_rate=RATE)


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    """A one-clip corpus written twice by the CLI (same seed) into two directories."""
    base = tmp_path_factory.mktemp("synthetic")
    params = base / "params.yaml"
    params.write_text(
        "synthetic_speaker:\n  seed: 3\n  n_videos: 1\n  seconds_per_video: 3.0\n  fps: 25\n"
        f"  width: {WIDTH}\n  height: {HEIGHT}\n  sample_rate: {RATE}\n  out_dir: {base / 'first'}\n")
    (base / "first").mkdir()
    (base / "first" / "stale.txt").write_text("from an older run")
    env = dict(os.environ, LIPSYNTH_PARAMS=str(params))
    command = [sys.executable, "-m", stage("synthetic_speaker").module]
    subprocess.run(command, cwd=ROOT, env=env, check=True, capture_output=True)
    subprocess.run(command + ["--out", str(base / "second")], cwd=ROOT, env=env, check=True,
                   capture_output=True)
    return base


def decoded_frames(path: Path) -> list[np.ndarray]:
    """RGB frames; copied to contiguous memory because dlib ignores numpy row padding."""
    with av.open(str(path)) as container:
        return [np.ascontiguousarray(f.to_ndarray(format="rgb24")) for f in container.decode(video=0)]


def best_lag_ms(leader: np.ndarray, follower: np.ndarray, step_ms: float, max_lag: int = 30) -> float:
    """Lag (ms) maximising corr(leader[t], follower[t + lag])."""
    a = (leader - leader.mean()) / leader.std()
    b = (follower - follower.mean()) / follower.std()
    lags = np.arange(-max_lag, max_lag + 1)
    corr = [np.mean(a[max(0, -k):len(a) - max(0, k)] * b[max(0, k):len(b) - max(0, -k)]) for k in lags]
    return float(lags[int(np.argmax(corr))] * step_ms)


def test_generator_is_deterministic(template, script):
    again = gen.script_video(template, seed=7, video_index=0, seconds=SECONDS, fps=FPS, sample_rate=RATE)
    for field in ("phones", "mouth", "closure", "pose", "landmarks", "audio"):
        np.testing.assert_array_equal(getattr(script, field), getattr(again, field))
    for t in (0, 37, 81):
        args = (script.landmarks[t].astype(float), float(script.closure[t]), script.pose[t].astype(float))
        np.testing.assert_array_equal(render.render_frame(template, *args),
                                      render.render_frame(template, *args))
    other = gen.script_video(template, seed=7, video_index=1, seconds=SECONDS, fps=FPS, sample_rate=RATE)
    assert not np.array_equal(other.audio, script.audio)


def test_phone_sequence_tiles_the_clip_with_pauses(script):
    phones = script.phones
    assert phones["start"][0] == 0.0 and phones["end"][-1] == SECONDS
    np.testing.assert_array_equal(phones["start"][1:], phones["end"][:-1])
    assert set(phones["label"]) <= set(language.PHONES)
    assert phones["label"][0] == "sil" and phones["label"][-1] == "sil"
    inner_pauses = phones[1:-1][phones["label"][1:-1] == "sil"]
    assert np.all((inner_pauses["end"] - inner_pauses["start"] >= 0.3 - 1e-9)
                  & (inner_pauses["end"] - inner_pauses["start"] <= 1.0 + 1e-9))
    assert (phones["label"] != "sil").sum() >= 10


def test_mouth_follows_phones_ahead_of_the_sound(script):
    phones = script.phones
    rng = gen.video_rng(7, 0, "mouth")
    targets, dominance = articulation.mouth_targets(phones, rng)
    times = np.arange(int(SECONDS * 1000)) / 1000.0
    opening = articulation.mouth_trajectory(phones, targets, dominance, times)[:, 0]
    np.testing.assert_allclose(opening[::40], script.mouth[:, 0], atol=1e-6)
    step_target = targets[language.phone_index_at(phones, times), 0]
    lag = best_lag_ms(opening, step_target, 1.0, max_lag=200)
    assert 50 <= lag <= 110, lag

    lead = articulation.MOUTH_LEAD_S
    centres = 0.5 * (phones["start"] + phones["end"])
    open_at = np.interp(centres - lead, times, opening)
    assert np.all(open_at[np.isin(phones["label"], BILABIALS)] < 0.1)
    assert np.mean(open_at[phones["label"] == "a"]) > 0.6
    long_silence = (phones["label"] == "sil") & (phones["end"] - phones["start"] > 0.5)
    assert np.all(open_at[long_silence] < 0.02)


def test_audio_is_speech_like_and_lags_the_mouth(script):
    assert script.audio.dtype == np.float32 and len(script.audio) == int(SECONDS * RATE)
    audio = script.audio.astype(np.float64)
    assert 0.5 < np.abs(audio).max() <= 1.0
    phones = script.phones
    def segment_power(index):
        a, b = int(phones["start"][index] * RATE), int(phones["end"][index] * RATE)
        return np.mean(audio[a:b] ** 2)
    speech = [segment_power(i) for i in np.flatnonzero(phones["label"] != "sil")]
    silence = [segment_power(i) for i in np.flatnonzero(phones["label"] == "sil")]
    assert 10 * np.log10(np.median(speech) / np.max(silence)) > 30

    hop = RATE // 100
    envelope = np.log(np.sqrt(uniform_filter1d(audio**2, 4 * hop)[::hop]) + 1e-4)
    frame_times = np.arange(len(envelope)) / 100.0
    targets, dominance = articulation.mouth_targets(phones, gen.video_rng(7, 0, "mouth"))
    opening = articulation.mouth_trajectory(phones, targets, dominance, frame_times)[:, 0]
    assert 30 <= best_lag_ms(opening, envelope, 10.0) <= 130


def test_fricatives_are_high_frequency_noise(script):
    audio, phones = script.audio, script.phones
    def high_band_fraction(index):
        start, end = phones["start"][index], phones["end"][index]
        a, b = int((0.8 * start + 0.2 * end) * RATE), int((0.2 * start + 0.8 * end) * RATE)
        power = np.abs(np.fft.rfft(audio[a:b] * np.hanning(b - a))) ** 2
        freqs = np.fft.rfftfreq(b - a, 1.0 / RATE)
        return power[freqs > 2000].sum() / power.sum()
    vowels = [high_band_fraction(i) for i in np.flatnonzero(np.isin(phones["label"], language.VOWELS))]
    sibilants = [high_band_fraction(i) for i in np.flatnonzero(np.isin(phones["label"], ("s", "sh")))]
    assert len(sibilants) >= 3, "the script has no sibilants: the test's precondition failed"
    assert np.median(vowels) < 0.1
    assert np.median(sibilants) > 0.8


def test_landmarks_inside_frame_and_mesh_never_folds(template, script):
    landmarks = script.landmarks
    assert landmarks.shape == (int(SECONDS * FPS), 68, 2) and landmarks.dtype == np.float32
    assert np.all((landmarks[..., 0] >= 0) & (landmarks[..., 0] < WIDTH))
    assert np.all((landmarks[..., 1] >= 0) & (landmarks[..., 1] < HEIGHT))

    def signed_areas(points):
        a, b, c = (points[template.triangles[:, j]] for j in range(3))
        return 0.5 * ((b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0])
    reference = np.sign(signed_areas(template.mesh_points))
    for t in range(len(landmarks)):
        points = articulation.frame_mesh_points(template, landmarks[t].astype(float),
                                                script.pose[t].astype(float))
        areas = signed_areas(points)
        assert np.all((np.sign(areas) == reference) | (np.abs(areas) < render.MIN_TRIANGLE_AREA)), t


def test_blinks_and_pose_are_smooth_and_bounded(script):
    blink_frames = np.flatnonzero(script.closure >= 0.5)
    assert 0 < len(blink_frames) < 0.15 * len(script.closure)
    pose = script.pose
    assert np.all(np.abs(pose[:, :3]) < 8.0)
    assert np.all(np.abs(np.diff(pose[:, :3], axis=0)) < 1.0)
    assert 0.9 < pose[:, 5].min() and pose[:, 5].max() < 1.1


def test_cli_writes_complete_deterministic_corpus(corpus):
    first, second = corpus / "first", corpus / "second"
    assert sorted(p.name for p in first.iterdir()) == ["speaker_00.mp4", "speaker_00.truth.npz"]
    assert not any(p.name.startswith(".") for p in corpus.iterdir())
    for name in ("speaker_00.mp4", "speaker_00.truth.npz"):
        assert (first / name).read_bytes() == (second / name).read_bytes()

    with av.open(str(first / "speaker_00.mp4")) as container:
        video, audio = container.streams.video[0], container.streams.audio[0]
        assert (video.codec_context.name, video.codec_context.pix_fmt) == ("h264", "yuv420p")
        assert (video.codec_context.width, video.codec_context.height) == (WIDTH, HEIGHT)
        assert (audio.codec_context.name, audio.codec_context.sample_rate) == ("aac", RATE)
        assert audio.codec_context.layout.nb_channels == 1

    truth = np.load(first / "speaker_00.truth.npz")
    n_frames = 75
    assert truth["landmarks"].shape == (n_frames, 68, 2) and truth["landmarks"].dtype == np.float32
    assert truth["pose"].shape == (n_frames, 6)
    assert truth["blink"].shape == (n_frames,) and truth["blink"].dtype == bool
    assert truth["mouth"].shape == (n_frames, 3)
    assert truth["voiced"].shape == (n_frames,) and truth["voiced"].dtype == bool
    assert truth["phones"].dtype.names == ("label", "start", "end")
    assert list(truth["mouth_names"]) == list(articulation.MOUTH_NAMES)


def test_hog_finds_the_face_and_predictor_agrees_with_truth(corpus):
    frames = decoded_frames(corpus / "first" / "speaker_00.mp4")
    truth = np.load(corpus / "first" / "speaker_00.truth.npz")
    assert len(frames) == len(truth["landmarks"])
    detector = dlib.get_frontal_face_detector()
    predictor = dlib.shape_predictor(dlib_face.predictor_path())
    found, errors = 0, []
    for t, frame in enumerate(frames):
        boxes = detector(frame, 0)
        found += len(boxes) > 0
        if len(boxes) and t % 10 == 0:
            shape = predictor(frame, boxes[0])
            predicted = np.array([[p.x, p.y] for p in shape.parts()], dtype=float)
            errors.append(np.linalg.norm(predicted - truth["landmarks"][t], axis=1).mean())
    assert found / len(frames) >= 0.98
    assert np.mean(errors) < 3.0
