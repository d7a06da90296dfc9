"""GRID s1 figures of the Karras family (issue 10): Karras vs the LSTM on the same minutes, the LSTM
on the whole corpus and the mean shape, on the same validation frames; plus ablation folders and
jitter.

    .venv/bin/python bench/karras_grid.py [--params runs/grid_s1/params.yaml] [--karras DIR ...]
                                          [--lstm-same-minutes] [--out bench/results/karras_grid.json]

Every model is scored by the shared predict path (``pipeline.models.mouth_prediction.predict_mouth``) at
each validation video's frame rate against the store's tracked mouth PCA (valid frames), with
``pipeline.measures.mouth_metrics`` (mouth error, opening correlation at lag 0, share of clips whose best
lag is within one frame). Jitter: median over clips of the mean |second difference| of the
predicted inner-lip opening (px/frame²), and the same for the tracked mouth.
``--lstm-same-minutes`` trains the paper-000 LSTM (train params, delay 200 ms) on exactly the
videos the first Karras folder was trained on (its config.json ``trained_on``).
"""
from __future__ import annotations

import argparse
import json
import logging
import time
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import numpy as np


from pipeline.measures import mouth_metrics
from pipeline.models.mouth_pca import reconstruct
from pipeline.models.mouth_prediction import predict_mouth, to_frames
from pipeline.params import load_params


def jitter(pred_coeffs: list, truths: list, oks: list, basis: dict) -> dict:
    """Frame-to-frame motion of predicted vs tracked mouths, medians over clips.

    opening: mean |second difference| of the inner-lip opening (px/frame²);
    delta: mean |Δ| of the 18 lip points between consecutive frames (px/frame), the tracked
    one over pairs of valid frames.
    """
    jp, jt, dp, dt = [], [], [], []
    for c, t, ok in zip(pred_coeffs, truths, oks):
        if ok.sum() < 10:
            continue
        pp, tp = reconstruct(c, basis), reconstruct(np.nan_to_num(t), basis)
        po, to = mouth_metrics.opening(pp), mouth_metrics.opening(tp)
        jp.append(np.abs(np.diff(po, 2)).mean())
        jt.append(np.abs(np.diff(to, 2))[ok[2:] & ok[1:-1] & ok[:-2]].mean())
        step = lambda s: np.linalg.norm(np.diff(s.reshape(len(s), -1, 2), axis=0), axis=-1).mean(1)
        dp.append(step(pp).mean())
        dt.append(step(tp)[ok[1:] & ok[:-1]].mean())
    med = lambda x: float(np.median(x))
    return dict(jitter=med(jp), jitter_tracked=med(jt), delta=med(dp), delta_tracked=med(dt))


def score(preds: list, data: dict, basis: dict, iod: float) -> dict:
    val = data["val"]
    truths, oks = [s["frame_y"] for s in val], [s["frame_ok"] for s in val]
    preds = [p[:len(t)] for p, t in zip(preds, truths)]
    m = mouth_metrics.evaluate_videos(preds, truths, oks, [s["fps"] for s in val], basis, iod)
    m.update(jitter(preds, truths, oks, basis))
    m.pop("per_clip", None)
    return m


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--params", default="runs/grid_s1/params.yaml")
    ap.add_argument("--karras", nargs="*", default=None, help="Karras model folders (default: karras.out)")
    ap.add_argument("--no-ensemble", action="store_true", help="also score the first folder with one inference")
    ap.add_argument("--lstm-same-minutes", action="store_true")
    ap.add_argument("--out", default="bench/results/karras_grid.json")
    a = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    from stages.train.train import feature_normalisation, fit_lstm, load_sequences
    from pipeline.models.delayed_lstm import pick_device
    p = load_params(a.params)
    data, basis, attrs = load_sequences(p.ingest.out, p.pca.out)
    iod = attrs["iod_px"]
    from pipeline.io.store import open_group
    src = open_group(p.ingest.out)
    audio = {}
    for v in src.attrs["videos"]:
        if not v.get("excluded") and v["n_frames"]:
            audio[v["name"]] = np.asarray(src["audio"][v["first_sample"]:v["first_sample"] + v["n_samples"]],
                                          np.float32) / 32768.0
    rows = {}
    mean_shape = np.concatenate([s["frame_y"][s["frame_ok"]] for s in data["train"]]).mean(0)
    rows["mean shape"] = score([np.tile(mean_shape, (len(s["frame_y"]), 1)) for s in data["val"]], data, basis, iod)
    folders = a.karras or [p.karras.out]
    for i, folder in enumerate(folders):
        cfg = json.loads((Path(folder) / "config.json").read_text())
        t0 = time.perf_counter()
        preds = [predict_mouth(audio[s["name"]], folder, s["fps"], source=s["name"])["coeffs"] for s in data["val"]]
        ms = 1000 * (time.perf_counter() - t0) / sum(len(s["frame_y"]) for s in data["val"])
        name = f"karras {Path(folder).name}"
        rows[name] = dict(score(preds, data, basis, iod), inference_ms_per_frame=ms,
                          training_seconds=cfg.get("training_seconds"), ablation={k: cfg["params"][k] for k in
                                                                                   ("motion", "emotions", "time_shift")},
                          steps=cfg["params"].get("steps"), epochs=cfg["params"].get("epochs"))
        if i == 0 and a.no_ensemble:
            from pipeline.models import karras_inference
            from pipeline.models.model_folder import load_karras
            model = load_karras(folder)
            preds = [karras_inference.predict(audio[s["name"]], model, s["fps"], ensemble=False)["coeffs"]
                     for s in data["val"]]
            rows[name + " (one inference, no 4 ms ensemble)"] = score(preds, data, basis, iod)
    if p.train.out and (Path(p.train.out) / "config.json").is_file():
        preds = [predict_mouth(audio[s["name"]], p.train.out, s["fps"], source=s["name"])["coeffs"] for s in data["val"]]
        rows["lstm whole corpus"] = score(preds, data, basis, iod)
    if a.lstm_same_minutes:
        names = set(json.loads((Path(folders[0]) / "config.json").read_text())["trained_on"])
        sub = dict(train=[s for s in data["train"] if s["name"] in names], val=data["val"])
        device = pick_device(p.train.device)
        mean, std = feature_normalisation(sub, p.train.feature_norm)
        t0 = time.perf_counter()
        _, hist, preds100 = fit_lstm(sub, p.train, p.train.delay, device, mean, std, desc="lstm same minutes")
        frames = [to_frames(c, s["frame_time"]) for c, s in zip(preds100, data["val"])]
        rows[f"lstm same minutes ({len(sub['train'])} videos)"] = dict(
            score(frames, data, basis, iod), train_seconds=time.perf_counter() - t0)
    mean_px = rows["mean shape"]["mouth_error_px"]
    print(f"\n{'model':<52} {'px':>6} {'%IOD':>6} {'ratio':>6} {'corr':>6} {'≤1 fr':>6} {'jitter':>7} {'|Δ|':>6}")
    for name, m in rows.items():
        print(f"{name:<52} {m['mouth_error_px']:6.3f} {m['mouth_error_iod_pct']:6.2f} "
              f"{m['mouth_error_px'] / mean_px:6.3f} {m['median_opening_corr']:6.3f} "
              f"{100 * m['av_within_one_frame']:5.0f}% {m['jitter']:7.3f} {m['delta']:6.3f}")
    t = rows["mean shape"]
    print(f"tracked mouth: jitter {t['jitter_tracked']:.3f} px/frame² (opening), |Δ| {t['delta_tracked']:.3f} px/frame "
          "(lip points)")
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
