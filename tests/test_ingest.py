"""ingest: splitting, timestamps, rates, alignment and bad input."""
import re
import subprocess
from fractions import Fraction

import av
import numpy as np
import pytest
import yaml

from pipeline.io import media
from pipeline.errors import BadInputError
from pipeline.params import as_dict, load_params
from stages.ingest.ingest import decode_video, layout, list_videos, probe_video, split_videos
from tests.conftest import ROOT, shared
from tests.helpers.media import face_frames, make_clip
from stages.registry import stage


@pytest.fixture
def ingest_params():
    return load_params(ROOT / "params.yaml").ingest


def run_one(path, params, tmp_path):
    """probe + decode one video as the stage does; {"error": msg} for bad input."""
    try:
        probe_video(str(path), params)
        return decode_video(str(path), params)
    except BadInputError as exc:
        return {"error": str(exc)}


def test_split_is_deterministic_by_video_and_stable():
    names = [f"clip{i:03d}" for i in range(50)]
    a = split_videos(names, 0.2, seed=0)
    assert a == split_videos(list(reversed(names)), 0.2, seed=0)
    assert sum(s == "val" for s in a.values()) == 10
    assert a != split_videos(names, 0.2, seed=1)
    assert sum(s == "val" for s in split_videos(names[:2], 0.2, 0).values()) == 1


@pytest.mark.parametrize("fps,rate,channels,delay", [
    (Fraction(30000, 1001), 48000, 2, 0.3),     # 29.97 fps, stereo 48 kHz, audio starts late
    (Fraction(25), 44100, 1, -0.2),             # audio starts before the video
    (Fraction(25), 16000, 2, 0.0),
])
def test_rates_channels_and_audio_alignment(tmp_path, ingest_params, fps, rate, channels, delay):
    path = make_clip(tmp_path / "c.mp4", n_frames=60, fps=fps, audio_rate=rate, channels=channels,
                     audio_delay=delay, tone_at=1.0)
    e = run_one(path, ingest_params, tmp_path)
    assert "error" not in e, e
    assert len(e["crops"]) == 60 and e["fps"] == pytest.approx(float(fps), rel=1e-4)
    assert len(e["audio"]) == round(60 / float(fps) * 16000)
    assert len(e["mfcc"]) == 1 + len(e["audio"]) // 160
    assert e["audio_offset"] == pytest.approx(delay, abs=0.03)
    audio, times = e["audio"].astype(float), e["frame_time"]
    assert times[0] == 0 and np.allclose(np.diff(times), 1 / float(fps), atol=1e-3)
    env = np.convolve(np.abs(audio), np.ones(160) / 160, "same")
    onset = np.argmax(env > 0.5 * env.max()) / 16000
    assert onset == pytest.approx(1.0 + delay, abs=0.04)       # the tone is heard when it should be


def test_layout_starts_every_video_on_a_shard():
    entries = [dict(est_frames=75, fps=25.0), dict(est_frames=600, fps=29.97), dict(est_frames=10, fps=25.0)]
    n, a, m = layout(entries, 256, 160000, 1000)
    for e in entries:
        assert e["first_frame"] % 256 == 0 and e["first_sample"] % 160000 == 0 and e["first_mfcc"] % 1000 == 0
        assert e["cap_frames"] >= e["est_frames"] and e["cap_samples"] >= e["cap_frames"] / e["fps"] * 16000
    ends = [e["first_frame"] + e["cap_frames"] for e in entries]
    assert all(end <= nxt["first_frame"] for end, nxt in zip(ends, entries[1:])) and ends[-1] <= n


def test_list_videos_folder_glob_and_errors(tmp_path):
    make_clip(tmp_path / "a.mp4", 10)
    make_clip(tmp_path / "b.mp4", 10)
    assert [p.rsplit("/", 1)[1] for p in list_videos(str(tmp_path))] == ["a.mp4", "b.mp4"]
    assert len(list_videos(str(tmp_path / "*.mp4"))) == 2
    (tmp_path / "empty").mkdir()
    with pytest.raises(BadInputError, match="empty: folder holds no video files"):
        list_videos(str(tmp_path / "empty"))
    with pytest.raises(BadInputError, match="nope.mp4: file not found"):
        list_videos(str(tmp_path / "nope.mp4"))


@pytest.mark.real
def test_bad_inputs_name_file_and_problem(tmp_path, ingest_params):
    zero = tmp_path / "zero.mp4"
    zero.write_bytes(b"")
    junk = tmp_path / "junk.mp4"
    junk.write_bytes(np.random.default_rng(0).integers(0, 255, 50000, dtype=np.uint8).tobytes())
    silent_video = make_clip(tmp_path / "mute.mp4", 30, audio=False)
    noface = make_clip(tmp_path / "noface.mp4", 30, frames=np.full((30, 128, 160, 3), 90, np.uint8))
    small = np.full((30, 256, 320, 3), 120, np.uint8)
    small[:, 100:164, 100:180] = face_frames(30)[:, ::4, ::4]           # a face ~22 px wide
    tiny = make_clip(tmp_path / "tiny.mp4", 30, frames=small)
    short = make_clip(tmp_path / "short.mp4", 5)
    cases = {zero: "empty", junk: "cannot be opened", silent_video: "no audio track",
             noface: "no face found", tiny: "face too small|no face found", short: "too short"}
    for path, problem in cases.items():
        e = run_one(path, ingest_params, tmp_path)
        assert "error" in e, path
        assert str(path) in e["error"]
        assert len(e["error"].splitlines()) == 1
        assert re.search(problem, e["error"]), e["error"]
    with pytest.raises(BadInputError, match="no video stream"):
        media.probe(shared("hdtf", "RD_Radio31_000.wav"))


@pytest.mark.real
def test_real_video_without_audio_fails_cleanly_through_the_cli(tmp_path):
    noaudio = shared("obama", "obama_noaudio.mp4")
    params = load_params(ROOT / "params.yaml")
    params.data.videos = str(noaudio)
    params.ingest.out = str(tmp_path / "ingest.zarr")
    params.cluster.n_workers = 1
    (tmp_path / "p.yaml").write_text(yaml.safe_dump(as_dict(params)))
    r = subprocess.run(stage("ingest").argv(tmp_path / "p.yaml"),
                       cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 2
    errors = [line for line in r.stderr.splitlines() if line.startswith("lipsynth: error:")]
    assert len(errors) == 1 and "obama_noaudio.mp4: no audio track" in errors[0]
    assert not (tmp_path / "ingest.zarr").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")], "temporary output left behind"


def mp2_in_mpegts(path, damaged: set, seconds=2.0, sr=44100):
    """A 220 Hz tone as MP2 in MPEG-TS; the packets numbered in ``damaged`` get a broken header."""
    out = av.open(str(path), "w", format="mpegts")
    st = out.add_stream("mp2", rate=sr)
    st.layout = "mono"
    t = np.arange(int(sr * seconds)) / sr
    pcm = (0.3 * 32767 * np.sin(2 * np.pi * 220 * t)).astype(np.int16).reshape(1, -1)
    packets = []
    for i in range(0, pcm.shape[1], 1152):
        fr = av.AudioFrame.from_ndarray(np.ascontiguousarray(pcm[:, i:i + 1152]), format="s16", layout="mono")
        fr.sample_rate, fr.pts = sr, i
        packets += st.encode(fr)
    packets += st.encode()
    for k, pk in enumerate(packets):
        if k in damaged:
            b = bytearray(bytes(pk))
            b[:4] = b"\0\0\0\0"
            bad = av.Packet(bytes(b))
            bad.pts, bad.dts, bad.duration, bad.time_base = pk.pts, pk.dts, pk.duration, pk.time_base
            pk = bad
        pk.stream = st
        out.mux(pk)
    out.close()


@pytest.mark.real
def test_isolated_damaged_audio_packets_are_concealed_and_counted(tmp_path, caplog):
    """A real clip with one damaged MP2 packet among 111 (GRID s4 bbaf2a) decodes, with a warning
    that counts it; its length matches the clean clips of the same corpus."""
    with caplog.at_level("WARNING", logger="lipsynth.media"):
        samples, _ = media.read_audio(shared("grid_s4", "bbaf2a.mpg"), 16000)
    assert "concealed 1 damaged audio packet(s) of 111" in caplog.text
    assert 2.8 < len(samples) / 16000 < 3.1 and np.abs(samples).max() > 0.05
    path = tmp_path / "one_bad.ts"
    mp2_in_mpegts(path, damaged={40})
    samples, _ = media.read_audio(path, 16000)
    assert abs(len(samples) / 16000 - 2.0) < 0.1            # the damaged stretch is silence, timing kept


def test_mostly_undecodable_audio_is_refused(tmp_path):
    path = tmp_path / "ruined.ts"
    mp2_in_mpegts(path, damaged=set(range(0, 80, 2)))
    with pytest.raises(BadInputError, match=r"ruined\.ts: audio stream is mostly undecodable \(\d+ of \d+ packets"):
        media.read_audio(path, 16000)
