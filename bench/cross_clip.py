"""Dubbing as users do it: another clip's words into a video of the same person, beside self-replay.

    python bench/cross_clip.py [--sets grid_s4 strangers people] [--methods two_band aligned]
        [--pairs 6] [--people runs/diagnosis] [--model models/base] [--set SECTION.KEY=VALUE]

Own-audio measures (the yardstick's Video J setting) put the target's own frame of every sound into the
candidate pool, and ``two_band``'s Viterbi, which favours runs of consecutive source frames, can then replay
the original: they flatter the renderer. Here the words come from another clip of the same person, so no
frame of the target says them. Every run is ``lipsynth speak --audio WORDS --target FACE --no-retime``,
scored by the independent yardstick (``../shared/tools/lipsync_yardstick.py``'s ``compare``: dlib on the
output against the footage that said the words — inner-lip opening correlation at lag 0 and at the best lag
within ±5 frames, mouth error over a static mouth's, sharpness and flicker as original ÷ output).

Sets:

* ``grid_s4`` — GRID speaker 4 (a person the base never met), sorted clips, pair i = clips 2i (words) and
  2i + 1 (face); ``models/base``;
* ``strangers`` — each clip of ``../shared/data/strangers`` of at least 10 s cut in two halves: the second
  half's words into the first half's video, scored against the second half; ``models/base``;
* ``people`` — every personalized person of ``--people`` (``bench/person_diagnosis.py``'s work folder: a
  model and its footage's segments): the held-out segment's words into each of the ``--faces`` training
  segments before it, with the person's own model.

Self-replay (the words' own clip as the face) is measured beside each pair. Writes
``results/cross_clip.json`` (commit, date, machine), ``docs/cross_clip.png`` and ``docs/cross_clip.md``.
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import numpy as np
import yaml

from bench.bench_results import publish, stamp

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
YARDSTICK = ROOT.parent / "shared" / "tools" / "lipsync_yardstick.py"
WORK = ROOT / "bench" / "results" / "cross_clip"
KEYS = ("corr", "corr_best", "err_ratio", "sharp", "flicker")
MIN_HALVES_S = 10.0


def yardstick():
    """The yardstick module (it shares no code with the project: imported from its file)."""
    spec = importlib.util.spec_from_file_location("lipsync_yardstick", YARDSTICK)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def grid_pairs(n: int) -> list[dict]:
    clips = sorted((DATA / "grid_s4").glob("*.mp4"))
    if len(clips) < 2 * n:
        raise SystemExit(f"{DATA / 'grid_s4'}: {len(clips)} clips, {2 * n} needed for {n} pairs")
    return [dict(set="grid_s4", person="grid_s4", words=str(clips[2 * i]), face=str(clips[2 * i + 1]), model=None)
            for i in range(n)]


def stranger_pairs() -> list[dict]:
    from pipeline.io import media
    from pipeline.io.segments import cut_video, video_seconds
    out = []
    for clip in sorted((DATA / "strangers").glob("*.mp4")):
        seconds = video_seconds(media.probe(clip))
        if seconds < MIN_HALVES_S:
            continue
        folder = WORK / "halves" / clip.stem
        halves = sorted(folder.glob("*.mp4")) if folder.is_dir() else []
        if len(halves) != 2:
            halves = cut_video(clip, seconds / 2, folder)
        out.append(dict(set="strangers", person=clip.stem, words=str(halves[1]), face=str(halves[0]), model=None))
    return out


def people_pairs(root: Path, faces: int) -> list[dict]:
    """Each person of a person_diagnosis work folder: the held-out segment's words into each of the ``faces``
    training segments before it, nearest first (the person's model has seen those faces' frames: its
    candidate bank is the person's training footage)."""
    from pipeline.io.store import open_group
    out = []
    for work in sorted(p for p in root.iterdir() if (p / "model").is_dir() and (p / "w" / "store").is_dir()):
        videos = open_group(str(work / "w" / "store" / "ingest.zarr")).attrs["videos"]
        file = lambda v: str((ROOT / v["path"]).resolve())        # the store names its videos from the project root
        val = [v for v in videos if v["split"] == "val"]
        train = [v for v in videos if v["split"] == "train"]
        if not val or not train:
            continue
        words = val[0]
        before = sorted((v for v in train if v["name"] < words["name"]), key=lambda v: v["name"]) or train
        for face in before[::-1][:faces]:
            out.append(dict(set="people", person=work.name, words=file(words), face=file(face), model=str(work / "model")))
    return out


def speak(model: str, words: str, face: str, out: Path, params: Path) -> str | None:
    """Run ``lipsynth speak``; returns its last error line, or None."""
    r = subprocess.run([sys.executable, "-m", "lipsynth.cli", "speak", "--model", model, "--audio", words, "--target",
                        face, "--out", str(out), "--no-retime", "--params", str(params), "--cache", str(WORK / "cache")],
                       cwd=ROOT, capture_output=True, text=True)
    if r.returncode and not out.is_file():
        return (r.stderr.strip().splitlines() or [f"rc {r.returncode}"])[-1]
    return None


def score(ys, words: str, out: Path) -> dict:
    r = ys.compare(words, str(out))
    if "error" in r:
        return r
    return dict(r, err_ratio=r["mouth_err"] / max(r["static_err"], 1e-9))


def medians(rows: list[dict]) -> dict:
    good = [r for r in rows if "error" not in r]
    return {k: float(np.median([r[k] for r in good])) if good else float("nan") for k in KEYS} | \
        {"n": len(good), "failed": len(rows) - len(good)}


def page(summary: dict) -> str:
    s = summary
    lines = ["<!-- Written by `python bench/cross_clip.py`; do not edit. -->", "# Dubbing: another clip's words into the target", "",
             f"Measured {s['date']} on commit `{s['commit']}` ({s['machine']}) by `bench/cross_clip.py`"
             + (f", params.yaml with {', '.join(s['settings'])}" if s.get("settings") else "") + ". "
             "Every row is `lipsynth speak --audio WORDS --target FACE --no-retime` scored by the independent yardstick "
             "(`../shared/tools/lipsync_yardstick.py`: dlib on the output against the footage that said the words). "
             "**Cross-clip**: the words of another clip of the same person, so no frame of the face says them — what a "
             "user does. **Self-replay**: the words' own clip as the face (the paper's Video J), beside it. Sets: GRID s4 "
             "(a person the base never met; clip 2i's words into clip 2i + 1), the strangers of at least 10 s (the second "
             "half's words into the first half), personalized people (their held-out part's words into the training parts "
             "before it, with their own model). Medians over the pairs; sharpness and flicker are output ÷ original "
             "(1 = as the real mouth). Mouth error, sharpness and flicker are read in the words' footage's mouth box: "
             "they compare like with like where both clips frame the face alike (the halves, a person's parts), not on "
             "GRID s4, whose clips place the head differently.", "",
             "| set | method | pairs | cross-clip corr lag 0 / best | self-replay corr lag 0 / best | cross-clip mouth error / static | sharpness | flicker |",
             "|---|---|---|---|---|---|---|---|"]
    for key, m in s["medians"].items():
        st, method = key.split("/")
        c, r = m["cross"], m["self"]
        lines.append(f"| {st} | {method} | {c['n']}{' (%d failed)' % c['failed'] if c['failed'] else ''} | "
                     f"{c['corr']:.2f} / {c['corr_best']:.2f} | {r['corr']:.2f} / {r['corr_best']:.2f} | {c['err_ratio']:.2f} | "
                     f"{c['sharp']:.2f} | {c['flicker']:.2f} |")
    lines += ["", "![cross-clip and self-replay opening correlation per set and method](cross_clip.png)", "",
              "Per pair (cross-clip corr lag 0 / best):", ""]
    for r in s["rows"]:
        c = r["cross"]
        got = f"{c['corr']:.2f} / {c['corr_best']:.2f}" if "error" not in c else c["error"]
        lines.append(f"- {r['set']} {r['method']}: {Path(r['words']).stem} → {Path(r['face']).stem}: {got}")
    return "\n".join(lines)


def plot(summary: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    keys = list(summary["medians"])
    fig, ax = plt.subplots(figsize=(max(6, 1.1 * len(keys)), 3.4))
    x = np.arange(len(keys))
    for i, (kind, label) in enumerate((("cross", "cross-clip, lag 0"), ("self", "self-replay, lag 0"))):
        ax.bar(x + 0.4 * i, [summary["medians"][k][kind]["corr"] for k in keys], 0.4, label=label)
    ax.set_xticks(x + 0.2, [k.replace("/", "\n") for k in keys], fontsize=8)
    ax.set_ylabel("opening correlation (yardstick)")
    ax.axhline(0, color="k", lw=0.5)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sets", nargs="*", default=["grid_s4", "strangers", "people"], choices=["grid_s4", "strangers", "people"])
    ap.add_argument("--pairs", type=int, default=6, help="GRID s4 pairs (default 6)")
    ap.add_argument("--methods", nargs="*", default=["auto", "two_band", "aligned"],
                    choices=["auto", "median", "aligned", "two_band", "warped"], help="synthesize.detail values compared")
    ap.add_argument("--model", default=str(ROOT / "models" / "base"), help="the model of the grid_s4 and strangers sets")
    ap.add_argument("--people", type=Path, default=ROOT / "runs" / "diagnosis",
                    help="bench/person_diagnosis.py's work folder (personalized models and their footage)")
    ap.add_argument("--people-methods", nargs="*", default=["auto"], help="the methods run on the people set "
                    "(default: auto, what users get; each person's speak runs are the slowest)")
    ap.add_argument("--faces", type=int, default=2, help="people: training segments each held-out part's words go into")
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="override a params.yaml key for every method (repeatable)")
    ap.add_argument("--no-self", action="store_true", help="cross-clip only (half the runs)")
    ap.add_argument("--reuse", action="store_true", help="score an output MP4 already in bench/results/cross_clip "
                    "instead of making it again (same code and params only)")
    ap.add_argument("--dry", action="store_true", help="print the rows only; write no results or page")
    a = ap.parse_args()
    if not YARDSTICK.is_file():
        raise SystemExit(f"{YARDSTICK}: the yardstick is not there (../shared/tools beside the project)")
    ys = yardstick()
    WORK.mkdir(parents=True, exist_ok=True)
    pairs = (grid_pairs(a.pairs) if "grid_s4" in a.sets else []) + (stranger_pairs() if "strangers" in a.sets else []) \
        + (people_pairs(a.people, a.faces) if "people" in a.sets and a.people.is_dir() else [])
    base = yaml.safe_load((ROOT / "params.yaml").read_text())
    for item in a.set:
        key, _, value = item.partition("=")
        section, _, name = key.partition(".")
        base[section] = dict(base[section], **{name: yaml.safe_load(value)})
    rows = []
    for method in a.methods:
        params = WORK / f"params_{method}.yaml"
        params.write_text(yaml.safe_dump(dict(base, synthesize=dict(base["synthesize"], detail=method)), sort_keys=False))
        for pair in pairs:
            if pair["set"] == "people" and method not in a.people_methods:
                continue
            row = dict(pair, method=method)
            for kind, face in (("cross", pair["face"]), ("self", pair["words"])):
                if kind == "self" and a.no_self:
                    continue
                out = WORK / f"{pair['set']}_{Path(pair['words']).stem}_into_{Path(face).stem}_{method}.mp4"
                err = None if a.reuse and out.is_file() else speak(pair["model"] or a.model, pair["words"], face, out, params)
                row[kind] = dict(error=err) if err else score(ys, pair["words"], out)
            rows.append(row)
            print(json.dumps({k: row[k] for k in ("set", "person", "method")} |
                             {k: {m: row[k].get(m) for m in KEYS + ("error",) if m in row[k]} for k in ("cross", "self") if k in row}),
                  flush=True)
    sets = [s for s in ("grid_s4", "strangers", "people") if any(r["set"] == s for r in rows)]
    meds = {f"{s}/{m}": {kind: medians([r[kind] for r in rows if r["set"] == s and r["method"] == m and kind in r])
                         for kind in ("cross", "self")} for s in sets for m in a.methods
            if any(r["set"] == s and r["method"] == m for r in rows)}
    print(json.dumps(meds, indent=1))
    if a.dry:
        return
    summary = dict(stamp(), model=str(Path(a.model).resolve().relative_to(ROOT)) if Path(a.model).resolve().is_relative_to(ROOT)
                   else a.model, settings=a.set, methods=a.methods, medians=meds, rows=rows)
    plot(summary, ROOT / "docs" / "cross_clip.png")
    publish("cross_clip", summary, page(summary))


if __name__ == "__main__":
    main()
