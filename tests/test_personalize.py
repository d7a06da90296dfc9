"""``lipsynth personalize``: refusals, pooling of short clips, and a still photo refused after preprocessing (the whole run: tests/test_dvc_pipeline.py)."""
import subprocess
import sys

import pytest

from tests.conftest import ROOT
from tests.helpers import one_error_line


def personalize(*args):
    cmd = [sys.executable, "-m", "lipsynth.cli", "personalize"] + [str(a) for a in args]
    return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=900)


def test_too_short_footage_says_how_much_is_needed(tmp_path):
    from tests.helpers.media import make_clip
    clip = tmp_path / "five_seconds.mp4"
    make_clip(clip, n_frames=125)
    line = one_error_line(personalize(clip, "--out", tmp_path / "m", "--work", tmp_path / "w"))
    assert str(clip) in line and "too short to split" in line and "needs at least 15 s" in line
    assert not (tmp_path / "m").exists()


def test_a_base_that_is_not_a_model_folder_is_one_line(tmp_path):
    from tests.helpers.media import make_clip
    clip = tmp_path / "clip.mp4"
    make_clip(clip, n_frames=50)
    line = one_error_line(personalize(clip, "--out", tmp_path / "m", "--base", tmp_path, "--work", tmp_path / "w"))
    assert str(tmp_path) in line


def test_clips_too_short_to_split_are_pooled_and_the_last_clip_held_out(tmp_path):
    from lipsynth.personalize import cut_footage, held_out_line
    from tests.helpers.media import make_clip
    clips = []
    for k in range(4):                                           # four 4-s clips, each shorter than 1.5 segments
        clips.append(tmp_path / f"clip{k}.mp4")
        make_clip(clips[-1], n_frames=100)
    segments = cut_footage(clips, 3.0, tmp_path / "footage", "anchor")
    assert [s.name for s in segments] == [f"anchor_s{k:03d}.mp4" for k in range(4)]
    line = held_out_line(segments, 0.2)
    assert line.startswith("held out: anchor_s003.mp4 (4.0 s of 16.0 s"), line


def test_long_clips_keep_their_own_names_and_split(tmp_path):
    from lipsynth.personalize import cut_footage
    from tests.helpers.media import make_clip
    clip = tmp_path / "long.mp4"
    make_clip(clip, n_frames=150)
    segments = cut_footage([clip], 3.0, tmp_path / "footage", "anchor")
    assert [s.name for s in segments] == ["long_s000.mp4", "long_s001.mp4"]


def test_a_single_clip_too_short_even_pooled_is_refused(tmp_path):
    from tests.helpers.media import make_clip
    clip = tmp_path / "short.mp4"
    make_clip(clip, n_frames=50)
    line = one_error_line(personalize(clip, "--out", tmp_path / "m", "--work", tmp_path / "w", "--segment-seconds", "3"))
    assert "too short" in line and str(clip) in line
    assert not (tmp_path / "m").exists()


@pytest.mark.slow
def test_a_photo_whose_mouth_never_moves_is_refused_before_training(tmp_path):
    """20 s of a still photo (drifting, with a hum): preprocessed, then one line before training."""
    from tests.helpers.media import make_clip
    clip = tmp_path / "photo.mp4"
    make_clip(clip, n_frames=500)
    r = personalize(clip, "--out", tmp_path / "m", "--work", tmp_path / "w")
    line = one_error_line(r)
    assert "the mouth barely moves" in line and str(clip) in line, line
    assert not (tmp_path / "m").exists() and not (tmp_path / "w" / "metrics.json").exists()


def test_a_base_of_another_family_is_one_line_before_any_work(tmp_path):
    import json
    from tests.helpers.media import make_clip
    clip = tmp_path / "clip.mp4"
    make_clip(clip, n_frames=50)
    base = tmp_path / "brand"
    base.mkdir()
    (base / "config.json").write_text(json.dumps({"model": "brand"}))
    (base / "arrays.npz").write_bytes(b"")
    line = one_error_line(personalize(clip, "--out", tmp_path / "m", "--base", base, "--work", tmp_path / "w"))
    assert "--base" in line and "brand" in line and "LSTM" in line, line
    assert not (tmp_path / "w" / "footage").exists()


def test_a_damaged_shipped_base_is_one_line(tmp_path):
    import shutil
    from pipeline.models.base_model import SHIPPED
    from tests.helpers.media import make_clip
    clip = tmp_path / "clip.mp4"
    make_clip(clip, n_frames=50)
    base = tmp_path / "base"
    shutil.copytree(SHIPPED, base)
    (base / "weights.pt").write_bytes((base / "weights.pt").read_bytes()[:-100])      # truncated
    line = one_error_line(personalize(clip, "--out", tmp_path / "m", "--base", base, "--work", tmp_path / "w"))
    assert "weights.pt does not match MANIFEST.json" in line, line
