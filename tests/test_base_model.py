"""The shipped base model (models/base): present on a clean clone, loadable, hash-checked."""
import json
import shutil

import pytest

from pipeline.models.base_model import LIVE_FILES, MODEL_FILES, SHIPPED, verify
from pipeline.models.model_folder import ModelError, load_model


def test_the_shipped_base_is_in_the_repository_and_loads():
    config = verify(SHIPPED)
    manifest = json.loads((SHIPPED / "MANIFEST.json").read_text())
    assert set(manifest["files"]) == set(MODEL_FILES + LIVE_FILES)          # the live LSTM is hash-checked too
    assert "CC BY 4.0" in manifest["licence"] and manifest["recipe"].startswith("python bench/shipped_base.py")
    model, cfg, arrays = load_model(SHIPPED)
    assert cfg == config and cfg["features"] == "whisper" and arrays["pca_components"].shape[0] == cfg["n_components"]
    assert not (SHIPPED / "bank.zarr").exists() and not (SHIPPED / "speaker.npz").exists()   # a base carries no person
    assert sum(p.stat().st_size for p in SHIPPED.iterdir()) < 2_000_000


@pytest.mark.parametrize("name", MODEL_FILES + LIVE_FILES)
def test_a_changed_or_missing_file_is_one_clear_error(tmp_path, name):
    folder = tmp_path / "base"
    shutil.copytree(SHIPPED, folder)
    data = bytearray((folder / name).read_bytes())
    data[len(data) // 2] ^= 0x01
    (folder / name).write_bytes(bytes(data))
    with pytest.raises(ModelError, match=f"{name} does not match MANIFEST.json|{name}"):
        verify(folder)
    (folder / name).unlink()
    with pytest.raises(ModelError, match=f"{name}"):
        verify(folder)
