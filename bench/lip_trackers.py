"""Lip trackers on free speech: dlib's 68-point lips (the pipeline's tracker) against MediaPipe's face
landmarker mesh mapped to dlib's lip order (``pipeline.face.mediapipe_lips``).

For each video, the first --seconds are decoded once (PyAV, ``pipeline.io.media``) and every frame goes
to three trackers:
  dlib        the landmarks stage's ``track_video`` as the pipeline runs it (HOG detection every 50
              frames, shape predictor + its confidence re-run on each frame, on the Y plane);
  MP video    MediaPipe VIDEO mode (RGB): face tracked between frames, landmarks smoothed over time
              by MediaPipe itself (one face: its LandmarksSmoothingCalculator);
  MP image    MediaPipe IMAGE mode: each frame detected and landmarked alone (the raw model, no smoothing).
All lengths are in % of one inter-ocular distance (IOD) per video: the median of dlib's outer-eye-corner
distance (36–45), the same unit for every tracker. Per video and tracker:

  jitter      on still frames — silent audio (speech-band level below p10 + 25 % of its p10–p90 range,
              the frame and both neighbours) where every tracker finds the face and no tracker's
              smoothed inner-lip opening moves more than 0.5 % IOD per frame — the RMS distance of the
              20 lip points from their smooth trend (Savitzky–Golay, 7 frames, order 2), %IOD
              (the JSON also has the RMS frame-to-frame step on those frames).
  env r       Pearson correlation of the inner-lip opening (IOD units) with the audio's 300–3000 Hz
              log-RMS envelope at the video frame rate (``lipsync_measures.audio_envelope``, then a
              3-frame moving mean), at lag 0 and at the best lag in ±5 frames (``best_lag``; + = the
              mouth moves after the sound). Also for MediaPipe's ``jawOpen`` blendshape.
  ms/frame    median wall time per frame of each tracker (dlib: predictor + confidence re-run and the
              occasional detection; MediaPipe: detect / detect_for_video incl. the mp.Image copy). The
              process is pinned to one CPU unless --all-cpus (MediaPipe 1.x has no thread setting).
  agreement   mean distance between dlib's and MP video's 20 lip points, %IOD (and after removing each
              point's median offset over the video: the part that is not a fixed convention), and the
              correlation of their inner-lip openings.

The GRID clips are also pooled into one row (series joined with NaN gaps). Writes the JSON (git commit,
date, CPU model, versions, per-video numbers) and a PNG next to it (bars per video: jitter and envelope
correlation per tracker), and prints a markdown table.

    python bench/lip_trackers.py [VIDEO ...] [--seconds 30] [--grid-clips 8] [--out bench/results/lip_trackers.json]

Needs the ``mediapipe`` extra: ``pip install -e .[mediapipe]``. About 1 min of one core on the defaults.
"""
from __future__ import annotations

import argparse
import datetime
import glob
import itertools
import json
import os
import platform
import subprocess
import time
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

from pipeline.face import dlib_face  # noqa: E402
from pipeline.face import mediapipe_lips as mpl  # noqa: E402
from pipeline.io import media  # noqa: E402
from pipeline.measures.lipsync_measures import audio_envelope, best_lag  # noqa: E402
from pipeline.params import Landmarks  # noqa: E402
from stages.landmarks.landmarks import track_video  # noqa: E402

DATA = ROOT.parent / "shared" / "data"
FREE_SPEECH = [DATA / "lieu" / "lieu_60s.mp4", DATA / "macron" / "macron_50s.mp4",
               DATA / "obama" / "obama_01.mp4", DATA / "hdtf" / "WDA_KatieHill_000.mp4"]
SR = 16000
MAX_LAG = 5
TREND = dict(window_length=7, polyorder=2)     # Savitzky–Golay trend removed before the jitter RMS
SILENT_FRACTION = 0.25                         # silent: level < p10 + this × (p90 − p10), dB
STILL_STEP = 0.005                             # still: smoothed opening moves < this (IOD) per frame
GAP = 8                                        # NaN frames between pooled clips (> lag and trend half-widths)


def default_videos(grid_clips: int) -> list[Path]:
    return FREE_SPEECH + [Path(p) for p in sorted(glob.glob(str(DATA / "grid_s4" / "*.mp4")))[:grid_clips]]


TRACKERS = ("dlib", "mediapipe", "mediapipe_image")
LABELS = {"dlib": "dlib", "mediapipe": "MP video", "mediapipe_image": "MP image"}


def track_both(path: Path, seconds: float) -> dict:
    """Decode the first ``seconds`` of ``path`` once; track every frame with dlib and MediaPipe (VIDEO
    and IMAGE mode).

    Returns per tracker ``lips`` (N, 20, 2) px, ``ok`` (N,) bool, ``ms`` (N,) and for MediaPipe ``iod``
    (N,) px and ``bs`` (N, 52); dlib's full ``lm68`` (N, 68, 2) px; the aligned 16 kHz audio; fps."""
    from tqdm import tqdm
    info = media.probe(path)
    n_max = int(round(seconds * info.fps))
    total = min(n_max, info.n_frames) if info.n_frames else n_max
    mps = {"mediapipe": mpl.LipTracker(info.fps, video=True), "mediapipe_image": mpl.LipTracker(info.fps, video=False)}
    rows = {k: [] for k in mps}
    ms = {k: [] for k in mps}
    handed, resumed, t0 = [], [], []

    def feed():
        frames = zip(media.iter_frames(path, "gray"), media.iter_frames(path, "rgb24"))
        for (t, gray), (_, rgb) in tqdm(itertools.islice(frames, n_max), total=total, desc=path.name,
                                        unit="frame", leave=False):
            if not t0:
                t0.append(t)
            for k, tr in mps.items():
                a = time.perf_counter()
                rows[k].append(tr.frame(rgb))
                ms[k].append(1000 * (time.perf_counter() - a))
            handed.append(time.perf_counter())
            yield gray
            resumed.append(time.perf_counter())          # track_video asks for the next frame: this one is done

    try:
        lm68, _, dl_ok, _ = track_video(feed(), Landmarks())
    finally:
        for tr in mps.values():
            tr.close()
    n = len(lm68)
    samples, a_start = media.read_audio(path, SR)
    out = dict(fps=info.fps, audio=media.align_audio(samples, a_start, t0[0] if t0 else 0.0, n / info.fps, SR),
               lm68=lm68, dlib=dict(lips=lm68[:, dlib_face.MOUTH], ok=dl_ok,
                                    ms=1000 * (np.array(resumed[:n]) - np.array(handed[:n]))))
    for k in mps:
        out[k] = dict(lips=np.array([r[0] for r in rows[k]]).reshape(-1, 20, 2), iod=np.array([r[1] for r in rows[k]]),
                      bs=np.array([r[2] for r in rows[k]]).reshape(-1, mpl.N_BLENDSHAPES),
                      ok=np.array([r[3] for r in rows[k]], bool), ms=np.array(ms[k]))
    return out


def smooth(x: np.ndarray, k: int = 3) -> np.ndarray:
    """Centred k-frame moving mean (NaN propagates)."""
    return np.convolve(np.pad(x, k // 2, mode="edge"), np.ones(k) / k, mode="valid")


def trend(x: np.ndarray) -> np.ndarray:
    """Savitzky–Golay trend along frames (axis 0); NaN where the window meets a missing frame."""
    from scipy.signal import savgol_filter
    if len(x) < TREND["window_length"]:
        return np.full_like(x, np.nan)
    return savgol_filter(x, axis=0, mode="interp", **TREND)


def prepare(raw: dict) -> dict:
    """Per-video series in IOD units: per tracker lips (N, 20, 2) (NaN where not ok), opening (N,),
    ms (N,); MediaPipe jawOpen; smoothed envelope; silent and still masks."""
    dl_ok = raw["dlib"]["ok"]
    iod = float(np.median(dlib_face.interocular(raw["lm68"][dl_ok]))) if dl_ok.any() \
        else float(np.nanmedian(raw["mediapipe"]["iod"]))
    n = len(dl_ok)
    level = audio_envelope(raw["audio"], raw["fps"], n, SR)
    lo, hi = np.nanpercentile(level, [10, 90])
    quiet = np.nan_to_num(level, nan=np.inf) < lo + SILENT_FRACTION * (hi - lo)
    silent = quiet & np.r_[quiet[1:], False] & np.r_[False, quiet[:-1]]
    out = dict(env=smooth(level), silent=silent, real=np.ones(n, bool), iod_px=iod, fps=raw["fps"],
               mp_iod_ratio=float(np.nanmedian(raw["mediapipe"]["iod"]) / iod))
    still = silent.copy()
    for t in TRACKERS:
        r = raw[t]
        lips = np.where(r["ok"][:, None, None], r["lips"], np.nan) / iod
        op = mpl.inner_opening(lips)      # = lipsync_measures.inner_opening (pairs 61/67, 62/66, 63/65)
        out[t] = dict(lips=lips, opening=op, ms=r["ms"])
        if "bs" in r:
            out[t]["jaw"] = np.where(r["ok"], r["bs"][:, mpl.JAW_OPEN], np.nan)
        step = np.abs(np.gradient(trend(op))) if n > 1 else np.full(n, np.nan)
        still &= r["ok"] & (step < STILL_STEP)             # NaN step: not still
    out["still"] = still
    return out


def pool(preps: list[dict]) -> dict:
    """Join per-clip series with GAP missing frames between them (ms: plain concatenation)."""
    def join(arrays):
        parts = []
        for x in arrays:
            gap = np.zeros((GAP,) + x.shape[1:], bool) if x.dtype == bool else np.full((GAP,) + x.shape[1:], np.nan)
            parts += [x, gap]
        return np.concatenate(parts[:-1])
    out = {k: join([p[k] for p in preps]) for k in ("env", "still", "silent", "real")}
    for t in TRACKERS:
        out[t] = {k: join([p[t][k] for p in preps]) for k in preps[0][t] if k != "ms"}
        out[t]["ms"] = np.concatenate([p[t]["ms"] for p in preps])
    out["iod_px"] = float(np.median([p["iod_px"] for p in preps]))
    out["mp_iod_ratio"] = float(np.median([p["mp_iod_ratio"] for p in preps]))
    return out


def corr_at(a: np.ndarray, b: np.ndarray, lag: int) -> float:
    """Correlation of a[t + lag] with b[t] over frames where both are finite."""
    x, y = a[max(lag, 0):len(a) + min(lag, 0)], b[max(-lag, 0):len(b) + min(-lag, 0)]
    ok = np.isfinite(x) & np.isfinite(y)
    if ok.sum() < 6 or x[ok].std() == 0 or y[ok].std() == 0:
        return float("nan")
    return float(np.corrcoef(x[ok], y[ok])[0, 1])


def env_corr(x: np.ndarray, env: np.ndarray) -> dict:
    """Correlation with the envelope at lag 0 and at the best lag in ±MAX_LAG (+ = x after the sound)."""
    lag = best_lag(x, env, MAX_LAG)
    return dict(lag0=corr_at(x, env, 0), best=corr_at(x, env, lag), lag=int(lag))


def jitter(lips: np.ndarray, still: np.ndarray) -> dict:
    """On still frames: RMS distance (%IOD) of the lip points from their trend, and RMS frame-to-frame step."""
    d = np.linalg.norm((lips - trend(lips))[still], axis=-1)
    step = np.linalg.norm(np.diff(lips, axis=0)[still[1:] & still[:-1]], axis=-1)
    rms = lambda v: 100 * float(np.sqrt(np.nanmean(v ** 2))) if np.isfinite(v).any() else float("nan")
    return dict(rms=rms(d), step_rms=rms(step))


def agreement(a: np.ndarray, b: np.ndarray) -> dict:
    """Mean distance (%IOD) of two trackers' lip points on frames both track; also with each point's
    median offset removed, and per point."""
    both = np.isfinite(a[:, 0, 0]) & np.isfinite(b[:, 0, 0])
    if not both.any():
        return dict(mean=float("nan"), offset_removed=float("nan"), per_point=None)
    diff = a[both] - b[both]
    dist = np.linalg.norm(diff, axis=-1)
    return dict(mean=100 * float(dist.mean()),
                offset_removed=100 * float(np.linalg.norm(diff - np.median(diff, axis=0), axis=-1).mean()),
                per_point=(100 * dist.mean(0)).round(2).tolist())


def measures(p: dict) -> dict:
    out = dict(frames=int(p["real"].sum()), still_frames=int(p["still"].sum()), silent_frames=int(p["silent"].sum()),
               iod_px=p["iod_px"], mp_iod_over_dlib_iod=p["mp_iod_ratio"],
               agreement=agreement(p["dlib"]["lips"], p["mediapipe"]["lips"]),
               agreement_image=agreement(p["dlib"]["lips"], p["mediapipe_image"]["lips"]),
               opening_corr_dlib_mp=corr_at(p["dlib"]["opening"], p["mediapipe"]["opening"], 0))
    for t in TRACKERS:
        s = p[t]
        out[t] = dict(ok_fraction=float(np.isfinite(s["lips"][p["real"], 0, 0]).mean()), jitter=jitter(s["lips"], p["still"]),
                      env=env_corr(s["opening"], p["env"]), ms_median=float(np.median(s["ms"])),
                      ms_mean=float(np.mean(s["ms"])), opening_mean=100 * float(np.nanmean(s["opening"])),
                      opening_std=100 * float(np.nanstd(s["opening"])))
        if "jaw" in s:
            out[t]["jawOpen_env"] = env_corr(s["jaw"], p["env"])
    return out


COLORS = {"dlib": "tab:blue", "mediapipe": "tab:orange", "mediapipe_image": "tab:green"}


def plot(rows: dict, path: Path) -> None:
    """Two panels of bars per video: jitter on still frames; envelope correlation (lag 0 pale, best lag
    solid) of each tracker's inner-lip opening, with MediaPipe jawOpen (best lag) as markers."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    names = list(rows)
    x = np.arange(len(names))
    fig, axes = plt.subplots(2, 1, figsize=(max(9, 0.9 * len(names) + 3), 7.5), sharex=True)
    w = 0.8 / len(TRACKERS)
    for i, t in enumerate(TRACKERS):
        off = (i - (len(TRACKERS) - 1) / 2) * w
        axes[0].bar(x + off, [rows[n][t]["jitter"]["rms"] for n in names], w, color=COLORS[t], label=LABELS[t])
        axes[1].bar(x + off, [rows[n][t]["env"]["lag0"] for n in names], w, color=COLORS[t], alpha=0.4)
        axes[1].bar(x + off, [rows[n][t]["env"]["best"] for n in names], w * 0.5, color=COLORS[t], label=f"{LABELS[t]}")
    axes[1].plot(x, [rows[n]["mediapipe"]["jawOpen_env"]["best"] for n in names], "k^", label="MP video jawOpen")
    axes[0].set_ylabel("lip jitter on silent, still frames\n(% IOD, RMS about 7-frame trend)")
    axes[0].legend(fontsize=8)
    axes[1].axhline(0, color="grey", lw=0.5)
    axes[1].set_ylabel("r(inner-lip opening, speech envelope)\npale: lag 0, narrow: best lag in ±5")
    axes[1].legend(fontsize=8, ncol=4)
    axes[1].set_xticks(x, names, rotation=30, ha="right", fontsize=8)
    fig.suptitle("Lip trackers on free speech: dlib 68-point vs MediaPipe face landmarker")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def table(rows: dict) -> str:
    """Markdown: per video, values as dlib / MP video / MP image."""
    def f(v, fmt="{:.2f}"):
        return "—" if v is None or not np.isfinite(v) else fmt.format(v)

    def tri(r, get, fmt="{:.2f}"):
        return " / ".join(f(get(r[t]), fmt) for t in TRACKERS)
    lines = ["Values: dlib / MediaPipe VIDEO mode / MediaPipe IMAGE mode. Lengths in % IOD; r = correlation with "
             "the 300–3000 Hz envelope (best lag in frames, + = mouth after sound).", "",
             "| video | frames (still) | jitter %IOD | env r lag 0 | env r best | best lag | jawOpen r lag0 / best (lag) "
             "| ms/frame | dlib↔MP agree %IOD (offset removed) | opening r dlib↔MP |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for n, r in rows.items():
        j, a = r["mediapipe"]["jawOpen_env"], r["agreement"]
        lags = " / ".join(f"{r[t]['env']['lag']:+d}" for t in TRACKERS)
        lines.append(
            f"| {n} | {r['frames']} ({r['still_frames']}) | {tri(r, lambda d: d['jitter']['rms'])} "
            f"| {tri(r, lambda d: d['env']['lag0'])} | {tri(r, lambda d: d['env']['best'])} "
            f"| {lags} "
            f"| {f(j['lag0'])} / {f(j['best'])} ({j['lag']:+d}) | {tri(r, lambda d: d['ms_median'], '{:.1f}')} "
            f"| {f(a['mean'])} ({f(a['offset_removed'])}) | {f(r['opening_corr_dlib_mp'])} |")
    return "\n".join(lines)


def machine() -> dict:
    cpu = next((ln.split(":", 1)[1].strip() for ln in Path("/proc/cpuinfo").read_text().splitlines()
                if ln.startswith("model name")), platform.processor())
    return dict(cpu=cpu, cpus_online=os.cpu_count(), cpus_used=sorted(os.sched_getaffinity(0)),
                load_average_at_start=os.getloadavg())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("videos", nargs="*", type=Path,
                    help="videos to measure (default: lieu, macron, obama_01, HDTF Katie Hill and --grid-clips GRID s4 clips)")
    ap.add_argument("--seconds", type=float, default=30.0, help="track only the first SECONDS of each video (default 30)")
    ap.add_argument("--grid-clips", type=int, default=8, help="GRID s4 clips in the default set, pooled into one row (default 8)")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "lip_trackers.json",
                    help="JSON output; the plot goes next to it as .png (default bench/results/lip_trackers.json)")
    ap.add_argument("--all-cpus", action="store_true",
                    help="do not pin the process to one CPU (MediaPipe then uses a thread pool on all of them)")
    a = ap.parse_args(argv)
    if not a.all_cpus:
        os.sched_setaffinity(0, {max(os.sched_getaffinity(0))})
    import mediapipe
    mpl.check_task(mpl.task_path())
    videos = a.videos or default_videos(a.grid_clips)
    host = machine()
    from tqdm import tqdm
    rows, grid = {}, []
    for path in tqdm(videos, desc="videos", unit="video"):
        p = prepare(track_both(path, a.seconds))
        rows[path.name] = measures(p)
        if "grid" in path.parent.name:
            grid.append(p)
    if len(grid) > 1:
        rows[f"GRID s4 pooled ({len(grid)} clips)"] = measures(pool(grid))
    commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    dirty = bool(subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT,
                                capture_output=True, text=True).stdout.strip())
    result = dict(
        bench="lip_trackers", git_commit=commit, git_dirty=dirty,
        date=datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"), machine=host,
        versions=dict(mediapipe=mediapipe.__version__, python=platform.python_version()),
        mediapipe_task=dict(path=str(mpl.task_path()), sha256=mpl.TASK_SHA256, package=mpl.PACKAGE),
        mapping=dict(dlib_points=list(range(48, 68)), mesh_indices=mpl.DLIB_LIPS_FROM_MESH.tolist(),
                     mesh_eye_outer=list(mpl.EYE_OUTER)),
        settings=dict(seconds=a.seconds, videos=[str(v) for v in videos], max_lag=MAX_LAG, trend=TREND,
                      silent_fraction=SILENT_FRACTION, still_step_iod=STILL_STEP, envelope="300–3000 Hz log RMS, 3-frame mean",
                      unit="% of the median dlib IOD (outer eye corners 36–45) of each video"),
        videos=rows)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(result, indent=2))
    plot(rows, a.out.with_suffix(".png"))
    print(table(rows))
    print(f"\nmediapipe {mediapipe.__version__}; CPU {host['cpu']} (pinned to {host['cpus_used']}); "
          f"written {a.out} and {a.out.with_suffix('.png')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
