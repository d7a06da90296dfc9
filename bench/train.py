"""Training and inference cost of the time-delayed LSTM on this machine.

Prints training throughput (sequence steps per second: forward + backward + Adam over batches
of ``batch_size`` streams × ``bptt`` steps) and inference cost (ms per second of audio: MFCC
features + LSTM + resampling to 30 fps), each the median of --repeats runs.

    python bench/train.py [--repeats 5] [--device auto]
"""
from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]

from pipeline.models.delayed_lstm import DelayedLSTM, pick_device  # noqa: E402
from pipeline.models.model_folder import save_model  # noqa: E402
from pipeline.models.mouth_prediction import predict_mouth  # noqa: E402
from pipeline.params import as_dict, load_params  # noqa: E402
from stages.pca.pca import fit_pca  # noqa: E402
from stages.train import lstm  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--device", default="auto")
    ap.add_argument("--windows", type=int, default=20, help="training windows per timed run")
    a = ap.parse_args()
    p = load_params(ROOT / "params.yaml").train
    dev = pick_device(a.device)
    torch.manual_seed(0)
    model = DelayedLSTM(28, p.hidden, 20, p.layers).to(dev)
    opt = torch.optim.Adam(model.parameters(), lr=p.lr)
    B, T = p.batch_size, p.bptt
    x = torch.randn(B, T * a.windows, 28, device=dev)
    y = torch.randn(B, T * a.windows, 20, device=dev)
    m = torch.ones(B, T * a.windows, device=dev)
    rates = []
    for _ in range(a.repeats + 1):
        state = None
        t0 = time.perf_counter()
        for w in range(a.windows):
            sl = slice(w * T, (w + 1) * T)
            pred, state = model(x[:, sl], state)
            state = tuple(s.detach() for s in state)
            loss = lstm.masked_l2(pred, y[:, sl], m[:, sl])
            opt.zero_grad()
            loss.backward()
            opt.step()
        if dev.type == "cuda":
            torch.cuda.synchronize()
        rates.append(B * T * a.windows / (time.perf_counter() - t0))
    rate = statistics.median(rates[1:])   # the first run warms up
    print(f"device {dev}, torch {torch.__version__}, {torch.get_num_threads()} threads")
    print(f"training: LSTM {p.hidden} cells, batch {B} × bptt {T}: {rate:,.0f} sequence steps/s "
          f"(median of {a.repeats}); one epoch of a 17-hour corpus (6.1 M steps at 100 Hz) ≈ {6.12e6 / rate / 60:.1f} min")
    with tempfile.TemporaryDirectory() as folder:
        basis = fit_pca(np.random.default_rng(0).normal(size=(200, 36)), 20)
        save_model(folder, model.cpu(), dict(model="lstm", delay=p.delay, hidden=p.hidden, layers=p.layers,
                                             n_features=28, n_components=20, feature_rate=100.0, params=as_dict(p)),
                   np.zeros(28, np.float32), np.ones(28, np.float32), basis, dict(lip_points=list(range(18)), iod_px=72.0))
        for seconds in (10.0, 60.0):
            audio = (np.random.default_rng(1).normal(size=int(seconds * 16000)) * 0.1).astype(np.float32)
            predict_mouth(audio, folder, 30.0, device=a.device)
            times = []
            for _ in range(a.repeats):
                t0 = time.perf_counter()
                predict_mouth(audio, folder, 30.0, device=a.device)
                times.append(time.perf_counter() - t0)
            ms = statistics.median(times) * 1000
            print(f"inference on {seconds:.0f} s of audio: {ms:.1f} ms ({ms / seconds:.2f} ms per second of audio, "
                  f"{seconds * 1000 / ms:.0f}× real time)")


if __name__ == "__main__":
    main()
