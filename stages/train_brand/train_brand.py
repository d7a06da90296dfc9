"""train_brand — Voice Puppetry (Brand 1999, paper 002): an entropic facial HMM remapped onto the voice.

1. Facial observations (§4.1): 39 frontalized face points (lips, jaw, brows) at ``brand.rate``,
   reduced to ``brand.face_dims`` PCA coordinates, position + velocity (px/s) → 2D-dim vectors,
   standardised (``observations``).
2. Entropic estimation (§4.2, Eqs. 1–4): a ``brand.states``-state full-covariance Gaussian HMM by
   MAP EM under P_e ∝ e^{−H}, trimming transitions and removing states that fall out of use
   (``entropic``). The same EM with the maximum-likelihood M-step is the baseline.
3. Remapping (§4.3): the facial model's state occupancies γ weight the synchronized voice
   features (``brand.features``) into each state's vocal Gaussian; the vocal HMM keeps the face's
   transition matrix.
4. Evaluation on the validation videos (the LSTM's split): the shared predict path
   (``pipeline.models.voice_puppet``: Viterbi on the voice → Eq. 5 trajectory) at each video's frame
   rate, scored like the LSTM (``pipeline.measures.mouth_metrics``); the paper's Eq. 7 error from the
   true face's state sequence and from the voice; entropy rate of the decoded state sequence
   and the transition perplexity (§5) — for the entropic and the ML model.

Writes ``models/brand/`` (config.json, arrays.npz, and the speaker: speaker.npz, bank.zarr),
``metrics/train_brand.json`` and ``plots/train_brand.csv`` (EM history of both models).

Run: ``python -m stages.train_brand.train_brand``.
"""
from __future__ import annotations

import csv
import json
import logging
import os
import time
from pathlib import Path

import numpy as np

from pipeline.measures import mouth_metrics
from pipeline.models import voice_puppet
from pipeline.errors import LipsynthError, ParameterError
from pipeline.models.model_folder import save_puppet
from pipeline.params import Params, as_dict
from pipeline.io.runner import stage_main, write_timing
from pipeline.models.speaker_bank import export_speaker
from pipeline.models.training_budget import seeded_subset
from pipeline.io.store import atomic_output
from stages.train_brand import entropic
from stages.train_brand.observations import FACE_POINTS, LIP_INDEX, face_pca, load_videos, observations, segments

log = logging.getLogger("lipsynth.train_brand")


def stack(videos: list[dict], key: str, rows: list[list[slice]]) -> np.ndarray:
    return np.concatenate([v[key][s] for v, segs in zip(videos, rows) for s in segs])


def weighted_gaussians(x: np.ndarray, gamma: np.ndarray, extra: float, reg: float) -> tuple[np.ndarray, np.ndarray]:
    """Per state the γ-weighted mean (K, A) and covariance (K, A, A) of x (N, A); the covariance is
    divided by Σγ + ``extra`` (1 for the entropic model's MAP estimate, 0 for ML) plus ``reg``·I."""
    n = gamma.sum(0)
    means = gamma.T @ x / np.maximum(n, 1e-10)[:, None]
    covs = np.empty((len(n), x.shape[1], x.shape[1]))
    for k in range(len(n)):
        d = x - means[k]
        covs[k] = (gamma[:, k, None] * d).T @ d / (n[k] + extra) + reg * np.eye(x.shape[1])
    return means, covs


def make_puppet(hmm, Z, V, lengths, center, scale, fpca, basis, config, extra) -> dict:
    """Remap the facial HMM onto the voice (§4.3) and express the face Gaussians in PCA px (px/s)."""
    gamma = hmm.predict_proba(Z, lengths)
    vmeans, vcovs = weighted_gaussians(V, gamma, extra, config["reg"])
    s = np.asarray(scale)
    return dict(config=config, startprob=hmm.startprob_, transmat=hmm.transmat_,
                face_means=hmm.means_ * s + center, face_covars=hmm.covars_ * s[None, :, None] * s[None, None, :],
                vocal_means=vmeans, vocal_covars=vcovs, face_pca_mean=fpca["mean"],
                face_pca_components=fpca["components"], lip_index=np.asarray(LIP_INDEX),
                pca_mean=basis["mean"], pca_components=basis["components"])


def eq7_error(true_pts: np.ndarray, pred_pts: np.ndarray, mean_face: np.ndarray) -> float:
    """Paper Eq. 7 over one clip: Σ‖x − y‖² / Σ‖x + y‖², x, y = true / reconstructed face points
    minus the mean training face (a ratio of sums: per-frame ratios explode near the rest face)."""
    x = true_pts.reshape(len(true_pts), -1) - mean_face
    y = pred_pts.reshape(len(pred_pts), -1) - mean_face
    return float(((x - y) ** 2).sum() / max(((x + y) ** 2).sum(), 1e-12))


def paper_measures(puppet: dict, hmm, videos: list[dict], obs: list, center, scale, fpca) -> dict:
    """Eq. 7 reconstruction error from the true face's Viterbi states and from the voice, and the
    entropy rate of the voice-decoded state sequence (nats/frame), averaged over clips."""
    rate = puppet["config"]["rate"]
    gauss = voice_puppet.split_covariances(puppet["face_means"], puppet["face_covars"])
    from_face, from_voice, entropy = [], [], []
    for v, (x, ok) in zip(videos, obs):
        truth = v["points"]
        segs = segments(ok)
        if not segs:
            continue
        zt, pt = [], []
        for s in segs:
            ll = voice_puppet.gaussian_loglik((x[s] - center) / scale, hmm.means_, hmm.covars_)
            path, _ = voice_puppet.viterbi(ll, puppet["startprob"], puppet["transmat"])
            y = voice_puppet.solve_trajectory(np.eye(ll.shape[1])[path], gauss, rate)
            zt.append(truth[s])
            pt.append(voice_puppet.face_points(y, puppet))
        from_face.append(eq7_error(np.concatenate(zt), np.concatenate(pt), fpca["mean"]))
        a = (v["voice"] - puppet["vocal_mean"]) / puppet["vocal_std"]
        ll = voice_puppet.gaussian_loglik(a, puppet["vocal_means"], puppet["vocal_covars"])
        path, _ = voice_puppet.viterbi(ll, puppet["startprob"], puppet["transmat"])
        y = voice_puppet.solve_trajectory(np.eye(ll.shape[1])[path], gauss, rate)
        good = v["ok"]
        from_voice.append(eq7_error(truth[good], voice_puppet.face_points(y, puppet)[good], fpca["mean"]))
        entropy.append(voice_puppet.sequence_entropy_rate(ll, puppet["startprob"], puppet["transmat"]))
    return dict(eq7_state_sequence=float(np.mean(from_face)), eq7_voice=float(np.mean(from_voice)),
                entropy_rate_nats=float(np.mean(entropy)), n_clips=len(from_voice))


def mouth_scores(puppet: dict, val: list[dict], basis: dict, iod_px: float) -> dict:
    """The shared predict path on each validation video's audio at its frame rate, scored like the LSTM."""
    preds, truths, oks, fps = [], [], [], []
    for v in val:
        c = voice_puppet.predict(v["samples"], puppet, v["fps"], v["name"])["coeffs"]
        m = min(len(c), len(v["frame_coeffs"]))
        preds.append(c[:m]), truths.append(v["frame_coeffs"][:m]), oks.append(v["frame_ok"][:m]), fps.append(v["fps"])
    return mouth_metrics.evaluate_videos(preds, truths, oks, fps, basis, iod_px)


def run(params: Params, ingest_path: str, landmarks_path: str, frontalize_path: str, pca_path: str,
        with_speaker: bool = True) -> dict:
    b = params.brand
    clock = {"start": time.perf_counter()}
    encoder = (dict(window_s=params.whisper.window_seconds, overlap_s=params.whisper.overlap_seconds)
               if b.features == "whisper" else None)
    videos, pc = load_videos(ingest_path, landmarks_path, frontalize_path, pca_path, b.rate, b.features, encoder)
    basis, attrs = pc["basis"], pc["attrs"]
    train, val = split_videos(videos, b, pca_path)
    clock["features_s"] = time.perf_counter() - clock["start"]
    projection = voice_pca(train, b.voice_dims) if b.features == "whisper" else None
    if projection is not None:
        for v in videos:
            v["voice"] = voice_puppet.project_voice(v["voice"], projection)
        log.info("voice: PCA of the %d-D encoder states to %d dims (%.1f%% of their variance)",
                 projection["vocal_projection"].shape[1], b.voice_dims, 100 * projection["explained"])
    fpca = face_pca(train, b.face_dims)
    obs = [observations(v, fpca, b.rate) for v in videos]
    by_name = {v["name"]: o for v, o in zip(videos, obs)}
    rows = [segments(by_name[v["name"]][1]) for v in train]
    for v in train:
        v["x"] = by_name[v["name"]][0]
    X, V = stack(train, "x", rows), stack(train, "voice", rows)
    lengths = np.array([s.stop - s.start for segs in rows for s in segs])
    if len(X) < 10 * b.states:
        raise LipsynthError(f"{pca_path}: {len(X)} usable training frames are too few for {b.states} states")
    center, scale = X.mean(0), np.maximum(X.std(0), 1e-9)
    vmean, vstd = V.mean(0), np.maximum(V.std(0), 1e-9)
    Z, Vn = (X - center) / scale, (V - vmean) / vstd
    log.info("Voice Puppetry: %d training frames in %d segments (%d videos), face %d-D (%.1f%% of the variance "
             "of %d points) + velocity, voice %d-D (%s), %d validation videos", len(X), len(lengths), len(train),
             b.face_dims, 100 * fpca["explained"].sum(), len(FACE_POINTS), V.shape[1], b.features, len(val))
    config = dict(model="brand", rate=b.rate, features=b.features, encoder=encoder, decode=b.decode, face_dims=b.face_dims,
                  face_points=FACE_POINTS, reg=b.reg, pca_fingerprint=attrs["fingerprint"],
                  lip_points=attrs["lip_points"], iod_px=attrs["iod_px"], params=as_dict(b), format=1)
    metrics = dict(model="brand", rate=b.rate, features=b.features, face_dims=b.face_dims,
                   face_variance_kept=float(fpca["explained"].sum()), training_frames=int(len(X)),
                   states_initial=b.states)
    curves, puppets = {}, {}
    for prior in ("entropic", "ml") if b.baseline else ("entropic",):
        t0 = time.perf_counter()
        hmm, history = entropic.fit(Z, lengths, b.states, prior, b.iterations, b.tolerance, b.reg,
                                    b.min_state_frames, b.trim, b.seed, b.prior_weight, desc=f"{prior} HMM")
        clock[f"em_{prior}_s"] = time.perf_counter() - t0
        clock[f"em_{prior}_iterations"] = len(history)
        cfg = dict(config, prior=prior, states=int(hmm.n_components))
        puppet = make_puppet(hmm, Z, Vn, lengths, center, scale, fpca, basis, cfg,
                             b.prior_weight if prior == "entropic" else 0.0)
        puppet.update(vocal_mean=vmean, vocal_std=vstd)
        if projection is not None:
            puppet.update(vocal_projection_mean=projection["vocal_projection_mean"],
                          vocal_projection=projection["vocal_projection"])
        curves[prior], puppets[prior] = history, puppet
        metrics[prior] = prior_metrics(prior, hmm, history, puppet, (train, val), by_name, (center, scale), fpca,
                                       basis, attrs["iod_px"])
    metrics["baseline_mean_shape"] = mean_shape_scores(train, val, basis, attrs["iod_px"])
    metrics["ratio_to_mean_shape"] = (metrics["entropic"]["val"]["mouth_error_px"]
                                      / metrics["baseline_mean_shape"]["mouth_error_px"])
    log.info("mean shape %.3f px; Voice Puppetry / mean shape = %.2f",
             metrics["baseline_mean_shape"]["mouth_error_px"], metrics["ratio_to_mean_shape"])
    with atomic_output(b.out) as tmp:
        save_puppet(tmp, puppets["entropic"])
        if with_speaker:
            metrics["speaker"] = export_speaker(tmp, ingest_path, landmarks_path, frontalize_path,
                                                params.train.bank_frames, params.train.identity_frames)
    write_outputs(metrics, curves, b)
    clock["total_s"] = time.perf_counter() - clock.pop("start")
    write_timing("train_brand", dict(clock, training_frames=len(X)))
    return metrics


def split_videos(videos: list[dict], b, pca_path: str) -> tuple[list[dict], list[dict]]:
    """The training videos (all, or a seeded subset of about ``brand.train_seconds``) and the validation videos;
    refused unless both are there."""
    train = [v for v in videos if v["split"] == "train"]
    val = [v for v in videos if v["split"] == "val"]
    if b.train_seconds:
        train = [train[i] for i in seeded_subset([len(v["samples"]) / 16000 for v in train], b.train_seconds, b.seed)]
        log.info("brand.train_seconds=%g: %d of the training videos (%.1f s), seeded", b.train_seconds, len(train),
                 sum(len(v["samples"]) for v in train) / 16000)
    if not train or not val:
        raise LipsynthError(f"{pca_path}: Voice Puppetry needs training and validation videos "
                            f"({len(train)} and {len(val)})")
    return train, val


def prior_metrics(prior: str, hmm, history: list[dict], puppet: dict, split: tuple[list, list], by_name: dict,
                  standardise: tuple, fpca: dict, basis: dict, iod_px: float) -> dict:
    """One HMM's metrics (``prior``: entropic or ml), logged in one line: size, perplexity, the paper's Eq. 7
    and entropy rate on the training and the validation videos (``split``; observations ``by_name``,
    standardised by ``standardise`` = (center, scale)), and the shared predict path's validation scores."""
    train, val = split
    center, scale = standardise
    tr_obs = [by_name[v["name"]] for v in train]
    va_obs = [by_name[v["name"]] for v in val]
    on_train = paper_measures(puppet, hmm, train, tr_obs, center, scale, fpca)
    on_test = paper_measures(puppet, hmm, val, va_obs, center, scale, fpca)
    m = dict(
        states=int(hmm.n_components), transitions=int((hmm.transmat_ > 0).sum()),
        iterations=len(history), log_likelihood_per_frame=history[-1]["log_likelihood"],
        transition_perplexity=voice_puppet.transition_perplexity(hmm.transmat_),
        entropy_rate_nats=on_test["entropy_rate_nats"],
        eq7={"state_sequence": {"train": on_train["eq7_state_sequence"], "test": on_test["eq7_state_sequence"]},
             "voice": {"train": on_train["eq7_voice"], "test": on_test["eq7_voice"]}},
        val=mouth_scores(puppet, val, basis, iod_px))
    log.info("%s HMM: %d states, %d transitions, perplexity %.2f, entropy rate %.3f nats/frame; Eq. 7 test "
             "%.3f (face states) / %.3f (voice); validation mouth error %.3f px (%.2f%% IOD), opening corr %.2f",
             prior, m["states"], m["transitions"], m["transition_perplexity"], m["entropy_rate_nats"],
             on_test["eq7_state_sequence"], on_test["eq7_voice"], m["val"]["mouth_error_px"],
             m["val"]["mouth_error_iod_pct"], m["val"]["median_opening_corr"])
    return m


def mean_shape_scores(train: list[dict], val: list[dict], basis: dict, iod_px: float) -> dict:
    """The baseline: the training videos' mean mouth shape on every validation frame, scored like the models."""
    mean_shape = np.nanmean(np.concatenate([v["frame_coeffs"][v["frame_ok"]] for v in train]), 0)
    return mouth_metrics.evaluate_videos(
        [np.tile(mean_shape, (len(v["frame_coeffs"]), 1)) for v in val], [v["frame_coeffs"] for v in val],
        [v["frame_ok"] for v in val], [v["fps"] for v in val], basis, iod_px)


def voice_pca(train: list[dict], dims: int) -> dict:
    """PCA of the training videos' voice frames: vocal_projection_mean (F,), vocal_projection (dims, F),
    explained (share of the variance kept)."""
    if dims < 1:
        raise ParameterError(f"brand.voice_dims={dims}: must be at least 1")
    x = np.concatenate([v["voice"] for v in train])
    mean = x.mean(0)
    _, s, vt = np.linalg.svd(x - mean, full_matrices=False)
    return dict(vocal_projection_mean=mean, vocal_projection=vt[:dims], explained=float((s[:dims] ** 2).sum() / (s ** 2).sum()))


def write_outputs(metrics: dict, curves: dict, b) -> None:
    Path(b.metrics).parent.mkdir(parents=True, exist_ok=True)
    tmp = b.metrics + ".tmp"
    with open(tmp, "w") as f:
        json.dump(metrics, f, indent=2)
    os.replace(tmp, b.metrics)
    Path(b.plots).parent.mkdir(parents=True, exist_ok=True)
    tmp = b.plots + ".tmp"
    with open(tmp, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["model", "iteration", "log_likelihood", "log_posterior", "states", "transitions"])
        for name, hist in curves.items():
            for h in hist:
                w.writerow([name, h["iteration"], f"{h['log_likelihood']:.5f}", f"{h['log_posterior']:.5f}",
                            h["states"], h["transitions"]])
    os.replace(tmp, b.plots)


def main(argv=None) -> int:
    return stage_main("lipsynth train-brand", __doc__,
                      lambda p: run(p, p.ingest.out, p.landmarks.out, p.frontalize.out, p.pca.out), argv)


if __name__ == "__main__":
    raise SystemExit(main())
