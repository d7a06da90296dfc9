"""Where is a person's lip sync lost? One row per person, one column per step (issue 32).

    python bench/person_diagnosis.py lieu=../shared/data/lieu/lieu_60s.mp4 \
        macron=../shared/data/macron/macron_50s.mp4 'obama=../shared/data/obama/obama_0*.mp4' \
        hdtf=../shared/data/hdtf/WDA_KatieHill_000.mp4 'grid_s4=../shared/data/grid_s4/*' \
        [--base models/base] [--out results/person_diagnosis.json]

For each person (``NAME=VIDEOS``: a file, a glob or a comma-separated list; a bare path is named
by its stem) it runs ``lipsynth personalize`` (the shipped base unless ``--base``) into
``runs/diagnosis/NAME`` and measures, on the footage ``personalize`` held out:

1. ``floor`` — the held-out clips re-encoded at CRF 18, scored by ``../shared/tools/lipsync_yardstick.py``:
   what the yardstick itself can see of this face (err ratio, opening correlation);
2. ``speech_share`` — the share of the person's mouth variance that follows speech: per mouth PCA
   coordinate, the magnitude-squared coherence with the speech-band envelope averaged over 1–8 Hz
   (the syllable rate), weighted by the coordinate's variance (all the person's footage);
3. ``in_store`` — personalize's held-out figures of each candidate (base, readout, fine_tune) and
   which was kept (ratio to the mean shape, opening correlation at the frame rate of the store);
4. ``speak`` — ``lipsynth speak --no-retime`` with the kept model, each held-out clip its own audio
   and target, scored by the yardstick (what a user gets);
5. ``oracle`` — the same render path with the clip's own tracked lips (``bench/speak_oracle.py``):
   the floor of the renderer;
6. ``stages`` — what the model knows against what `speak` shows (``bench/speak_stages.py``), self-replay
   (the held-out clip's words into itself) and cross-clip (into the training segment before it): the model's
   predicted opening against dlib's on the footage that said the words (``lipsynth predict-mouth``'s lip
   points), the candidates' and the re-tracked output's.

Writes the JSON (with commit, date and machine), a plot beside it and a markdown table
(``--table``, default ``docs/person_diagnosis.md``).
"""
from __future__ import annotations

import argparse
import datetime
import glob
import json
import platform
import subprocess
import sys
import time
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
YARDSTICK = ROOT.parent / "shared" / "tools" / "lipsync_yardstick.py"
BAND_HZ = (1.0, 8.0)
TAG = ""                 # --tag: suffix of the scored files of this run (e.g. the code version measured)
CANDIDATES = ("base", "readout", "encoder_readout", "average", "retrieval", "fine_tune")


def videos_of(spec: str) -> tuple[str, list[str]]:
    name, eq, rest = spec.partition("=")
    if not eq:
        name, rest = Path(spec).stem, spec
    paths = []
    for part in rest.split(","):
        hits = sorted(glob.glob(part))
        paths += [h for h in hits if Path(h).suffix.lower() in (".mp4", ".mpg", ".mov", ".mkv", ".avi")] or []
    if not paths:
        raise SystemExit(f"{spec}: no videos")
    return name, paths


def segment_seconds(paths: list[str]) -> float:
    """10-s segments, shorter when one short clip is all there is (HDTF's 8 s: 2.5 s)."""
    from pipeline.io import media
    from pipeline.io.segments import video_seconds
    total = sum(video_seconds(media.probe(p)) for p in paths)
    return 10.0 if total >= 30 or len(paths) >= 5 else round(max(2.5, total / 3.2), 1)


def speech_share(ingest_path: str, pca_path: str) -> dict:
    """Variance-weighted coherence of the mouth PCA coordinates with the speech-band envelope."""
    from scipy.signal import coherence
    from pipeline.io.store import open_group
    from pipeline.measures.lipsync_measures import audio_envelope
    src, pca = open_group(ingest_path), open_group(pca_path)
    coeffs, valid = np.asarray(pca["coeffs"][...], np.float64), np.asarray(pca["valid"][...], bool)
    audio, rate = src["audio"], int(src.attrs["sample_rate"])
    num, den, per_coord = 0.0, 0.0, []
    for v in pca.attrs["videos"]:
        if v.get("excluded") or v["n_frames"] < 64:
            continue
        f0, n = v["first_frame"], v["n_frames"]
        y, ok = coeffs[f0:f0 + n], valid[f0:f0 + n]
        if ok.mean() < 0.8:
            continue
        t = np.arange(n)
        y = np.stack([np.interp(t, t[ok], y[ok, k]) for k in range(y.shape[1])], 1)
        env = audio_envelope(np.asarray(audio[v["first_sample"]:v["first_sample"] + v["n_samples"]], np.float32) / 32767.0,
                             v["fps"], n, rate)
        good = np.isfinite(env)
        env, y = env[good], y[good]
        nper = min(64, len(env) // 2)
        coh = []
        for k in range(y.shape[1]):
            f, c = coherence(env - env.mean(), y[:, k] - y[:, k].mean(), fs=v["fps"], nperseg=nper)
            band = (f >= BAND_HZ[0]) & (f <= min(BAND_HZ[1], v["fps"] / 2))
            coh.append(float(c[band].mean()))
        var = y.var(0)
        num += float((var * np.array(coh)).sum()) * len(y)
        den += float(var.sum()) * len(y)
        per_coord.append(np.array(coh))
    return dict(share=num / den if den else float("nan"),
                first_coords=[round(float(c), 3) for c in np.mean(per_coord, 0)[:5]] if per_coord else [])


def held_out(ingest_path: str) -> list[str]:
    from pipeline.io.store import open_group
    return [str((ROOT / v["path"]).resolve()) for v in open_group(ingest_path).attrs["videos"] if v["split"] == "val"]


def yardstick(make: str, clips: list[str], json_path: Path) -> dict:
    r = subprocess.run([sys.executable, str(YARDSTICK), "--make", make, "--json", str(json_path), *clips],
                       cwd=ROOT, capture_output=True, text=True)
    if not json_path.is_file():
        raise SystemExit(f"yardstick wrote nothing (rc {r.returncode}): {r.stderr.strip()[-500:]}")
    return yardstick_summary(json.loads(json_path.read_text()))


def yardstick_summary(res: dict) -> dict:
    s = res["summary"]
    return {k: s.get(k) for k in ("err_ratio", "corr", "corr_best", "within_1_frame", "sharp", "flicker", "ok", "clips")} | \
        {"errors": [r["error"] for r in res["rows"] if "error" in r]}


def diagnose(name: str, paths: list[str], base: str | None, work_root: Path, steps: int, reuse: bool) -> dict:
    py = sys.executable
    work, model = work_root / name, work_root / name / "model"
    seg = segment_seconds(paths)
    t0 = time.perf_counter()
    if reuse and (work / "w" / "summary.json").is_file() and model.is_dir():
        print(f"== {name}: personalized model found in {work}, reused", flush=True)
        return measure(name, paths, work, model, seg, json.loads((work / "w" / "summary.json").read_text())["seconds"], reuse)
    cmd = [py, "-m", "lipsynth.cli", "personalize", *paths, "--out", str(model), "--work", str(work / "w"),
           "--segment-seconds", str(seg), "--steps", str(steps)] + (["--base", base] if base else [])
    work.mkdir(parents=True, exist_ok=True)
    r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    (work / "personalize.log").write_text(r.stdout + r.stderr)
    if r.returncode:
        return dict(name=name, videos=paths, error=(r.stderr.strip().splitlines() or ["?"])[-1])
    print(r.stdout.strip(), flush=True)
    return measure(name, paths, work, model, seg, round(time.perf_counter() - t0, 1), reuse)


def measure(name: str, paths: list[str], work: Path, model: Path, seg: float, seconds: float, reuse: bool) -> dict:
    py = sys.executable
    summary = json.loads((work / "w" / "summary.json").read_text())
    store = work / "w" / "store"
    clips = held_out(str(store / "ingest.zarr"))
    row = dict(name=name, videos=[str(p) for p in paths], segment_seconds=seg, held_out=[Path(c).name for c in clips],
               personalize_seconds=seconds, tracker_floor_corr=summary.get("tracker_floor_corr"), chosen=summary["chosen"],
               in_store={k: dict(ratio=round(v["ratio_to_mean_shape"], 3), corr=round(v["median_opening_corr"], 3))
                         for k, v in (summary["candidates"] or {}).items()},
               speech_share=speech_share(str(store / "ingest.zarr"), str(store / "pca.zarr")))
    cache = work / "speak_cache"
    rows = {
        "floor": f"{py} bench/yardstick_floor.py reencode {{target}} {{out}} --crf 18",
        "speak": f"{py} -m lipsynth.cli speak --model {model} --audio {{audio}} --target {{target}} --out {{out}} "
                 f"--no-retime --cache {cache}",
        "oracle": f"{py} bench/speak_oracle.py --model {model} --audio {{audio}} --target {{target}} --out {{out}} "
                  f"--cache {cache}",
    }
    for key, make in rows.items():
        done = work / f"{key}{TAG if key != 'floor' else ''}.json"
        if reuse and done.is_file() and json.loads(done.read_text())["summary"].get("ok"):
            row[key] = yardstick_summary(json.loads(done.read_text()))
        else:
            row[key] = yardstick(make, clips, done)
        print(f"{name} {key}: {row[key]}", flush=True)
    row["stages"] = speak_stages(model, work, store, clips[0], cache, reuse)
    return row


def speak_stages(model: Path, work: Path, store: Path, held: str, cache: Path, reuse: bool) -> dict:
    """``bench/speak_stages.py`` on the first held-out clip: its own words into itself (self) and into the
    training segment before it (cross)."""
    from bench import speak_stages as ss
    from pipeline.io.store import open_group
    done = work / f"stages{TAG}.json"
    if reuse and done.is_file():
        return json.loads(done.read_text())
    train = {v["name"]: str((ROOT / v["path"]).resolve()) for v in open_group(str(store / "ingest.zarr")).attrs["videos"]
             if v["split"] == "train"}
    before = [n for n in train if n < Path(held).stem] or list(train)
    face = train[max(before)]
    res = {kind: ss.run(str(model), held, target, held, str(ROOT / "params.yaml"), [], cache)
           for kind, target in (("self", held), ("cross", face))}
    done.write_text(json.dumps(res, indent=1))
    print(f"stages: {json.dumps({k: v['stages'] for k, v in res.items()})}", flush=True)
    return res


def fmt(x, spec=".2f"):
    return "–" if x is None or (isinstance(x, float) and not np.isfinite(x)) else format(x, spec)


def stage_cells(r: dict) -> str:
    st = r.get("stages")
    if not st:
        return "– | – | – |"
    lb = lambda x: f"{fmt(x['corr'])} / {fmt(x['corr_best'])}"
    s, c = st["self"]["stages"], st["cross"]["stages"]
    return f"{lb(s['model'])} | {lb(s['candidates'])} · {lb(s['output'])} | {lb(c['output'])} |"


def table(rows: list[dict]) -> str:
    lines = ["| person | held out | floor: re-encode ratio / corr | mouth variance following speech | in-store ratio (corr): "
             "base · readout · encoder_readout · average · retrieval · fine_tune | kept | `speak` ratio / corr lag 0 / best | `speak` sharpness / "
             "flicker (yardstick: output ÷ original) | oracle render ratio / corr | model alone: predicted vs tracked, lag 0 / best | "
             "`speak` self-replay: candidates · output, lag 0 / best | `speak` cross-clip: output, lag 0 / best |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['name']} | {r['error']} |  |  |  |  |  |  |  |  |  |  |")
            continue
        st = r["in_store"]
        cands = " · ".join(f"{fmt(st[c]['ratio'])} ({fmt(st[c]['corr'])})" for c in CANDIDATES if c in st)
        sp, orc, fl = r["speak"], r["oracle"], r["floor"]
        lines.append(f"| {r['name']} | {len(r['held_out'])} clip{'s' if len(r['held_out']) != 1 else ''} | {fmt(fl['err_ratio'])} / {fmt(fl['corr'])} | "
                     f"{fmt(r['speech_share']['share'])} | {cands} | {r['chosen']} | "
                     f"{fmt(sp['err_ratio'])} / {fmt(sp['corr'])} / {fmt(sp['corr_best'])} | "
                     f"{fmt(sp['sharp'])} / {fmt(sp['flicker'])} | {fmt(orc['err_ratio'])} / {fmt(orc['corr'])} | " + stage_cells(r))
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    good = [r for r in rows if "error" not in r]
    steps = [("floor", lambda r: r["floor"]["corr"]), ("speech share", lambda r: r["speech_share"]["share"]),
             ("in-store kept", lambda r: r["in_store"][r["chosen"]]["corr"]), ("speak", lambda r: r["speak"]["corr"]),
             ("oracle", lambda r: r["oracle"]["corr"])]
    fig, ax = plt.subplots(figsize=(8, 3.4))
    w = 0.8 / len(steps)
    for i, (label, get) in enumerate(steps):
        ax.bar(np.arange(len(good)) + i * w, [get(r) or 0 for r in good], w, label=label)
    ax.axhline(0.6, color="crimson", ls="--", lw=1, label="goal corr 0.60")
    ax.set_xticks(np.arange(len(good)) + 0.4 - w / 2, [r["name"] for r in good])
    ax.set_ylabel("opening correlation (speech share: coherence)")
    ax.legend(fontsize=7, ncol=3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("people", nargs="+", help="NAME=VIDEOS (a file, glob or comma-separated list) or a video path")
    ap.add_argument("--base", help="the base to personalize from (default: personalize's, the shipped models/base)")
    ap.add_argument("--steps", type=int, default=600, help="personalize --steps (default 600)")
    ap.add_argument("--work", type=Path, default=ROOT / "runs" / "diagnosis")
    ap.add_argument("--reuse", action="store_true", help="keep a person's model and scored rows from an earlier run")
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "person_diagnosis.json")
    ap.add_argument("--table", type=Path, default=ROOT / "docs" / "person_diagnosis.md")
    ap.add_argument("--tag", default="", help="suffix of this run's scored files in the work folder (reuse keeps "
                    "each tag's own)")
    a = ap.parse_args()
    global TAG
    TAG = a.tag
    if not YARDSTICK.is_file():
        raise SystemExit(f"{YARDSTICK}: the yardstick is not there (../shared/tools beside the project)")
    rows = [diagnose(*videos_of(spec), a.base, a.work, a.steps, a.reuse) for spec in a.people]
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(dict(commit=commit, date=datetime.datetime.now().isoformat(timespec="minutes"),
                                     machine=f"{platform.processor() or platform.machine()}, {__import__('os').cpu_count()} cores",
                                     base=a.base or "models/base", rows=rows), indent=1))
    plot(rows, a.out.with_suffix(".png"))
    text = table(rows)
    a.table.parent.mkdir(parents=True, exist_ok=True)
    a.table.write_text(f"<!-- written by bench/person_diagnosis.py at {commit}; do not edit -->\n{text}")
    print(text)
    print(f"wrote {a.out}, {a.out.with_suffix('.png')} and {a.table}")


if __name__ == "__main__":
    main()
