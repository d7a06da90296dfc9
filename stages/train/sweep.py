"""delay-sweep — validation loss of the LSTM against its target delay (paper 000 Fig. 9a, Table 1).

Trains the ``train`` LSTM once per delay in ``delay_sweep.delays`` (10 ms steps) on the same
data, normalisation and seed, and writes one row per delay to ``delay_sweep.plots`` (a DVC plot:
delay_ms on x, val_loss / val_mouth_error_px on y).

Run: ``python -m stages.train.sweep``.
"""
from __future__ import annotations

import csv
import dataclasses
import logging
import os
from pathlib import Path

from pipeline.params import Params
from pipeline.io.runner import stage_main

log = logging.getLogger("lipsynth.sweep")


def run(params: Params, ingest_path: str, pca_path: str) -> list[dict]:
    from pipeline.models.delayed_lstm import pick_device
    from stages.train.train import feature_normalisation, fit_lstm, kept_point, load_sequences, score
    p, s = params.train, params.delay_sweep
    data, basis, pattrs = load_sequences(ingest_path, pca_path)
    device = pick_device(p.device)
    mean, std = feature_normalisation(data, p.feature_norm)
    rows = []
    for d in s.delays:
        _, hist, preds, kept = fit_lstm(data, dataclasses.replace(p, steps=s.steps), d, device, mean, std, desc="sweep")
        sc, best = score(preds, data, basis, pattrs["iod_px"]), kept_point(hist, kept)
        rows.append(dict(delay_steps=d, delay_ms=10 * d, steps=kept, train_loss=best["train_loss"],
                         val_loss=best["val_loss"], val_mouth_error_px=sc["mouth_error_px"],
                         median_opening_corr=sc["median_opening_corr"]))
        log.info("delay %3d ms: val loss %.4f, mouth error %.3f px", 10 * d, rows[-1]["val_loss"],
                 rows[-1]["val_mouth_error_px"])
    out = Path(s.plots)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    with open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.5f}" if isinstance(v, float) else v) for k, v in r.items()})
    os.replace(tmp, out)
    return rows


def main(argv=None) -> int:
    return stage_main("lipsynth delay-sweep", __doc__, lambda p: run(p, p.ingest.out, p.pca.out), argv)


if __name__ == "__main__":
    raise SystemExit(main())
