"""Does averaging models help? Validation mouth error of single models and of every ensemble of them.

    .venv/bin/python bench/ensemble.py runs/grid_s1/models/lstm_pitch runs/grid_s1/models/lstm_pitch_s1 ... \
        [--params runs/grid_s1/params.yaml] [--out bench/results/ensemble.json]

Each folder predicts every validation video of the store (the shared predict path at the video's
fps); an ensemble's prediction is the mean of its members' coefficients, exactly what an
`lipsynth ensemble` folder does (``pipeline.models.model_ensemble.average``). Scored against the tracked
mouth PCA with ``pipeline.measures.mouth_metrics`` (the same figures as bench/karras_grid.py). Prints one line
per combination and writes a plot of error against ensemble size next to the JSON.
"""
from __future__ import annotations

import argparse
import itertools
import json
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import numpy as np


from bench.karras_grid import score
from pipeline.models.mouth_prediction import predict_mouth
from pipeline.params import load_params
from pipeline.io.store import open_group


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("models", nargs="+", help="model folders trained on the store of --params")
    ap.add_argument("--params", default="runs/grid_s1/params.yaml")
    ap.add_argument("--out", default="bench/results/ensemble.json")
    a = ap.parse_args()
    from stages.train.train import load_sequences
    p = load_params(a.params)
    data, basis, attrs = load_sequences(p.ingest.out, p.pca.out)
    src = open_group(p.ingest.out)
    audio = {v["name"]: np.asarray(src["audio"][v["first_sample"]:v["first_sample"] + v["n_samples"]],
                                   np.float32) / 32768.0
             for v in src.attrs["videos"] if not v.get("excluded") and v["n_frames"]}
    preds = {m: [predict_mouth(audio[s["name"]], m, s["fps"])["coeffs"] for s in data["val"]] for m in a.models}
    rows = []
    for k in range(1, len(a.models) + 1):
        for combo in itertools.combinations(a.models, k):
            avg = [np.mean([preds[m][i] for m in combo], 0) for i in range(len(data["val"]))]
            r = score(avg, data, basis, attrs["iod_px"])
            rows.append(dict(members=[Path(m).name for m in combo], mouth_error_px=r["mouth_error_px"],
                             median_opening_corr=r["median_opening_corr"], within_one_frame=r["av_within_one_frame"]))
            print(f"{len(combo)}  {r['mouth_error_px']:.4f} px  corr {r['median_opening_corr']:.3f}  "
                  f"≤1 frame {100 * r['av_within_one_frame']:.0f}%  {' + '.join(rows[-1]['members'])}", flush=True)
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(dict(videos=len(data["val"]), rows=rows), indent=2))
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(5, 3.5))
    sizes = [len(r["members"]) for r in rows]
    ax.scatter(sizes, [r["mouth_error_px"] for r in rows], s=14, alpha=0.6)
    best = {n: min(r["mouth_error_px"] for r in rows if len(r["members"]) == n) for n in sorted(set(sizes))}
    ax.plot(list(best), list(best.values()), "-", lw=1)
    ax.set(xlabel="models averaged", ylabel="validation mouth error (px)",
           title=f"ensembles, {len(data['val'])} validation videos")
    fig.tight_layout()
    fig.savefig(Path(a.out).with_suffix(".png"), dpi=110)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
