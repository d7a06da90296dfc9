"""Other people's footage as base-model training targets (stages/train/extra_corpora)."""
import numpy as np
import pytest

from pipeline.errors import LipsynthError, ParameterError
from stages.train import extra_corpora


def test_retargeted_keeps_the_motion_and_takes_the_main_mean():
    rng = np.random.default_rng(0)
    own_mean, main_mean = rng.normal(50, 5, 36), rng.normal(60, 5, 36)
    motion = rng.normal(0, 2, (40, 36))
    motion -= motion.mean(0)
    lips = own_mean + motion
    valid = np.ones(40, bool)
    out = extra_corpora.retargeted(lips, valid, 1.5, main_mean)
    np.testing.assert_allclose(out.mean(0), main_mean, atol=1e-9)       # the person's resting shape is gone
    np.testing.assert_allclose(out - main_mean, 1.5 * motion, atol=1e-9)  # the motion kept, in main-store pixels


def test_retargeted_takes_the_mean_over_valid_frames_only():
    lips = np.zeros((10, 36))
    lips[:5] = 3.0
    lips[5:] = 1000.0                                                      # a lost face's garbage
    valid = np.arange(10) < 5
    out = extra_corpora.retargeted(lips, valid, 1.0, np.full(36, 7.0))
    np.testing.assert_allclose(out[:5], 7.0)
    with pytest.raises(ParameterError):
        extra_corpora.retargeted(lips, np.zeros(10, bool), 1.0, np.zeros(36))


def test_a_missing_store_is_named(tmp_path):
    (tmp_path / "ingest.zarr").mkdir()
    with pytest.raises(LipsynthError, match="missing landmarks.zarr, frontalize.zarr, whisper.zarr"):
        extra_corpora.corpus_paths(str(tmp_path))


def test_extra_corpora_need_the_whisper_front_end():
    with pytest.raises(ParameterError, match="whisper"):
        extra_corpora.load(["x"], "mfcc", {}, 1.0)
    with pytest.raises(ParameterError, match="extra_repeat"):
        extra_corpora.load(["x"], "whisper", {}, 1.0, repeat=0)
