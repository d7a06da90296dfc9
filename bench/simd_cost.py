"""What one set of kernels on every CPU costs: the Whisper encoder and an LSTM training step per MKL branch.

    python bench/simd_cost.py [--repeats 5]

``pipeline/simd_level.py`` holds Intel MKL (the matrix products of CTranslate2's Whisper encoder and of
PyTorch's LSTM) at its vendor-neutral branch (``MKL_CBWR=COMPATIBLE``: SSE2, the only branch Intel
documents as giving the same results on AMD), and CTranslate2 on MKL on every vendor. This times both
workloads in a fresh process per setting — the branch a library reads once, when it loads:

* ``COMPATIBLE`` — what lipsynth runs (the same bytes on Intel and AMD);
* ``AVX2`` — MKL's AVX2 branch (Intel CPUs only; AMD falls back to ``AUTO``), what it ran before;
* ``AUTO`` — MKL's own dispatch, all this CPU offers.

Whisper: ms of encoder time per second of audio (16 s of HDTF speech, the whisper stage's 10-s windows);
LSTM: ms per optimizer step of the train stage's network (60 cells, batch 100, 100 steps of 384-D
features). Medians of ``--repeats`` runs after one warm-up. Writes ``results/simd_cost.json`` (commit,
date, machine) and ``docs/simd_cost.md``.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

from bench.bench_results import publish, stamp

ROOT = Path(__file__).resolve().parents[1]
AUDIO = ROOT.parent / "shared" / "data" / "hdtf" / "RD_Radio31_000.wav"
BRANCHES = ("COMPATIBLE", "AVX2", "AUTO")


def measure(repeats: int) -> dict:
    """In this process (its MKL branch fixed at load): medians of whisper ms per audio second and LSTM ms per step."""
    import numpy as np
    import torch

    from pipeline.audio import whisper_encoder
    from pipeline.io import media
    samples, _ = media.read_audio(AUDIO)          # 16 kHz mono
    rate = 16000
    torch.set_num_threads(1)
    times = []
    for _ in range(repeats + 1):
        t0 = time.perf_counter()
        whisper_encoder.encoder_states(samples, threads=1)
        times.append(time.perf_counter() - t0)
    whisper = 1e3 * statistics.median(times[1:]) / (len(samples) / rate)
    torch.manual_seed(0)
    net = torch.nn.LSTM(384, 60, batch_first=True)
    head = torch.nn.Linear(60, 20)
    opt = torch.optim.Adam([*net.parameters(), *head.parameters()], lr=1e-3)
    x, y = torch.randn(100, 100, 384), torch.randn(100, 100, 20)
    steps = []
    for _ in range(5 * repeats + 1):
        t0 = time.perf_counter()
        opt.zero_grad()
        loss = ((head(net(x)[0]) - y) ** 2).mean()
        loss.backward()
        opt.step()
        steps.append(time.perf_counter() - t0)
    return dict(whisper_ms_per_audio_s=whisper, lstm_ms_per_step=1e3 * statistics.median(steps[1:]),
                mkl_cbwr=os.environ.get("MKL_CBWR", ""), numpy=np.__version__, torch=torch.__version__)


def page(summary: dict) -> str:
    lines = ["<!-- Written by `python bench/simd_cost.py`; do not edit. -->", "# The cost of the same bytes on every CPU", "",
             f"Measured {summary['date']} on commit `{summary['commit']}` ({summary['machine']}) by `bench/simd_cost.py`: "
             "one thread, medians of repeated runs. `COMPATIBLE` is what lipsynth runs on every CPU (`pipeline/"
             "simd_level.py`: Intel MKL's one branch documented to give the same results on Intel and AMD); `AVX2` "
             "MKL's AVX2 branch (Intel only); `AUTO` all this CPU offers. Whisper: encoder ms per second of audio; "
             "LSTM: ms per optimizer step of the train stage's network.", "",
             "| MKL branch | Whisper ms per audio s | LSTM ms per step |", "|---|---|---|"]
    for r in summary["rows"]:
        lines.append(f"| {r['branch']} | {r['whisper_ms_per_audio_s']:.1f} | {r['lstm_ms_per_step']:.1f} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--child", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        print(json.dumps(measure(a.repeats)))
        return
    rows = []
    for branch in BRANCHES:
        env = dict(os.environ, MKL_CBWR=branch)
        r = subprocess.run([sys.executable, __file__, "--child", branch, "--repeats", str(a.repeats)], env=env,
                           capture_output=True, text=True, check=True)
        row = dict(branch=branch, **json.loads(r.stdout.strip().splitlines()[-1]))
        rows.append(row)
        print(json.dumps(row), flush=True)
    summary = dict(stamp(), rows=rows)
    publish("simd_cost", summary, page(summary))

if __name__ == "__main__":
    main()
