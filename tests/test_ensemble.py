"""Model ensembles (pipeline/models/model_ensemble.py, `lipsynth ensemble`): the folder, the average, the refusals."""
import json

import numpy as np
import pytest
import torch

from lipsynth import ensemble as ensemble_cli
from pipeline.models import delayed_lstm
from pipeline.models import model_ensemble
from pipeline.errors import ParameterError
from pipeline.models.model_folder import ModelError, load_speaker, save_model
from pipeline.models.mouth_prediction import check_model_folder
from pipeline.models.mouth_prediction import predict_mouth
from stages.pca.pca import fit_pca

BASIS = fit_pca(np.random.default_rng(0).normal(size=(200, 36)), 20)


def lstm_folder(folder, seed, basis=BASIS, identity_shift=0.0):
    """A small untrained LSTM model folder with a speaker record."""
    torch.manual_seed(seed)
    net = delayed_lstm.DelayedLSTM(28, 12, 20)
    save_model(folder, net, dict(model="lstm", delay=20, hidden=12, layers=1, n_features=28, n_components=20,
                                 feature_rate=100.0, params={"seed": seed}), np.zeros(28, np.float32),
               np.ones(28, np.float32), basis, dict(lip_points=list(range(18)), iod_px=72.0))
    ident = np.linspace(-0.1, 0.1, 128).astype(np.float32) + identity_shift
    np.savez(folder / "speaker.npz", shape3d=np.ones((68, 3), np.float32), identity=ident,
             identity_spread=np.array([0.1], np.float32))
    (folder / "audio_domain.json").write_text(json.dumps(dict(held_out_max=0.2)))
    return folder


@pytest.fixture(scope="module")
def members(tmp_path_factory):
    return [lstm_folder(tmp_path_factory.mktemp(f"m{s}"), s) for s in range(3)]


@pytest.fixture(scope="module")
def speech():
    t = np.arange(32000) / 16000
    return (0.3 * np.sin(2 * np.pi * 180 * t) * (np.sin(2 * np.pi * 3 * t) > 0)).astype(np.float32)


def test_ensemble_predicts_the_mean_of_its_members(tmp_path, members, speech):
    out = tmp_path / "ens"
    cfg = model_ensemble.write(out, members)
    assert cfg["families"] == ["lstm"] * 3 and check_model_folder(out)["model"] == "ensemble"
    ens = predict_mouth(speech, out, 29.97)
    each = [predict_mouth(speech, m, 29.97) for m in members]
    assert ens["coeffs"].shape == (60, 20) and ens["members"] == 3
    np.testing.assert_allclose(ens["coeffs"], np.mean([e["coeffs"] for e in each], 0), atol=1e-5)
    np.testing.assert_allclose(ens["lip_points"], np.mean([e["lip_points"] for e in each], 0), atol=1e-4)
    # the members really differ, so the average is not any one of them
    assert min(np.abs(ens["coeffs"] - e["coeffs"]).max() for e in each) > 1e-3
    assert ens["pca_fingerprint"] == each[0]["pca_fingerprint"]


def test_ensemble_folder_is_self_contained(tmp_path, members, speech):
    out = tmp_path / "ens"
    model_ensemble.write(out, members[:2])
    moved = tmp_path / "moved"
    out.rename(moved)                       # it travels: no path back to the members' folders
    assert load_speaker(moved) is not None and (moved / "audio_domain.json").is_file()
    assert np.isfinite(predict_mouth(speech, moved, 25)["coeffs"]).all()


def test_members_of_another_basis_or_speaker_are_refused(tmp_path, members):
    other_basis = fit_pca(np.random.default_rng(5).normal(size=(200, 36)), 20)
    odd = lstm_folder(tmp_path / "odd", 7, basis=other_basis)
    with pytest.raises(ModelError, match=r"odd: PCA basis .* differs"):
        model_ensemble.write(tmp_path / "e1", [members[0], odd])
    stranger = lstm_folder(tmp_path / "stranger", 8, identity_shift=0.3)
    with pytest.raises(ModelError, match=r"stranger: records another speaker"):
        model_ensemble.write(tmp_path / "e2", [members[0], stranger])
    with pytest.raises(ParameterError, match="at least 2"):
        model_ensemble.write(tmp_path / "e3", [members[0]])
    assert not any(p.name.startswith(("e1", "e2", "e3", ".e")) for p in tmp_path.iterdir())   # nothing half-written


def test_a_broken_member_is_named(tmp_path, members):
    out = tmp_path / "ens"
    model_ensemble.write(out, members[:2])
    (out / "members" / "1" / "weights.pt").unlink()
    with pytest.raises(ModelError, match=r"members/1: .*missing weights.pt"):
        check_model_folder(out)


def test_cli_writes_the_folder_and_reports_errors(tmp_path, members, capsys):
    assert ensemble_cli.main([str(members[0]), str(members[1]), "--out", str(tmp_path / "ens")]) == 0
    assert check_model_folder(tmp_path / "ens")["members"] == ["members/0", "members/1"]
    assert ensemble_cli.main([str(members[0]), str(tmp_path / "nope"), "--out", str(tmp_path / "e2")]) != 0
    assert "nope" in capsys.readouterr().err and not (tmp_path / "e2").exists()
