"""One video cut into segments and split in time (pipeline/io/segments)."""
import numpy as np
import pytest

from pipeline.errors import BadInputError, ParameterError
from pipeline.io import media
from pipeline.io.segments import cut_video, segment_bounds, segment_group, time_split


def test_bounds_cover_the_video_and_a_short_tail_joins_the_last_segment():
    assert segment_bounds(24.0, 10.0) == [(0.0, 10.0), (10.0, 24.0)]
    assert len(segment_bounds(25.0, 10.0)) == 3
    assert segment_bounds(26.0, 10.0) == [(0.0, 10.0), (10.0, 20.0), (20.0, 26.0)]
    assert segment_bounds(4.0, 10.0) == [(0.0, 4.0)]
    b = segment_bounds(60.0, 10.0)
    assert len(b) == 6 and b[0][0] == 0 and b[-1][1] == 60 and all(x[1] == y[0] for x, y in zip(b, b[1:]))
    with pytest.raises(ParameterError):
        segment_bounds(10.0, 0.0)


def test_time_split_holds_out_the_end_of_each_video_and_keeps_whole_videos_for_training():
    names = [f"lieu_s{k:03d}" for k in range(6)] + [f"macron_s{k:03d}" for k in (4, 0, 2, 1, 3)] + ["clip"]
    s = time_split(names, 0.2)
    assert [n for n in names if s[n] == "val"] == ["lieu_s005", "macron_s004"]
    assert s["clip"] == "train" and s["lieu_s000"] == "train"
    assert segment_group("a_b_s012") == ("a_b", 12) and segment_group("a_s12") is None
    assert sum(v == "val" for v in time_split(names, 0.4).values()) == 2 + 2


def test_cut_video_writes_synced_segments_that_add_up_to_the_video(tmp_path):
    from tests.helpers.media import make_clip
    clip = tmp_path / "person.mp4"
    make_clip(clip, n_frames=115, tone_at=3.0)                      # 4.6 s; a loud tone from 3 s of audio
    parts = cut_video(clip, 2.0, tmp_path / "seg")
    assert [p.name for p in parts] == ["person_s000.mp4", "person_s001.mp4"]    # 2 s + 2.6 s (the 0.6-s tail joins)
    frames = [sum(1 for _ in media.iter_frames(p, fmt="gray")) for p in parts]
    assert frames == [50, 65]
    audio = [media.read_audio(p)[0] for p in parts]
    assert abs(len(audio[1]) / 16000 - 2.6) < 0.1
    loud = np.flatnonzero(np.abs(audio[1]) > 0.2)
    assert abs(loud[0] / 16000 - 1.0) < 0.06                        # the tone starts 1 s into the second segment
    assert not any(p.name.startswith(".") for p in tmp_path.iterdir())


def test_too_short_footage_and_footage_without_audio_are_one_line(tmp_path):
    from tests.helpers.media import make_clip
    short, mute = tmp_path / "short.mp4", tmp_path / "mute.mp4"
    make_clip(short, n_frames=50)
    make_clip(mute, n_frames=50, audio=False)
    with pytest.raises(BadInputError, match="too short to split.*needs at least 15 s"):
        cut_video(short, 10.0, tmp_path / "seg")
    with pytest.raises(BadInputError, match="no audio track"):
        cut_video(mute, 1.0, tmp_path / "seg")
    assert not (tmp_path / "seg").exists()
