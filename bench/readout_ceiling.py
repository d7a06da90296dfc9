"""How far a linear read-out of the Whisper states reaches on the strangers, by training data (issue 47, item 5).

    python bench/readout_ceiling.py [--grid runs/grid3/store] [--people runs/diagnosis]

Where is the strangers' lip sync lost: in the shipped base's LSTM, in its training data (one read speaker),
or in the front end? A ridge regression from context-stacked Whisper tiny.en encoder states (±300 ms at 60-ms
steps, 11 × 384 inputs; ``pipeline.audio.front_ends.frame_features``, as ``speak`` computes them) to the
per-clip standardised inner-lip opening (landmarks 62–66 over the inter-ocular distance) is trained on each
data set below and correlated at lag 0 with each stranger's tracked opening — beside the shipped base's own
prediction (``models/base``):

    grid                 GRID s1 clips (the stores of ``bench/shipped_base.py --every 3``)
    grid+obama           … plus the Obama clips (public domain)
    grid+obama+s4        … plus GRID s4 (another read speaker)
    all_people           … plus Lieu, Macron and the two HDTF people (not shippable: research material)
    natural_people_only  Obama, Lieu and HDTF only
    loo_strangers        the other eight strangers (leave-one-person-out; never shippable)
    all_people+loo       all of the above

The people's stores are those ``bench/person_diagnosis.py`` leaves in ``--people`` (``NAME/w/store``); the
strangers' tracked lips are read from ``bench/strangers.py``'s cache. Writes ``results/readout_ceiling.json``.
"""
from __future__ import annotations

import argparse
import datetime
import json
import subprocess
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import numpy as np

from pipeline.audio import front_ends
from pipeline.io.store import open_group
from pipeline.models.mouth_prediction import load_audio

from bench.strangers import model_corr, video_opening

ROOT = Path(__file__).resolve().parents[1]
ENC = {"window_s": 10.0, "overlap_s": 2.0}
OFFS = np.arange(-30, 31, 6)           # 100 Hz context offsets (±300 ms)
CACHE = ROOT / "runs" / "readout_ceiling"        # encoder states per clip (.npy), made once


def clips_of(landmarks: Path) -> list[dict]:
    """Each video of a landmarks store: its name, file, fps and (T,) tracked opening (NaN where untracked)."""
    g = open_group(str(landmarks))
    out = []
    for v in g.attrs["videos"]:
        if v.get("excluded"):
            continue
        path = Path(v["path"]) if Path(v["path"]).is_absolute() else (ROOT / v["path"]).resolve()
        out.append(dict(name=v["name"], path=str(path), fps=float(v["fps"]), truth=video_opening(g, v)))
    return out


def states(clip: dict) -> np.ndarray:
    """(T100, 384) encoder states of the clip's audio, as ``speak`` computes them (cached per file)."""
    CACHE.mkdir(parents=True, exist_ok=True)
    f = CACHE / f"{Path(clip['path']).stem}.npy"
    if not f.exists():
        np.save(f, front_ends.frame_features(load_audio(clip["path"]), "whisper", ENC))
    return np.load(f)


def design(clip: dict) -> np.ndarray:
    """(T, 11 × 384) the states at each video frame's time and ±OFFS steps around it."""
    x = states(clip)
    idx = np.round(np.arange(len(clip["truth"])) / clip["fps"] * 100).astype(int)
    return np.concatenate([x[np.clip(idx + o, 0, len(x) - 1)] for o in OFFS], 1)


def fit(clips: list[dict], lam: float = 0.3) -> tuple:
    """Ridge (λ · frames on standardised inputs) of each clip's standardised opening on ``design``."""
    xs, ys = [], []
    for c in clips:
        y = c["truth"]
        m = np.isfinite(y)
        xs.append(design(c)[m])
        ys.append((y[m] - y[m].mean()) / (y[m].std() + 1e-9))
    x, y = np.concatenate(xs), np.concatenate(ys)
    mu, sd = x.mean(0), x.std(0) + 1e-6
    xn = (x - mu) / sd
    w = np.linalg.solve(xn.T @ xn + lam * len(xn) * np.eye(xn.shape[1]), xn.T @ y)
    return mu, sd, w, len(x)


def corr(clip: dict, model: tuple) -> float:
    """Lag-0 correlation of the read-out's prediction with the clip's tracked opening."""
    mu, sd, w, _ = model
    pred = ((design(clip) - mu) / sd) @ w
    m = np.isfinite(clip["truth"])
    return float(np.corrcoef(pred[m], clip["truth"][m])[0, 1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--grid", type=Path, default=ROOT / "runs" / "grid3" / "store", help="GRID s1 stores")
    ap.add_argument("--grid-videos", type=Path, default=ROOT.parent / "shared" / "data" / "grid_s1" / "video")
    ap.add_argument("--people", type=Path, default=ROOT / "runs" / "diagnosis", help="NAME/w/store of each person")
    ap.add_argument("--strangers", type=Path, default=ROOT.parent / "shared" / "data" / "strangers")
    ap.add_argument("--cache", type=Path, default=ROOT / "runs" / "strangers" / "cache", help="the strangers' speak cache")
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "readout_ceiling.json")
    a = ap.parse_args()
    strangers = []
    for mp4 in sorted(a.strangers.glob("*.mp4")):
        c = clips_of(sorted(a.cache.glob(f"{mp4.stem}-*/landmarks.zarr"))[-1])[0]
        c["path"] = str(mp4)
        strangers.append(c)
    grid = clips_of(a.grid / "landmarks.zarr")
    for c in grid:                     # the store names the links of ``--every``: read the corpus' own files
        c["path"] = str(a.grid_videos / Path(c["path"]).name)
    people = {p: clips_of(a.people / p / "w" / "store" / "landmarks.zarr")
              for p in ("obama", "grid_s4", "lieu", "macron", "hdtf_aoc", "hdtf_hill")}
    print("clips: grid", len(grid), {k: len(v) for k, v in people.items()}, flush=True)
    rows = {"base_lstm": {c["name"]: model_corr(Path(c["path"]), a.cache, str(ROOT / "models" / "base"))["corr"]
                          for c in strangers}}
    sets = {
        "grid": grid,
        "grid+obama": grid + people["obama"],
        "grid+obama+s4": grid + people["obama"] + people["grid_s4"],
        "all_people": grid + sum(people.values(), []),
        "natural_people_only": people["obama"] + people["lieu"] + people["hdtf_aoc"] + people["hdtf_hill"],
    }
    frames = {}
    for name, clips in sets.items():
        model = fit(clips)
        frames[name] = model[3]
        rows[name] = {c["name"]: corr(c, model) for c in strangers}
    everyone = grid + sum(people.values(), [])
    rows["loo_strangers"], rows["all_people+loo"] = {}, {}
    for i, c in enumerate(strangers):
        others = strangers[:i] + strangers[i + 1:]
        rows["loo_strangers"][c["name"]] = corr(c, fit(others))
        rows["all_people+loo"][c["name"]] = corr(c, fit(everyone + others))
    names = [c["name"] for c in strangers]
    medians = {k: float(np.median([r[n] for n in names])) for k, r in rows.items()}
    print("set".ljust(22), " ".join(n[:9].rjust(9) for n in names), "  median")
    for k, r in rows.items():
        print(k.ljust(22), " ".join(f"{r[n]:9.2f}" for n in names), f"  {medians[k]:.3f}")
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    a.out.write_text(json.dumps(dict(commit=commit, date=datetime.datetime.now().isoformat(timespec="minutes"),
                                     offsets_100hz=OFFS.tolist(), training_frames=frames, medians=medians, rows=rows),
                                indent=1))
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
