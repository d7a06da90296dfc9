"""``lipsynth live``: the causal front end, the streaming model, the stream I/O and the command end to end."""
import io
import json
import struct
import subprocess
import sys

import av
import numpy as np
import pytest

from lipsynth.live import DetailPicker, ping_pong
from lipsynth.live_stream import AudioBuffer
from pipeline.audio.streaming_features import StreamingFeatures, causal_features
from pipeline.errors import BadInputError, ParameterError
from pipeline.io.live_io import StreamWriter, pcm_blocks, skip_wav_header
from tests.conftest import ROOT

MODEL = ROOT / "models" / "base"          # committed (models/lstm is a DVC output, absent on a clean clone)


@pytest.fixture(scope="module")
def speaker(tmp_path_factory):
    """Two 6-s clips of the synthetic speaker (speaker_00: the target, speaker_01: the new speech)."""
    from pipeline.params import load_params
    from stages.synthetic_speaker.generate import generate_corpus, validated_settings
    settings = validated_settings(load_params(ROOT / "params.yaml").synthetic_speaker)
    settings.update(n_videos=2, seconds_per_video=6.0, out_dir=str(tmp_path_factory.mktemp("speaker") / "clips"))
    return generate_corpus(settings)


def speech_like(seconds: float, seed: int = 0) -> np.ndarray:
    """Noise bursts with a syllable-rate envelope (16 kHz)."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * 16000)) / 16000
    return (0.2 * rng.standard_normal(len(t)) * (0.5 + 0.5 * np.sin(2 * np.pi * 4 * t)) ** 2).astype(np.float32)


def test_ping_pong_loops_forward_then_backward():
    assert [ping_pong(k, 4) for k in range(10)] == [0, 1, 2, 3, 2, 1, 0, 1, 2, 3]
    assert {ping_pong(k, 1) for k in range(5)} == {0}


@pytest.mark.parametrize("front_end", ["mfcc", "whisper"])
def test_committed_frames_never_see_audio_beyond_the_look_ahead(front_end):
    """Two streams equal for 2 s and different after: every frame committed before the difference arrived is
    the same in both (no future leaks in), and the committed frames stop ≥ ahead before the audio's end."""
    a = speech_like(4.0, 1)
    b = a.copy()
    b[32000:] = speech_like(2.0, 2)
    streams = [StreamingFeatures(front_end, ahead_s=0.2, hop_s=0.2, past_s=1.0) for _ in range(2)]
    first = [np.concatenate([s.push(x[a0:a0 + 320]) for a0 in range(0, 32000, 320)]) for s, x in zip(streams, (a, b))]
    np.testing.assert_array_equal(first[0], first[1])
    assert len(first[0]) > 100
    assert (len(first[0]) - 1) / 100 + 0.2 <= 2.0 + 1e-9


def test_piece_size_does_not_change_the_frames():
    x = speech_like(3.0, 3)
    coarse = causal_features(x, "mfcc", past_s=1.0, ahead_s=0.2, hop_s=0.2, piece_s=0.25)
    fine = causal_features(x, "mfcc", past_s=1.0, ahead_s=0.2, hop_s=0.2, piece_s=0.01)
    np.testing.assert_array_equal(coarse, fine)
    assert len(fine) == 1 + len(x) // 160


def test_streaming_features_refuse_bad_settings():
    with pytest.raises(ParameterError, match="hop_s"):
        StreamingFeatures("mfcc", hop_s=0.0)
    with pytest.raises(ParameterError, match="front end"):
        StreamingFeatures("spectrogram")


def test_streaming_mouth_gives_one_shape_per_frame_and_refuses_other_families():
    from pipeline.models.streaming_mouth import stream_mouth
    x = speech_like(2.3, 4)
    lips = stream_mouth(x, MODEL, 25.0, past_s=1.0, ahead_s=0.2, hop_s=0.2)
    assert lips.shape == (round(2.3 * 25), 18, 2) and np.isfinite(lips).all()
    assert lips.std(0).mean() > 0                       # the mouth moves


def test_other_model_families_are_refused_live(tmp_path):
    from pipeline.models.model_folder import FAMILY_FILES
    from pipeline.models.streaming_mouth import StreamingMouth
    (tmp_path / "brand").mkdir()
    for name in FAMILY_FILES["brand"]:                   # a folder of the brand family's files (read_config checks them)
        (tmp_path / "brand" / name).write_bytes(b"")
    (tmp_path / "brand" / "config.json").write_text(json.dumps(dict(model="brand")))
    with pytest.raises(ParameterError, match="cannot run live"):
        StreamingMouth(tmp_path / "brand", 25.0)


def wav_header(rate: int, channels: int, bits: int = 16) -> bytes:
    fmt = struct.pack("<HHIIHH", 1, channels, rate, rate * channels * bits // 8, channels * bits // 8, bits)
    return b"RIFF" + struct.pack("<I", 36) + b"WAVE" + b"fmt " + struct.pack("<I", 16) + fmt + b"data" + struct.pack("<I", 0)


def test_wav_header_is_skipped_or_refused_and_raw_pcm_passes():
    pcm = (np.arange(100, dtype="<i2") * 100).tobytes()
    assert skip_wav_header(io.BytesIO(wav_header(16000, 1) + pcm), "s") == b""
    assert skip_wav_header(io.BytesIO(pcm), "s") == pcm[:12]
    with pytest.raises(BadInputError, match="44100 Hz"):
        skip_wav_header(io.BytesIO(wav_header(44100, 2) + pcm), "stdin")
    warned = []
    blocks = list(pcm_blocks(io.BytesIO(wav_header(16000, 1) + pcm + b"\x01"), "stdin", warned.append))
    got = np.concatenate([b for b, _ in blocks])
    np.testing.assert_allclose(got, np.arange(100) * 100 / 32768)
    assert len(warned) == 1 and "inside a sample" in warned[0]


def test_stream_writer_interleaves_video_and_audio_of_the_same_length(tmp_path):
    out = tmp_path / "s.ts"
    with open(out, "wb") as f:
        w = StreamWriter(f, 25.0, (160, 120))
        for k in range(50):
            w.write(np.full((120, 160, 3), 4 * k, np.uint8), 0.1 * np.sin(np.arange(640) / 7).astype(np.float32))
        w.close()
    with av.open(str(out)) as c:
        assert {s.type for s in c.streams} == {"video", "audio"}
        video = [f.time for f in c.decode(video=0)]
    with av.open(str(out)) as c:
        audio = [(f.time, f.samples) for f in c.decode(audio=0)]
    assert len(video) == 50
    # AAC's first packet is the encoder's priming (1024 samples), which the muxer puts before the first
    # frame: speech starts with the video, and both end together (the last AAC packet is padded)
    assert audio[1][0] == pytest.approx(video[0], abs=1e-3)
    audio_end = audio[-1][0] + audio[-1][1] / 16000
    assert abs(audio_end - (video[-1] + 1 / 25)) <= 1024 / 16000


def test_detail_picker_holds_a_run_until_switching_pays():
    pool = np.array([10, 11, 12, 50])
    pick = DetailPicker(pool, switch_cost=1.0)
    assert pick.pick(np.array([0.0, 5, 5, 3])) == [(0, 1.0)]
    assert pick.pick(np.array([5.0, 0.5, 5, 0])) == [(1, 1.0)]          # the run's next frame, within the cost
    assert pick.pick(np.array([5.0, 5, 9, 0])) == [(3, 1.0)]            # 9 > 0 + 1: switch


def test_audio_buffer_slices_across_growth():
    buf = AudioBuffer()
    x = speech_like(130.0, 5)
    for a in range(0, len(x), 16000):
        buf.append(x[a:a + 16000])
    np.testing.assert_array_equal(buf.slice(1_000_000, 1_000_640), x[1_000_000:1_000_640])
    assert len(buf.slice(len(x) - 10, len(x) + 100)) == 10


@pytest.fixture(scope="module")
def prepared_speaker(tmp_path_factory, speaker):
    cache = tmp_path_factory.mktemp("live_cache")
    r = subprocess.run([sys.executable, "-m", "lipsynth.cli", "prepare", str(speaker / "speaker_00.mp4"), "--model",
                        str(MODEL), "--cache", str(cache)], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "prepared" in r.stdout
    return cache, speaker


def live(args, prepared, **kw):
    cache, speaker = prepared
    return subprocess.run([sys.executable, "-m", "lipsynth.cli", "live", "--target", str(speaker / "speaker_00.mp4"),
                           "--model", str(MODEL), "--cache", str(cache), *args], cwd=ROOT, capture_output=True,
                          timeout=600, **kw)


def test_live_streams_a_file_with_audio_and_no_drift(prepared_speaker, tmp_path):
    from pipeline.io import media
    speaker = prepared_speaker[1]
    out, stats = tmp_path / "o.ts", tmp_path / "o.json"
    r = live(["--audio", str(speaker / "speaker_01.mp4"), "--out", str(out), "--stats", str(stats)], prepared_speaker)
    assert r.returncode == 0, r.stderr[-2000:]
    s = json.loads(stats.read_text())
    audio, _ = media.read_audio(speaker / "speaker_01.mp4", 16000)
    fps = media.probe(speaker / "speaker_00.mp4").fps
    assert s["frames"] == round(len(audio) / 16000 * fps) and s["drift_frames"] == 0
    assert s["repeated"] == 0                            # a file without --realtime: every frame is made
    with av.open(str(out)) as c:
        assert {st.type for st in c.streams} == {"video", "audio"}
        frames = [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]
    assert len(frames) == s["frames"]
    assert np.abs(np.diff(np.stack(frames[:20]).astype(np.int16), axis=0)).mean() > 0.1     # it moves
    assert not list(tmp_path.glob(".*.part"))


def test_every_target_frame_geometry_is_made_before_the_stream_starts(prepared_speaker):
    """Made on demand, the first pass through a 720p target cost each frame ≈ 5 ms more while streaming."""
    import argparse
    from lipsynth.live import LiveEngine
    from lipsynth.prepare import prepared
    from pipeline.models.mouth_prediction import open_model
    from pipeline.params import load_params
    cache, speaker = prepared_speaker
    target, model = str(speaker / "speaker_00.mp4"), open_model(MODEL)
    p, stores, entry, _ = prepared(target, load_params(ROOT / "params.yaml"), model, cache, prepared_only=True)
    engine = LiveEngine(p, stores, entry, target, model, argparse.Namespace(past=1.5, ahead=0.2, hop=0.1, pad=2.0,
                                                                             threads=2))
    geometry, n = engine.tgt.geometry, len(engine.frames)
    posed = int(np.count_nonzero(engine.tgt.pose_ok[:n]))
    assert posed > n // 2 and geometry.misses == posed and len(geometry.items) == posed
    rest = engine.mouth.mean_shape
    for k in range(n):                                   # the first ping-pong pass: every frame of the target
        engine.frame(k, *engine.plan(rest))
    assert geometry.misses == posed


def test_live_from_stdin_survives_the_consumer_going_away(prepared_speaker, tmp_path):
    pcm = (speech_like(6.0, 6) * 32767).astype("<i2").tobytes()
    cache, speaker = prepared_speaker
    cmd = (f"{sys.executable} -m lipsynth.cli live --target {speaker / 'speaker_00.mp4'} --model {MODEL} "
           f"--cache {cache} | head -c 20000 > {tmp_path / 'head.ts'}")
    r = subprocess.run(["bash", "-o", "pipefail", "-c", cmd], input=pcm, cwd=ROOT, capture_output=True, timeout=600)
    assert r.returncode == 0                             # live's own status too (pipefail)
    assert b"consumer went away" in r.stderr
    assert b"Traceback" not in r.stderr and b"BrokenPipe" not in r.stderr, r.stderr[-2000:]
    assert (tmp_path / "head.ts").stat().st_size == 20000


def test_live_names_the_command_that_prepares_a_target(tmp_path, speaker):
    r = live(["--audio", str(speaker / "speaker_01.mp4"), "--out", str(tmp_path / "o.ts")], (tmp_path / "empty", speaker))
    assert r.returncode == 2
    err = [line for line in r.stderr.decode().splitlines() if "error" in line.lower()]
    assert len(err) == 1 and "not prepared" in err[0] and "lipsynth prepare" in err[0]
    assert not (tmp_path / "o.ts").exists()


def test_live_refuses_a_wav_of_the_wrong_rate_and_closes_its_output(prepared_speaker, tmp_path):
    pcm = (speech_like(1.0, 7) * 32767).astype("<i2").tobytes()
    out = tmp_path / "o.ts"
    r = live(["--out", str(out)], prepared_speaker, input=wav_header(44100, 1) + pcm)
    assert r.returncode == 2
    err = [line for line in r.stderr.decode().splitlines() if "error" in line.lower()]
    assert len(err) == 1 and "44100 Hz" in err[0] and "Traceback" not in r.stderr.decode()
    assert not out.exists() and not list(tmp_path.glob(".*.part"))


def test_the_page_plays_the_live_stream_with_sound(prepared_speaker, tmp_path):
    """``live --serve``: headless Chromium opens the page while the stream is made; its clock advances and the
    stream it plays has an audio track that decodes."""
    import re
    import threading
    import time
    from tests.helpers.browser import page_errors, page_session, screenshot
    cache, speaker = prepared_speaker
    proc = subprocess.Popen([sys.executable, "-m", "lipsynth.cli", "live", "--target", str(speaker / "speaker_00.mp4"),
                             "--model", str(MODEL), "--cache", str(cache), "--audio",
                             str(speaker / "speaker_01.mp4"), "--realtime", "--hls", str(tmp_path / "hls"), "--serve"],
                            cwd=ROOT, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True)
    lines: list[str] = []
    threading.Thread(target=lambda: lines.extend(proc.stderr), daemon=True).start()
    try:
        deadline = time.monotonic() + 120
        while not any("serving http" in line for line in lines):
            assert proc.poll() is None and time.monotonic() < deadline, "".join(lines)[-2000:]
            time.sleep(0.2)
        url = re.search(r"http://127\.0\.0\.1:\d+/", "".join(lines)).group(0)
        with page_session(url, tmp_path / "profile") as (dt, s):
            state = ("(() => { const v = document.getElementById('video'); if (!v || !window.lipsynth) "
                     "return {t: -1, errors: []}; return {t: v.currentTime, ...window.lipsynth, "
                     "frames: v.webkitDecodedFrameCount, audioBytes: v.webkitAudioDecodedByteCount}; })()")
            deadline = time.monotonic() + 60
            while (first := dt.evaluate(s, state))["t"] < 0.5:
                assert time.monotonic() < deadline and not first["errors"], first
                time.sleep(0.25)
            time.sleep(2.0)
            second = dt.evaluate(s, state)
            screenshot(dt, s, tmp_path / "page.png")
            errors = page_errors(dt)
        assert second["t"] - first["t"] >= 1.0, (first, second)          # the clock advances as it plays
        assert second["audio"] and "mp4a" in second["audio"], second       # an AAC track…
        assert second["audioBytes"] > 0 and second["frames"] > 10, second  # …that decodes, beside the video
        assert errors == [] and second["errors"] == []
    finally:
        proc.terminate()
        proc.wait(timeout=30)


def test_a_live_lstm_is_used_only_with_the_stream_settings_it_was_taught(tmp_path):
    import shutil
    import torch
    from pipeline.models.streaming_mouth import StreamingMouth
    folder = tmp_path / "model"
    shutil.copytree(MODEL, folder)
    for name in ("live.pt", "live.json", "MANIFEST.json"):          # a model folder without a live LSTM
        (folder / name).unlink()
    m = StreamingMouth(folder, 25.0)
    assert not m.student                                             # no live.pt: the offline LSTM
    taught = {k: v + 0.5 for k, v in m.model.lstm.state_dict().items()}
    torch.save(taught, folder / "live.pt")
    stream = dict(past_s=1.5, ahead_s=0.2, hop_s=0.2, pad_s=2.0)
    (folder / "live.json").write_text(json.dumps(dict(stream=stream)))
    m = StreamingMouth(folder, 25.0, **stream)
    assert m.student
    for k, v in m.model.lstm.state_dict().items():
        torch.testing.assert_close(v, taught[k])
    other = StreamingMouth(folder, 25.0, **dict(stream, ahead_s=0.3))
    assert not other.student
    for k, v in other.model.lstm.state_dict().items():
        torch.testing.assert_close(v, taught[k] - 0.5)
