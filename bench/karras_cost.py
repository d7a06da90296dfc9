"""Compute cost of the Karras et al. network (Table 1) on this machine, before training it.

Prints multiply–adds per frame, forward ms per frame (one frame, and batched 100), forward +
backward + Adam step ms per training sample (batch 100 = 50 temporal pairs, with the training
noise), the implied time of the paper's 500 epochs over GRID s1's ~54 000 training frames, and
the autocorrelation features' cost. Medians of --repeats runs.

    python bench/karras_cost.py [--repeats 5] [--outputs 84]
"""
from __future__ import annotations

import argparse
import statistics
import time

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import numpy as np
import torch


from pipeline.models.karras_network import KarrasNetwork, multiply_adds
from pipeline.audio.speech_autocorrelation import autocorrelation_features


def timed(fn, repeats: int) -> float:
    fn()
    out = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t)
    return statistics.median(out)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--outputs", type=int, default=84, help="target dimension (84 = 42 lower-face points × 2)")
    ap.add_argument("--frames", type=int, default=54000, help="training frames per epoch")
    a = ap.parse_args()
    torch.manual_seed(0)
    m = KarrasNetwork(a.outputs)
    print(f"threads {torch.get_num_threads()}; {sum(p.numel() for p in m.parameters()) / 1e6:.2f} M weights, "
          f"{multiply_adds(m) / 1e6:.1f} M multiply-adds per frame")
    x1, e1 = torch.randn(1, 1, 64, 32), torch.zeros(1, 16)
    xb, eb = torch.randn(100, 1, 64, 32), torch.zeros(100, 16)
    with torch.no_grad():
        single = timed(lambda: m(x1, e1), a.repeats)
        batch = timed(lambda: m(xb, eb), a.repeats)
    opt = torch.optim.Adam(m.parameters(), 1e-3)
    y = torch.randn(100, a.outputs)

    def step():
        opt.zero_grad()
        loss = ((m(xb, eb, noise=True) - y) ** 2).mean()
        loss.backward()
        opt.step()
    train = timed(step, a.repeats)
    audio = np.random.default_rng(0).standard_normal(16000 * 10)
    feats = timed(lambda: autocorrelation_features(audio, np.arange(250) / 25.0), a.repeats)
    print(f"forward: {1000 * single:.2f} ms for one frame, {1000 * batch / 100:.3f} ms per frame batched 100 "
          f"(paper, GPU: 6.3 / 0.2 ms)")
    per_sample = train / 100
    hours = per_sample * a.frames * 500 / 3600
    print(f"training step (batch 100, noise, Adam): {1000 * per_sample:.2f} ms per sample → "
          f"{per_sample * a.frames / 60:.1f} min per epoch of {a.frames} frames, {hours:.1f} h for 500 epochs")
    print(f"autocorrelation features: {1000 * feats / 250:.3f} ms per output frame ({1000 * feats / 10:.1f} ms per "
          "second of audio at 25 fps)")


if __name__ == "__main__":
    main()
