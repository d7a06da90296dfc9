"""Speed of audio → video (synthesize + composite), ms/frame per phase, at GRID size, 720p, 1080p and 4K.

    python bench/synthesize.py --repeats 3                       # the AVX2 row (lipsynth's default everywhere)
    LIPSYNTH_SIMD=native python bench/synthesize.py --repeats 3  # on an AVX-512 CPU: the AVX-512 row

Writes results/synthesize_speed.json: per CPU feature level (AVX-512 or AVX2, numpy's
dispatch), the per-phase medians with commit, date and machine; and docs/synthesis_speed.md.

The path ``lipsynth speak`` runs, with the shipped base model (``--model``) and 32 s of radio
speech (../shared/data/hdtf), re-timing on. GRID: the GRID s1 clip ``GRID_CLIP`` (the model's
speaker: the corpus 3D face and the model's candidate bank; the 3 s target is extended by
ping-pong). 720p: ``obama_08.mp4`` (another person: its own 3D face and mouths; 448 px crop,
192 px texture). 1080p: the same clip upscaled to 1920×1080 (bicubic, once, into
bench/results/synthesize; same crop and texture sizes — the face covers 2.25× the pixels). 1080p native:
the same footage with crop and texture as ``auto`` sizes them for a 1080-line face (the texture follows the
face, up to ``frontalize.max_texture_size``). 4K native: the clip upscaled to 3840×2160, sized by ``auto`` likewise.
Preprocessing of the target is not timed (it is cached in bench/results/cache); model loading
and mouth prediction are (in "prediction").

Phases: prediction (audio → MFCC → LSTM → shapes; includes torch's first-call set-up),
retiming, candidate_pool (reading the pool's textures), candidate_search, weighted_median,
teeth, decode (target frames), retime_flow (half-way frames for repeats), target_geometry (per target
frame, cached: layer masks, colour statistics, the ray map of render-back), flow (colour match +
jaw-correction optical flow), render_back, blend, check (the self-check: dlib re-reads every
output mouth), encode. Phase figures are thread time per
frame (texture synthesis, then compositing, each run 2 threads, so they add up to more than the
wall time); "total" is wall time. Medians over repeats; the machine is noisy. The paper: 0.45
s/frame on one core.
"""
from __future__ import annotations

import argparse
import copy
import dataclasses
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

import pipeline  # noqa: E402,F401  (first: it sets the SIMD level every library reads when it loads)
import numpy as np  # noqa: E402
from lipsynth import speak  # noqa: E402
from pipeline.params import load_params  # noqa: E402
from pipeline.io.runner import setup_logging  # noqa: E402

SHARED = ROOT.parent / "shared" / "data"
SIZES = ("grid", "720p", "1080p", "1080p native", "4K native")
GRID_CLIP = "bbaf2n.mp4"      # a GRID s1 clip: the base model's speaker (its candidate bank joins the pool)
PHASES = ["prediction", "retiming", "candidate_pool", "candidate_search", "weighted_median", "teeth", "detail",
          "decode", "retime_flow", "target_geometry", "flow", "render_back", "blend", "check", "encode"]


def long_speech(out: Path, seconds: float | None = None) -> Path:
    """The four 8 s radio-speech WAVs of ../shared/data/hdtf joined: 32 s, so fixed costs
    (model load, reading the pool) weigh as little as in real use; or their first ``seconds``."""
    import wave
    if out.exists():
        return out
    frames, params = [], None
    for f in sorted((SHARED / "hdtf").glob("RD_*.wav")):
        with wave.open(str(f)) as w:
            params = params or w.getparams()
            frames.append(w.readframes(w.getnframes()))
    data = b"".join(frames)
    if seconds is not None:
        data = data[:int(seconds * params.framerate) * params.sampwidth * params.nchannels]
    with wave.open(str(out), "wb") as w:
        w.setparams(params)
        w.writeframes(data)
    return out


def upscaled(video: Path, out: Path, size: tuple[int, int]) -> Path:
    """``video`` resized to ``size`` = (width, height) (bicubic), with its audio, written once."""
    import cv2
    from pipeline.io import media
    if out.exists():
        return out
    audio, _ = media.read_audio(video, 48000)
    tmp = out.with_name(out.stem + ".tmp.mp4")
    media.write_video(tmp, (cv2.resize(rgb, size, interpolation=cv2.INTER_CUBIC) for _, rgb in media.iter_frames(video)),
                      media.probe(video).fps, audio, 48000)
    tmp.replace(out)
    return out


def one_run(prep, audio: str, target: str, work: Path) -> tuple[dict, float, int]:
    """Synthesis and compositing as ``lipsynth speak`` runs them after its preparation
    (``speak.synthesize_and_composite``): ``prep`` saying ``audio`` into ``target``; mouth prediction is timed
    (in "prediction")."""
    from pipeline.io import media
    out = work / "out.mp4"
    t0 = time.perf_counter()
    ms = speak.synthesize_and_composite(dataclasses.replace(prep, mouth=None), audio, target, str(out))
    wall = time.perf_counter() - t0
    return ms, wall, media.probe(out).n_frames


def report(name: str, runs: list) -> dict:
    n = runs[0][2]
    print(f"\n{name}: {n} output frames, {len(runs)} runs (medians)")
    row = dict(name=name, frames=n, runs=len(runs), ms_per_frame={})
    for k in PHASES:
        v = float(np.median([r[0].get(k, 0.0) for r in runs]))
        row["ms_per_frame"][k] = round(v, 2)
        print(f"  {k:<17} {v:7.1f} ms/frame")
    wall = float(np.median([r[1] for r in runs]))
    row["frames_per_s"] = round(n / wall, 2)
    print(f"  {'total':<17} {1000 * wall / n:7.1f} ms/frame → {n / wall:.1f} frames/s (wall, 2 cores)")
    return row


def cpu_features() -> str:
    """'AVX-512' when numpy dispatches AVX-512 kernels here (x86-simd-sort's 16-bit sort), else the
    highest of AVX2 / baseline — the row label of the speed table."""
    from numpy._core._multiarray_umath import __cpu_features__ as f
    return "AVX-512" if f.get("AVX512_SKX") else "AVX2" if f.get("AVX2") else "baseline"


def write_results(rows: dict, path: Path) -> None:
    import datetime
    import json
    import os
    import platform
    import subprocess
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    key = cpu_features()
    old = json.loads(path.read_text()) if path.is_file() else {}
    date = datetime.datetime.now().isoformat(timespec="minutes")
    model = next((line.split(":", 1)[1].strip() for line in open("/proc/cpuinfo") if line.startswith("model name")),
                 platform.processor() or platform.machine()) if os.path.exists("/proc/cpuinfo") else platform.machine()
    machine = f"{model}, {os.cpu_count()} cores"
    for r in rows.values():
        r.update(commit=commit, date=date, machine=machine)
    entry = old.setdefault("by_cpu", {}).setdefault(key, dict(rows={}))
    for r in entry["rows"].values():                     # rows of earlier runs keep their own commit, date and machine
        r.setdefault("commit", entry.get("commit"))
        r.setdefault("date", entry.get("date"))
        r.setdefault("machine", entry.get("machine"))
    entry.update(commit=commit, date=date, machine=machine)
    entry["rows"].update(rows)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(old, indent=1))
    print(f"wrote {path} ({key} row)")
    write_page(path)


def write_page(path: Path, page: Path = ROOT / "docs" / "synthesis_speed.md") -> None:
    """docs/synthesis_speed.md from the results file: one table per CPU feature level."""
    import json
    res = json.loads(path.read_text())
    lines = ["<!-- written by bench/synthesize.py from results/synthesize_speed.json; do not edit -->",
             "# Synthesis speed", "",
             "`python bench/synthesize.py --repeats 3`: synthesis and compositing as `lipsynth speak` runs them "
             "(with the shipped base model) of 32 s of speech into a GRID s1 clip, obama_08 (720p) "
             "and the same upscaled to 1080p (with 720p's 448 px crop and 192 px texture; `1080p native`: as `auto` "
             "sizes them for the 1080-line face; `4K native`: the clip upscaled to 3840×2160, sized by `auto`); ms/frame per phase (thread time: each phase runs on two "
             "threads, so phases add up to more than the wall time), medians over repeats; "
             "frames/s is wall time on 2 cores; each column keeps the commit and date it was measured on. Goals: GRID ≥ 60, 720p ≥ 30, 1080p ≥ 20 frames/s (issue 33); 1080p native ≥ 30, 4K ≥ 10 frames/s (issue 48). Columns named with a "
             "method (`two_band`) ran with that `synthesize.detail` (`--detail`); the others with params.yaml's. "
             "The AVX2 table is what lipsynth runs on every CPU with AVX2, AVX-512 ones included (the cap of "
             "`pipeline/simd_level.py`, for the same bytes everywhere); the AVX-512 table lifts the cap "
             "(`LIPSYNTH_SIMD=native python bench/synthesize.py`).", ""]
    for cpu, entry in res["by_cpu"].items():
        rows = entry["rows"]
        machines = sorted({r.get("machine", entry["machine"]) for r in rows.values()})
        lines += [f"## {cpu} ({'; '.join(machines)})", "",
                  "| phase | " + " | ".join(rows) + " |", "|---|" + "---|" * len(rows)]
        for k in PHASES:
            lines.append(f"| {k} | " + " | ".join(f"{r['ms_per_frame'].get(k, 0):.1f}" for r in rows.values()) + " |")
        lines += ["| **frames/s (wall)** | " + " | ".join(f"**{r['frames_per_s']:.1f}**" for r in rows.values()) + " |",
                  "| measured | " + " | ".join(f"{r.get('commit', entry['commit'])}, {str(r.get('date', entry['date']))[:10]}"
                                           for r in rows.values()) + " |"]
        if len(machines) > 1:
            lines.append("| machine | " + " | ".join(r.get("machine", entry["machine"]).split(",")[0] for r in rows.values())
                         + " |")
        lines.append("")
    page.write_text("\n".join(lines) + "\n")
    print(f"wrote {page}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--model", default=str(ROOT / "models" / "base"), help="model folder (default: the shipped base model)")
    ap.add_argument("--audio", default=None, help="speech file (default: 32 s of radio speech, see long_speech)")
    ap.add_argument("--only", choices=SIZES, default=None)
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "synthesize_speed.json",
                    help="results file; one entry per CPU feature level (AVX-512 / AVX2 / baseline)")
    ap.add_argument("--page-only", action="store_true", help="only rewrite docs/synthesis_speed.md from --out")
    ap.add_argument("--detail", choices=("median", "aligned", "two_band"), default=None,
                    help="synthesize.detail for every row (rows are then named e.g. 'grid two_band')")
    a = ap.parse_args()
    if a.page_only:
        return write_page(a.out)
    rows = {}
    setup_logging()
    import logging
    for name in ("lipsynth.synthesize", "lipsynth.composite", "lipsynth.speak", "lipsynth.target", "lipsynth.ingest",
                 "lipsynth.landmarks", "lipsynth.frontalize", "lipsynth.parallel"):
        logging.getLogger(name).setLevel(logging.WARNING)
    project = load_params(ROOT / "params.yaml")
    if a.detail:
        project.synthesize.detail = a.detail
    work = ROOT / "bench" / "results" / "synthesize"
    work.mkdir(parents=True, exist_ok=True)
    a.audio = a.audio or str(long_speech(work / "speech_32s.wav"))

    cache = ROOT / "bench" / "results" / "cache"
    for size in SIZES:
        if a.only not in (None, size):
            continue
        base = copy.deepcopy(project)
        base.composite.diagnostic = False
        if size == "grid":
            target = SHARED / "grid_s1" / "video" / GRID_CLIP
        else:
            target = SHARED / "obama" / "obama_08.mp4"
            if not size.endswith("native"):                # crop and texture as auto gives 720p
                base.ingest.crop_size = 448
                base.frontalize.texture_size = 192
            if size.startswith("1080p"):
                target = upscaled(target, work / "obama_08_1080p.mp4", (1920, 1080))
            if size.startswith("4K"):
                target = upscaled(target, work / "obama_08_2160p.mp4", (3840, 2160))
        prep = speak.prepare(a.audio, str(target), base, a.model, cache=cache)
        e = prep.entry
        rows[size + (f" {a.detail}" if a.detail else "")] = report(
            f"{size} {e['width']}×{e['height']} (target {target.name}, {e['n_frames']} frames; {prep.report['path']})",
            [one_run(prep, a.audio, str(target), work) for _ in range(a.repeats)])
    write_results(rows, a.out)

if __name__ == "__main__":
    main()
