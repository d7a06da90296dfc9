"""What the live front end's look-ahead costs in lip sync (issue 48): the look-ahead curve.

    python bench/live_lookahead.py [--ahead 0 0.1 0.2 0.3 0.5] [--past 1.5] [--hop 0.2] [--pad 2] [--model models/base]

For every clip of GRID speaker 4 (read speech, held out of the base) and of the strangers (natural
speech), the model's predicted inner-lip opening (lip points 62–66) is correlated at lag 0 with the
clip's own tracked opening (``bench/strangers.py``'s ``tracked_opening`` of the cached targets ``lipsynth speak``
made for ``bench/strangers.py`` and ``bench/person_diagnosis.py``), once for the offline front end (``predict_mouth``: the whole
file) and once per look-ahead for the causal one (``pipeline.models.streaming_mouth``: audio pushed in
20-ms pieces), with the model's own LSTM and — where the model folder has one taught with those stream
settings (``bench/live_student.py``) — with its live LSTM. Writes ``results/live_lookahead.json``, the plot
``docs/live_lookahead.png`` and the page ``docs/live_lookahead.md``.
"""
from __future__ import annotations

import argparse
import datetime
import json
import subprocess
import time
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import numpy as np

from pipeline.audio.streaming_features import STREAM

ROOT = Path(__file__).resolve().parents[1]
from bench.live import cpu_name  # noqa: E402  (bench/live.py: the CPU's model name)
from bench.strangers import tracked_opening  # noqa: E402  (bench/strangers.py: the clip's tracked opening)

DATA = ROOT.parent / "shared" / "data"
GROUPS = {"grid_s4": (DATA / "grid_s4", ROOT / "runs" / "s4cache"),
          "strangers": (DATA / "strangers", ROOT / "runs" / "strangers" / "cache")}


def corr(truth: np.ndarray, lips: np.ndarray) -> float:
    pred = np.linalg.norm(lips[:, 13] - lips[:, 16], axis=1)
    n = min(len(truth), len(pred))
    ok = np.isfinite(truth[:n])
    return float(np.corrcoef(truth[:n][ok], pred[:n][ok])[0, 1])


def taught(model: str, stream: dict) -> bool:
    """Has the model folder a live LSTM taught with these stream settings?"""
    f = Path(model) / "live.json"
    return f.is_file() and all(abs(json.loads(f.read_text())["stream"][k] - v) < 1e-9 for k, v in stream.items())


def page(result: dict) -> str:
    aheads = list(next(iter(result["groups"].values()))["causal"])
    lines = ["# The live front end's look-ahead", "",
             f"Written by `python bench/live_lookahead.py` ({result['date']}, commit {result['commit']}, "
             f"{result['machine']}). Median over each group's clips of the correlation, at lag 0, between the model's "
             f"predicted inner-lip opening and the clip's tracked opening (`{result['model']}`; live windows: "
             f"{result['past_s']} s before, hop {result['hop_s']} s, padded to {result['pad_s']} s).", "",
             "Each causal column is the live front end with the model's own LSTM; where the model folder has a live "
             "LSTM taught for that look-ahead (`bench/live_student.py`), the arrow gives it.", "",
             "| clips | offline front end | " + " | ".join(f"causal, look-ahead {a} s" for a in aheads) + " |",
             "|---|---|" + "---|" * len(aheads)]
    for name, g in result["groups"].items():
        cells = []
        for a in aheads:
            cell = f"{g['causal'][a]:.3f}"
            if a in g.get("live", {}):
                cell += f" → **{g['live'][a]:.3f}** with the live LSTM"
            cells.append(cell)
        lines.append(f"| {name} ({g['clips']}) | {g['offline']:.3f} | " + " | ".join(cells) + " |")
    lines += ["", "The same, as means over the clips (a median of nine short clips moves with one clip):", "",
              "| clips | offline front end | " + " | ".join(f"look-ahead {a} s" for a in aheads) + " | live LSTM |",
              "|---|---|" + "---|" * (len(aheads) + 1)]
    for name, g in result["groups"].items():
        m = g["mean"]
        live = ", ".join(f"{m[k]:.3f} ({k[5:]} s)" for k in m if k.startswith("live ")) or "—"
        lines.append(f"| {name} | {m['offline']:.3f} | " + " | ".join(f"{m[a]:.3f}" for a in aheads) + f" | {live} |")
    lines += ["", "![look-ahead curve](live_lookahead.png)", ""]
    return "\n".join(lines)


def plot(result: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 3.6))
    for name, g in result["groups"].items():
        xs = [float(a) for a in g["causal"]]
        line, = ax.plot(xs, [g["causal"][a] for a in g["causal"]], "o-", label=f"{name}: causal")
        ax.axhline(g["offline"], color=line.get_color(), ls="--", lw=1, label=f"{name}: offline front end")
        for a, v in g.get("live", {}).items():
            ax.plot([float(a)], [v], "*", ms=12, color=line.get_color(), label=f"{name}: live LSTM")
    ax.set_xlabel("look-ahead (s)")
    ax.set_ylabel("median opening corr, lag 0")
    ax.set_title(f"live front end: past {result['past_s']} s, hop {result['hop_s']} s, pad {result['pad_s']} s")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ahead", type=float, nargs="+", default=[0.0, 0.1, 0.2, 0.3, 0.5])
    ap.add_argument("--past", type=float, default=STREAM["past_s"])
    ap.add_argument("--hop", type=float, default=STREAM["hop_s"])
    ap.add_argument("--pad", type=float, default=STREAM["pad_s"])
    ap.add_argument("--model", default="models/base")
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "live_lookahead.json")
    a = ap.parse_args()
    from pipeline.io import media
    from pipeline.models.mouth_prediction import load_audio, predict_mouth
    from pipeline.models.streaming_mouth import stream_mouth
    result = dict(model=a.model, past_s=a.past, hop_s=a.hop, pad_s=a.pad, groups={}, clips={},
                  commit=subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                                        text=True).stdout.strip(),
                  date=datetime.date.today().isoformat(), machine=cpu_name())
    for name, (folder, cache) in GROUPS.items():
        per_clip = {}
        for clip in sorted(p for p in folder.iterdir() if p.suffix in (".mp4", ".mpg", ".mov")):
            tracked = tracked_opening(clip, cache)
            if tracked is None:
                print(f"{clip.name}: no cached target in {cache} (run bench/strangers.py or speak on it): skipped")
                continue
            truth, fps = tracked
            raw, _ = media.read_audio(str(clip), 16000)
            row = dict(offline=corr(truth, predict_mouth(load_audio(str(clip)), a.model, fps)["lip_points"]))
            t0 = time.perf_counter()
            for ahead in a.ahead:
                row[str(ahead)] = corr(truth, stream_mouth(raw, a.model, fps, a.past, ahead, a.hop, a.pad,
                                                           use_student=False))
                if taught(a.model, dict(past_s=a.past, ahead_s=ahead, hop_s=a.hop, pad_s=a.pad)):
                    row[f"live {ahead}"] = corr(truth, stream_mouth(raw, a.model, fps, a.past, ahead, a.hop, a.pad))
            row["stream_seconds_per_audio_second"] = (time.perf_counter() - t0) / len(a.ahead) / (len(raw) / 16000)
            per_clip[clip.name] = row
            print(name, clip.name, " ".join(f"{k} {v:.3f}" for k, v in row.items()), flush=True)
        result["clips"][name] = per_clip
        result["groups"][name] = dict(
            clips=len(per_clip), offline=float(np.median([r["offline"] for r in per_clip.values()])),
            mean={k: float(np.mean([r[k] for r in per_clip.values()])) for k in next(iter(per_clip.values()))
                  if k != "stream_seconds_per_audio_second"},
            causal={str(ah): float(np.median([r[str(ah)] for r in per_clip.values()])) for ah in a.ahead},
            live={k[5:]: float(np.median([r[k] for r in per_clip.values()])) for k in next(iter(per_clip.values()))
                  if k.startswith("live ")})
        print(name, json.dumps(result["groups"][name]), flush=True)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(result, indent=1) + "\n")
    plot(result, ROOT / "docs" / "live_lookahead.png")
    (ROOT / "docs" / "live_lookahead.md").write_text(page(result))
    print(f"wrote {a.out}, docs/live_lookahead.png and docs/live_lookahead.md")


if __name__ == "__main__":
    main()
