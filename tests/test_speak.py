"""`lipsynth speak` refuses bad input with one line before doing any work (no model needed)."""
import subprocess
import sys

import numpy as np
import pytest
import yaml

from pipeline.params import load_params
from tests.conftest import ROOT, shared
from tests.helpers import one_error_line


def speak(*args):
    return subprocess.run([sys.executable, "-m", "lipsynth.cli", "speak", *map(str, args)], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)


@pytest.mark.real
def test_audio_without_an_audio_track_is_refused_before_preprocessing(tmp_path):
    noaudio = shared("obama", "obama_noaudio.mp4")
    target = shared("obama", "obama_08.mp4")
    out = tmp_path / "o.mp4"
    line = one_error_line(speak("--audio", noaudio, "--target", target, "--out", out, "--cache", tmp_path / "c"))
    assert str(noaudio) in line and "no audio" in line
    assert not out.exists() and not (tmp_path / "c").exists()       # the target was not preprocessed


def test_missing_files_and_bad_output_names(tmp_path):
    from tests.helpers.media import make_clip
    clip = tmp_path / "clip.mp4"
    make_clip(clip, n_frames=30)
    line = one_error_line(speak("--audio", tmp_path / "nope.wav", "--target", clip, "--out", tmp_path / "o.mp4"))
    assert "nope.wav" in line and "not found" in line
    line = one_error_line(speak("--audio", clip, "--target", clip, "--out", tmp_path / "o.avi"))
    assert "o.avi" in line and ".mp4" in line


def test_too_short_audio_is_refused(tmp_path):
    from tests.helpers.media import make_clip
    short = tmp_path / "short.mp4"
    make_clip(short, n_frames=5)                                     # 0.2 s
    line = one_error_line(speak("--audio", short, "--target", short, "--out", tmp_path / "o.mp4",
                                "--cache", tmp_path / "c"))
    assert str(short) in line and "too short" in line
    assert np.all([not p.name.startswith(".") for p in tmp_path.iterdir()])


def test_missing_output_folder_is_one_line(tmp_path):
    from tests.helpers.media import make_clip
    clip = tmp_path / "clip.mp4"
    make_clip(clip, n_frames=30)
    line = one_error_line(speak("--audio", clip, "--target", clip, "--out", tmp_path / "nowhere" / "o.mp4"))
    assert "nowhere" in line and "does not exist" in line


def test_distinct_shapes_counts_clearly_different_mouths():
    from lipsynth.speak import distinct_shapes
    rng = np.random.default_rng(0)
    base = rng.normal(0, 5, (18, 2))
    same = base + rng.normal(0, 0.05, (40, 18, 2))                 # one shape, jittered
    assert distinct_shapes(same, 1.0) == 1
    opened = np.stack([base + [0, k * 3.0] for k in range(6)])     # six openings 3 px apart
    assert distinct_shapes(np.concatenate([same, opened, opened]), 1.0) == 6
    nan = opened.copy()
    nan[2] = np.nan                                                # frames without landmarks are ignored
    assert distinct_shapes(nan, 1.0) == 5


def test_auto_detail_warps_mouths_for_a_target_with_few_shapes_only():
    """Another person's target with fewer distinct mouths than speak.min_mouth_shapes: synthesize.detail auto →
    aligned; a target with enough, the model's own speaker (no count) or a detail set by hand: unchanged."""
    import copy
    from lipsynth.speak import few_shapes
    from pipeline.params import load_params
    p = load_params()
    assert p.synthesize.detail == "auto"
    n = p.speak.min_mouth_shapes
    assert few_shapes(dict(distinct_mouth_shapes=n - 1), p)
    assert not few_shapes(dict(distinct_mouth_shapes=n), p)
    assert not few_shapes(dict(path="same speaker"), p)
    q = copy.deepcopy(p)
    q.synthesize.detail = "two_band"
    assert not few_shapes(dict(distinct_mouth_shapes=1), q)


def test_stage_advice_about_training_corpora_is_removed_for_speak():
    from lipsynth.target import without_training_hints
    msg = "/v/wall.mp4: no face found in 9 sampled frames (set data.on_bad_input: skip to leave such videos out)"
    assert without_training_hints(msg) == "/v/wall.mp4: no face found in 9 sampled frames"
    msg = "/v/a.mp4: face tracked in only 3.0% of frames (landmarks.min_valid_fraction=0.5) — set data.on_bad_input: skip to leave it out"
    assert without_training_hints(msg) == ("/v/a.mp4: face tracked in only 3.0% of frames "
                                           "(landmarks.min_valid_fraction=0.5 of --params)")


def _check(frames, fallen_back, not_posed=0, face=0, mouth=0, sharp=0):
    return dict(frames=frames, checked=frames - not_posed, fallen_back=fallen_back, not_posed=not_posed,
                failed_by=dict(face_error=face, mouth_error=mouth, sharpness=sharp))


def test_lip_sync_verdict_says_when_lip_sync_was_not_made(caplog):
    """latsync_demo2 before its 3D fit was mended: 479 of 480 frames fell back to the untouched target and
    speak exited 0. Above a tenth: one line with the share and the cause; above half: a non-zero exit
    whose line says the file was written."""
    from lipsynth.speak import lip_sync_verdict
    from pipeline.errors import NoLipSyncError
    s = load_params(ROOT / "params.yaml").speak
    with caplog.at_level("WARNING", logger="lipsynth.speak"):
        assert lip_sync_verdict(_check(500, 40, face=40), s, "t.mp4", "o.mp4") == pytest.approx(0.08)
    assert not caplog.records                                          # 8 %: quiet
    with caplog.at_level("WARNING", logger="lipsynth.speak"):
        share = lip_sync_verdict(_check(500, 60, not_posed=40, face=10, mouth=50), s, "t.mp4", "o.mp4")
    assert share == pytest.approx(0.2)
    (rec,) = caplog.records
    assert "t.mp4" in rec.message and "20%" in rec.message and "dlib reads another mouth" in rec.message
    with pytest.raises(NoLipSyncError) as exc:
        lip_sync_verdict(_check(480, 479, face=479, mouth=12), s, "t.mp4", "o.mp4")
    msg = str(exc.value)
    assert msg.startswith("t.mp4: lip sync not made on 100%") and "3D fit" in msg and "o.mp4 was written" in msg
    assert lip_sync_verdict(None, s, "t.mp4", "o.mp4") is None        # self-check off: nothing to say


@pytest.mark.real
def test_a_video_corrupt_mid_file_is_one_line_without_dask_shutdown_noise(tmp_path):
    """20 kB overwritten in the middle of a target: the ingest task fails on a worker while the other
    warms up; the run ends with the one error line, not the cluster's shutdown warnings above it."""
    target = tmp_path / "damaged.mp4"
    data = bytearray(shared("hdtf", "WDA_KatieHill_000.mp4").read_bytes())
    data[len(data) // 2:len(data) // 2 + 20000] = np.random.default_rng(0).integers(0, 256, 20000, np.uint8).tobytes()
    target.write_bytes(bytes(data))
    out = tmp_path / "o.mp4"
    tree = yaml.safe_load((ROOT / "params.yaml").read_text())
    tree["cluster"]["n_workers"] = 2          # workers asked for: a 200-frame target would otherwise run in process
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(tree))
    r = subprocess.run([sys.executable, "-m", "lipsynth.cli", "speak", "--audio", shared("hdtf", "RD_Radio31_000.wav"),
                        "--target", target, "--out", out, "--model", ROOT / "models" / "base", "--cache", tmp_path / "c",
                        "--params", tmp_path / "params.yaml"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert "starting LocalCluster" in r.stderr, r.stderr[-2000:]
    line = one_error_line(r)
    assert str(target) in line and "corrupt" in line
    assert not [line for line in r.stderr.splitlines() if "distributed" in line or "WARNING" in line], r.stderr
    assert not out.exists()
