"""Personalization from a base model: six candidates, scored fold by fold over the person's segments.

``lipsynth personalize`` preprocesses a person's footage and calls ``run``. From the base model (the
shipped ``models/base`` or ``--base``), whose read-out is first re-expressed in the person's mouth
PCA (``fine_tune.initial_state``: W₀ = s·C_n·C_bᵀ·W_b), it builds

1. ``base`` — the base as it is;
2. ``readout`` — the base's LSTM with a read-out fitted to the person: ridge regression of the
   person's PCA coefficients y_t on the base's hidden states h_t, shrunk toward W₀,

       [W b] = argmin Σ_t ‖W h_t + b − y_t‖² + λ ‖W − W₀‖² + λ_b ‖b − b₀‖²;

3. ``encoder_readout`` — a ridge read-out of the (normalised) encoder states x_t themselves,
   y_t ≈ V x_t + b, shrunk toward V = 0 (the model's ``skip`` map; the LSTM's read-out set to 0):
   what the pretrained encoder says about this person's mouth without the base's recurrence, which
   learned one read speaker's timing;
4. ``average`` — the mean of the shapes of 1–3, itself one linear model (each read-out is linear);
   ``retrieval`` — the person's own shapes along a Viterbi path (``pipeline/models/mouth_retrieval``),
   keyed by the base's predictions (left out when the footage holds too little moving mouth);
5. ``fine_tune`` — every weight trained from the better of 2 and 3 (by cross-validation error) for
   ``train.steps``, early stopping on the held-out part (``patience``) and an L2 pull toward the
   starting weights, λ_sp Σ ‖θ − θ₀‖² (L2-SP; ``stages/train/lstm.train``'s ``anchor``).

In 2 and 3, λ = α · (training frames), α chosen by leave-one-segment-out cross-validation on the
training part. Selection (``stages/train/selection.py``): the person's segments, in time order, are cut
into ``selection.FOLDS`` blocks; each block is held out while 2 and 3 are refitted on the rest (the
retrieval database rebuilt from it, and 5 fine-tuned on it for as many steps as the early-stopped run
kept — no early stopping inside a fold), and every candidate is scored on it by its utility, opening
correlation at lag 0 plus the share of the mean shape's mouth error removed. A candidate replaces the
base only when its per-fold gain over the base is above noise (mean more than one standard error above
0); among those the best mean is kept. Every candidate's per-fold
figures are logged and written to the metrics (``folds``), with each candidate's held-out figures (the
final fits, trained on the training part). When even the kept candidate is worse than the person's mean
mouth shape on the held-out part, one warning line says so (the model is still written: ``speak`` needs
one, and the figures are in the metrics).
"""
from __future__ import annotations

import logging
import shutil
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from pipeline.io.store import atomic_output
from pipeline.models import mouth_retrieval
from pipeline.models.delayed_lstm import DelayedLSTM, pick_device, predict_sequence
from pipeline.models.model_folder import save_model
from pipeline.models.speaker_bank import export_speaker
from pipeline.models.training_budget import Budget
from pipeline.params import Params, as_dict
from stages.train import fine_tune, lstm, offsets, selection
from stages.train.train import (encoder_settings, feature_normalisation, load_sequences, rest_shape, score,
                                write_outputs)

log = logging.getLogger("lipsynth.adapt")
ALPHAS = (1e-3, 1e-2, 1e-1, 1.0, 10.0)      # ridge strength per training frame (read-out candidate)
BIAS_SHRINK = 1e-3                            # λ_b / λ: the bias follows the person's own mean shape
CANDIDATES = ("base", "readout", "encoder_readout", "average", "retrieval", "fine_tune")


def hidden_states(model: DelayedLSTM, x: np.ndarray, delay: int, device) -> np.ndarray:
    """(m, hidden) LSTM outputs aligned with the m targets of normalised features x (m, n_in):
    row i is the state the read-out turns into the shape of step i (step i + delay of the input)."""
    import torch
    model.eval()
    xd = np.concatenate([x, np.zeros((delay, x.shape[1]), np.float32)]).astype(np.float32)
    with torch.no_grad():
        h, _ = model.lstm(torch.from_numpy(xd[None]).to(device))
    return h[0].cpu().numpy()[delay:delay + len(x)].astype(np.float64)


def ridge_readout(H: np.ndarray, Y: np.ndarray, W0: np.ndarray, b0: np.ndarray, lam: float) -> tuple[np.ndarray, np.ndarray]:
    """The read-out of the module doc for one λ.

    Parameters
    ----------
    H : (n, h) hidden states; Y : (n, k) targets (PCA coefficients, canonical px)
    W0 : (k, h), b0 : (k,) the read-out shrunk toward; lam : λ (λ_b = BIAS_SHRINK · λ)

    Returns
    -------
    W (k, h), b (k,)
    """
    n, h = H.shape
    Ha = np.hstack([H, np.ones((n, 1))])
    prior = np.hstack([W0, b0[:, None]]).T                                   # (h+1, k)
    reg = np.full(h + 1, float(lam))
    reg[-1] *= BIAS_SHRINK
    A = Ha.T @ Ha + np.diag(reg)
    Wa = np.linalg.solve(A, Ha.T @ Y + reg[:, None] * prior)
    return Wa[:-1].T, Wa[-1]


def choose_alpha(Hs: list[np.ndarray], Ys: list[np.ndarray], W0, b0, alphas=ALPHAS) -> tuple[float, dict]:
    """α of the read-out by leave-one-sequence-out squared error over the training sequences
    (each a segment of the footage); with one sequence, the middle α. Returns (α, {α: cv error})."""
    n = sum(len(h) for h in Hs)
    if len(Hs) < 2:
        return alphas[len(alphas) // 2], {}
    errors = {}
    for a in alphas:
        se = 0.0
        for k in range(len(Hs)):
            H = np.concatenate([h for i, h in enumerate(Hs) if i != k])
            Y = np.concatenate([y for i, y in enumerate(Ys) if i != k])
            W, b = ridge_readout(H, Y, W0, b0, a * n)
            se += float(((Hs[k] @ W.T + b - Ys[k]) ** 2).sum())
        errors[a] = se / n
    return min(errors, key=errors.get), errors


def input_states(x: np.ndarray, delay: int) -> np.ndarray:
    """(m, n_in) inputs aligned like ``hidden_states``: row i is the input step whose output is the
    shape of step i (the ``skip`` map's pairs)."""
    xd = np.concatenate([x, np.zeros((delay, x.shape[1]), np.float32)])
    return xd[delay:delay + len(x)].astype(np.float64)


def with_readout(init: dict, n_in: int, k: int, out_w, out_b, skip_w=None) -> tuple[DelayedLSTM, dict]:
    """The base's LSTM with the given read-out (and ``skip`` map); (model, its state dict)."""
    import torch
    state = {kk: v.clone() for kk, v in init["state"].items()}
    state["out.weight"] = torch.from_numpy(np.asarray(out_w, np.float32))
    state["out.bias"] = torch.from_numpy(np.asarray(out_b, np.float32))
    if skip_w is not None:
        state["skip.weight"] = torch.from_numpy(np.asarray(skip_w, np.float32))
    model = DelayedLSTM(n_in, init["hidden"], k, init["layers"], skip=skip_w is not None)
    model.load_state_dict(state)
    return model.eval(), state


def linear_fits(init: dict, seqs: list, delay: int, device) -> dict:
    """The two ridge read-outs (module doc 2, 3) fitted on normalised ``seqs`` [(x, y, ok)]:
    {readout: (W, b, α, cv), encoder_readout: (V, c, α, cv)}."""
    W0, b0 = init["state"]["out.weight"].numpy().astype(np.float64), init["state"]["out.bias"].numpy().astype(np.float64)
    n_in, k = seqs[0][0].shape[1], seqs[0][1].shape[1]
    base, _ = with_readout(init, n_in, k, W0, b0)
    base = base.to(device)
    Ys = [y[ok] for _, y, ok in seqs]
    n = sum(len(y) for y in Ys)
    Hs = [hidden_states(base, x, delay, device)[ok] for x, _, ok in seqs]
    alpha_h, cv_h = choose_alpha(Hs, Ys, W0, b0)
    W, b = ridge_readout(np.concatenate(Hs), np.concatenate(Ys), W0, b0, alpha_h * n)
    Zs = [input_states(x, delay)[ok] for x, _, ok in seqs]
    alpha_z, cv_z = choose_alpha(Zs, Ys, np.zeros((k, n_in)), b0)
    V, c = ridge_readout(np.concatenate(Zs), np.concatenate(Ys), np.zeros((k, n_in)), b0, alpha_z * n)
    return dict(readout=(W, b, alpha_h, cv_h), encoder_readout=(V, c, alpha_z, cv_z))


def linear_models(init: dict, n_in: int, k: int, fits: dict, device) -> dict:
    """{name: (DelayedLSTM, state dict)} of the base, the two read-outs and their ``average``: the mean of
    the three candidates' shapes, itself one model (every read-out is linear: the mean of the LSTM read-outs
    plus a third of the encoder map)."""
    W0, b0 = init["state"]["out.weight"].numpy().astype(np.float64), init["state"]["out.bias"].numpy().astype(np.float64)
    W, b = fits["readout"][:2]
    V, c = fits["encoder_readout"][:2]
    made = dict(base=with_readout(init, n_in, k, W0, b0), readout=with_readout(init, n_in, k, W, b),
                encoder_readout=with_readout(init, n_in, k, np.zeros_like(W0), c, V),
                average=with_readout(init, n_in, k, (W0 + W) / 3, (b0 + b + c) / 3, V / 3))
    return {name: (model.to(device), state) for name, (model, state) in made.items()}


def retrieval_database(base, seqs: list, delay: int, device) -> tuple[np.ndarray, np.ndarray] | None:
    """(keys, shapes) of the person's valid training steps for ``pipeline/models/mouth_retrieval``: the base's
    predictions with context as keys, the tracked PCA coefficients as values; None when the footage holds
    too few (``MIN_FRAMES``) steps of a moving mouth to retrieve from."""
    ks, vs = [], []
    for x, y, ok in seqs:
        ks.append(mouth_retrieval.keys(predict_sequence(base, x, delay, device))[ok])
        vs.append(y[ok])
    values = np.concatenate(vs)
    if len(values) < mouth_retrieval.MIN_FRAMES or float(values.std(0).max()) < 1e-6:
        return None
    return np.concatenate(ks).astype(np.float32), values.astype(np.float32)


def fold_figures(init: dict, segments: list, plan: list, mean, std, delay: int, device, basis, iod_px,
                 tune: dict | None = None) -> dict:
    """Per-fold figures of the candidates: for each block of ``plan`` held out, the read-outs fitted on the
    other segments (and, with ``tune`` = dict(p, steps, anchor), the fine-tune run for ``steps`` from the
    better read-out on them, no early stopping) and every candidate scored on the block. Returns
    {name: [dict(mouth_error_px, ratio_to_mean_shape, median_opening_corr, utility) per fold]}."""
    norm = lambda s: (((s["x"] - mean) / std).astype(np.float32), s["y"].astype(np.float64), s["ok"])
    out: dict[str, list] = {}
    for block in plan:
        held, out_of_fold = [segments[i] for i in block], set(block.tolist())
        rest = [s for i, s in enumerate(segments) if i not in out_of_fold]
        seqs = [norm(s) for s in rest]
        fits = linear_fits(init, seqs, delay, device)
        models = linear_models(init, seqs[0][0].shape[1], seqs[0][1].shape[1], fits, device)
        fold = dict(val=held)
        shape = np.concatenate([s["y"][s["ok"]] for s in rest]).mean(0)
        ref = score([np.tile(shape, (len(s["x"]), 1)) for s in held], fold, basis, iod_px)["mouth_error_px"]
        preds = {name: [predict_sequence(model, norm(s)[0], delay, device) for s in held]
                 for name, (model, _) in models.items()}
        if tune is not None:
            start = better_readout(fits)
            f32 = [(x, y.astype(np.float32), ok) for x, y, ok in seqs]
            tuned, _, _ = lstm.train(f32, f32[-1:], replace(tune["p"], fine_tune="all"), delay, device, seed=tune["p"].seed,
                                     desc="fine-tune (fold)", budget=Budget(tune["steps"], tune["steps"], None, 0.0),
                                     init=dict(state=models[start][1], hidden=init["hidden"], layers=init["layers"],
                                               anchor=tune["anchor"], skip=start == "encoder_readout"))
            preds["fine_tune"] = [predict_sequence(tuned, norm(s)[0], delay, device) for s in held]
        db = retrieval_database(models["base"][0], seqs, delay, device)
        if db is not None:
            preds["retrieval"] = [mouth_retrieval.retrieve(mouth_retrieval.keys(b), *db) for b in preds["base"]]
        for name, pred in preds.items():
            f = score(pred, fold, basis, iod_px)
            ratio = f["mouth_error_px"] / ref
            out.setdefault(name, []).append(dict(mouth_error_px=f["mouth_error_px"], ratio_to_mean_shape=ratio,
                                                 median_opening_corr=f["median_opening_corr"],
                                                 utility=selection.utility(f["median_opening_corr"], ratio)))
    return out


def better_readout(fits: dict) -> str:
    """The read-out a fine-tune starts from: the lower leave-one-segment-out error (``readout`` when unknown)."""
    cv_h, cv_z = fits["readout"][3], fits["encoder_readout"][3]
    return "encoder_readout" if cv_z and cv_h and min(cv_z.values()) < min(cv_h.values()) else "readout"


def candidate_models(init: dict, data: dict, mean, std, p, delay: int, device, anchor: float):
    """The candidates as {name: DelayedLSTM} (module doc; fitted on the training part) and notes on how each
    was made."""
    norm = lambda s: (((s["x"] - mean) / std).astype(np.float32), s["y"].astype(np.float64), s["ok"])
    train_seqs = [norm(s) for s in data["train"]]
    n_in, k = train_seqs[0][0].shape[1], train_seqs[0][1].shape[1]
    fits = linear_fits(init, train_seqs, delay, device)
    models = linear_models(init, n_in, k, fits, device)
    (_, _, alpha_h, cv_h), (_, _, alpha_z, cv_z) = fits["readout"], fits["encoder_readout"]
    for name, alpha, cv in (("read-out", alpha_h, cv_h), ("encoder read-out", alpha_z, cv_z)):
        log.info("%s candidate: ridge α = %g per frame (leave-one-segment-out error %s)", name, alpha,
                 ", ".join(f"{a:g}: {e:.3f}" for a, e in cv.items()) or "— one training segment")
    start = better_readout(fits)
    f32 = lambda s: (((s["x"] - mean) / std).astype(np.float32), s["y"].astype(np.float32), s["ok"])
    budget = Budget(p.steps, p.val_every, p.patience or 5, p.min_delta)
    tuned, history, kept = lstm.train([f32(s) for s in data["train"]], [f32(s) for s in data["val"]],
                                      replace(p, fine_tune="all"), delay, device, seed=p.seed, desc="fine-tune",
                                      budget=budget,
                                      init=dict(state=models[start][1], hidden=init["hidden"], layers=init["layers"],
                                                anchor=anchor, skip=start == "encoder_readout"))
    notes = dict(readout=dict(alpha=alpha_h, cv_error=cv_h), encoder_readout=dict(alpha=alpha_z, cv_error=cv_z),
                 fine_tune=dict(start=start, anchor=anchor, steps_run=history[-1]["step"], step_kept=kept,
                                history=history))
    return dict({name: model for name, (model, _) in models.items()}, fine_tune=tuned), notes


def align_recordings(data: dict, mean, std, delay: int) -> dict:
    """Estimate each source recording's audio–video offset (``stages/train/offsets``) from all its segments
    (clips of one segment each share one offset, as a corpus recorded in one set-up does) and align its targets
    in place (100-Hz ``y``/``ok`` shifted, frame times moved for scoring). Logs one line per recording;
    returns {recording: dict(offset_ms, best_lag_ms, reliable, reason, cv_error)}."""
    by_recording: dict[str, list] = {}
    for s in data["train"] + data["val"]:
        by_recording.setdefault(offsets.recording_of(s["name"]), []).append(s)
    single = [k for k, v in by_recording.items() if len(v) == 1]
    if len(single) > 1:                 # whole clips (one segment each): one offset for them all, as for a corpus
        by_recording[f"{len(single)} whole clips"] = [by_recording.pop(k)[0] for k in single]
    found = {}
    for name, segs in by_recording.items():
        xs = [input_states(((s["x"] - mean) / std).astype(np.float32), delay) for s in segs]
        est = offsets.estimate(xs, [s["y"].astype(np.float64) for s in segs], [np.asarray(s["ok"], bool) for s in segs])
        found[name] = dict(offset_ms=10 * est["lag"], best_lag_ms=10 * est["best"] if "best" in est else None,
                           reliable=est["reliable"], reason=est["reason"],
                           cv_error={str(k): round(v, 3) for k, v in est["errors"].items()})
        if not est["reliable"]:
            log.warning("%s: its audio–video offset cannot be estimated (%s): no shift", name, est["reason"])
            continue
        log.info("%s: audio–video offset %+d ms (%s; the audio best predicts its mouth at %+d ms, footage in sync "
                 "at %+d ms)%s", name, 10 * est["lag"], "the video is late" if est["lag"] > 0 else "the video is early"
                 if est["lag"] < 0 else "in sync", 10 * est["best"], 10 * offsets.SYNCED_LAG,
                 ": targets aligned" if est["lag"] else "")
        for s in segs:
            s["y"], s["ok"] = offsets.shift(s["y"], np.asarray(s["ok"], bool), est["lag"])
            s["frame_time"] = np.asarray(s["frame_time"]) - est["lag"] / 100.0
    return found


def copy_live_lstm(base_folder, base_model, model, folder) -> bool:
    """The base's live LSTM (``live.pt``, ``bench/live_student.py``) into the person's folder when the kept
    candidate runs the base's own LSTM (a read-out, not a fine-tune): ``lipsynth live`` then hears the live
    front end as the base does."""
    base_folder = Path(base_folder)
    same = all(torch.equal(a, b) for a, b in zip(base_model.lstm.state_dict().values(),
                                                  model.lstm.state_dict().values()))
    if not same or not (base_folder / "live.pt").is_file():
        return False
    for name in ("live.pt", "live.json"):
        shutil.copy(base_folder / name, Path(folder) / name)
    return True


def run(params: Params, base_folder: str, anchor: float = 1e-3) -> dict:
    """Personalize from ``base_folder`` on the stores of ``params`` (ingest, pca, whisper/phonetic);
    write the kept model (with the person's speaker) to ``train.out`` and the metrics to
    ``train.metrics``. Returns the metrics."""
    t0 = time.perf_counter()
    p = params.train
    data, basis, pattrs = load_sequences(params.ingest.out, params.pca.out, p.features, params.phonetic.out,
                                         params.whisper.out)
    device = pick_device(p.device)
    feature_normalisation(data, p.feature_norm, p.features)             # utterance CMVN in place when the base used it
    encoder = encoder_settings(p.features, params.whisper.out)
    init = fine_tune.initial_state(base_folder, p.features, encoder, basis, pattrs["iod_px"], device)
    mean, std = init["feature_mean"], init["feature_std"]
    delay = int(init["base_config"]["delay"])
    found_offsets = align_recordings(data, mean, std, delay)
    models, notes = candidate_models(init, data, mean, std, p, delay, device, anchor)
    own = data["train"]
    normed = lambda x: ((x - mean) / std).astype(np.float32)
    predictors = {name: (lambda x, m=model: predict_sequence(m, normed(x), delay, device)) for name, model in models.items()}
    db = retrieval_database(models["base"], [(normed(s["x"]), s["y"], s["ok"]) for s in own], delay, device)
    if db is None:
        log.warning("retrieval candidate: the training part holds too few steps of a moving mouth (%d needed): left "
                    "out, the parametric candidates compete", mouth_retrieval.MIN_FRAMES)
    else:
        predictors["retrieval"] = lambda x: mouth_retrieval.retrieve(mouth_retrieval.keys(predictors["base"](x)), *db)
    mean_shape = np.concatenate([s["y"][s["ok"]] for s in own]).mean(0)
    baseline = score([np.tile(mean_shape, (len(s["x"]), 1)) for s in data["val"]], data, basis, pattrs["iod_px"])
    figures = {}
    for name, predict in predictors.items():
        figures[name] = score([predict(s["x"]) for s in data["val"]], data, basis, pattrs["iod_px"])
        figures[name]["ratio_to_mean_shape"] = figures[name]["mouth_error_px"] / baseline["mouth_error_px"]
        log.info("candidate %-15s held-out mouth error %.3f px (%.2f %% IOD), ratio to the mean shape %.2f, opening "
                 "correlation %.2f", name, figures[name]["mouth_error_px"], figures[name]["mouth_error_iod_pct"],
                 figures[name]["ratio_to_mean_shape"], figures[name]["median_opening_corr"])
    segments = sorted(data["train"] + data["val"], key=lambda s: s["name"])          # the footage in time order
    plan = selection.fold_plan(len(segments), selection.FOLDS)
    tune = dict(p=p, steps=max(int(notes["fine_tune"]["step_kept"]), 1), anchor=anchor)
    per_fold = fold_figures(init, segments, plan, mean, std, delay, device, basis, pattrs["iod_px"], tune)
    chosen, table = selection.choose({n: [f["utility"] for f in fs] for n, fs in per_fold.items()})
    for name, folds in per_fold.items():
        t = table[name]
        log.info("candidate %-15s folds (ratio / corr): %s → utility %.3f, gain over the base %+.3f ± %.3f%s", name,
                 " · ".join(f"{f['ratio_to_mean_shape']:.2f} / {f['median_opening_corr']:.2f}" for f in folds),
                 t["mean"], t["gain"], t["gain_se"], " (beats the base)" if t["beats_base"] else "")
    log.info("kept: %s (%d folds of %d segments; a candidate replaces the base only when its gain is above %g "
             "standard errors)", chosen, len(plan), len(segments), selection.Z_NOISE)
    if figures[chosen]["ratio_to_mean_shape"] >= 1.0:
        log.warning("the personalized model is worse than the person's mean mouth shape on the held-out part "
                    "(ratio %.2f): their tracked lips follow the audio too little to learn from this footage",
                    figures[chosen]["ratio_to_mean_shape"])
    model = models["base" if chosen == "retrieval" else chosen].cpu()
    retrieval = {} if chosen != "retrieval" else dict(
        config=dict(k=mouth_retrieval.K, smooth=mouth_retrieval.SMOOTH, context=mouth_retrieval.CONTEXT,
                    step=mouth_retrieval.STEP), arrays=dict(retrieval_keys=db[0], retrieval_values=db[1]))
    metrics = dict(model="lstm", features=p.features, delay_steps=delay, base=str(base_folder), chosen=chosen,
                   candidates=figures, folds=dict(plan=[[segments[i]["name"] for i in b] for b in plan],
                                                  per_fold=per_fold, table=table),
                   adaptation=notes, offsets=found_offsets, val=figures[chosen], baseline_mean_shape=baseline,
                   ratio_to_mean_shape=figures[chosen]["ratio_to_mean_shape"])
    rest = rest_shape(own, params.ingest.out)
    with atomic_output(p.out) as tmp:
        save_model(tmp, model, dict(model="lstm", delay=delay, hidden=model.lstm.hidden_size,
                                    layers=model.lstm.num_layers, skip=model.skip is not None,
                                    n_features=int(mean.shape[0]),
                                    n_components=int(basis["components"].shape[0]), feature_rate=100.0,
                                    feature_norm=p.feature_norm, features=p.features, params=as_dict(p),
                                    encoder=encoder, personalized=dict(base=str(base_folder), chosen=chosen),
                                    **({"retrieval": retrieval["config"]} if retrieval else {})),
                   mean, std, basis, pattrs, rest, extra_arrays=retrieval.get("arrays"))
        metrics["speaker"] = export_speaker(tmp, params.ingest.out, params.landmarks.out, params.frontalize.out,
                                            p.bank_frames, p.identity_frames)
        metrics["live_lstm"] = copy_live_lstm(base_folder, models["base"], model, tmp)
    curves = {"fine_tune": notes["fine_tune"].pop("history")}
    write_outputs(metrics, curves, p)
    metrics["seconds"] = time.perf_counter() - t0
    return metrics
