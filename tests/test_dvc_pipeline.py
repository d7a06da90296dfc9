"""The whole pipeline on the embedded synthetic speaker, reproduced once with DVC (the default
corpus: 6 videos × 10 s), then checked: stores, landmarks against ground truth, training
against the baselines, and DVC's caching when params change."""
import contextlib
import csv
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
import zarr

from pipeline.params import load_params
from tests.conftest import ROOT
from tests.helpers import copy_project, dvc, dvc_status, one_error_line
from tests.helpers.media import write_wav
from stages import registry


@contextlib.contextmanager
def edited_params(proj, section, key, value):
    """params.yaml of ``proj`` with one key changed; restored afterwards even when the test fails,
    so one failing test cannot leak its edit into the next one's ``dvc status``."""
    path = proj / "params.yaml"
    original = path.read_text()
    params = yaml.safe_load(original)
    params[section][key] = value
    path.write_text(yaml.safe_dump(params, sort_keys=False))
    try:
        yield
    finally:
        path.write_text(original)


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    """A copy of the project's pipeline with a tiny synthetic corpus, reproduced once."""
    proj = copy_project(tmp_path_factory.mktemp("dvcproj"), {"delay_sweep": {"delays": [0, 20], "steps": 100}})
    out = dvc(proj, "repro")
    for stage in STAGES:
        assert f"Running stage '{stage}'" in out
    shutil.copy(proj / "dvc.lock", proj / "dvc.lock.first")      # later tests edit params and re-run
    return proj


STAGES = tuple(s.name for s in registry.STAGES)


def stage_outputs(project) -> dict[str, list[Path]]:
    """Every stage's outs, metrics and plots of dvc.yaml, their ``${section.key}`` resolved from params.yaml."""
    stages = yaml.safe_load((project / "dvc.yaml").read_text())["stages"]
    params = yaml.safe_load((project / "params.yaml").read_text())

    def resolve(text):
        return re.sub(r"\$\{(\w+)\.(\w+)\}", lambda m: str(params[m[1]][m[2]]), text)
    out = {}
    for name, stage in stages.items():
        entries = [e for key in ("outs", "metrics", "plots") for e in stage.get(key, [])]
        out[name] = [project / resolve(e if isinstance(e, str) else next(iter(e))) for e in entries]
    return out


@pytest.mark.slow
def test_repro_builds_all_stores(project):
    """Every stage of dvc.yaml wrote every output it declares: a zarr store with its metadata, a
    non-empty folder or a non-empty file."""
    outputs = stage_outputs(project)
    assert len(outputs) >= 16 and all(outputs.values()), outputs
    for stage, paths in outputs.items():
        for path in paths:
            assert path.exists(), f"{stage}: {path} missing"
            if path.suffix == ".zarr":
                assert (path / "zarr.json").is_file(), f"{stage}: {path} is not a zarr store"
            elif path.is_dir():
                assert any(path.iterdir()), f"{stage}: {path} is empty"
            else:
                assert path.stat().st_size > 0, f"{stage}: {path} is empty"
    assert "up to date" in dvc(project, "status")


@pytest.mark.slow
def test_landmarks_match_ground_truth(project):
    lm = zarr.open_group(str(project / "store" / "landmarks.zarr"))
    valid = np.asarray(lm["valid"][...])
    pts = np.asarray(lm["landmarks"][...])
    errs = []
    for v in lm.attrs["videos"]:
        truth = np.load(project / "data" / "synthetic_speaker" / f"{v['name']}.truth.npz")["landmarks"]
        sl = slice(v["first_frame"], v["first_frame"] + v["n_frames"])
        assert len(truth) == v["n_frames"]
        iod = np.linalg.norm(truth[:, 45] - truth[:, 36], axis=1)
        err = np.linalg.norm(pts[sl] - truth, axis=-1).mean(1) / iod
        errs.append(err[valid[sl]])
        assert valid[sl].mean() >= 0.98, v["name"]
    errs = np.concatenate(errs)
    assert np.median(errs) < 0.04, np.median(errs)         # dlib vs the generator's truth, ≈ 1.7 % IOD
    assert np.percentile(errs, 99) < 0.10


@pytest.mark.slow
def test_frontalized_pose_follows_true_head_motion(project):
    from pipeline.face.geometry import euler_degrees
    fr = zarr.open_group(str(project / "store" / "frontalize.zarr"))
    pose, ok = np.asarray(fr["pose"][...]), np.asarray(fr["pose_valid"][...])
    est, true = [], []
    for v in fr.attrs["videos"]:
        t = np.load(project / "data" / "synthetic_speaker" / f"{v['name']}.truth.npz")["pose"]
        sl = slice(v["first_frame"], v["first_frame"] + v["n_frames"])
        assert ok[sl].mean() >= 0.98, v["name"]
        est.append(np.array([euler_degrees(r) for r in pose[sl, :3]])[ok[sl]])
        true.append(t[ok[sl], :3])
    est, true = np.concatenate(est), np.concatenate(true)
    roll_corr = np.corrcoef(est[:, 2], true[:, 2])[0, 1]
    yaw_corr = abs(np.corrcoef(est[:, 0], true[:, 0])[0, 1])
    assert roll_corr > 0.9 and yaw_corr > 0.7, (roll_corr, yaw_corr)


@pytest.mark.slow
def test_training_learns_and_beats_the_mean_shape(project):
    m = json.loads((project / "metrics" / "train.json").read_text())
    assert m["val"]["mouth_error_px"] <= 0.7 * m["baseline_mean_shape"]["mouth_error_px"], m
    rows = list(csv.DictReader(open(project / "plots" / "train_loss.csv")))
    lstm = [float(r["train_loss"]) for r in rows if r["model"] == "lstm"]
    assert lstm[-1] < 0.5 * lstm[0]
    assert (project / "models" / "lstm" / "weights.pt").exists()
    sweep = {int(r["delay_steps"]): float(r["val_loss"]) for r in csv.DictReader(open(project / "plots" / "delay_sweep.csv"))}
    assert sweep[20] < sweep[0]      # the synthetic mouth leads its sound by 80 ms: a delay helps


@pytest.mark.slow
def test_voice_puppetry_trains_beats_the_mean_shape_and_predicts(project, tmp_path):
    m = json.loads((project / "metrics" / "train_brand.json").read_text())
    for prior in ("entropic", "ml"):
        assert m[prior]["val"]["mouth_error_px"] < 0.9 * m["baseline_mean_shape"]["mouth_error_px"], m
        assert 2 <= m[prior]["states"] <= 26
        for source in ("state_sequence", "voice"):          # Eq. 7: 0 = exact, ≈ 1 = unrelated motion
            assert 0 < m[prior]["eq7"][source]["train"] < 0.5 and 0 < m[prior]["eq7"][source]["test"] < 0.5, m[prior]
    rows = list(csv.DictReader(open(project / "plots" / "train_brand.csv")))
    post = [float(r["log_posterior"]) for r in rows if r["model"] == "entropic"]
    assert post[-1] > post[0]
    clip = project / "data" / "synthetic_speaker" / "speaker_00.mp4"
    r = subprocess.run([sys.executable, "-m", "lipsynth.cli", "predict-mouth", str(clip), "--model",
                        str(project / "models" / "brand"), "--fps", "50", "--out", str(tmp_path / "b.npz")],
                       cwd=project, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    out = np.load(tmp_path / "b.npz")
    assert out["lip_points"].shape == (500, 18, 2) and np.isfinite(out["lip_points"]).all()
    from pipeline.measures.mouth_metrics import opening
    opening = opening(out["lip_points"])
    assert opening.std() > 0.3                      # the mouth opens and closes with the speech (canonical px)
    # a Voice Puppetry folder from another store is refused by synthesize, naming the mismatch
    bad = tmp_path / "brand_other"
    shutil.copytree(project / "models" / "brand", bad)
    cfg = json.loads((bad / "config.json").read_text())
    (bad / "config.json").write_text(json.dumps(dict(cfg, pca_fingerprint="0123456789abcdef")))
    r = subprocess.run([sys.executable, "-m", "lipsynth.cli", "predict-mouth", str(clip), "--model", str(bad),
                        "--out", str(tmp_path / "c.npz")], cwd=project, capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and "PCA basis" in r.stderr and not (tmp_path / "c.npz").exists()


@pytest.mark.slow
def test_karras_trains_beats_the_mean_shape_and_mines_emotions(project, tmp_path):
    m = json.loads((project / "metrics" / "train_karras.json").read_text())
    k = load_params(project / "params.yaml").karras
    assert m["steps_run"] == m["step_kept"] == k.steps and m["emotion_candidates"] >= 1
    assert m["val"]["mouth_error_px"] < 0.9 * m["baseline_mean_shape"]["mouth_error_px"], m
    rows = list(csv.DictReader(open(project / "plots" / "train_karras_loss.csv")))
    assert [int(r["step"]) for r in rows] == list(range(k.val_every, k.steps + 1, k.val_every))
    val = [float(r["val_position"]) for r in rows if r["val_position"]]
    # the validation curve falls from its first point (one epoch in): measured 2.47 → 1.57 px² over
    # the demo's 120 steps on the synthetic speaker; an unlearning network stays flat
    assert len(val) >= 3 and val[-1] < 0.75 * val[0], val
    # the training loss of one epoch is noisy (measured: the last of the demo's 10 spiked from 1.17 to 1.83
    # while the validation error fell), so the last three epochs' mean is compared with the first epoch's
    train = [float(r["position"]) for r in rows]
    assert len(train) >= 4 and np.mean(train[-3:]) < 0.5 * train[0], train
    r = subprocess.run([sys.executable, "-m", "lipsynth.cli", "emotions", "--model", str(project / "models" / "karras")],
                       cwd=project, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0 and "← default" in r.stdout, r.stderr
    clip = project / "data" / "synthetic_speaker" / "speaker_00.mp4"
    last = m["emotion_candidates"] - 1
    r = subprocess.run([sys.executable, "-m", "lipsynth.cli", "predict-mouth", str(clip), "--model",
                        str(project / "models" / "karras"), "--fps", "30", "--emotion", f"0:{last}:0.5",
                        "--out", str(tmp_path / "k.npz")], cwd=project, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    out = np.load(tmp_path / "k.npz")
    assert out["face_points"].shape == (300, 42, 2) and out["lip_points"].shape == (300, 18, 2)
    from pipeline.measures.mouth_metrics import opening
    assert opening(out["lip_points"]).std() > 0.3
    jaw = out["face_points"][:, 6, 1]                                # dlib point 8, the chin: the jaw moves too
    assert jaw.std() > 0.1
    r = subprocess.run([sys.executable, "-m", "lipsynth.cli", "predict-mouth", str(clip), "--model",
                        str(project / "models" / "karras"), "--emotion", str(last + 1), "--out", str(tmp_path / "x.npz")],
                       cwd=project, capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and "does not exist" in r.stderr and not (tmp_path / "x.npz").exists()


@pytest.mark.slow
def test_render_mesh_stage_wrote_the_karras_face(project):
    import av
    out = project / load_params(project / "params.yaml").render_mesh.out
    with av.open(str(out)) as c:
        kinds = sorted(s.type for s in c.streams)
        frames = [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]
    assert kinds == ["audio", "video"] and len(frames) == 250 and frames[0].shape[:2] == (512, 1024)
    h = frames[0].shape[0]
    assert np.stack([f[h // 6:h // 3, h // 4:3 * h // 4] for f in frames]).mean() > 40    # the textured face is drawn
    from pipeline.face.mesh_export import read_pc2
    head = project / load_params(project / "params.yaml").render_mesh.export
    cache = read_pc2(head / "head.pc2")
    assert cache.shape[0] == 250 and cache.shape[1] >= 4000
    assert_the_mouth_moves_more_than_the_brow_once_the_head_turn_is_removed(cache.astype(float))
    assert sum(x.startswith("v ") for x in (head / "head.obj").read_text().splitlines()) == cache.shape[1]
    from tests.helpers.gltf_validator import validate                  # the glTF head and its audio beside it
    assert (head / "head.wav").is_file()
    assert validate(head / "head.glb")["issues"]["numErrors"] == 0


def assert_the_mouth_moves_more_than_the_brow_once_the_head_turn_is_removed(cache: np.ndarray) -> None:
    """The stage's head turns and blinks with the footage (render_mesh.head_motion, .blinks), so the whole
    picture moves; in the point cache (T, N, 3), each frame aligned rigidly onto the first, the lower third
    of the face (mouth, jaw) must move at least twice as much as the upper third (brows, eyes and lids)."""
    ref = cache[0] - cache[0].mean(0)

    def aligned(x):
        u, _, vt = np.linalg.svd((x - x.mean(0)).T @ ref)
        r = u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))]) @ vt
        return (x - x.mean(0)) @ r
    motion = np.stack([aligned(f) for f in cache]).std(0).mean(1)            # per vertex, mm
    y = ref[:, 1]                                                            # up (the cache's y points up)
    lower, upper = motion[y < np.percentile(y, 33)].mean(), motion[y >= np.percentile(y, 67)].mean()
    assert cache.std(0).mean() > 1.0                                         # the head does turn (mm)
    assert lower > 2 * upper, (lower, upper)


def assert_the_mouth_moves_and_the_brow_stays(frames: list) -> None:
    """In the front view (left half) the lower face changes over the clip (the mouth and jaw move) at least 3×
    as much as the upper third (brows, eyes: held still) — and the head is drawn there at all."""
    h = frames[0].shape[0]
    stack = np.stack([f[:, :h].astype(float) for f in frames])
    upper, lower = stack[:, h // 6:h // 3, h // 4:3 * h // 4], stack[:, h // 2:5 * h // 6, h // 4:3 * h // 4]
    assert upper.mean() > 40                                   # the textured face, not the black background
    assert lower.std(0).mean() > 3 * upper.std(0).mean()


@pytest.mark.slow
def test_karras_param_reruns_only_karras_stages(project):
    with edited_params(project, "karras", "val_every", 7):
        status = dvc_status(project)
    # render_mesh depends on models/karras, not on the karras params: it reruns when the model changes
    assert set(status) == {"train_karras", "report"}, status
    assert "up to date" in dvc(project, "status")


@pytest.mark.slow
def test_render_mesh_cli_writes_an_mp4_with_audio(project, tmp_path):
    import av
    clip = project / "data" / "synthetic_speaker" / "speaker_01.mp4"
    out = tmp_path / "mesh.mp4"
    r = subprocess.run([sys.executable, "-m", "lipsynth.cli", "render-mesh", str(clip), "--model",
                        str(project / "models" / "brand"), "--out", str(out), "--size", "160"],
                       cwd=project, capture_output=True, text=True, timeout=600, env=dict(os.environ, OFF_SCREEN="True"))
    assert r.returncode == 0, r.stderr
    with av.open(str(out)) as c:
        kinds = sorted(s.type for s in c.streams)
        frames = [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]
    assert kinds == ["audio", "video"] and len(frames) == 250 and frames[0].shape[:2] == (160, 320)
    assert_the_mouth_moves_and_the_brow_stays(frames)


@pytest.mark.slow
def test_phonetic_store_and_a_phonetic_model(project, tmp_path):
    """The phonetic stage stores one class per 10 ms frame on the MFCC axis; train.features reruns
    training (not the phone recogniser); a model trained on mfcc+phonetic answers predict_mouth."""
    from pipeline.models.mouth_prediction import load_audio, predict_mouth
    ph, ing = zarr.open_group(str(project / "store" / "phonetic.zarr")), zarr.open_group(str(project / "store" / "ingest.zarr"))
    phones = np.asarray(ph["phones"][...])
    assert phones.shape == (ing["mfcc"].shape[0], 40)
    for v in ph.attrs["videos"]:
        rows = phones[v["first_mfcc"]:v["first_mfcc"] + v["n_mfcc"]]
        assert (rows.sum(1) == 1).all(), v["name"]
    # the shipped whisper front end's training depends on the whisper store only: `dvc repro train` never runs
    # the phone recogniser
    train_deps = {d["path"] for d in yaml.safe_load((project / "dvc.lock.first").read_text())["stages"]["train"]["deps"]}
    assert "store/whisper.zarr" in train_deps and "store/phonetic.zarr" not in train_deps, train_deps
    with edited_params(project, "train", "features", "mfcc+phonetic"):
        status = set(dvc_status(project))
    assert "train" in status and not {"ingest", "phonetic", "pca", "train_brand", "train_karras"} & status, status
    params = yaml.safe_load((project / "params.yaml").read_text())
    params["train"].update(features="mfcc+phonetic", steps=15, baselines=False, out=str(tmp_path / "m"),
                           metrics=str(tmp_path / "m.json"), plots=str(tmp_path / "m.csv"))
    (tmp_path / "p.yaml").write_text(yaml.safe_dump(params))
    train = registry.stage("train").argv(tmp_path / "p.yaml")
    r = subprocess.run(train, cwd=project, capture_output=True, text=True, timeout=1200)
    assert "train.feature_store='store/whisper.zarr'" in one_error_line(r) and "set train.feature_store: store/phonetic.zarr" in r.stderr
    params["train"]["feature_store"] = "store/phonetic.zarr"
    (tmp_path / "p.yaml").write_text(yaml.safe_dump(params))
    r = subprocess.run(train, cwd=project, capture_output=True, text=True, timeout=1200)
    assert r.returncode == 0, r.stderr[-2000:]
    assert json.loads((tmp_path / "m" / "config.json").read_text())["features"] == "mfcc+phonetic"
    out = predict_mouth(load_audio(project / "data" / "synthetic_speaker" / "speaker_01.mp4"), tmp_path / "m", 25)
    assert out["coeffs"].shape == (250, 20) and np.isfinite(out["coeffs"]).all()
    # audio the recogniser finds no speech in (silence, noise) gives a finite mouth no more open than speech's median
    from pipeline.face.dlib_face import LIP_POINTS
    top, bottom = [LIP_POINTS.index(k) for k in (61, 62, 63)], [LIP_POINTS.index(k) for k in (67, 66, 65)]
    opening = lambda m: (m["lip_points"][:, bottom, 1] - m["lip_points"][:, top, 1]).mean(1)
    for quiet in (np.zeros(32000, np.float32), 0.003 * np.random.default_rng(0).standard_normal(32000).astype(np.float32)):
        q = predict_mouth(quiet, tmp_path / "m", 25)
        assert np.isfinite(q["lip_points"]).all()
        assert np.median(opening(q)) <= np.median(opening(out)) + 0.2, (np.median(opening(q)), np.median(opening(out)))


@pytest.mark.slow
def test_whisper_store_and_a_whisper_model(project, tmp_path):
    """The whisper stage stores 384-D encoder states on the MFCC axis; its window reruns it and what
    reads it (never ingest, phonetic, the face stages or Karras); a model trained on it records the
    windowing and answers predict_mouth with finite shapes, for speech and for silence."""
    from pipeline.models.mouth_prediction import load_audio, predict_mouth
    wh, ing = zarr.open_group(str(project / "store" / "whisper.zarr")), zarr.open_group(str(project / "store" / "ingest.zarr"))
    states = np.asarray(wh["states"][...], np.float32)
    assert states.shape == (ing["mfcc"].shape[0], 384) and np.isfinite(states).all()
    for v in wh.attrs["videos"]:
        rows = states[v["first_mfcc"]:v["first_mfcc"] + v["n_mfcc"]]
        assert rows.std(0).mean() > 0.05, v["name"]                 # every video's rows written, and moving
    with edited_params(project, "whisper", "window_seconds", 8.0):
        status = set(dvc_status(project))
    # train reads whisper.zarr, so it reruns once whisper has (dvc status flags only stages whose own deps
    # changed); Voice Puppetry computes its voice features from the audio, so its whisper params flag it now
    assert {"whisper", "train_brand"} <= status and "train" not in status, status
    assert not {"ingest", "phonetic", "landmarks", "frontalize", "pca", "train_karras"} & status, status
    params = yaml.safe_load((project / "params.yaml").read_text())
    params["train"].update(features="whisper", feature_norm="corpus", vtlp_warps=[], pitch_shifts=[], steps=15,
                           baselines=False, out=str(tmp_path / "m"), metrics=str(tmp_path / "m.json"),
                           plots=str(tmp_path / "m.csv"))
    (tmp_path / "p.yaml").write_text(yaml.safe_dump(params))
    r = subprocess.run(registry.stage("train").argv(tmp_path / "p.yaml"),
                       cwd=project, capture_output=True, text=True, timeout=1200)
    assert r.returncode == 0, r.stderr[-2000:]
    cfg = json.loads((tmp_path / "m" / "config.json").read_text())
    assert cfg["features"] == "whisper" and cfg["encoder"] == {"window_s": 10.0, "overlap_s": 2.0}
    out = predict_mouth(load_audio(project / "data" / "synthetic_speaker" / "speaker_01.mp4"), tmp_path / "m", 25)
    assert out["coeffs"].shape == (250, 20) and np.isfinite(out["coeffs"]).all()
    quiet = predict_mouth(np.zeros(32000, np.float32), tmp_path / "m", 25)
    assert np.isfinite(quiet["lip_points"]).all()


@pytest.mark.slow
def test_a_store_read_as_an_extra_corpus_keeps_each_videos_motion(project):
    """The demo store read back as another person's corpus: each video's targets differ from the pca
    stage's own coefficients by one constant (its resting shape, replaced by the corpus mean), and the
    inputs are the whisper states of the same frames."""
    from stages.train import extra_corpora
    from stages.train.train import load_sequences
    store = project / "store"
    data, basis, attrs = load_sequences(str(store / "ingest.zarr"), str(store / "pca.zarr"), "whisper",
                                        whisper_path=str(store / "whisper.zarr"))
    own = {s["name"]: s for s in data["train"] + data["val"]}
    extra = extra_corpora.load([str(store)], "whisper", basis, attrs["iod_px"], repeat=2)
    assert len(extra) == 2 * len(own) and all(s["extra"] for s in extra)
    for s in extra[::2]:
        o = own[s["name"].split("/", 1)[1]]
        np.testing.assert_array_equal(s["x"], o["x"])
        both = s["ok"] & o["ok"]
        assert both.mean() > 0.8, s["name"]
        diff = (o["y"] - s["y"])[both]
        assert np.abs(diff - diff.mean(0)).max() < 1e-3, s["name"]       # one offset per video: motion intact
        assert np.abs(diff.mean(0)).max() > 1e-4 or len(own) == 1          # the resting shape did move


@pytest.mark.slow
def test_fine_tuning_from_a_model_folder_trains_only_what_it_is_told(project, tmp_path):
    """train.init_from starts from a model folder (here the demo's own LSTM): with fine_tune: output the
    recurrent weights stay the base's and the read-out moves; a base of another front end is one line."""
    import torch
    params = yaml.safe_load((project / "params.yaml").read_text())
    params["train"].update(init_from=str(project / "models" / "lstm"), fine_tune="output", steps=20, baselines=False,
                           out=str(tmp_path / "m"), metrics=str(tmp_path / "m.json"), plots=str(tmp_path / "m.csv"))
    (tmp_path / "p.yaml").write_text(yaml.safe_dump(params))
    r = subprocess.run(registry.stage("train").argv(tmp_path / "p.yaml"),
                       cwd=project, capture_output=True, text=True, timeout=1200)
    assert r.returncode == 0, r.stderr[-2000:]
    base = torch.load(project / "models" / "lstm" / "weights.pt", weights_only=True)
    tuned = torch.load(tmp_path / "m" / "weights.pt", weights_only=True)
    for k in base:
        same = torch.equal(base[k], tuned[k])
        assert same == k.startswith("lstm."), k
    cfg = json.loads((tmp_path / "m" / "config.json").read_text())
    assert cfg["params"]["init_from"] == str(project / "models" / "lstm") and cfg["hidden"] == 60
    params["train"].update(features="mfcc", feature_store="store/ingest.zarr", fine_tune="all")
    (tmp_path / "p.yaml").write_text(yaml.safe_dump(params))
    r = subprocess.run(registry.stage("train").argv(tmp_path / "p.yaml"),
                       cwd=project, capture_output=True, text=True, timeout=600)
    assert r.returncode != 0 and "reads 'whisper' features" in r.stderr.strip().splitlines()[-1], r.stderr[-800:]


@pytest.mark.slow
def test_personalize_one_video_split_in_time_from_scratch_and_from_the_shipped_base(project, tmp_path):
    """lipsynth personalize on one 10-s video: cut into segments, the end held out (one line says so),
    preprocessed; from scratch (--base none) and from the shipped base by default: the recording's
    offset estimated, six candidates scored fold by fold, the base replaced only by one that beats it
    beyond noise; the figures printed, a speak-ready folder."""
    video = project / "data" / "synthetic_speaker" / "speaker_01.mp4"
    common = [sys.executable, "-m", "lipsynth.cli", "personalize", str(video), "--segment-seconds", "2.5"]
    r = subprocess.run(common + ["--out", str(tmp_path / "scratch"), "--steps", "30", "--work", str(tmp_path / "w1"),
                                 "--base", "none"], cwd=project, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "held-out footage (1 clips)" in r.stdout and "personalized" in r.stdout, r.stdout
    assert "held out: speaker_01_s003.mp4 (" in r.stdout, r.stdout
    idx = zarr.open_group(str(tmp_path / "w1" / "store" / "ingest.zarr")).attrs["videos"]
    assert [(v["name"], v["split"]) for v in idx] == [(f"speaker_01_s{k:03d}", "train" if k < 3 else "val") for k in range(4)]
    summary = json.loads((tmp_path / "w1" / "summary.json").read_text())
    assert np.isfinite(summary["ratio_to_mean_shape"]) and summary["base"] is None and summary["chosen"] == "scratch"
    assert (tmp_path / "scratch" / "bank.zarr").is_dir() and (tmp_path / "scratch" / "speaker.npz").is_file()
    r = subprocess.run(common + ["--out", str(tmp_path / "tuned"), "--steps", "20", "--work", str(tmp_path / "w2")],
                       cwd=project, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    tuned = json.loads((tmp_path / "w2" / "summary.json").read_text())
    cfg = json.loads((tmp_path / "tuned" / "config.json").read_text())
    assert tuned["base"] == str(project / "models" / "base") and cfg["personalized"]["base"] == tuned["base"]
    errors = {c: f["mouth_error_px"] for c, f in tuned["candidates"].items()}
    assert set(errors) == {"base", "readout", "encoder_readout", "average", "retrieval", "fine_tune"}, tuned
    folds = tuned["folds"]
    assert set(folds) == set(errors) and not folds["base"]["beats_base"]
    chosen = tuned["chosen"]
    assert chosen == "base" or folds[chosen]["beats_base"], tuned                       # never a change within noise
    assert chosen == max([c for c in folds if folds[c]["beats_base"]] or ["base"], key=lambda c: folds[c]["mean"]), tuned
    assert tuned["ratio_to_mean_shape"] == tuned["candidates"][chosen]["ratio_to_mean_shape"]
    assert list(tuned["offsets"]) == ["speaker_01"] and "offset_ms" in tuned["offsets"]["speaker_01"]
    for c in errors:
        assert f"candidate {c}" in r.stdout, r.stdout
        assert f"candidate {c}" in r.stderr, r.stderr[-3000:]                          # the per-fold lines
    assert "audio–video offset" in r.stderr, r.stderr[-3000:]
    assert (tmp_path / "tuned" / "bank.zarr").is_dir() and cfg["features"] == "whisper"


@pytest.mark.slow
def test_the_report_page_dvc_repro_wrote_renders_in_headless_chromium(project, tmp_path):
    """The page the report stage wrote in this reproduction: its players play, its plots render, no errors."""
    from tests.helpers.browser import assert_page_renders, check_in_browser
    params = yaml.safe_load((project / "params.yaml").read_text())
    page = project / params["report"]["out"] / "index.html"
    text = page.read_text()
    state = check_in_browser(page, tmp_path / "screenshot.png")
    assert text.count("<video") >= 1 and text.count("<svg") >= 1
    assert_page_renders(state, n_videos=text.count("<video"), n_svgs=text.count("<svg"))


@pytest.mark.slow
def test_editing_a_parameters_meaning_reruns_nothing(project):
    """A key's meaning (pipeline/params/help.yaml) and the params.yaml comments rendered from it are
    prose no stage runs: editing them must leave every stage cached."""
    meanings = project / "pipeline" / "params" / "help.yaml"
    params = project / "params.yaml"
    original = meanings.read_text(), params.read_text()
    assert "master seed" in original[0]
    try:
        meanings.write_text(original[0].replace("master seed", "the seed every clip's sub-seed comes from"))
        render = ("from lipsynth import params_doc as d; "
                  "d.PARAMS_YAML.write_text(d.commented_params(d.PARAMS_YAML.read_text()))")
        subprocess.run([sys.executable, "-c", render], cwd=project, check=True)
        assert "the seed every clip's sub-seed" in params.read_text()          # the comment was rendered
        assert "up to date" in dvc(project, "status")
    finally:
        meanings.write_text(original[0])
        params.write_text(original[1])


@pytest.mark.slow
def test_brand_param_reruns_only_train_brand(project):
    with edited_params(project, "brand", "decode", "posterior"):
        status = dvc_status(project)
    assert set(status) == {"train_brand", "report"}, status        # the page shows the brand section
    assert "up to date" in dvc(project, "status")


@pytest.mark.slow
def test_predict_mouth_cli_on_a_synthetic_clip(project, tmp_path):
    clip = project / "data" / "synthetic_speaker" / "speaker_00.mp4"
    r = subprocess.run([sys.executable, "-m", "lipsynth.cli", "predict-mouth", str(clip), "--model", str(project / "models" / "lstm"),
                        "--fps", "29.97", "--out", str(tmp_path / "m.npz"), "--chunk-seconds", "1.5"],
                       cwd=project, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    out = np.load(tmp_path / "m.npz")
    assert out["lip_points"].shape == (300, 18, 2)             # 10 s at 29.97 fps


@pytest.mark.slow
def test_frontalize_param_reruns_only_frontalize_and_downstream(project):
    """A frontalize param invalidates frontalize (and, through its output, what reads it), never the
    stages upstream. `dvc repro frontalize` runs the edited stage with its upstream checked — what
    this test asserts — without retraining everything downstream; undoing the edit then brings the
    old output back from DVC's run cache, so the project is up to date again for the next tests."""
    with edited_params(project, "frontalize", "inpaint_radius",      # + 2: inpainting runs at half resolution
                       yaml.safe_load((project / "params.yaml").read_text())["frontalize"]["inpaint_radius"] + 2.0):
        status = dvc_status(project)
        # dvc status names only the edited stage — and the report, which shows every section's params
        assert set(status) == {"frontalize", "report"}, status
        out = dvc(project, "repro", "frontalize")
        assert "Running stage 'frontalize'" in out
        for stage in ("synthetic_speaker", "ingest", "landmarks"):
            assert f"Running stage '{stage}'" not in out
            assert f"Stage '{stage}' didn't change, skipping" in out
        downstream = set(dvc_status(project))
        assert {"pca", "train", "train_brand", "train_karras", "synthesize", "composite"} <= downstream, downstream
        assert not {"synthetic_speaker", "ingest", "landmarks", "frontalize"} & downstream, downstream
    out = dvc(project, "repro", "frontalize")
    assert "Running stage 'frontalize'" not in out, out              # restored from the run cache
    assert "up to date" in dvc(project, "status")


@pytest.mark.slow
def test_cluster_param_invalidates_nothing(project):
    with edited_params(project, "cluster", "n_workers", 1):
        assert "up to date" in dvc(project, "status")


def opening_of(video, project):
    """Inner-lip opening per frame of a video, from the pipeline's own landmark tracker."""
    from lipsynth import lipsync_quality as quality
    _, lms, valid = quality.video_landmarks(video, load_params(project / "params.yaml").landmarks)
    assert valid.mean() > 0.9, f"{video}: a face on only {valid.mean():.0%} of the frames"
    return quality.inner_opening(lms), valid


@pytest.mark.slow
def test_repro_ends_with_a_lip_synced_mp4_of_the_synthetic_speaker(project):
    import av
    params = yaml.safe_load((project / "params.yaml").read_text())
    out = project / params["composite"]["out_dir"] / "result.mp4"
    with av.open(str(out)) as c:
        v, a = c.streams.video[0], c.streams.audio[0]
        assert v.codec_context.name == "h264" and v.codec_context.pix_fmt == "yuv420p"
        assert a.codec_context.name == "aac"
        assert abs(float(v.average_rate) - 25.0) < 1e-6
        n = sum(1 for _ in c.decode(video=0))
    assert n == 250                                              # the 10 s audio at the target's 25 fps
    assert (out.parent / "result.diagnostic.mp4").exists()
    timing = json.loads((project / "logs" / "composite.timing.json").read_text())     # untracked, outside DVC
    assert set(timing) >= {"decode", "flow", "render_back", "blend", "encode"}
    # lip sync: the output mouth follows the mouth the audio was spoken with (speaker_03's truth),
    # not the target's own (speaker_00)
    opening, valid = opening_of(out, project)
    source = np.load(project / "data" / "synthetic_speaker" / "speaker_03.truth.npz")["mouth"][:, 0]
    target = np.load(project / "data" / "synthetic_speaker" / "speaker_00.truth.npz")["mouth"][:, 0]
    corr_source = np.corrcoef(opening[valid], source[valid])[0, 1]
    corr_target = np.corrcoef(opening[valid], target[valid])[0, 1]
    assert corr_source > 0.6, corr_source
    assert corr_source > corr_target + 0.3, (corr_source, corr_target)


def speak(project, tmp_path, *args):
    return subprocess.run([sys.executable, "-m", "lipsynth.cli", "speak", "--model", str(project / "models" / "lstm"),
                           "--cache", str(tmp_path / "cache"), *map(str, args)],
                          cwd=project, capture_output=True, text=True, timeout=600)


@pytest.mark.slow
def test_speak_with_silent_audio_gives_a_closed_mouth(project, tmp_path):
    silent = tmp_path / "silent.wav"
    write_wav(silent, np.zeros(44100 * 4), 44100, channels=2)     # 4 s of digital silence, 44.1 kHz stereo
    target = project / "data" / "synthetic_speaker" / "speaker_01.mp4"
    out = tmp_path / "silent.mp4"
    r = speak(project, tmp_path, "--audio", silent, "--target", target, "--out", out)
    assert r.returncode == 0, r.stderr
    import av
    with av.open(str(out)) as c:
        assert c.streams.audio and sum(1 for _ in c.decode(video=0)) == 100
    silent_opening, _ = opening_of(out, project)
    spoken_opening, _ = opening_of(project / "outputs" / "synthetic_speaker" / "result.mp4", project)
    assert np.percentile(silent_opening, 90) < 0.4 * np.percentile(spoken_opening, 90), \
        (np.percentile(silent_opening, 90), np.percentile(spoken_opening, 90))
    assert not list(tmp_path.glob(".*tmp*")) and not list(tmp_path.glob(".lipsynth-speak-*"))


@pytest.mark.slow
def test_speak_into_a_target_without_an_audio_track(project, tmp_path):
    """The target only receives new speech: a silent video of the speaker is a valid target
    (a training video without audio is still refused by ingest)."""
    import av
    target = tmp_path / "mute.mp4"
    with av.open(str(project / "data" / "synthetic_speaker" / "speaker_01.mp4")) as c:
        frames = [f.to_ndarray(format="rgb24") for _, f in zip(range(100), c.decode(video=0))]
    from pipeline.io import media
    media.write_video(target, frames, 25.0)                      # 4 s, no audio stream
    with av.open(str(target)) as c:
        assert not c.streams.audio
    out = tmp_path / "voiced.mp4"
    r = speak(project, tmp_path, "--audio", project / "data" / "synthetic_speaker" / "speaker_03.mp4",
              "--target", target, "--out", out)
    assert r.returncode == 0, r.stderr
    assert "far from the model's training audio" not in r.stderr           # the speaker's own voice
    with av.open(str(out)) as c:
        assert c.streams.audio and sum(1 for _ in c.decode(video=0)) == 250     # the 10 s speech


@pytest.mark.slow
def test_speak_refuses_a_target_without_a_face_and_keeps_the_old_output(project, tmp_path):
    from tests.helpers.media import make_clip
    rng = np.random.default_rng(0)
    noface = tmp_path / "wall.mp4"
    make_clip(noface, frames=rng.integers(0, 255, (50, 256, 320, 3), dtype=np.uint8))
    out = tmp_path / "result.mp4"
    out.write_bytes(b"previous result")
    r = speak(project, tmp_path, "--audio", project / "data" / "synthetic_speaker" / "speaker_03.mp4",
              "--target", noface, "--out", out)
    assert r.returncode == 2, r.stderr
    err = r.stderr.strip().splitlines()
    assert err[-1].startswith("lipsynth: error: ") and str(noface) in err[-1] and "face" in err[-1], r.stderr
    assert "on_bad_input" not in err[-1], err[-1]                 # speak's message names no training parameter
    assert [e for e in err if e.startswith("lipsynth: error")] == [err[-1]]
    assert out.read_bytes() == b"previous result"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cache", "result.mp4", "wall.mp4"]


@pytest.mark.slow
def test_speak_into_a_phone_video_stored_sideways(project, tmp_path):
    """A portrait phone video: frames stored turned a quarter counter-clockwise, a display rotation
    of 90° in the track header. speak finds the face and its output plays upright like the input."""
    from pipeline.io import media
    from tests.helpers.media import set_display_rotation
    source = project / "data" / "synthetic_speaker" / "speaker_03.mp4"
    info = media.probe(source)
    phone = tmp_path / "phone.mp4"
    audio, _ = media.read_audio(source, 48000)
    media.write_video(phone, (np.rot90(f, 1) for _, f in media.iter_frames(source)), info.fps, audio, 48000)
    set_display_rotation(phone, 90)
    shown = media.probe(phone)
    assert (shown.width, shown.height) == (info.width, info.height)        # plays upright
    out = tmp_path / "out.mp4"
    r = speak(project, tmp_path, "--audio", source, "--target", phone, "--out", out, "--no-retime")
    assert r.returncode == 0, r.stderr[-2000:]
    result = media.probe(out)
    assert (result.width, result.height) == (info.width, info.height)
    _, first = next(media.iter_frames(out))
    _, original = next(media.iter_frames(source))
    assert np.abs(first.astype(float) - original).mean() < 10                # upright, the same picture


@pytest.mark.slow
def test_speak_into_a_variable_frame_rate_video(project, tmp_path):
    """A phone-style variable frame rate: the first half of a clip at 50 fps, the rest at 25 fps
    with every third frame missing. speak's output is constant-rate, as long as the input, and
    each output frame shows the input's picture of that moment (the face is composited in place)."""
    from pipeline.io import media
    from tests.helpers.media import make_vfr_clip
    source = project / "data" / "synthetic_speaker" / "speaker_03.mp4"
    info = media.probe(source)
    frames = np.stack([f for _, f in media.iter_frames(source)])
    t = np.arange(len(frames)) / info.fps
    half = len(frames) // 2
    fast = np.repeat(np.arange(half), 2)                                   # 50 fps: each frame twice
    keep = np.concatenate([fast, [k for k in range(half, len(frames)) if k % 3]])
    times = np.concatenate([np.arange(len(fast)) / (2 * info.fps), t[half:][(np.arange(half, len(frames)) % 3) > 0]])
    audio, _ = media.read_audio(source, 48000)
    vfr = make_vfr_clip(tmp_path / "vfr.mp4", times, frames=frames[keep], audio=audio)
    shown = media.probe(vfr)
    assert abs(shown.fps - info.fps) > 1                                   # not the source's rate
    out = tmp_path / "out.mp4"
    r = speak(project, tmp_path, "--audio", source, "--target", vfr, "--out", out, "--no-retime")
    assert r.returncode == 0, r.stderr[-2000:]
    result = media.probe(out)
    played = [f for _, f in media.iter_frames(vfr)]
    got = [f for _, f in media.iter_frames(out)]
    assert abs(len(got) / result.fps - len(played) / shown.fps) < 2 / shown.fps  # as long as the input
    for k in range(0, min(len(got), len(played)), 7):                      # the input's picture at each moment
        assert np.abs(got[k][:40].astype(float) - played[k][:40]).mean() < 6, k   # the top rows: no mouth there


@pytest.mark.slow
@pytest.mark.real
def test_speak_into_real_footage_of_another_speaker(project, tmp_path):
    """HDTF footage (512², 25 fps) as target, radio speech (16 kHz stereo WAV) as audio, the
    synthetic speaker's model (re-targeted onto the real mouth): only the lower face changes."""
    from lipsynth import lipsync_quality as quality
    from tests.conftest import shared
    target = shared("hdtf", "WDA_KatieHill_000.mp4")
    audio = shared("hdtf", "RD_Radio36_000.wav")
    out = tmp_path / "katie.mp4"
    with edited_params(project, "cluster", "n_workers", 2):          # workers asked for: 200 frames would run in process
        r = speak(project, tmp_path, "--audio", audio, "--target", target, "--out", out, "--no-retime")
    assert r.returncode == 0, r.stderr
    assert "re-targeting predicted mouth shapes" in r.stderr
    assert "far from the model's training audio" in r.stderr               # radio speech, not the synthetic voice
    assert "another person" in r.stderr and "candidate bank" not in r.stderr     # never the synthetic face's mouth
    assert r.stderr.count("starting LocalCluster") == 1, r.stderr[-3000:]    # one cluster for all preprocessing
    import zarr
    stores = list((tmp_path / "cache").glob("WDA_KatieHill_000-*/ingest.zarr"))
    assert len(stores) == 1 and zarr.open_group(stores[0], mode="r")["crops"].shards[0] == 64   # speak.target_shard_frames
    checked = re.search(r"self-check: (\d+) frames checked, (\d+) fell back", r.stderr)
    assert checked and int(checked[1]) >= 190 and int(checked[2]) <= 10, r.stderr[-2000:]
    landmarks = load_params(project / "params.yaml").landmarks
    out_gray, out_lm, out_ok = quality.video_landmarks(out, landmarks)
    ref_gray, ref_lm, ref_ok = quality.video_landmarks(target, landmarks)
    assert len(out_gray) == 200 and out_ok.mean() > 0.9            # 8 s at 25 fps, still a face
    ok = out_ok & ref_ok
    iod = np.median(quality.interocular(ref_lm[ok]))
    lip_shift = np.linalg.norm(out_lm[ok][:, 48:68].mean(1) - ref_lm[ok][:, 48:68].mean(1), axis=1)
    assert np.median(lip_shift) < 0.08 * iod, np.median(lip_shift) / iod   # the mouth stays where it was
    box = quality.one_box(quality.mouth_boxes(ref_lm[ref_ok], ref_gray.shape[1:]))
    assert quality.mean_abs_difference(out_gray, ref_gray, box) > 3.0       # ... but it is a new mouth
    assert quality.sharpness(out_gray, box) / quality.sharpness(ref_gray, box) < 2.0   # not a scribbled blob
    top = (0, 0, ref_gray.shape[2], int(ref_lm[ref_ok][:, 19, 1].min()) - 10)    # above the eyebrows
    assert quality.mean_abs_difference(out_gray, ref_gray, top) < 2.0      # the rest is the target


@pytest.mark.slow
def test_synthesize_stage_takes_only_corpus_targets(project, tmp_path):
    """The DVC stage reads declared inputs only: a video file as target is refused (with the way
    out: lipsynth speak), and nothing is preprocessed behind DVC's back."""
    params = yaml.safe_load((project / "params.yaml").read_text())
    clip = tmp_path / "new_take.mp4"
    shutil.copy(project / "data" / "synthetic_speaker" / "speaker_02.mp4", clip)
    params["synthesize"].update(target=str(clip), out=str(tmp_path / "synth.zarr"))
    (tmp_path / "p.yaml").write_text(yaml.safe_dump(params))
    r = subprocess.run(registry.stage("synthesize").argv(tmp_path / "p.yaml"),
                       cwd=project, capture_output=True, text=True, timeout=600)
    assert r.returncode == 2, r.stderr
    assert "not a video of the corpus" in r.stderr and "lipsynth speak" in r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["new_take.mp4", "p.yaml"]
    assert not (project / "store" / "targets").exists()


@pytest.mark.slow
def test_a_fresh_run_reproduces_the_committed_dvc_lock(project):
    """A fresh run of the default pipeline in another folder (a temporary one, of another length than the
    checkout that made the lock), on a machine loaded by a second test process, reproduces every dependency and
    output hash of the committed dvc.lock: the stores and models hold nothing machine-specific (paths are
    project-relative, no timings) and nothing that depends on the load. Left out: the report (it carries its
    date and measured timings by design, and reads the sweep) and the delay sweep, whose budget this fixture
    shortens."""
    ours = yaml.safe_load((project / "dvc.lock.first").read_text())["stages"]
    committed = yaml.safe_load((ROOT / "dvc.lock").read_text())["stages"]
    assert set(ours) == set(committed) and len(committed) == 16
    assert str(ROOT) not in (project / "dvc.lock.first").read_text()
    compared = set(committed) - {"report", "delay_sweep"}
    differ = [stage for stage in sorted(compared) if ours[stage]["outs"] != committed[stage]["outs"]]
    assert differ == [], f"outputs differ from the committed dvc.lock: {differ}"
    differ = [stage for stage in sorted(compared) if ours[stage]["deps"] != committed[stage]["deps"]]
    assert differ == [], f"dependencies differ from the committed dvc.lock: {differ}"


@pytest.mark.slow
def test_a_library_change_reruns_exactly_the_stages_that_import_it(project):
    """Code deps are derived from imports: pipeline/video/repeats.py is used by composite only (and by
    evaluate, which runs composite's entry point)."""
    status = lambda: set(dvc_status(project))
    before = status()
    path = project / "pipeline" / "video" / "repeats.py"
    text = path.read_text()
    path.write_text(text + "\n# touched\n")
    try:
        assert status() - before == {"composite", "evaluate"}
        geometry = project / "pipeline" / "face" / "geometry.py"
        g = geometry.read_text()
        geometry.write_text(g + "\n# touched\n")
        try:
            assert {"frontalize", "synthesize", "composite"} <= status()
            assert not {"ingest", "landmarks"} & status()
        finally:
            geometry.write_text(g)
    finally:
        path.write_text(text)


@pytest.mark.slow
def test_repro_ends_with_the_report_page_and_it_renders_in_chromium(project, tmp_path):
    """`dvc repro` on a fresh copy writes reports/<corpus>/index.html with its videos; the page
    loads in headless Chromium without errors (skipped when Chromium is absent)."""
    from tests.helpers.browser import assert_page_renders, check_in_browser
    folder = project / yaml.safe_load((project / "params.yaml").read_text())["report"]["out"]
    page = folder / "index.html"
    assert page.is_file() and (project / "metrics" / "evaluate.json").is_file()
    html = page.read_text()
    videos = re.findall(r'<video[^>]*src="([^"]+)"', html) + re.findall(r'<source[^>]*src="([^"]+)"', html)
    assert videos and all((folder / v).is_file() for v in videos), videos     # relative, shipped with the page
    state = check_in_browser(page, tmp_path / "screenshot.png")
    assert_page_renders(state, n_videos=html.count("<video"), n_svgs=html.count("<svg"))
