"""``lipsynth live`` measured: latency, keeping up, memory, drift; ``lipsynth prepare``'s time (issue 48).

    python bench/live.py [--repeats 3] [--long 600] [--out results/live.json]

For each target — GRID s1 (360×288), HDTF (512²), an Obama weekly address (1280×720) — a fresh cache is
prepared (``lipsynth prepare``, timed) and an 8-s HDTF speech WAV is streamed through ``lipsynth live
--realtime`` (released at the pace it plays, as a live source would) ``--repeats`` times. From each
run's ``--stats``: every frame's latency (an audio sample's arrival → its frame leaving the muxer),
frames repeated to keep up, video − audio at the end (frames), and the process's peak memory (RSS
polled every 0.1 s). ``--long S`` also streams S seconds of speech (the four HDTF WAVs, repeated) into the
720p target, and runs ``lipsynth speak`` on the same audio, for memory and drift over a long run.
``--prepare VIDEO`` times ``prepare`` of another target too (default: a 20-s 720×1280 stranger).

Writes the JSON (medians over the repeats; commit, date, CPU), ``docs/live_latency.png`` (latency
histogram per target) and the page ``docs/live_figures.md``.
"""
from __future__ import annotations

import argparse
import datetime
import json
import platform
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import numpy as np

from pipeline.audio.streaming_features import STREAM

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
TARGETS = {"grid": DATA / "grid_s1" / "video" / "bbaf2n.mp4",
           "512²": DATA / "hdtf" / "WDA_KatieHill_000.mp4",
           "720p": DATA / "obama" / "obama_08.mp4"}
SPEECH = DATA / "hdtf" / "RD_Radio34_002.wav"
MODEL = "models/base"


def cpu_name() -> str:
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return platform.processor()


def run_polled(cmd: list[str], **kw) -> tuple[subprocess.CompletedProcess, float]:
    """Run ``cmd``; returns it and its peak RSS (GB, the process and its children, polled every 0.1 s)."""
    import psutil
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, **kw)
    peak = 0.0
    done = threading.Event()

    def poll():
        nonlocal peak
        p = psutil.Process(proc.pid)
        while not done.is_set():
            try:
                rss = p.memory_info().rss + sum(c.memory_info().rss for c in p.children(recursive=True))
                peak = max(peak, rss / 1e9)
            except psutil.Error:
                pass
            time.sleep(0.1)
    t = threading.Thread(target=poll, daemon=True)
    t.start()
    _, err = proc.communicate()
    done.set()
    t.join()
    if proc.returncode:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{err.decode()[-3000:]}")
    return subprocess.CompletedProcess(cmd, proc.returncode, None, err), peak


def prepare(video: Path, cache: Path) -> float:
    t0 = time.perf_counter()
    run_polled([sys.executable, "-m", "lipsynth.cli", "prepare", str(video), "--model", MODEL, "--cache", str(cache)])
    return time.perf_counter() - t0


def live(video: Path, audio: Path, cache: Path, work: Path, extra=()) -> dict:
    stats = work / "stats.json"
    _, peak = run_polled([sys.executable, "-m", "lipsynth.cli", "live", "--target", str(video), "--model", MODEL,
                          "--cache", str(cache), "--audio", str(audio), "--realtime", "--out", str(work / "o.ts"),
                          "--stats", str(stats), *extra])
    s = json.loads(stats.read_text())
    lat = np.asarray(s["latency_ms"])
    return dict(median_ms=float(np.median(lat)), p95_ms=float(np.percentile(lat, 95)), frames=s["frames"],
                repeated=s["repeated"], drift_frames=s["drift_frames"], peak_gb=peak,
                shape_median_ms=float(np.median(s["shape_ms"])), latency_ms=s["latency_ms"],
                thread_ms=s["thread_ms_median"], method=s["method"], texture_px=s["texture_px"])


def long_audio(seconds: float, path: Path) -> Path:
    import wave
    from pipeline.io import media
    parts = [media.read_audio(str(f), 16000)[0] for f in sorted((DATA / "hdtf").glob("*.wav"))]
    x = np.resize(np.concatenate(parts), int(seconds * 16000))
    with wave.open(str(path), "wb") as w:
        w.setnchannels(1), w.setsampwidth(2), w.setframerate(16000)
        w.writeframes((np.clip(x, -1, 1) * 32767).astype("<i2").tobytes())
    return path


def plot(result: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    for name, r in result["targets"].items():
        ax.hist(r["latency_ms"], bins=40, histtype="step", lw=1.5, label=f"{name}: median {r['median_ms']:.0f} ms")
    for goal in (350, 500):
        ax.axvline(goal, color="grey", ls="--", lw=1)
    ax.set_xlabel("latency: audio sample arrives → its frame leaves (ms)")
    ax.set_ylabel("frames")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def table(result: dict) -> str:
    lines = ["# Live, measured", "", f"Measured by `python bench/live.py` on {result['cpu']} ({result['date']}, commit {result['commit']}); "
             f"medians of {result['repeats']} runs; model `{MODEL}`, look-ahead {result['ahead_s']} s, hop "
             f"{result.get('hop_s', 0.2)} s. Goals (issue 48): latency median ≤ 350 ms for GRID and 512², ≤ 500 ms "
             "(p95 ≤ 800 ms) for 720p.", "",
             "| target | prepare (s) | latency median (ms) | p95 (ms) | from audio to shape, median (ms) | frames "
             "repeated to keep up | video − audio at the end (frames) | peak memory (GB) | texture (method, px) | "
             "thread ms per frame: texture / composite / encode |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for name, r in result["targets"].items():
        lines.append(f"| {name} ({r['size']}) | {r['prepare_s']:.1f} | {r['median_ms']:.0f} | {r['p95_ms']:.0f} | "
                     f"{r['shape_median_ms']:.0f} | {r['repeated']} of {r['frames']} | {r['drift_frames']} | "
                     f"{r['peak_gb']:.2f} | {r['method']}, {r['texture_px']} | "
                     f"{r['thread_ms']['texture']:.0f} / {r['thread_ms']['composite']:.0f} / {r['thread_ms']['encode']:.0f} |")
    for name, r in result.get("prepare", {}).items():
        lines.append(f"\n`lipsynth prepare` of {name} ({r['size']}, {r['seconds_of_video']:.0f} s of video): "
                     f"{r['seconds']:.1f} s.")
    if "long" in result:
        r = result["long"]
        lines.append(f"\nLong run (commit {r['commit']}): {r['audio_s']:.0f} s of speech: `live` peak memory {r['live']['peak_gb']:.2f} GB, latency "
                     f"median {r['live']['median_ms']:.0f} ms / p95 {r['live']['p95_ms']:.0f} ms, "
                     f"{r['live']['repeated']} frames repeated, video − audio {r['live']['drift_frames']} frames; "
                     f"`speak` peak memory {r['speak']['peak_gb']:.2f} GB, {r['speak']['seconds']:.0f} s, "
                     f"video − audio {r['speak']['drift_s'] * 1000:.0f} ms.")
    lines += ["", "![latency histogram](live_latency.png)"]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--long", type=float, default=0.0, help="seconds of speech for the long run (0: keep the last "
                    "one --out holds)")
    ap.add_argument("--prepare", type=Path, default=DATA / "strangers" / "latsync_demo2.mp4")
    ap.add_argument("--ahead", type=float, default=STREAM["ahead_s"])
    ap.add_argument("--hop", type=float, default=STREAM["hop_s"])
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "live.json")
    a = ap.parse_args()
    from pipeline.io import media
    result = dict(commit=subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                                        text=True).stdout.strip(), date=datetime.date.today().isoformat(),
                  cpu=cpu_name(), cores=len(__import__("os").sched_getaffinity(0)), repeats=a.repeats,
                  ahead_s=a.ahead, hop_s=a.hop, targets={}, prepare={})
    with tempfile.TemporaryDirectory(prefix="bench-live-") as tmp:
        tmp = Path(tmp)
        for name, video in TARGETS.items():
            info = media.probe(video)
            cache = tmp / f"cache-{name}"
            prep = prepare(video, cache)
            runs = [live(video, SPEECH, cache, tmp, ["--ahead", str(a.ahead), "--hop", str(a.hop)]) for _ in range(a.repeats)]
            med = {k: float(np.median([r[k] for r in runs])) for k in ("median_ms", "p95_ms", "shape_median_ms",
                                                                       "peak_gb")}
            result["targets"][name] = dict(med, size=f"{info.width}×{info.height}", prepare_s=prep,
                                           thread_ms={k: float(np.median([r["thread_ms"][k] for r in runs]))
                                                      for k in runs[0]["thread_ms"]},
                                           method=runs[0]["method"], texture_px=runs[0]["texture_px"],
                                           frames=runs[0]["frames"], repeated=max(r["repeated"] for r in runs),
                                           drift_frames=max(abs(r["drift_frames"]) for r in runs),
                                           latency_ms=runs[len(runs) // 2]["latency_ms"])
            print(name, {k: v for k, v in result["targets"][name].items() if k != "latency_ms"}, flush=True)
        if a.prepare:
            info = media.probe(a.prepare)
            result["prepare"][a.prepare.name] = dict(seconds=prepare(a.prepare, tmp / "cache-prepare"),
                                                     size=f"{info.width}×{info.height}",
                                                     seconds_of_video=info.duration)
            print("prepare", result["prepare"], flush=True)
        if a.long:
            audio = long_audio(a.long, tmp / "long.wav")
            video = TARGETS["720p"]
            r = live(video, audio, tmp / "cache-720p", tmp, ["--ahead", str(a.ahead), "--hop", str(a.hop)])
            t0 = time.perf_counter()
            out = tmp / "long.mp4"
            _, peak = run_polled([sys.executable, "-m", "lipsynth.cli", "speak", "--audio", str(audio), "--target",
                                  str(video), "--model", MODEL, "--cache", str(tmp / "cache-720p"), "--out", str(out)])
            info = media.probe(out)
            from pipeline.io.media import read_audio
            heard = len(read_audio(str(out), 16000)[0]) / 16000
            result["long"] = dict(audio_s=a.long, live={k: v for k, v in r.items() if k != "latency_ms"},
                                  speak=dict(peak_gb=peak, seconds=time.perf_counter() - t0,
                                             drift_s=info.n_frames / info.fps - heard))
            print("long", result["long"], flush=True)
        shutil.rmtree(tmp, ignore_errors=True)
    if not a.long and a.out.is_file() and "long" in json.loads(a.out.read_text()):    # kept from its own run
        before = json.loads(a.out.read_text())
        result["long"] = dict(before["long"], commit=before["long"].get("commit", before["commit"]))
    if "long" in result:
        result["long"].setdefault("commit", result["commit"])
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(result) + "\n")
    plot(result, ROOT / "docs" / "live_latency.png")
    (ROOT / "docs" / "live_figures.md").write_text(table(result))
    print(table(result))


if __name__ == "__main__":
    main()
