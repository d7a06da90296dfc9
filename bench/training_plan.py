"""Expected training time of every family for a corpus of a given length, on this machine.

Each training budget is in optimizer steps (``pipeline.models.training_budget``), so its time is
steps × seconds per step, and a step's cost depends on the batch, not on the corpus. This bench
measures the seconds per step of the real training loops on random inputs of the right shapes
(the LSTM at the batch a corpus of that length gets, Karras et al. at its minibatch of 100), and
Voice Puppetry's seconds per EM iteration (a pass over all frames: it grows with the corpus), then
prints the plan of every training stage for the params file's budgets (median of --repeats).

    python bench/training_plan.py [--params params.yaml] [--seconds 51 2700] [--repeats 3]
"""
from __future__ import annotations

import argparse
import dataclasses
import logging
import statistics
import time
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]

from pipeline.models.training_budget import format_duration  # noqa: E402
from pipeline.params import load_params  # noqa: E402

logging.disable(logging.INFO)


def lstm_seconds_per_step(p, seconds: float, n_in: int = 28, steps: int = 12) -> float:
    """One LSTM optimizer step on a corpus of ``seconds`` of audio (its batch: ≤ batch_size streams)."""
    from stages.train import lstm
    frames = int(seconds * 100)
    rng = np.random.default_rng(0)
    seqs = [(rng.normal(size=(min(frames, 30000), n_in)).astype(np.float32),
             rng.normal(size=(min(frames, 30000), 20)).astype(np.float32), np.ones(min(frames, 30000), bool))
            for _ in range(max(1, frames // 30000))]
    q = dataclasses.replace(p, steps=steps, val_every=steps)
    t0 = time.perf_counter()
    lstm.train(seqs, [], q, p.delay, "cpu")
    return (time.perf_counter() - t0) / steps


def karras_seconds_per_step(k, steps: int = 6) -> float:
    """One Karras et al. optimizer step (``batch`` samples; on-the-fly autocorrelation included)."""
    from stages.train_karras.fit import FitConfig, fit
    rng = np.random.default_rng(0)
    videos = [dict(name=f"v{i}", split="train", samples=0.1 * rng.standard_normal(16000 * 10),
                   frame_time=np.arange(250) / 25.0, ok=np.ones(250, bool),
                   targets=rng.normal(size=(250, 84)).astype(np.float32)) for i in range(4)]
    cfg = FitConfig(steps=steps, val_every=steps, batch=k.batch)
    fit(videos, cfg, progress=False)                     # warm-up
    t0 = time.perf_counter()
    fit(videos, cfg, progress=False)
    return (time.perf_counter() - t0) / steps


def brand_seconds_per_iteration(b, seconds: float) -> float:
    """One EM iteration of the entropic HMM over ``seconds`` of face frames at ``brand.rate``."""
    from stages.train_brand import entropic
    n = int(seconds * b.rate)
    rng = np.random.default_rng(0)
    X = rng.normal(size=(n, 2 * b.face_dims))
    lengths = np.full(max(1, n // 75), 75)
    lengths[-1] += n - lengths.sum()
    t0 = time.perf_counter()
    entropic.fit(X, lengths, b.states, "entropic", 2, 0.0, b.reg, 0.0, b.trim, 0, b.prior_weight, desc="bench")
    return (time.perf_counter() - t0) / 2


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--params", default=str(ROOT / "params.yaml"))
    ap.add_argument("--seconds", type=float, nargs="+", default=[51.0, 2700.0],
                    help="training footage (s): the synthetic speaker's 51 s, GRID s1's 45 min")
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    p = load_params(a.params)
    torch.set_num_threads(max(1, torch.get_num_threads()))
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads; budgets from {a.params}")
    karras = statistics.median(karras_seconds_per_step(p.karras) for _ in range(a.repeats))
    for seconds in a.seconds:
        lstm_s = statistics.median(lstm_seconds_per_step(p.train, seconds) for _ in range(a.repeats))
        brand_s = statistics.median(brand_seconds_per_iteration(p.brand, seconds) for _ in range(a.repeats))
        runs = 2 if p.train.baselines else 1
        rows = [("train (LSTM" + (" + delay-0 baseline)" if runs == 2 else ")"), runs * p.train.steps, lstm_s),
                (f"delay_sweep ({len(p.delay_sweep.delays)} delays)", len(p.delay_sweep.delays) * p.delay_sweep.steps,
                 lstm_s),
                ("train_karras", p.karras.steps, karras),
                ("train_brand (EM iterations, at most)", (2 if p.brand.baseline else 1) * p.brand.iterations, brand_s)]
        print(f"\n{seconds:,.0f} s of training footage:")
        total = 0.0
        for name, n, per in rows:
            total += n * per
            print(f"  {name:40s} {n:>7,} × {per:7.3f} s = {format_duration(n * per)}")
        print(f"  {'all training (sequential, at most)':40s} {'':>19} {format_duration(total)}")


if __name__ == "__main__":
    main()
