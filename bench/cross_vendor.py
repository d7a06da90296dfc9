"""Do the numeric kernels behind the stored outputs give the same bits on another CPU vendor?

    python bench/cross_vendor.py [--cpu native EPYC-Rome-v1 Haswell-v4]   (needs Debian's qemu-user)

The committed dvc.lock is made on an Intel CPU; a fresh clone on an AMD CPU must reproduce it. Each
probe runs one kernel family the stages' outputs go through, on fixed inputs, and hashes the result:

- ``whisper``: the Whisper encoder (CTranslate2 on Intel MKL) on 8 s of synthetic voiced audio, as the
  whisper stage stores it (float16);
- ``lstm``: three Adam steps of the train stage's network (PyTorch LSTM + linear, 384 → 60 → 20);
- ``karras``: two Adam steps of Karras et al.'s network (PyTorch convolutions, oneDNN);
- ``opencv``: Gaussian blur, affine warp, remap, resize and colour conversion of one image;
- ``numpy``: matrix product, SVD, least squares (OpenBLAS) and transcendental loops;
- ``x264``: ten frames through the project's H.264 writer.

``native`` runs on this machine's CPU; any other name runs the probes in ``qemu-x86_64 -cpu NAME``
(user-mode emulation: the libraries see that CPU's CPUID — its vendor, instruction sets and caches —
and pick their kernels by it, as on the real machine). An emulated Intel CPU is the control: it shows
that emulation itself does not change a bit. One thing emulation does not copy: ``rsqrtps`` and ``rcpps``
(approximations whose last bits differ between CPU makers) come out exact under qemu, so a kernel that
uses them shows as a difference here too — rightly, since its bits differ between makers. Every probe is single-process (no dask workers), so
the whole of it runs on the emulated CPU. Writes results/cross_vendor.json and docs/cross_vendor.md.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path


PROBES = ("whisper", "lstm", "karras", "opencv", "numpy", "x264")
# the emulated CPUs have no AVX-512, while /proc/cpuinfo (which qemu-user does not emulate) shows the
# host's: the cap must not name AVX-512 groups there (pipeline.simd_level.cap_for of an AVX2 CPU)
EMULATED_ENV = {"NPY_DISABLE_CPU_FEATURES": "", "OPENCV_CPU_DISABLE": ""}


def digest(*arrays) -> str:
    h = hashlib.sha256()
    for a in arrays:
        h.update(a.tobytes() if hasattr(a, "tobytes") else bytes(a))
    return h.hexdigest()[:16]


def voiced_audio(seconds: float = 8.0, rate: int = 16000):
    """(S,) float32: harmonics of a gliding 90–180 Hz pitch under a syllable-rate envelope, plus noise."""
    import numpy as np
    rng = np.random.default_rng(0)
    t = np.arange(int(seconds * rate)) / rate
    f0 = 135 + 45 * np.sin(2 * np.pi * 0.3 * t)
    phase = 2 * np.pi * np.cumsum(f0) / rate
    voice = sum(np.sin(k * phase) / k for k in range(1, 20))
    envelope = 0.5 + 0.5 * np.sin(2 * np.pi * 4 * t) ** 2
    return (0.1 * envelope * voice + 0.01 * rng.standard_normal(len(t))).astype(np.float32)


def probe(name: str) -> str:
    import numpy as np
    rng = np.random.default_rng(1)
    if name == "whisper":
        from pipeline.audio.whisper_encoder import whisper_features
        return digest(whisper_features(voiced_audio()).astype(np.float16))
    if name in ("lstm", "karras"):
        import torch
        torch.manual_seed(0)
        if name == "lstm":
            from pipeline.models.delayed_lstm import DelayedLSTM
            net, steps = DelayedLSTM(384, 60, 20), 3
            x, y = torch.randn(20, 100, 384), torch.randn(20, 100, 20)
            args = (x,)
        else:
            from pipeline.models.karras_network import KarrasNetwork
            net, steps = KarrasNetwork(20), 2
            x, e, y = torch.randn(16, 1, 64, 32), torch.randn(16, 16), torch.randn(16, 20)
            args = (x, e)
        from pipeline.models.adam import adam
        opt = adam(net.parameters(), 1e-3)
        for _ in range(steps):
            out = net(*args)
            out = out[0] if isinstance(out, tuple) else out
            loss = ((out - y) ** 2).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
        return digest(*(p.detach().numpy() for p in net.parameters()))
    if name == "opencv":
        import cv2
        img = rng.integers(0, 256, (288, 360, 3), np.uint8)
        img = cv2.GaussianBlur(img, (0, 0), 2.0)
        m = cv2.getRotationMatrix2D((180, 144), 7.5, 1.13)
        grid = np.mgrid[0:288, 0:360].astype(np.float32)
        map_x, map_y = grid[1] + 3 * np.sin(grid[0] / 17), grid[0] + 2 * np.cos(grid[1] / 23)
        return digest(img, cv2.warpAffine(img, m, (360, 288), flags=cv2.INTER_LINEAR),
                      cv2.remap(img, map_x, map_y, cv2.INTER_LINEAR),
                      cv2.resize(img, (173, 131), interpolation=cv2.INTER_AREA),
                      cv2.cvtColor(img, cv2.COLOR_BGR2Lab), cv2.GaussianBlur(img.astype(np.float32), (0, 0), 4.5))
    if name == "numpy":
        a, b = rng.standard_normal((300, 200)), rng.standard_normal((200, 150))
        u, s, vt = np.linalg.svd(a, full_matrices=False)
        sol = np.linalg.lstsq(a, rng.standard_normal(300), rcond=None)[0]
        v = rng.standard_normal(100_000)
        f = v.astype(np.float32)
        return digest(a @ b, s, np.abs(u), sol, np.exp(v), np.log1p(np.abs(v)), np.sin(v), np.exp(f), np.tanh(f), np.sort(v))
    if name == "x264":
        import tempfile
        from pipeline.io.video_writer import write_video
        frames = [np.roll(rng.integers(0, 256, (128, 160, 3), np.uint8), 4 * i, 1) for i in range(10)]
        with tempfile.TemporaryDirectory() as tmp:
            write_video(Path(tmp) / "probe.mp4", frames, 25.0)
            import av
            with av.open(str(Path(tmp) / "probe.mp4")) as f:
                return digest(*(bytes(p) for p in f.demux(f.streams.video[0]) if p.size))
    raise SystemExit(f"unknown probe {name!r}; known: {', '.join(PROBES)}")


def start_on(cpu: str, probes: list[str]) -> subprocess.Popen:
    """A child process running ``probes`` on ``cpu`` ('native' or a qemu model); its last line is JSON."""
    cmd = [sys.executable, __file__, "--probe", *probes]
    env = dict(os.environ)
    if cpu != "native":
        qemu = shutil.which("qemu-x86_64")
        if qemu is None:
            raise SystemExit(f"--cpu {cpu}: qemu-x86_64 is not installed (apt-get install -y qemu-user)")
        cmd, env = [qemu, "-cpu", cpu] + cmd, {**env, **EMULATED_ENV}
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def result_of(cpu: str, child: subprocess.Popen, t0: float) -> dict:
    """{probe: hash, ..., "seconds": s} of a finished child."""
    out, err = child.communicate()
    if child.returncode:
        raise SystemExit(f"probes on {cpu} failed:\n{err[-2000:]}")
    return dict(json.loads(out.strip().splitlines()[-1]), seconds=round(time.perf_counter() - t0, 1))


def page(summary: dict) -> str:
    cpus = list(summary["cpus"])
    lines = ["# The same bits on another CPU vendor", "",
             f"Written by `python bench/cross_vendor.py` (commit {summary['commit']}, {summary['date']}, "
             f"{summary['machine']}). Each cell is a probe's hash on that CPU; **bold** where it differs from "
             f"`native`. Emulated CPUs run under `qemu-x86_64 -cpu NAME` (the libraries dispatch by its CPUID). "
             "What each probe runs: the bench's docstring.", "",
             "| probe | " + " | ".join(cpus) + " |", "|---|" + "---|" * len(cpus)]
    for p in summary["probes"]:
        ref = summary["cpus"]["native"].get(p)
        cells = [summary["cpus"][c][p] if summary["cpus"][c][p] == ref else f"**{summary['cpus'][c][p]}**" for c in cpus]
        lines.append(f"| {p} | " + " | ".join(cells) + " |")
    lines.append("| seconds (all CPUs side by side) | " + " | ".join(str(summary["cpus"][c]["seconds"]) for c in cpus) + " |")
    same = [c for c in cpus if all(summary["cpus"][c][p] == summary["cpus"]["native"][p] for p in summary["probes"])]
    lines += ["", f"Identical to `native` on every probe: {', '.join(same)}."]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cpu", nargs="+", default=["native", "EPYC-Rome-v1", "Haswell-v4"],
                    help="'native' and qemu CPU models (qemu-x86_64 -cpu help lists them)")
    ap.add_argument("--probes", nargs="+", default=list(PROBES), choices=PROBES)
    ap.add_argument("--probe", nargs="+", help=argparse.SUPPRESS)     # the child: run these probes here, print JSON
    a = ap.parse_args()
    if a.probe:
        import pipeline  # noqa: F401  (before NumPy: the SIMD cap, as every stage has it)
        print(json.dumps({p: probe(p) for p in a.probe}))
        return
    if "native" not in a.cpu:
        a.cpu.insert(0, "native")
    from bench.bench_results import publish, stamp
    t0 = time.perf_counter()
    children = {cpu: start_on(cpu, a.probes) for cpu in a.cpu}     # emulation is slow: all at once
    cpus = {}
    for cpu, child in children.items():
        cpus[cpu] = result_of(cpu, child, t0)
        print(cpu, cpus[cpu], flush=True)
    summary = dict(stamp(), probes=a.probes, cpus=cpus)
    publish("cross_vendor", summary, page(summary))


if __name__ == "__main__":
    main()
