"""Model ensembles: several trained folders of one speaker, their mouth shapes averaged.

Models trained on the same corpus with other seeds or front ends make partly independent errors;
the mean of their predicted PCA coefficients is closer to the tracked mouth than any one of them
(GRID s1, 180 validation videos: one LSTM 0.826–0.843 px, two 0.809–0.821 px, five 0.801 px;
bench/ensemble.py). An ensemble folder is self-contained, so it travels as one folder:

    models/<ensemble>/
        config.json       model: "ensemble", members (relative paths), their families and sources,
                          the shared PCA fingerprint; features/params of the first member
        members/<k>/      each member's own files (weights.pt, config.json, arrays.npz)
        speaker.npz, bank.zarr, audio_domain.json   the speaker, copied from the first member

Members must share the mouth PCA basis (one fingerprint) and, when they record one, the speaker
(same corpus 3D model and identity) — otherwise averaging their shapes means nothing, and
``check`` says which member differs.
"""
from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path

import numpy as np

from pipeline.errors import ParameterError
from pipeline.models.model_folder import FAMILY_FILES, ModelError, check_model, load_speaker, read_config

SPEAKER_FILES = ("speaker.npz", "audio_domain.json")
AVERAGED = ("coeffs", "lip_points", "face_points")


def member_folders(folder) -> list[Path]:
    """The member folders of an ensemble folder, in order."""
    return [Path(folder) / m for m in read_config(folder)["members"]]


def check_members(members: list, configs: list[dict], fingerprint: str) -> None:
    """Raise ModelError naming the first member that is itself an ensemble or has another PCA basis."""
    for m, cfg in zip(members, configs):
        if cfg["model"] == "ensemble":
            raise ModelError(f"{m}: is itself an ensemble (give its members instead)")
        if cfg["pca_fingerprint"] != fingerprint:
            raise ModelError(f"{m}: PCA basis {cfg['pca_fingerprint']} differs from the ensemble's {fingerprint}: "
                             "members must be trained on one store")


def check(folder) -> dict:
    """Check every member (any family) and that they share the ensemble's PCA basis; its config.

    Raises ModelError naming the member that is missing, broken or of another basis.
    """
    config = read_config(folder)
    members = member_folders(folder)
    if len(members) < 2:
        raise ModelError(f"{folder}: an ensemble needs at least 2 members, it lists {len(members)}")
    for m in members:
        if not m.is_dir():
            raise ModelError(f"{folder}: member {m} is missing")
    check_members(members, [read_config(m) for m in members], config["pca_fingerprint"])
    for m in members:
        check_model(m)
    return config


def same_speaker(a: dict | None, b: dict | None) -> bool:
    """Do two speaker records (``model_folder.load_speaker``) describe one corpus speaker?"""
    if a is None or b is None:
        return a is b
    return bool(np.allclose(a["shape3d"], b["shape3d"], atol=1e-4) and np.allclose(a["identity"], b["identity"],
                                                                                   atol=1e-4))


def write(out, members: list) -> dict:
    """Make the ensemble folder ``out`` (atomically) from trained model folders ``members``.

    Copies each member's own files into ``out/members/<k>`` and the first member's speaker
    (speaker.npz, bank.zarr, audio_domain.json) into ``out``. Returns its config.
    """
    if len(members) < 2:
        raise ParameterError(f"an ensemble needs at least 2 model folders, got {len(members)}")
    out = Path(out)
    configs = [read_config(m) for m in members]
    check_members(members, configs, configs[0]["pca_fingerprint"])
    for m in members:
        check_model(m)
    speaker = load_speaker(members[0])
    for m in members[1:]:
        if not same_speaker(speaker, load_speaker(m)):
            raise ModelError(f"{m}: records another speaker than {members[0]} (other corpus 3D model or identity)")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}-", dir=out.parent))
    try:
        names = []
        for k, (m, cfg) in enumerate(zip(members, configs)):
            dest = tmp / "members" / str(k)
            dest.mkdir(parents=True)
            for f in FAMILY_FILES[cfg["model"]]:
                shutil.copy2(Path(m) / f, dest / f)
            names.append(f"members/{k}")
        first = Path(members[0])
        for f in SPEAKER_FILES:
            if (first / f).is_file():
                shutil.copy2(first / f, tmp / f)
        if (first / "bank.zarr").is_dir():
            shutil.copytree(first / "bank.zarr", tmp / "bank.zarr")
        config = dict(model="ensemble", members=names, families=[c["model"] for c in configs],
                      sources=[str(m) for m in members], pca_fingerprint=configs[0]["pca_fingerprint"],
                      features=configs[0].get("features", "mfcc"), params=configs[0].get("params", {}),
                      iod_px=configs[0].get("iod_px"))
        (tmp / "config.json").write_text(json.dumps(config, indent=2))
        if out.exists():
            shutil.rmtree(out)
        tmp.rename(out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return config


def average(outputs: list[dict]) -> dict:
    """One prediction from the members' ``predict_mouth`` outputs: the mean of coeffs (T, k),
    lip_points (T, 18, 2) and — when every member has them — face_points (T, P, 2); the other
    keys (frame_time, fps, pca_fingerprint, mean_shape, ...) from the first member."""
    T = min(len(o["coeffs"]) for o in outputs)
    out = {k: v for k, v in outputs[0].items() if k not in AVERAGED + ("coeffs_100hz",)}
    for key in AVERAGED:
        if all(key in o for o in outputs):
            out[key] = np.mean([np.asarray(o[key][:T], np.float64) for o in outputs], 0).astype(np.float32)
    out["frame_time"] = np.asarray(outputs[0]["frame_time"])[:T]
    out["members"] = len(outputs)
    return out
