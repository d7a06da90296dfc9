"""Which base transfers to people it never met: candidate bases scored on the strangers (issue 47, item 5).

    python bench/base_transfer.py shipped=models/base grid_third=runs/grid3/base_grid/model \
        grid_third+obama=runs/grid3/mix_obama/model [--s4]

For each candidate base (``NAME=MODEL_FOLDER``) and each clip of ``../shared/data/strangers/`` (nine people
talking naturally; none is in any candidate's training data), the model's predicted inner-lip opening for the
clip's own audio is correlated with the clip's tracked opening (``bench/strangers.model_corr``: lag 0 and the
best lag within ±5 frames). This is where the strangers' lip sync is lost today (docs/strangers.md: the render
passes on what the model predicts), and it needs no rendering, so many candidates are cheap to compare.

The choice is judged leave-one-person-out: for each stranger, the candidate with the best median over the
*other* eight is picked and scored on the one left out; the median of those scores is what choosing a base
this way earns on a new person (choosing by the nine medians directly would flatter the winner). ``--s4`` adds
GRID s4's 24 mp4 clips (read speech of another person, known sync) so the read-speech side is seen too.

A clip not yet preprocessed is prepared into ``--cache`` by ``lipsynth prepare`` (the path users run).
Writes ``results/base_transfer.json`` and ``.png``, and ``docs/base_transfer.md`` with the plot's copy beside it.
"""
from __future__ import annotations

import argparse
import datetime
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import numpy as np

from bench.strangers import STRANGERS, model_corr

ROOT = Path(__file__).resolve().parents[1]
GRID_S4 = STRANGERS.parent / "grid_s4"


def prepared(clip: Path, cache: Path) -> None:
    """``lipsynth prepare`` the clip into ``cache`` unless its landmarks are already there."""
    if not sorted(cache.glob(f"{clip.stem}-*/landmarks.zarr")):
        subprocess.run([sys.executable, "-m", "lipsynth.cli", "prepare", str(clip), "--cache", str(cache)],
                       cwd=ROOT, check=True, capture_output=True)


def scores(models: dict[str, str], clips: list[Path], cache: Path) -> dict[str, list[dict]]:
    """{candidate: [model_corr row per clip]} (a row: corr, corr_best, lag)."""
    for clip in clips:
        prepared(clip, cache)
    return {name: [model_corr(clip, cache, folder) for clip in clips] for name, folder in models.items()}


def leave_one_out(table: np.ndarray) -> tuple[list[int], np.ndarray]:
    """(C, N) scores of C candidates on N people → for each person the candidate with the best median over
    the other N − 1, and that candidate's score on the person left out, (N,)."""
    picks, held = [], []
    for i in range(table.shape[1]):
        rest = np.delete(table, i, axis=1)
        pick = int(np.argmax(np.median(rest, axis=1)))
        picks.append(pick)
        held.append(table[pick, i])
    return picks, np.array(held)


def plot(names: list[str], clips: list[str], table: np.ndarray, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(8, 3.4))
    x = np.arange(len(clips))
    w = 0.8 / len(names)
    for k, name in enumerate(names):
        ax.bar(x - 0.4 + w * (k + 0.5), table[k], w, label=f"{name} (median {np.median(table[k]):.2f})")
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xticks(x, clips, rotation=30, ha="right", fontsize=8)
    ax.set_ylabel("predicted vs tracked opening, corr lag 0")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def markdown(result: dict) -> str:
    names, clips = list(result["candidates"]), result["clips"]
    head = "| candidate | " + " | ".join(Path(c).stem for c in clips) + " | median lag 0 | median best lag |"
    lines = [head, "|---" * (len(clips) + 3) + "|"]
    for name in names:
        rows = result["strangers"][name]
        lines.append(f"| {name} | " + " | ".join(f"{r['corr']:.2f}" for r in rows)
                     + f" | **{np.median([r['corr'] for r in rows]):.3f}** | {np.median([r['corr_best'] for r in rows]):.3f} |")
    loo, best = result["leave_one_out"], result["leave_one_out_best_lag"]
    lines.append("| chosen leave-one-person-out, by lag 0 | " + " | ".join(f"{v:.2f} ({names[p]})" for v, p in
                                                                          zip(loo["scores"], loo["picks"]))
                 + f" | **{loo['median']:.3f}** | |")
    lines.append("| chosen leave-one-person-out, by best lag | " + " | ".join(f"{v:.2f} ({names[p]})" for v, p in
                                                                             zip(best["scores"], best["picks"]))
                 + f" | | **{best['median']:.3f}** |")
    lags = {n: [r["lag"] for r in result["strangers"][n]] for n in names}
    lines.append("")
    lines.append("Best lag per stranger (frames; negative: the prediction trails the tracked lips): " + "; ".join(
        f"{n} {lags[n]}" for n in names) + ".")
    text = "\n".join(lines) + "\n"
    if result.get("grid_s4"):
        text += "\nGRID s4 (read speech of another person, 24 clips), median corr lag 0: " + ", ".join(
            f"{n} {np.median([r['corr'] for r in rows]):.3f} (best lag {np.median([r['corr_best'] for r in rows]):.3f})"
            for n, rows in result["grid_s4"].items()) + "\n"
    return text


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("models", nargs="+", metavar="NAME=MODEL_FOLDER", help="candidate bases")
    ap.add_argument("--s4", action="store_true", help="also score GRID s4's clips (read speech)")
    ap.add_argument("--cache", type=Path, default=ROOT / "runs" / "strangers" / "cache")
    ap.add_argument("--s4-cache", type=Path, default=ROOT / "runs" / "s4cache")
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "base_transfer.json")
    ap.add_argument("--table", type=Path, default=ROOT / "docs" / "base_transfer.md")
    a = ap.parse_args()
    models = {}
    for spec in a.models:
        name, _, folder = spec.partition("=")
        if not name or not Path(folder, "config.json").is_file():
            ap.error(f"{spec!r}: write NAME=MODEL_FOLDER (a folder with config.json)")
        models[name] = folder
    clips = sorted(STRANGERS.glob("*.mp4"))
    strangers = scores(models, clips, a.cache)
    table = np.array([[r["corr"] for r in strangers[n]] for n in models])
    picks, held = leave_one_out(table)
    best_picks, best_held = leave_one_out(np.array([[r["corr_best"] for r in strangers[n]] for n in models]))
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT, capture_output=True,
                           text=True).stdout.strip()
    commit += "+changes" if dirty else ""
    result = dict(commit=commit, date=datetime.datetime.now().isoformat(timespec="minutes"), candidates=models,
                  clips=[c.name for c in clips], strangers=strangers,
                  leave_one_out=dict(picks=picks, scores=held.tolist(), median=float(np.median(held))),
                  leave_one_out_best_lag=dict(picks=best_picks, scores=best_held.tolist(),
                                              median=float(np.median(best_held))))
    if a.s4:
        result["grid_s4"] = scores(models, sorted(GRID_S4.glob("*.mp4")), a.s4_cache)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(result, indent=1))
    plot(list(models), [c.stem for c in clips], table, a.out.with_suffix(".png"))
    shutil.copy(a.out.with_suffix(".png"), a.table.with_suffix(".png"))       # the page's copy (mkdocs serves docs/ only)
    text = markdown(result)
    a.table.write_text(f"<!-- written by bench/base_transfer.py at {commit}; do not edit -->\n"
                       "# Which base transfers to strangers\n\n"
                       "Each candidate base's predicted inner-lip opening for a stranger's own audio, correlated with the "
                       "stranger's tracked opening (lag 0), on the nine clips of `../shared/data/strangers/` (no candidate "
                       "saw them). The last row picks, for each stranger, the candidate with the best median over the "
                       f"other eight (leave-one-person-out). Measured at {commit}, {result['date'][:10]}, by "
                       "`python bench/base_transfer.py`; figures in `results/base_transfer.json`.\n\n"
                       f"![candidates per stranger](base_transfer.png)\n\n{text}")
    print(text)
    print(f"wrote {a.out}, {a.out.with_suffix('.png')} and {a.table}")


if __name__ == "__main__":
    main()
