"""``lipsynth personalize`` refusals that need no preprocessing (the whole run: tests/test_dvc_pipeline.py)."""
import subprocess
import sys

from tests.conftest import ROOT


def personalize(*args):
    return subprocess.run([sys.executable, "-m", "lipsynth.cli", "personalize", *map(str, args)], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)


def one_error_line(r):
    lines = [l for l in r.stderr.strip().splitlines() if l.startswith("lipsynth: error")]
    assert r.returncode == 2 and len(lines) == 1, r.stderr
    return lines[0]


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
