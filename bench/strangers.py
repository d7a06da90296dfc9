"""Lip sync on people no model here has met: the strangers dev set through `lipsynth speak` (issue 47).

    python bench/strangers.py [CLIP ...] [--model models/base] [--out results/strangers.json]

Each clip (default: every video of ``../shared/data/strangers/``) gets its own audio through
``lipsynth speak --no-retime`` into itself (the Obama paper's Video J setting), with
``--report`` so the self-check's fallbacks are known, and is scored by the independent
yardstick (``../shared/tools/lipsync_yardstick.py``: dlib on the output against the original):
err ratio, opening correlation at lag 0 and at the best lag within ±5 frames, sharpness.

A clip where most frames fell back to the untouched target is scored too, but the yardstick
then measures the original, not lipsynth: the table shows the share of frames with lip sync
made beside every figure, and the summary counts only clips made on ≥ 90 % of their frames.

Writes the JSON (commit, date, machine), a plot beside it and a markdown table (``--table``).
"""
from __future__ import annotations

import argparse
import datetime
import importlib.util
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
YARDSTICK = ROOT.parent / "shared" / "tools" / "lipsync_yardstick.py"
STRANGERS = ROOT.parent / "shared" / "data" / "strangers"
MADE_AT_LEAST = 0.9          # a clip measures lipsynth when lip sync was made on this share of its frames


def yardstick_module():
    spec = importlib.util.spec_from_file_location("lipsync_yardstick", YARDSTICK)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def made_share(report: dict | None) -> float | None:
    """Share of output frames where lip sync was made (not the self-check's fallback, not unposed)."""
    check = (report or {}).get("self_check")
    if not check or not check.get("frames"):
        return None
    return 1.0 - (check["fallen_back"] + check.get("not_posed", 0)) / check["frames"]


def run_clip(clip: Path, model: str, work: Path, cache: Path, params: str | None) -> dict:
    out, rep = work / f"{clip.stem}.mp4", work / f"{clip.stem}.report.json"
    for f in (out, rep):
        f.unlink(missing_ok=True)
    cmd = [sys.executable, "-m", "lipsynth.cli", "speak", "--audio", str(clip), "--target", str(clip), "--out",
           str(out), "--no-retime", "--model", model, "--cache", str(cache), "--report", str(rep)]
    cmd += ["--params", params] if params else []
    t0 = time.perf_counter()
    r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    row = dict(clip=clip.name, rc=r.returncode, seconds=round(time.perf_counter() - t0, 1))
    errors = [ln for ln in r.stderr.splitlines() if ln.startswith("lipsynth: error:")]
    warnings = [ln.split(" WARNING: ", 1)[1] for ln in r.stderr.splitlines() if " WARNING: " in ln]
    if errors:
        row["message"] = errors[-1]
    row["warnings"] = warnings
    report = json.loads(rep.read_text()) if rep.is_file() else None
    row["made_share"] = made_share(report)
    if report:
        row["fit"] = report.get("fit")
        row["self_check"] = report.get("self_check")
    (work / f"{clip.stem}.log").write_text(r.stderr)
    return row


def score(rows: list[dict], clips: list[Path], work: Path) -> None:
    ys = yardstick_module()
    for row, clip in zip(rows, clips):
        out = work / f"{clip.stem}.mp4"
        if out.is_file() and "yardstick" not in row:
            row["yardstick"] = ys.compare(str(clip), str(out))


def tracked_opening(clip: Path, cache: Path) -> tuple[np.ndarray, float] | None:
    """(T,) inner-lip opening (landmarks 62–66) over the inter-ocular distance of the clip's cached target
    landmarks (NaN where untracked), and its fps; None when the clip was never preprocessed into ``cache``."""
    from pipeline.io.store import open_group
    found = sorted(cache.glob(f"{clip.stem}-*/landmarks.zarr"))
    if not found:
        return None
    g = open_group(str(found[-1]))
    v = g.attrs["videos"][0]
    return video_opening(g, v), float(v["fps"])


def video_opening(g, v: dict) -> np.ndarray:
    """(T,) inner-lip opening (landmarks 62–66) over the inter-ocular distance of video ``v`` (an entry of the
    landmarks group ``g``'s ``videos``), NaN where untracked."""
    sl = slice(v["first_frame"], v["first_frame"] + v["n_frames"])
    lm, ok = np.asarray(g["landmarks"][sl], np.float64), np.asarray(g["valid"][sl])
    with np.errstate(invalid="ignore"):
        opening = np.linalg.norm(lm[:, 62] - lm[:, 66], axis=1) / np.linalg.norm(lm[:, 36] - lm[:, 45], axis=1)
    return np.where(ok, opening, np.nan)


def model_corr(clip: Path, cache: Path, model: str) -> dict | None:
    """Where the signal goes before rendering: the model's predicted inner-lip opening (its lip points,
    62–66) against the clip's own tracked opening (``tracked_opening``), correlation at lag 0 and the best
    lag within ±5 frames."""
    from pipeline.measures.lipsync_measures import best_lag
    from pipeline.models.mouth_prediction import load_audio, predict_mouth
    tracked = tracked_opening(clip, cache)
    if tracked is None:
        return None
    truth, fps = tracked
    lips = predict_mouth(load_audio(str(clip)), model, fps)["lip_points"]      # 18 points: 61–63, 65–67 inner
    pred = np.linalg.norm(lips[:, 13] - lips[:, 16], axis=1)
    n = min(len(truth), len(pred))
    truth, pred = truth[:n], pred[:n]
    both = np.isfinite(truth)
    lag = best_lag(truth, pred)
    x, y = truth[max(lag, 0):n + min(lag, 0)], pred[max(-lag, 0):n + min(-lag, 0)]
    good = np.isfinite(x)
    return dict(corr=float(np.corrcoef(truth[both], pred[both])[0, 1]), corr_best=float(np.corrcoef(x[good], y[good])[0, 1]),
                lag=int(lag))


def summary(rows: list[dict]) -> dict:
    made = [r for r in rows if (r.get("made_share") or 0) >= MADE_AT_LEAST and "error" not in r.get("yardstick", {"error": 1})]
    corr = [r["yardstick"]["corr"] for r in made]
    best = [r["yardstick"]["corr_best"] for r in made]
    ratio = [r["yardstick"]["mouth_err"] / r["yardstick"]["static_err"] for r in made]
    model = [r["model_corr"]["corr"] for r in rows if r.get("model_corr")]
    return dict(clips=len(rows), made=len(made), model_corr=float(np.median(model)) if model else None,
                corr=float(np.median(corr)) if corr else None,
                corr_best=float(np.median(best)) if best else None, corr_min=float(min(corr)) if corr else None,
                err_ratio=float(np.median(ratio)) if ratio else None)


def fmt(x, spec=".2f"):
    return "–" if x is None or (isinstance(x, float) and not np.isfinite(x)) else format(x, spec)


def table(rows: list[dict], summ: dict) -> str:
    lines = ["| clip | lip sync made on | model: predicted vs tracked opening, corr lag 0 / best | `speak`: err ratio | "
             "`speak`: corr lag 0 / best (lag) | sharpness | target 3D fit | exit |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        y = r.get("yardstick") or {}
        fit = r.get("fit") or {}
        ratio = y["mouth_err"] / y["static_err"] if "mouth_err" in y else None
        mc = r.get("model_corr") or {}
        lines.append(f"| {r['clip']} | {fmt(r.get('made_share'), '.0%')} | {fmt(mc.get('corr'))} / {fmt(mc.get('corr_best'))} | "
                     f"{fmt(ratio)} | "
                     f"{fmt(y.get('corr'))} / {fmt(y.get('corr_best'))} ({y.get('offset', '–')}) | {fmt(y.get('sharp'))} | "
                     f"{fit.get('method', '–')}, {fmt(fit.get('reprojection_iod'), '.3f')} × IOD | {r['rc']} |")
    lines.append(f"| **median** of the {summ['made']} of {summ['clips']} clips made on ≥ {MADE_AT_LEAST:.0%} | | "
                 f"{fmt(summ['model_corr'])} | {fmt(summ['err_ratio'])} | {fmt(summ['corr'])} / {fmt(summ['corr_best'])} "
                 f"(min {fmt(summ['corr_min'])}) | | | |")
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    names = [Path(r["clip"]).stem for r in rows]
    y0 = [(r.get("yardstick") or {}).get("corr", 0) or 0 for r in rows]
    yb = [(r.get("yardstick") or {}).get("corr_best", 0) or 0 for r in rows]
    made = [r.get("made_share") or 0 for r in rows]
    x = np.arange(len(rows))
    fig, ax = plt.subplots(figsize=(8, 3.4))
    ax.bar(x - 0.2, y0, 0.4, label="opening corr, lag 0")
    ax.bar(x + 0.2, yb, 0.4, label="best lag (±5)")
    ax.plot(x, made, "kx", label="share of frames with lip sync made")
    ax.axhline(0.5, color="crimson", ls="--", lw=1, label="goal: median 0.50")
    ax.set_xticks(x, names, rotation=30, ha="right", fontsize=8)
    ax.set_ylim(-0.2, 1.05)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("clips", nargs="*", type=Path, help="videos with their own speech (default: the strangers)")
    ap.add_argument("--model", default="models/base", help="model folder (default: the shipped base)")
    ap.add_argument("--params", default=None, help="params file for speak (default: ./params.yaml)")
    ap.add_argument("--work", type=Path, default=ROOT / "runs" / "strangers")
    ap.add_argument("--cache", type=Path, default=None, help="preprocessed targets (default: WORK/cache)")
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "strangers.json")
    ap.add_argument("--reuse", action="store_true", help="keep the speak runs and scores of --out's clips (re-score the model)")
    ap.add_argument("--table", type=Path, default=ROOT / "docs" / "strangers.md")
    a = ap.parse_args()
    for need in (YARDSTICK, STRANGERS):
        if not need.exists():
            raise SystemExit(f"{need}: not there (../shared beside the project)")
    clips = a.clips or sorted(STRANGERS.glob("*.mp4"))
    a.work.mkdir(parents=True, exist_ok=True)
    rows = []
    earlier = {r["clip"]: r for r in json.loads(a.out.read_text())["rows"]} if a.reuse and a.out.is_file() else {}
    for clip in clips:
        if clip.name in earlier and (a.work / f"{clip.name[:-4]}.mp4").is_file():
            rows.append(earlier[clip.name])
            continue
        rows.append(run_clip(clip.resolve(), a.model, a.work, a.cache or a.work / "cache", a.params))
        print(f"{clip.name}: rc {rows[-1]['rc']}, made on {fmt(rows[-1]['made_share'], '.0%')} "
              f"({rows[-1]['seconds']} s) {rows[-1].get('message', '')}", flush=True)
    score(rows, clips, a.work)
    for row, clip in zip(rows, clips):
        row["model_corr"] = model_corr(clip.resolve(), a.cache or a.work / "cache", a.model)
    summ = summary(rows)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    dirty = bool(subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT, capture_output=True,
                                text=True).stdout.strip())
    stamp = commit + ("+changes" if dirty else "")
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(dict(commit=stamp, date=datetime.datetime.now().isoformat(timespec="minutes"),
                                     machine=f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores",
                                     model=a.model, summary=summ, rows=rows), indent=1, default=str))
    plot(rows, a.out.with_suffix(".png"))
    text = table(rows, summ)
    a.table.parent.mkdir(parents=True, exist_ok=True)
    a.table.write_text(f"<!-- written by bench/strangers.py at {stamp} (model {a.model}); do not edit -->\n"
                       f"# Strangers: lip sync on people no model has met\n\n"
                       f"Each clip of `../shared/data/strangers/` (nine people talking naturally; portrait phone video "
                       f"and small faces among them) gets its own audio through `lipsynth speak --no-retime --model "
                       f"{a.model}` into itself, scored by the independent yardstick (`../shared/tools/"
                       f"lipsync_yardstick.py`: dlib on the output against the original). *Lip sync made on* is the "
                       f"share of output frames that are not the untouched target (`speak --report`). Measured at "
                       f"{stamp}, {datetime.date.today().isoformat()}, by `python bench/strangers.py`; the figures "
                       f"are in `results/strangers.json`.\n\n{text}")
    print(text)
    print(f"wrote {a.out}, {a.out.with_suffix('.png')} and {a.table}")


if __name__ == "__main__":
    main()
