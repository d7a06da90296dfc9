"""The model folder: everything synthesis needs, and loud failure when pieces do not match.

    models/lstm/ (paper 000)
        weights.pt        torch state_dict
        config.json       model family, delay, sizes, params, PCA fingerprint
        arrays.npz        feature_mean (28,), feature_std (28,), pca_mean (36,), pca_components (k, 36)
    models/brand/ (paper 002, ``pipeline.models.voice_puppet``)
        config.json       family, model rate, voice features, decode, PCA fingerprint
        arrays.npz        the puppet's arrays (HMM, face and voice Gaussians, PCA bases)
    models/karras/ (paper 001, ``pipeline.models.karras_inference``)
        weights.pt        KarrasNetwork state_dict
        config.json       family, outputs, emotion size, face points, default emotion, PCA fingerprint
        arrays.npz        pca_mean, pca_components (mouth PCA), lip_index (18,), face_mean (P·2,),
                          emotion_candidates (K, E) mined from the emotion database,
                          emotion_database (N, E) (one learned vector per training frame)

    models/<name>/ (an ensemble, ``pipeline.models.model_ensemble``)
        config.json       family "ensemble", member paths, shared PCA fingerprint
        members/<k>/      each member's own files (any family above)

All may also hold their speaker (speaker.npz, bank.zarr; ``pipeline/models/speaker_bank``).

An application opens a folder once (``pipeline.models.mouth_prediction.open_model``: config read and the
family's model checked) into a ``ModelFolder`` record and passes the record on; every function here that
takes a folder takes the record too, and reads its config and speaker from it instead of from disk.
"""
from __future__ import annotations

import functools
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.errors import LipsynthError
from pipeline.models.mouth_pca import fingerprint

FILES = ("weights.pt", "config.json", "arrays.npz")
FAMILY_FILES = {"lstm": FILES, "brand": ("config.json", "arrays.npz"), "karras": FILES,
                "ensemble": ("config.json", "members")}


class ModelError(LipsynthError):
    """A model folder is missing, incomplete, or does not match the data it is used with."""


def save_model(folder, model, config: dict, feature_mean, feature_std, basis: dict, pca_attrs: dict,
               rest_coeffs=None, extra_arrays: dict | None = None) -> None:
    """An LSTM model folder; ``rest_coeffs`` (k,): the PCA coefficients of the mouth in the training
    audio's silent stretches (prediction rests the mouth there); ``extra_arrays``: more arrays for
    arrays.npz (a retrieval database: ``retrieval_keys``, ``retrieval_values``)."""
    import torch
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    torch.save(model.state_dict(), folder / "weights.pt")
    config = dict(config, pca_fingerprint=fingerprint(basis), lip_points=pca_attrs["lip_points"],
                  iod_px=pca_attrs["iod_px"], format=1)
    (folder / "config.json").write_text(json.dumps(config, indent=2))
    extra = {} if rest_coeffs is None else {"rest_coeffs": np.asarray(rest_coeffs, np.float32)}
    extra.update(extra_arrays or {})
    np.savez(folder / "arrays.npz", feature_mean=feature_mean, feature_std=feature_std,
             pca_mean=basis["mean"], pca_components=basis["components"], **extra)


@dataclass(frozen=True)
class ModelFolder:
    """A model folder opened and checked once (``mouth_prediction.open_model``).

    Attributes
    ----------
    path : Path
        the folder
    config : dict
        its config.json, read once
    """
    path: Path
    config: dict

    def __fspath__(self) -> str:            # a record goes wherever a folder path goes (Path(record), open, …)
        return str(self.path)

    def __str__(self) -> str:               # in messages and params: the folder's path
        return str(self.path)

    @property
    def family(self) -> str:
        """``lstm``, ``brand``, ``karras`` or ``ensemble``."""
        return self.config["model"]

    @functools.cached_property
    def speaker(self) -> dict | None:
        """``load_speaker`` of the folder, read on first use and kept."""
        return _read_speaker(self.path)


def read_config(folder) -> dict:
    """config.json of a model folder of any family, checked for the family's files (a ``ModelFolder``:
    the config it holds)."""
    if isinstance(folder, ModelFolder):
        return folder.config
    folder = Path(os.fspath(folder))
    if not (folder / "config.json").is_file():
        raise ModelError(f"{folder}: not a lipsynth model folder (no config.json) — run `dvc repro`")
    config = json.loads((folder / "config.json").read_text())
    family = config.get("model")
    if family not in FAMILY_FILES:
        raise ModelError(f"{folder}: unknown model family {family!r} (known: {', '.join(FAMILY_FILES)})")
    missing = [f for f in FAMILY_FILES[family] if not (folder / f).exists()]
    if missing:
        raise ModelError(f"{folder}: incomplete {family} model folder (missing {', '.join(missing)})")
    return config


def check_model(folder) -> dict:
    """Load the one model a folder of a single family holds (raises ModelError on any inconsistency);
    its config. Ensemble folders are checked by ``pipeline.models.model_ensemble.check`` (any folder:
    ``pipeline.models.mouth_prediction.check_model_folder``)."""
    config = read_config(folder)
    if config["model"] == "brand":
        load_puppet(folder)
    elif config["model"] == "karras":
        load_karras(folder)
    elif config["model"] == "ensemble":
        raise ModelError(f"{folder}: an ensemble folder, not a single model")
    else:
        load_model(folder)
    return config


def save_puppet(folder, puppet: dict) -> None:
    """Write a Voice Puppetry model (``pipeline.models.voice_puppet``) into ``folder``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    basis = dict(mean=puppet["pca_mean"], components=puppet["pca_components"])
    config = dict(puppet["config"], pca_fingerprint=fingerprint(basis))
    (folder / "config.json").write_text(json.dumps(config, indent=2))
    np.savez(folder / "arrays.npz", **{k: np.asarray(v) for k, v in puppet.items() if k not in ("config", "gauss")})


PUPPET_OPTIONAL = ("vocal_projection_mean", "vocal_projection")     # a PCA of wide voice features (whisper)
PUPPET_ARRAYS = ("startprob", "transmat", "face_means", "face_covars", "vocal_means", "vocal_covars", "vocal_mean",
                 "vocal_std", "face_pca_mean", "face_pca_components", "lip_index", "pca_mean", "pca_components")


def load_puppet(folder, expect_fingerprint: str | None = None) -> dict:
    """A Voice Puppetry model folder → puppet dict. Raises ModelError on any inconsistency."""
    config = read_config(folder)               # a ModelFolder's own config, not read again
    folder = Path(os.fspath(folder))
    if config["model"] != "brand":
        raise ModelError(f"{folder}: a {config['model']} model, not a Voice Puppetry (brand) model")
    with np.load(folder / "arrays.npz") as z:
        missing = [k for k in PUPPET_ARRAYS if k not in z.files]
        if missing:
            raise ModelError(f"{folder}: arrays.npz lacks {', '.join(missing)}")
        puppet = {k: z[k] for k in PUPPET_ARRAYS + PUPPET_OPTIONAL if k in z.files}
    puppet["config"] = config
    basis = dict(mean=puppet["pca_mean"], components=puppet["pca_components"])
    if fingerprint(basis) != config.get("pca_fingerprint"):
        raise ModelError(f"{folder}: PCA basis in arrays.npz does not match config.json (mixed files from two runs?)")
    if expect_fingerprint is not None and expect_fingerprint != config["pca_fingerprint"]:
        raise ModelError(f"{folder}: trained on PCA basis {config['pca_fingerprint']}, but the store uses "
                         f"{expect_fingerprint} — retrain (dvc repro) instead of mixing models and data")
    K, d2 = puppet["face_means"].shape
    A = puppet["vocal_means"].shape[1]
    if (puppet["transmat"].shape != (K, K) or puppet["face_covars"].shape != (K, d2, d2)
            or puppet["vocal_covars"].shape != (K, A, A) or puppet["face_pca_components"].shape[0] != d2 // 2):
        raise ModelError(f"{folder}: arrays.npz shapes do not agree ({K} states, {d2} face dims, {A} voice dims)")
    return puppet


KARRAS_ARRAYS = ("pca_mean", "pca_components", "lip_index", "face_mean", "emotion_candidates", "emotion_database")


def save_karras(folder, net, config: dict, arrays: dict) -> None:
    """Write a Karras et al. model (network weights, config, arrays — see the module doc)."""
    import torch
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    torch.save(net.state_dict(), folder / "weights.pt")
    basis = dict(mean=arrays["pca_mean"], components=arrays["pca_components"])
    config = dict(config, model="karras", pca_fingerprint=fingerprint(basis), format=1)
    (folder / "config.json").write_text(json.dumps(config, indent=2))
    np.savez(folder / "arrays.npz", **{k: np.asarray(arrays[k]) for k in KARRAS_ARRAYS})


def load_karras(folder, device="cpu", expect_fingerprint: str | None = None) -> dict:
    """A Karras model folder → dict(net, config, and the arrays). Raises ModelError on any inconsistency."""
    from pipeline.models.karras_network import KarrasNetwork
    config = read_config(folder)
    folder = Path(os.fspath(folder))
    if config["model"] != "karras":
        raise ModelError(f"{folder}: a {config['model']} model, not a Karras et al. (karras) model")
    with np.load(folder / "arrays.npz") as z:
        missing = [k for k in KARRAS_ARRAYS if k not in z.files]
        if missing:
            raise ModelError(f"{folder}: arrays.npz lacks {', '.join(missing)}")
        out = {k: z[k] for k in KARRAS_ARRAYS}
    basis = dict(mean=out["pca_mean"], components=out["pca_components"])
    if fingerprint(basis) != config.get("pca_fingerprint"):
        raise ModelError(f"{folder}: PCA basis in arrays.npz does not match config.json (mixed files from two runs?)")
    if expect_fingerprint is not None and expect_fingerprint != config["pca_fingerprint"]:
        raise ModelError(f"{folder}: trained on PCA basis {config['pca_fingerprint']}, but the store uses "
                         f"{expect_fingerprint} — retrain (dvc repro) instead of mixing models and data")
    n_out, e_dim = config["n_outputs"], config["emotion_dim"]
    if (out["face_mean"].shape != (n_out,) or out["emotion_candidates"].ndim != 2
            or out["emotion_candidates"].shape[1] != e_dim or len(out["emotion_candidates"]) == 0
            or out["lip_index"].max() >= n_out // 2):
        raise ModelError(f"{folder}: arrays.npz does not fit config.json ({n_out} outputs, emotion size {e_dim})")
    net = KarrasNetwork(n_out, e_dim)
    try:
        net.load_state_dict(read_state_dict(folder / "weights.pt", device))
    except (RuntimeError, KeyError) as exc:
        raise ModelError(f"{folder}: weights.pt does not fit config.json ({str(exc).splitlines()[0]})") from None
    out.update(net=net.to(device).eval(), config=config)
    return out


def read_state_dict(path: Path, device="cpu") -> dict:
    """A torch state dict file (tensors only: ``weights_only``); ModelError naming the file when it is
    damaged or not one (a truncated download, another file saved under its name)."""
    import pickle

    import torch
    try:
        return torch.load(path, map_location=device, weights_only=True)
    except (pickle.UnpicklingError, EOFError, ValueError, RuntimeError) as exc:
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:160]
        raise ModelError(f"{path}: damaged or not a PyTorch state dict ({first})") from None


def load_model(folder, device="cpu", expect_fingerprint: str | None = None):
    """Load a model folder → (model, config, arrays). Raises ModelError on any inconsistency."""
    from pipeline.models.delayed_lstm import DelayedLSTM
    given, folder = folder, Path(os.fspath(folder))
    missing = [f for f in FILES if not (folder / f).exists()]
    if missing:
        raise ModelError(f"{folder}: not a lipsynth model folder (missing {', '.join(missing)}) — run `dvc repro train`")
    config = read_config(given)
    if config["model"] != "lstm":
        raise ModelError(f"{folder}: a {config['model']} model folder, not an LSTM one")
    arrays = dict(np.load(folder / "arrays.npz"))
    basis = dict(mean=arrays["pca_mean"], components=arrays["pca_components"])
    if fingerprint(basis) != config.get("pca_fingerprint"):
        raise ModelError(f"{folder}: PCA basis in arrays.npz does not match config.json (mixed files from two runs?)")
    if expect_fingerprint is not None and expect_fingerprint != config["pca_fingerprint"]:
        raise ModelError(f"{folder}: trained on PCA basis {config['pca_fingerprint']}, but the store uses "
                         f"{expect_fingerprint} — retrain (dvc repro) instead of mixing models and data")
    k = arrays["pca_components"].shape[0]
    if config["n_components"] != k or arrays["feature_mean"].shape != (config["n_features"],):
        raise ModelError(f"{folder}: config sizes ({config['n_features']} features, {config['n_components']} "
                         f"components) do not match the stored arrays")
    model = DelayedLSTM(config["n_features"], config["hidden"], k, config.get("layers", 1), bool(config.get("skip", False)))
    try:
        model.load_state_dict(read_state_dict(folder / "weights.pt", device))
    except (RuntimeError, KeyError) as exc:
        raise ModelError(f"{folder}: weights.pt does not fit config.json ({str(exc).splitlines()[0]})") from None
    return model.to(device), config, arrays


def load_speaker(folder) -> dict | None:
    """The speaker a model folder was trained on, or None for a folder without one (a ``ModelFolder``:
    the speaker it holds, read once).

    Returns dict(shape3d (68, 3) mm, identity (128,), identity_spread (F,), bank: the path of the
    candidate bank zarr (None when the folder has no bank); and, from folders written since the
    mesh render, surface_depth (H, W), surface_grid (3,), texture_window (4,); since the dense head,
    head_texture (H, W, 3), head_window (5,), head_landmarks (68, 2)). See ``pipeline/models/speaker_bank``.
    """
    if isinstance(folder, ModelFolder):
        return folder.speaker
    return _read_speaker(Path(os.fspath(folder)))


def _read_speaker(folder: Path) -> dict | None:
    """speaker.npz (and the bank's path) of ``folder``, or None."""
    if not (folder / "speaker.npz").is_file():
        return None
    with np.load(folder / "speaker.npz") as z:
        out = {k: z[k] for k in ("shape3d", "identity", "identity_spread")}
        out.update({k: z[k] for k in ("surface_depth", "surface_grid", "texture_window", "head_texture", "head_window",
                                      "head_landmarks") if k in z.files})
    out["bank"] = folder / "bank.zarr" if (folder / "bank.zarr").is_dir() else None
    return out
