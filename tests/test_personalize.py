"""``lipsynth personalize`` refusals that need no preprocessing (the whole run: tests/test_dvc_pipeline.py)."""
import subprocess
import sys

from tests.conftest import ROOT
from tests.test_speak import one_error_line


def personalize(*args):
    cmd = [sys.executable, "-m", "lipsynth.cli", "personalize"] + [str(a) for a in args]
    return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=120)


def test_too_short_footage_says_how_much_is_needed(tmp_path):
    from tests.media_fixtures import make_clip
    clip = tmp_path / "five_seconds.mp4"
    make_clip(clip, n_frames=125)
    line = one_error_line(personalize(clip, "--out", tmp_path / "m", "--work", tmp_path / "w"))
    assert str(clip) in line and "too short to split" in line and "needs at least 15 s" in line
    assert not (tmp_path / "m").exists()


def test_a_base_that_is_not_a_model_folder_is_one_line(tmp_path):
    from tests.media_fixtures import make_clip
    clip = tmp_path / "clip.mp4"
    make_clip(clip, n_frames=50)
    line = one_error_line(personalize(clip, "--out", tmp_path / "m", "--base", tmp_path, "--work", tmp_path / "w"))
    assert str(tmp_path) in line
