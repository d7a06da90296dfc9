"""train_karras — Karras et al. 2017 (paper 001): audio autocorrelation → conv net with learned emotions → face.

1. Targets (``targets``): per frame the 42 frontalized lower-face points (jaw 2–14, nose 27–35,
   lips 48–67; canonical texture px) → 84-D, from the store; audio: the video's 16 kHz track,
   autocorrelation windows (§3.2) cut on the fly (``pipeline.audio.speech_autocorrelation``).
2. Training set: the store's training videos, or — ``karras.train_seconds`` — a seeded subset of
   them totalling that much speech (the paper trains on 3–5 minutes, §4.5).
3. Training (``fit``, §4): temporal pairs, one learned emotion per frame, time shifts, feature-map
   noise, the self-normalised position + motion + emotion loss, Adam with the paper's schedule.
   The budget is ``karras.steps`` optimizer steps (``pipeline.models.training_budget``); every
   ``karras.val_every`` steps: the position loss on a fixed sample of validation frames (the
   validation curve), which stops the run early when ``karras.patience`` is set.
4. Emotion mining (``emotions``, §5.1) → a few robust emotion vectors; candidate 0 is the default.
5. Evaluation on the validation videos (the LSTM's split) through the shared predict path (two
   inferences 4 ms apart, default emotion) at each video's frame rate, scored like the LSTM
   (``pipeline.measures.mouth_metrics``), plus the mean shape on the same frames.

Writes ``models/karras/`` (weights.pt, config.json, arrays.npz, and the speaker), the metrics
json and the loss-curve csv. Run: ``python -m stages.train_karras.train_karras``.
"""
from __future__ import annotations

import csv
import json
import logging
import os
import time
from pathlib import Path

import numpy as np
import torch

from pipeline.models import karras_inference
from pipeline.measures import mouth_metrics
from pipeline.models.delayed_lstm import pick_device
from pipeline.errors import LipsynthError
from pipeline.models.model_folder import load_karras, save_karras
from pipeline.params import Params, as_dict
from pipeline.io.runner import stage_main, write_timing
from pipeline.models.speaker_bank import export_speaker
from pipeline.models.training_budget import seeded_subset
from pipeline.audio.speech_autocorrelation import padded_track, windows
from pipeline.io.store import atomic_output, open_group
from stages.train_karras import emotions as emotion_mining
from stages.train_karras.fit import FitConfig, fit
from stages.train_karras.targets import FACE_POINTS, LIP_INDEX, load_targets

log = logging.getLogger("lipsynth.train_karras")
UPPER, LOWER = FACE_POINTS.index(62), FACE_POINTS.index(66)       # inner-lip midpoints: the opening


def choose_training_videos(train: list[dict], seconds: float | None, seed: int) -> list[dict]:
    """All training videos, or a seeded random subset whose durations first reach ``seconds``."""
    return [train[i] for i in seeded_subset([len(v["samples"]) / 16000 for v in train], seconds, seed)]


def validation_sample(val: list[dict], n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Fixed validation windows (n, 1, 64, 32) and targets (n, D) at valid frames."""
    rows = [(vi, fi) for vi, v in enumerate(val) for fi in np.flatnonzero(v["ok"])]
    rows = [rows[i] for i in np.sort(np.random.default_rng(seed).choice(len(rows), min(n, len(rows)), replace=False))]
    x = np.concatenate([windows(val[vi]["padded"], val[vi]["frame_time"][[fi]]) for vi, fi in rows])
    y = np.stack([val[vi]["targets"][fi] for vi, fi in rows])
    return x[:, None], y


def load_pca(pca_path: str) -> tuple[dict, dict, dict]:
    """Mouth PCA basis, store attributes, and per video name (coeffs (T, k), valid (T,))."""
    pca = open_group(pca_path)
    coeffs, valid = np.asarray(pca["coeffs"][...], np.float32), np.asarray(pca["valid"][...])
    per = {v["name"]: (coeffs[v["first_frame"]:v["first_frame"] + v["n_frames"]],
                       valid[v["first_frame"]:v["first_frame"] + v["n_frames"]])
           for v in pca.attrs["videos"] if not v.get("excluded") and v["n_frames"]}
    basis = {k: np.asarray(pca[k][...], np.float64) for k in ("mean", "components")}
    return basis, dict(pca.attrs), per


def split_videos(videos: list[dict], frontalize_path: str) -> tuple[list[dict], list[dict]]:
    """The training and the validation videos; refused unless both are there."""
    train_all = [v for v in videos if v["split"] == "train"]
    val = [v for v in videos if v["split"] == "val"]
    if not train_all or not val:
        raise LipsynthError(f"{frontalize_path}: the Karras network needs training and validation videos "
                            f"({len(train_all)} and {len(val)})")
    return train_all, val


def validation_curve(xv: np.ndarray, yv: np.ndarray, device):
    """``fit``'s ``on_validation``: the position loss (px²) and the mean point error (px) of the network with
    the mean learned emotion on the fixed validation windows ``xv`` against their targets ``yv``."""
    xv_t = torch.as_tensor(xv, device=device)

    def on_validation(step, net, emo):
        e = emo.mean(0, keepdim=True).to(device)
        out = np.concatenate([net(xv_t[i:i + 512], e.expand(len(xv_t[i:i + 512]), -1)).cpu().numpy()
                              for i in range(0, len(xv_t), 512)])
        err = np.linalg.norm((out - yv).reshape(len(yv), -1, 2), axis=-1).mean()
        log.debug("step %d: validation position %.4f px², error %.3f px", step, ((out - yv) ** 2).mean(), err)
        return dict(val_position=float(((out - yv) ** 2).mean()), val_error_px=float(err))
    return on_validation


def mine_emotions(net, database: np.ndarray, sources: list, val: list[dict], k) -> dict:
    """The emotion candidates (§5.1, ``emotions.mine``); with ``karras.emotions`` off (the ablation: the network
    never saw an emotion) one zero vector, its input in training."""
    if k.emotions:
        return emotion_mining.mine(net, database, sources, val, UPPER, LOWER, k.mine_candidates, k.mine_probes,
                                   k.mine_playback, k.mine_playback_clips, k.emotion_clusters, k.seed)
    return dict(candidates=np.zeros((1, k.emotion_dim), np.float32),
                info=[dict(index=0, database_row=-1, video="", frame=-1, cluster_size=0, videos={})], steps={})


def mean_shape_scores(train: list[dict], val: list[dict], pca_frames: dict, basis: dict, iod_px: float) -> dict:
    """The baseline: the training videos' mean mouth PCA coefficients on every validation frame, scored like
    the network."""
    mean_shape = np.nanmean(np.concatenate([pca_frames[v["name"]][0][pca_frames[v["name"]][1]] for v in train]), 0)
    return mouth_metrics.evaluate_videos(
        [np.tile(mean_shape, (len(pca_frames[v["name"]][0]), 1)) for v in val],
        [pca_frames[v["name"]][0] for v in val], [pca_frames[v["name"]][1] for v in val],
        [v["fps"] for v in val], basis, iod_px)


def run(params: Params, ingest_path: str, landmarks_path: str, frontalize_path: str, pca_path: str,
        with_speaker: bool = True) -> dict:
    k = params.karras
    clock = {"start": time.perf_counter()}
    device = pick_device(k.device)
    torch.set_num_threads(max(1, k.threads or os.cpu_count() or 1))
    torch.set_flush_denormal(True)
    videos = load_targets(ingest_path, landmarks_path, frontalize_path)
    basis, attrs, pca_frames = load_pca(pca_path)
    for v in videos:
        v["padded"] = padded_track(v["samples"], v["name"])
    train_all, val = split_videos(videos, frontalize_path)
    train = choose_training_videos(train_all, k.train_seconds, k.seed)
    seconds = sum(len(v["samples"]) for v in train) / 16000
    xv, yv = validation_sample(val, k.val_frames, k.seed)
    log.info("Karras et al.: %d of %d training videos (%.1f min of speech, %d frames), %d validation videos "
             "(%d sampled frames for the curve), %d outputs (%d face points), %d steps on %s",
             len(train), len(train_all), seconds / 60, sum(len(v["targets"]) for v in train), len(val), len(yv),
             2 * len(FACE_POINTS), len(FACE_POINTS), k.steps, device)
    on_validation = validation_curve(xv, yv, device)
    config = FitConfig(steps=k.steps, batch=k.batch, lr=k.lr, emotion_dim=k.emotion_dim,
                       emotion_sigma=k.emotion_sigma, motion=k.motion, emotions=k.emotions,
                       time_shift=k.time_shift, seed=k.seed, device=device, val_every=k.val_every,
                       patience=k.patience, min_delta=k.min_delta)
    t0 = time.perf_counter()
    net, database, history = fit(videos=[dict(v, split="train") for v in train], config=config, on_validation=on_validation)
    clock["fit_s"] = time.perf_counter() - t0
    net = net.cpu().eval()
    sources = [(v["name"], i) for v in train for i in range(len(v["targets"]))]
    t0 = time.perf_counter()
    mined = mine_emotions(net, database, sources, val, k)
    clock["mine_s"] = time.perf_counter() - t0
    ys = np.concatenate([v["targets"][v["ok"]] for v in train])
    arrays = dict(pca_mean=basis["mean"], pca_components=basis["components"], lip_index=np.asarray(LIP_INDEX),
                  face_mean=ys.mean(0), emotion_candidates=mined["candidates"], emotion_database=database)
    model_config = dict(n_outputs=int(ys.shape[1]), emotion_dim=k.emotion_dim, face_points=FACE_POINTS,
                        default_emotion=0, emotion_info=mined["info"], lip_points=attrs["lip_points"],
                        iod_px=attrs["iod_px"], trained_on=[v["name"] for v in train],
                        training_seconds=seconds, params=as_dict(k))
    with atomic_output(k.out) as tmp:
        save_karras(tmp, net, model_config, arrays)
        model = load_karras(tmp)
        t0 = time.perf_counter()
        val_scores, n_frames = evaluate(model, val, pca_frames, basis, attrs["iod_px"])
        clock["evaluate_s"] = time.perf_counter() - t0
        clock["inference_ms_per_frame"] = 1000 * clock["evaluate_s"] / max(n_frames, 1)
        if with_speaker:
            speaker = export_speaker(tmp, ingest_path, landmarks_path, frontalize_path,
                                     params.train.bank_frames, params.train.identity_frames)
    baseline = mean_shape_scores(train, val, pca_frames, basis, attrs["iod_px"])
    metrics = dict(model="karras", training_videos=len(train), training_seconds=seconds,
                   training_frames=int(sum(len(v["targets"]) for v in train)), steps=k.steps,
                   steps_run=history[-1]["step"], step_kept=history[-1].get("kept_step", history[-1]["step"]),
                   epochs=round(history[-1]["epoch"], 3),
                   val=val_scores, baseline_mean_shape=baseline,
                   ratio_to_mean_shape=val_scores["mouth_error_px"] / baseline["mouth_error_px"],
                   final_val_error_px=history[-1].get("val_error_px"), emotions=mined["steps"],
                   emotion_candidates=len(mined["candidates"]),
                   ablation=dict(motion=k.motion, emotions=k.emotions, time_shift=k.time_shift))
    if with_speaker:
        metrics["speaker"] = speaker
    log.info("Karras: validation mouth error %.3f px (%.2f%% IOD), opening corr %.2f, %.0f%% of clips within one "
             "frame; mean shape %.3f px → ratio %.2f; %d emotion candidates", val_scores["mouth_error_px"],
             val_scores["mouth_error_iod_pct"], val_scores["median_opening_corr"],
             100 * val_scores["av_within_one_frame"], baseline["mouth_error_px"], metrics["ratio_to_mean_shape"],
             len(mined["candidates"]))
    write_outputs(metrics, history, k)                 # timings go to logs/ only: the metrics stay deterministic
    clock["seconds_per_step"] = clock["fit_s"] / max(history[-1]["step"], 1)
    clock["total_s"] = time.perf_counter() - clock.pop("start")
    write_timing("train_karras", clock)
    return metrics


def evaluate(model: dict, val: list[dict], pca_frames: dict, basis: dict, iod_px: float) -> tuple[dict, int]:
    """The shared predict path (default emotion, two inferences 4 ms apart) on every validation video."""
    preds, truths, oks, fps, n = [], [], [], [], 0
    for v in val:
        c = karras_inference.predict(v["samples"], model, v["fps"], source=v["name"])["coeffs"]
        true, ok = pca_frames[v["name"]]
        m = min(len(c), len(true))
        preds.append(c[:m]), truths.append(true[:m]), oks.append(ok[:m]), fps.append(v["fps"])
        n += len(c)
    return mouth_metrics.evaluate_videos(preds, truths, oks, fps, basis, iod_px), n


def write_outputs(metrics: dict, history: list[dict], k) -> None:
    with atomic_output(k.metrics, suffix=".json") as tmp:
        tmp.write_text(json.dumps(metrics, indent=2))
    Path(k.plots).parent.mkdir(parents=True, exist_ok=True)
    tmp = k.plots + ".tmp"
    cols = ["step", "epoch", "position", "motion", "emotion", "val_position", "val_error_px"]
    with open(tmp, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(cols)
        for h in history:
            w.writerow([h["step"]] + [f"{h[c]:.6g}" if c in h else "" for c in cols[1:]])
    os.replace(tmp, k.plots)


def main(argv=None) -> int:
    return stage_main("lipsynth train-karras", __doc__,
                      lambda p: run(p, p.ingest.out, p.landmarks.out, p.frontalize.out, p.pca.out), argv)


if __name__ == "__main__":
    raise SystemExit(main())
