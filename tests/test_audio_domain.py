"""pipeline.audio.audio_domain: the distance of new audio from a model's training audio."""
import json

import numpy as np
import pytest

from pipeline.audio import audio_domain
from tests.conftest import SHARED


def test_shift_is_zero_for_the_corpus_mean_and_one_for_a_one_std_offset():
    rng = np.random.default_rng(0)
    frames = rng.normal(3.0, 2.0, (5000, 28))
    mean, std = audio_domain.corpus_statistics([frames[:2500], frames[2500:]])
    assert np.allclose(mean, frames.mean(0)) and np.allclose(std, frames.std(0))
    assert audio_domain.utterance_shift(frames, mean, std) < 1e-9
    assert audio_domain.utterance_shift(frames + std, mean, std) == pytest.approx(1.0)
    half = frames.copy()
    half[:, :14] += 2 * std[:14]                   # half the dimensions two std away: sqrt(4 / 2)
    assert audio_domain.utterance_shift(half, mean, std) == pytest.approx(np.sqrt(2.0))
    with pytest.raises(ValueError, match="28 corpus dimensions"):
        audio_domain.utterance_shift(frames[:, :13], mean, std)


def test_assess_calls_far_only_beyond_factor_times_the_held_out_maximum():
    rng = np.random.default_rng(1)
    train = [rng.normal(0, 1, (300, 28)) for _ in range(20)]
    held = [rng.normal(0, 1, (300, 28)) + rng.normal(0, 0.05, 28) for _ in range(5)]
    rec = audio_domain.reference(train, held)
    assert len(rec["held_out_shifts"]) == 5 and rec["held_out_max"] == pytest.approx(max(rec["held_out_shifts"]), abs=1e-4)
    rec = dict(rec, mean=np.asarray(rec["mean"]), std=np.asarray(rec["std"]))
    near = audio_domain.assess(held[0], rec, 1.2)
    assert not near["far"] and near["shift"] <= rec["held_out_max"] + 1e-4
    far = audio_domain.assess(held[0] + 0.5, rec, 1.2)            # every dimension half a std away
    assert far["far"] and far["shift"] > far["limit"] == pytest.approx(1.2 * rec["held_out_max"], abs=1e-4)


def test_export_reads_the_ingest_store_and_load_round_trips(tmp_path):
    import zarr
    rng = np.random.default_rng(2)
    mfcc = np.concatenate([rng.normal(0, 1, (100, 28)), rng.normal(0, 1, (100, 28)), rng.normal(5, 1, (100, 28))])
    g = zarr.open_group(str(tmp_path / "ingest.zarr"), mode="w")
    g.create_array("mfcc", data=mfcc.astype(np.float32))
    g.attrs["videos"] = [dict(name="a", split="train", first_mfcc=0, n_mfcc=100),
                         dict(name="b", split="val", first_mfcc=100, n_mfcc=100),
                         dict(name="bad", split="val", first_mfcc=200, n_mfcc=100, excluded=True)]
    folder = tmp_path / "model"
    folder.mkdir()
    summary = audio_domain.export(folder, str(tmp_path / "ingest.zarr"))
    rec = audio_domain.load(folder)
    assert json.loads((folder / "audio_domain.json").read_text())["held_out_shifts"] == [summary["held_out_max"]]
    assert rec["mean"].shape == (28,) and summary["held_out_max"] < 0.5        # the excluded video is not counted
    assert audio_domain.load(tmp_path) is None


@pytest.mark.real
def test_other_voices_are_far_and_the_speakers_own_clips_are_not():
    """GRID s1 statistics from 70 clips and limits from 20 held-out ones (measured max 0.29):
    10 further s1 clips stay within the default limit (measured 0.07–0.15); another GRID speaker's
    720×576 recording (0.54), Obama (0.84) and HDTF radio speech (0.82) are beyond it (0.34)."""
    from pipeline.audio import audio_features
    from pipeline.models.mouth_prediction import load_audio
    clips = sorted((SHARED / "grid_s1" / "video").glob("*.mp4"))[::9][:100]
    if len(clips) < 100 or not (SHARED / "obama" / "obama_01.mp4").is_file():
        pytest.skip(f"real footage not available under {SHARED}")
    feats = lambda p: audio_features.mfcc_features(load_audio(p))
    s1 = [feats(c) for c in clips]
    rec = audio_domain.reference(s1[:70], s1[70:90])
    rec = dict(rec, mean=np.asarray(rec["mean"]), std=np.asarray(rec["std"]))
    for f in s1[90:]:
        assert not audio_domain.assess(f, rec, 1.2)["far"]
    for other in (SHARED / "grid_s4" / "bginza.mpg", SHARED / "obama" / "obama_01.mp4",
                  SHARED / "hdtf" / "RD_Radio36_000.wav"):
        res = audio_domain.assess(feats(other), rec, 1.2)
        assert res["far"] and res["shift"] > 1.4 * res["limit"], (other.name, res)
