"""Teach a model's LSTM to hear through the live front end: distillation onto causal encoder states (issue 48).

    python bench/live_student.py [--model models/base] [--ahead 0.2 --past 1.5 --hop 0.2 --pad 2] [--steps 1500]

The live front end (``pipeline.audio.streaming_features``) gives the Whisper encoder 2 s windows with a
short look-ahead; the model's LSTM was trained on states of 10-s windows, and states of short windows
differ (their normalised distance is about half their spread), which costs lip sync whatever the
look-ahead (``bench/live_lookahead.py``). No video is needed to undo that: the model itself, run on the
offline front end, is the teacher. For speech that neither the evaluation people (GRID s4, the
strangers, Macron, Lieu, HDTF) use and whose licence lets it ship — GRID s1 (CC BY 4.0, the base's own
corpus, one clip in ``--every``, default 3) and the Obama clips (public domain) — the student (a copy of the LSTM) reads the causal
states and learns the teacher's hidden states and output (MSE on both; only the LSTM learns, the read-out stays the model's, so
a person's read-out of the hidden states still fits), for ``--steps`` Adam steps on 2-s sequences; a tenth of the clips is held out
and the best held-out step kept.

Writes ``live.pt`` (the student's LSTM weights) and ``live.json`` (the stream settings it was taught with, the
data, the held-out losses) into the model folder; ``StreamingMouth`` uses them when the settings match
and the model folder's MANIFEST (if any) is rewritten with their hashes.
"""
from __future__ import annotations

import argparse
import copy
import json
import time
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import numpy as np
import torch

from pipeline.audio.streaming_features import STREAM

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"


def speech_files(every: int = 3) -> list[Path]:
    """Every ``every``-th GRID s1 clip and the Obama clips."""
    grid = sorted((DATA / "grid_s1" / "video").glob("*.mp4"))[::every]
    return grid + sorted((DATA / "obama").glob("obama_0*.mp4"))


def pairs(files, model, config, arrays, stream: dict):
    """Per file: (causal features, teacher hidden states, teacher outputs), normalised features."""
    from pipeline.audio import audio_features, front_ends
    from pipeline.audio.streaming_features import causal_features
    from pipeline.io import media
    mu, sd = arrays["feature_mean"], arrays["feature_std"]
    out = []
    for k, f in enumerate(files):
        raw, _ = media.read_audio(str(f), 16000)
        if len(raw) < 8000:
            continue
        off = front_ends.frame_features(audio_features.rms_normalize(raw), config["features"], config.get("encoder"))
        cau = causal_features(raw, config["features"], config.get("encoder"), piece_s=stream["hop_s"], **stream)
        n = min(len(off), len(cau))
        x_off = torch.from_numpy(((off[:n] - mu) / sd).astype(np.float32))[None]
        with torch.no_grad():
            h, _ = model.lstm(x_off)
            y = model.out(h)
        out.append((((cau[:n] - mu) / sd).astype(np.float32), h[0].numpy(), y[0].numpy()))
        if k % 25 == 0:
            print(f"  features {k + 1}/{len(files)}", flush=True)
    return out


def batches(data, length: int, size: int, rng):
    """Random windows (size, length, ·) of the sequences (shorter ones padded by repetition)."""
    xs, hs, ys = [], [], []
    for i in rng.integers(0, len(data), size):
        x, h, y = data[i]
        a = int(rng.integers(0, max(1, len(x) - length)))
        idx = np.arange(a, a + length) % len(x)
        xs.append(x[idx]), hs.append(h[idx]), ys.append(y[idx])
    return (torch.from_numpy(np.stack(v)) for v in (xs, hs, ys))


def loss_of(student, x, h, y):
    hs, _ = student.lstm(x)
    return torch.mean((hs - h) ** 2) + torch.mean((student.out(hs) - y) ** 2)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", type=Path, default=ROOT / "models" / "base")
    ap.add_argument("--past", type=float, default=STREAM["past_s"])
    ap.add_argument("--ahead", type=float, default=STREAM["ahead_s"])
    ap.add_argument("--hop", type=float, default=STREAM["hop_s"])
    ap.add_argument("--pad", type=float, default=STREAM["pad_s"])
    ap.add_argument("--steps", type=int, default=1500)
    ap.add_argument("--every", type=int, default=3, help="teach on every N-th GRID s1 clip (and the Obama clips)")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    from pipeline.models.model_folder import load_model
    torch.manual_seed(a.seed)
    rng = np.random.default_rng(a.seed)
    model, config, arrays = load_model(a.model, torch.device("cpu"))
    model.eval()
    if getattr(model, "skip", None) is not None:
        raise SystemExit(f"{a.model}: a model with a skip read-out (a personalized encoder read-out) is not distilled")
    stream = dict(past_s=a.past, ahead_s=a.ahead, hop_s=a.hop, pad_s=a.pad)
    files = speech_files(a.every)
    t0 = time.perf_counter()
    data = pairs(files, model, config, arrays, stream)
    held = data[::10]
    train = [d for i, d in enumerate(data) if i % 10]
    print(f"{len(data)} files ({sum(len(d[0]) for d in data) / 100 / 60:.1f} min) in {time.perf_counter() - t0:.0f} s; "
          f"{len(held)} held out", flush=True)
    student = copy.deepcopy(model)
    student.train()
    opt = torch.optim.Adam(student.lstm.parameters(), lr=1e-3)     # the read-out stays the model's

    def held_loss():
        with torch.no_grad():
            return float(np.mean([loss_of(student, *(torch.from_numpy(v)[None] for v in d)).item() for d in held]))

    start = best = held_loss()
    best_state, best_step, curve = copy.deepcopy(student.lstm.state_dict()), 0, [(0, start)]
    for step in range(1, a.steps + 1):
        x, h, y = batches(train, 200, 32, rng)
        loss = loss_of(student, x, h, y)
        opt.zero_grad()
        loss.backward()
        opt.step()
        if step % 100 == 0:
            v = held_loss()
            curve.append((step, v))
            print(f"step {step}: train {loss.item():.4f}, held out {v:.4f}", flush=True)
            if v < best:
                best, best_state, best_step = v, copy.deepcopy(student.lstm.state_dict()), step
    torch.save(best_state, a.model / "live.pt")
    record = dict(stream=stream, files=len(data), minutes=sum(len(d[0]) for d in data) / 6000, held_out=len(held),
                  held_out_loss_before=start, held_out_loss=best, step_kept=best_step, steps=a.steps, curve=curve,
                  teacher=a.model.name, data=f"GRID s1 (one clip in {a.every}; CC BY 4.0), Obama weekly-address "
                  "clips (public domain)", seconds=time.perf_counter() - t0)
    (a.model / "live.json").write_text(json.dumps(record, indent=1) + "\n")
    manifest = a.model / "MANIFEST.json"
    if manifest.is_file():
        from pipeline.models.base_model import write_manifest
        m = json.loads(manifest.read_text())
        m.update(live_recipe="python bench/live_student.py", live_data=record["data"])
        write_manifest(a.model, {k: v for k, v in m.items() if k != "files"})
    print(f"held-out loss {start:.4f} → {best:.4f} (step {best_step}); wrote {a.model / 'live.pt'}")


if __name__ == "__main__":
    main()
