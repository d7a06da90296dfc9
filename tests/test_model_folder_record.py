"""A model folder is opened and checked once into a ModelFolder record that is passed on: the functions
taking a folder read its config and speaker from the record, not from disk again."""
import shutil

import numpy as np
import pytest

from pipeline.models.model_folder import ModelError, ModelFolder, load_speaker, read_config
from pipeline.models.mouth_prediction import check_emotion, open_model, predict_mouth
from tests.conftest import ROOT


@pytest.fixture
def base_copy(tmp_path):
    folder = tmp_path / "base"
    shutil.copytree(ROOT / "models" / "base", folder)
    return folder


def test_open_model_checks_once_and_the_record_goes_where_a_path_goes(base_copy):
    record = open_model(base_copy)
    assert isinstance(record, ModelFolder) and record.family == "lstm" and open_model(record) is record
    assert str(record) == str(base_copy) and (base_copy / "config.json").samefile(record.path / "config.json")
    (base_copy / "config.json").write_text("{ not json")            # the folder changes after it was opened
    assert read_config(record) is record.config                      # … the record keeps what was checked
    with pytest.raises(ValueError):
        read_config(base_copy)
    samples = np.random.default_rng(0).normal(0, 0.05, 16000 * 2).astype(np.float32)
    out = predict_mouth(samples, record, 25.0)                        # predicts from the record's config
    assert out["lip_points"].shape[0] == 50 and np.isfinite(out["lip_points"]).all()
    assert load_speaker(record) is load_speaker(record)               # read once, kept
    check_emotion(record, None)


def test_open_model_refuses_a_broken_folder_with_one_line(base_copy):
    (base_copy / "weights.pt").write_bytes(b"not a state dict")
    with pytest.raises(ModelError, match="weights.pt: damaged or not a PyTorch state dict"):
        open_model(base_copy)
    with pytest.raises(ModelError, match="not a lipsynth model folder"):
        open_model(base_copy.parent / "nothing")
