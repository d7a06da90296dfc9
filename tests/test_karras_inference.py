"""Karras inference, model folder and emotion choice (paper 001 §5), without training."""
import json

import numpy as np
import pytest
import torch

from pipeline.models import karras_inference
from pipeline.errors import ParameterError
from pipeline.face.dlib_face import LIP_POINTS
from pipeline.models.karras_network import KarrasNetwork
from pipeline.models.model_folder import ModelError, load_karras, save_karras
from stages.train_karras.targets import FACE_POINTS, LIP_INDEX

CANDIDATES = np.arange(3 * 16, dtype=np.float32).reshape(3, 16) / 10


def test_parse_emotion_index_interpolation_and_default():
    assert np.array_equal(karras_inference.parse_emotion(None, CANDIDATES), CANDIDATES[0])
    assert np.array_equal(karras_inference.parse_emotion("2", CANDIDATES), CANDIDATES[2])
    assert np.array_equal(karras_inference.parse_emotion(1, CANDIDATES), CANDIDATES[1])
    assert np.allclose(karras_inference.parse_emotion("0:2:0", CANDIDATES), CANDIDATES[0])
    assert np.allclose(karras_inference.parse_emotion("0:2:1", CANDIDATES), CANDIDATES[2])
    assert np.allclose(karras_inference.parse_emotion("0:2:0.25", CANDIDATES), 0.75 * CANDIDATES[0] + 0.25 * CANDIDATES[2])


@pytest.mark.parametrize("spec, words", [("3", "candidate 3 does not exist"), ("-1", "candidate -1"),
                                         ("0:1:1.5", "outside [0, 1]"), ("0:1", "K1:K2:t"), ("a", "not a candidate"),
                                         ("0:7:0.5", "candidate 7"), ("0:1:x", "not a number")])
def test_parse_emotion_refuses_with_one_line(spec, words):
    with pytest.raises(ParameterError, match="--emotion") as e:
        karras_inference.parse_emotion(spec, CANDIDATES)
    assert words in str(e.value)


def small_model(tmp_path, seed=0):
    torch.manual_seed(seed)
    d = 2 * len(FACE_POINTS)
    net = KarrasNetwork(d, 16)
    rng = np.random.default_rng(seed)
    face_mean = rng.normal(64, 20, d)
    lips = face_mean.reshape(-1, 2)[LIP_INDEX].ravel()
    comps = np.linalg.qr(rng.normal(size=(36, 20)))[0].T          # orthonormal rows (20, 36)
    arrays = dict(pca_mean=lips, pca_components=comps, lip_index=np.asarray(LIP_INDEX), face_mean=face_mean,
                  emotion_candidates=CANDIDATES, emotion_database=rng.normal(size=(50, 16)).astype(np.float32))
    cfg = dict(n_outputs=d, emotion_dim=16, face_points=FACE_POINTS, default_emotion=0, iod_px=40.0,
               lip_points=list(LIP_POINTS), emotion_info=[dict(index=i, video="v", frame=i) for i in range(3)])
    save_karras(tmp_path / "k", net, cfg, arrays)
    return tmp_path / "k", net


def test_model_folder_round_trip_and_mismatch(tmp_path):
    folder, net = small_model(tmp_path)
    m = load_karras(folder)
    for a, b in zip(m["net"].state_dict().values(), net.state_dict().values()):
        assert torch.equal(a, b)
    assert m["config"]["model"] == "karras" and len(m["emotion_candidates"]) == 3
    cfg = json.loads((folder / "config.json").read_text())
    (folder / "config.json").write_text(json.dumps(dict(cfg, n_outputs=cfg["n_outputs"] + 2)))
    with pytest.raises(ModelError, match="does not fit"):
        load_karras(folder)


def test_two_inferences_4ms_apart_are_averaged(tmp_path):
    folder, _ = small_model(tmp_path)
    m = load_karras(folder)
    rng = np.random.default_rng(1)
    samples = rng.normal(0, 0.1, 16000).astype(np.float32)
    from pipeline.audio.speech_autocorrelation import padded_track
    padded = padded_track(samples)
    t = np.array([0.3, 0.5])
    e = CANDIDATES[1]
    both = karras_inference.face_points_at(m["net"], padded, t, e)
    early = karras_inference.face_points_at(m["net"], padded, t - 0.002, e, ensemble=False)
    late = karras_inference.face_points_at(m["net"], padded, t + 0.002, e, ensemble=False)
    assert np.allclose(both, (early + late) / 2, atol=1e-5)
    assert not np.allclose(early, late, atol=1e-5)       # the two inferences see different windows


def test_predict_output_is_consistent_with_the_mouth_pca(tmp_path):
    folder, _ = small_model(tmp_path)
    m = load_karras(folder)
    samples = np.random.default_rng(2).normal(0, 0.1, 24000).astype(np.float32)
    out = karras_inference.predict(samples, m, 30.0, "0:1:0.5")
    n = 45                                                  # 1.5 s at 30 fps
    assert out["face_points"].shape == (n, len(FACE_POINTS), 2) and out["coeffs"].shape == (n, 20)
    assert out["lip_points"].shape == (n, 18, 2)
    lips = out["face_points"][:, LIP_INDEX].reshape(n, -1)
    basis_proj = (lips - m["pca_mean"]) @ m["pca_components"].T @ m["pca_components"] + m["pca_mean"]
    assert np.allclose(out["lip_points"].reshape(n, -1), basis_proj, atol=1e-3)
    assert np.allclose(out["emotion"], (CANDIDATES[0] + CANDIDATES[1]) / 2)
    other = karras_inference.predict(samples, m, 30.0, 2)
    assert not np.allclose(other["face_points"], out["face_points"])      # the emotion is an input


def test_predict_mouth_dispatches_and_emotion_is_refused_for_other_families(tmp_path):
    from pipeline.models.mouth_prediction import check_emotion, predict_mouth
    folder, _ = small_model(tmp_path)
    samples = np.random.default_rng(3).normal(0, 0.1, 16000).astype(np.float32)
    out = predict_mouth(samples, folder, 25.0, emotion="1")
    assert out["face_points"].shape == (25, 42, 2) and out["face_point_ids"] == FACE_POINTS
    with pytest.raises(ParameterError, match="candidate 5 does not exist"):
        check_emotion(folder, "5")
    other = tmp_path / "brand"
    other.mkdir()
    (other / "config.json").write_text(json.dumps({"model": "brand"}))
    (other / "arrays.npz").write_bytes(b"")
    with pytest.raises(ParameterError, match="only Karras models take an emotion"):
        check_emotion(other, "0")


def test_mesh_driving_points_use_the_whole_lower_face():
    from pipeline.face.canonical import TextureWindow
    from stages.render_mesh.render_mesh import driving_points
    window = TextureWindow(-80.0, 20.0, 160.0 / 128, 128)
    rng = np.random.default_rng(4)
    face = rng.uniform(10, 110, (5, 42, 2)).astype(np.float32)
    mouth = dict(face_points=face, face_mean=face.mean(0), face_point_ids=FACE_POINTS,
                 lip_points=face[:, LIP_INDEX], mean_shape=face.mean(0)[LIP_INDEX])
    ids, moved = driving_points(mouth, window)
    assert ids == FACE_POINTS and moved.shape == (5, 42, 2)
    assert np.allclose(moved, face * window.mm_per_px + [window.x0, window.y0], atol=1e-4)   # texture px → mm
    del mouth["face_points"]
    ids, moved = driving_points(mouth, window)                  # other families: the 18 lip points
    assert moved.shape == (5, 18, 2) and ids == [FACE_POINTS[i] for i in LIP_INDEX]


def test_training_targets_refuse_another_landmark_layout(tmp_path):
    import zarr
    from pipeline.errors import LipsynthError
    from stages.train_karras.targets import load_targets
    for name in ("ingest", "landmarks"):
        zarr.open_group(str(tmp_path / f"{name}.zarr"), mode="w")
    fr = zarr.open_group(str(tmp_path / "frontalize.zarr"), mode="w")
    fr.create_array("frontal_landmarks", shape=(10, 5, 2), dtype="float32")
    with pytest.raises(LipsynthError, match=r"layout \(5, 2\).*68 points"):
        load_targets(str(tmp_path / "ingest.zarr"), str(tmp_path / "landmarks.zarr"), str(tmp_path / "frontalize.zarr"))


def test_silent_or_short_audio_is_one_clear_error(tmp_path):
    from pipeline.errors import BadInputError
    folder, _ = small_model(tmp_path)
    m = load_karras(folder)
    with pytest.raises(BadInputError, match="silent"):
        karras_inference.predict(np.zeros(16000, np.float32), m, 25.0, source="quiet.wav")
    with pytest.raises(BadInputError, match="too short"):
        karras_inference.predict(np.ones(4000, np.float32), m, 25.0, source="short.wav")
