"""Voice Puppetry cost on this machine: synthesis ms per second of audio, and the last training run.

Synthesis = the shared predict path of a ``models/brand`` folder on whole audio files: voice
features (LPC, RASTA-PLP, formants, band energies, or MFCC) → vocal-HMM state log-likelihoods
→ Viterbi → the closed-form Eq. 5 trajectory at 25 fps → mouth PCA. Each phase is timed
separately; figures are medians over --repeats runs per file, in ms per second of audio (far
below 1000 = faster than real time). Training time is read from ``logs/train_brand.timing.json``
(written by the stage; seconds per phase).

    python bench/brand.py [--params runs/grid_s1/params.yaml] [--repeats 5] [AUDIO ...]
"""
from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

from pipeline.models import voice_puppet  # noqa: E402
from pipeline.audio import vocal_features  # noqa: E402
from pipeline.models.model_folder import load_puppet  # noqa: E402
from pipeline.models.mouth_prediction import load_audio  # noqa: E402
from pipeline.params import load_params  # noqa: E402

DEFAULT_AUDIO = sorted((ROOT.parent / "shared/data/hdtf").glob("*.wav"))[:2] + \
    sorted((ROOT.parent / "shared/data/grid_s1/video").glob("*.mp4"))[:3]


def time_once(samples, puppet, fps=25.0) -> dict:
    cfg = puppet["config"]
    t = [time.perf_counter()]
    n = int(np.floor(len(samples) / 16000 * cfg["rate"] + 0.5))
    a = vocal_features.vocal_features(samples, cfg["features"], cfg["rate"], n)
    t.append(time.perf_counter())
    ll = voice_puppet.gaussian_loglik((a - puppet["vocal_mean"]) / puppet["vocal_std"], puppet["vocal_means"],
                                      puppet["vocal_covars"])
    w = voice_puppet.state_weights(ll, puppet, "viterbi")
    t.append(time.perf_counter())
    voice_puppet.trajectory_at(w, puppet, fps, int(np.floor(len(samples) / 16000 * fps + 0.5)))
    t.append(time.perf_counter())
    sec = len(samples) / 16000
    return dict(features=(t[1] - t[0]) * 1000 / sec, decode=(t[2] - t[1]) * 1000 / sec,
                trajectory=(t[3] - t[2]) * 1000 / sec, total=(t[3] - t[0]) * 1000 / sec)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("audio", nargs="*", type=Path, default=DEFAULT_AUDIO)
    ap.add_argument("--params", default=str(ROOT / "params.yaml"))
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args()
    p = load_params(a.params).brand
    puppet = load_puppet(p.out)
    print(f"model {p.out}: {len(puppet['startprob'])} states, voice features {puppet['config']['features']}, "
          f"face {puppet['face_means'].shape[1] // 2}-D + velocity")
    time_once(load_audio(a.audio[0]), puppet)                       # warm-up (numba JIT of librosa.lpc)
    rows = []
    for path in a.audio:
        samples = load_audio(path)
        runs = [time_once(samples, puppet) for _ in range(a.repeats)]
        med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
        rows.append(med)
        print(f"{path.name:<28} {len(samples) / 16000:5.1f} s audio: " +
              ", ".join(f"{k} {v:6.1f}" for k, v in med.items()) + "  ms per s of audio")
    print("median over files: " + ", ".join(f"{k} {statistics.median(r[k] for r in rows):.1f}" for k in rows[0])
          + " ms per second of audio (one process, 2-core machine)")
    timing = ROOT / "logs/train_brand.timing.json"
    if timing.exists():
        print(f"last training run ({timing.relative_to(ROOT)}): {json.dumps(json.loads(timing.read_text()))}")


if __name__ == "__main__":
    main()
