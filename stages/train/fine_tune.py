"""Start an LSTM from a base model (``train.init_from``): issue 24's fine-tuning of a new person.

The base model (``bench/base_model.py``) maps encoder states to mouth PCA coefficients of *its*
basis. A new person's store has its own PCA basis, so the base's read-out is re-expressed in the
new basis before training: the base's coefficients y_b mean the lip motion d = C_bᵀ y_b about its
mean shape (canonical px of the base store); the new person makes the same motion scaled to their
interocular distance, s·d with s = iod_new / iod_base, about their own mean, whose coefficients in
the new basis are

    y_n = s · C_n C_bᵀ y_b      ⇒  W_n = s · C_n C_bᵀ W_b,   b_n = s · C_n C_bᵀ b_b

(the new mean is the PCA mean of the person's training frames, so the person's average mouth is
y_n ≈ 0). The recurrent weights and the input normalisation are the base's; training then adapts
the chosen parameters (``train.fine_tune``: ``all`` weights or only the ``output`` layer) with the
train params' rate and budget.
"""
from __future__ import annotations

import numpy as np

from pipeline.errors import ParameterError
from pipeline.models.model_folder import load_model

PARTS = ("all", "output")


def rebased_readout(weight: np.ndarray, bias: np.ndarray, base_components: np.ndarray,
                    new_components: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """The base's linear read-out expressed in the new PCA basis.

    Parameters
    ----------
    weight : (k_b, hidden); bias : (k_b,) — the base's output layer (coefficients of its basis)
    base_components : (k_b, 36); new_components : (k_n, 36) — orthonormal rows, canonical px
    scale : iod_new / iod_base

    Returns
    -------
    weight (k_n, hidden), bias (k_n,) float32
    """
    if base_components.shape[1] != new_components.shape[1]:
        raise ParameterError(f"base and new PCA bases have different shape vectors ({base_components.shape[1]} vs "
                             f"{new_components.shape[1]} values)")
    t = scale * new_components @ base_components.T                       # (k_n, k_b)
    return (t @ weight).astype(np.float32), (t @ bias).astype(np.float32)


def initial_state(folder: str, features: str, encoder: dict | None, basis: dict, iod_px: float, device) -> dict:
    """The base model of ``folder`` as the starting point of a new person's LSTM.

    Returns dict(state: a state_dict for ``DelayedLSTM(n_in, hidden, k_n, layers)``, hidden, layers,
    feature_mean, feature_std, base_config). One clear error when the base does not fit this corpus
    (another front end, windowing or lip-point set).
    """
    import torch
    model, cfg, arrays = load_model(folder, device="cpu")
    where = f"train.init_from={folder}"
    if cfg.get("features", "mfcc") != features:
        raise ParameterError(f"{where}: the base model reads {cfg.get('features', 'mfcc')!r} features, this corpus "
                             f"trains on {features!r} (set train.features to the base's)")
    if (cfg.get("encoder") or None) != (encoder or None):
        raise ParameterError(f"{where}: the base model's encoder windows {cfg.get('encoder')} differ from this "
                             f"corpus' whisper store {encoder}")
    state = {k: v.clone() for k, v in model.state_dict().items()}
    w, b = rebased_readout(state["out.weight"].numpy(), state["out.bias"].numpy(), arrays["pca_components"],
                           np.asarray(basis["components"]), iod_px / float(cfg["iod_px"]))
    state["out.weight"], state["out.bias"] = torch.from_numpy(w), torch.from_numpy(b)
    return dict(state=state, hidden=int(cfg["hidden"]), layers=int(cfg.get("layers", 1)),
                feature_mean=arrays["feature_mean"], feature_std=arrays["feature_std"], base_config=cfg)
