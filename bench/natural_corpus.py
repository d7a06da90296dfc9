"""A natural-speech talking-head corpus of many people from public repositories (issue 61, item 1).

    python bench/natural_corpus.py [--mirrors /work/.mirror] [--out runs/natural_corpus] [--skip-missing]
        [--only public_domain cc0 cc_by measure_only]

Corpus
------
``bench/natural_corpus_manifest.tsv`` lists single-person talking-head clips shipped in git by public talking-head,
lip-sync and lip-reading repositories: per clip its repository, commit, path, SHA-256, size, fps, duration, a
stable ``person`` id, licence class and why it is free, and what it shows. Where a repository keeps a clip's
video and its speech apart (an mp4 with no audio track beside a wav of the same length), ``audio_path`` names the
wav (checked by ``audio_sha256``) and the two are muxed into one mp4.

Licences
--------
What counts is the footage's licence, not the repository's code licence.

``public_domain``
    US federal government works (17 U.S.C. §105): presidential weekly addresses and congressional weekly
    addresses (HDTF's ``WDA_*`` / ``WRA_*`` material), recognised by file name, speaker and setting.
``cc0`` / ``cc_by``
    Footage under CC0 / CC BY, e.g. GRID corpus speakers (CC BY 4.0: attribute Cooke, Barker, Cunningham and
    Shao 2006). GRID is read speech with a fixed grammar.
``measure_only``
    Footage of unknown licence: may be used to measure (held-out people), never to train weights that ship.

Only the first three classes may train shipped weights. The footage never goes into git: only the manifest does.

What the script does
--------------------
Each clip is taken from its repository's git mirror (``git --git-dir=MIRRORS/owner+name/repo show COMMIT:PATH``,
as ``bench/tight_crops.py`` does), checked against the manifest's SHA-256 and written to ``OUT/clips/NAME.mp4``
(an mp4 without a separate wav is copied as is; other containers, and clips with a separate wav, are converted
with PyAV to H.264 + AAC). Each clip is then checked and LEFT OUT, with one printed line, when it has no audio
stream, no speech (audio RMS below ``MIN_RMS_DB``), no face (dlib HOG on ``SAMPLES`` frames finds a face on fewer
than half), a scene cut (a frame-to-frame mean absolute difference above ``CUT_FACTOR`` × its running median and
above ``CUT_MIN``), or two faces on most sampled frames. ``OUT/corpus.json`` records per clip kept / left out and
why, person, licence class and duration, and the totals (people and minutes per licence class).
"""
from __future__ import annotations

import argparse
import csv
import json
from fractions import Fraction
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import av
import numpy as np

from bench.git_mirror import git_blob
from pipeline.face import dlib_face

ROOT = Path(__file__).resolve().parents[1]
MANIFEST = ROOT / "bench" / "natural_corpus_manifest.tsv"
MIRRORS = ROOT.parent / ".mirror"
CLASSES = ("public_domain", "cc0", "cc_by", "measure_only")
SHIPPABLE = ("public_domain", "cc0", "cc_by")
MIN_RMS_DB = -40.0         # speech: audio RMS above this (dBFS)
SAMPLES = 8                # frames sampled for the face checks
CUT_FACTOR, CUT_MIN = 6.0, 12.0   # a cut: frame difference > CUT_FACTOR × running median and > CUT_MIN (0–255)
CUT_WINDOW = 25            # frames in the running median


def manifest(path: Path = MANIFEST) -> list[dict]:
    """The manifest's rows (a plain TSV with a header row; no CSV quoting)."""
    with path.open(newline="") as f:
        return list(csv.DictReader(f, delimiter="\t", quoting=csv.QUOTE_NONE))


def convert(video: Path, audio: Path | None, dest: Path) -> None:
    """``video`` (and the audio of ``audio`` when given, else the video's own) re-encoded into an H.264 + AAC mp4."""
    src, asrc = av.open(str(video)), av.open(str(audio)) if audio else None
    a_in = (asrc or src).streams.audio[0] if (asrc or src).streams.audio else None
    v_in = src.streams.video[0]
    rate = v_in.average_rate or Fraction(25)
    with av.open(str(dest), "w") as out:
        vs = out.add_stream("libx264", rate=rate, options={"crf": "18", "preset": "medium"})
        vs.width, vs.height, vs.pix_fmt = v_in.width // 2 * 2, v_in.height // 2 * 2, "yuv420p"
        as_ = out.add_stream("aac", rate=a_in.rate) if a_in else None
        for i, frame in enumerate(src.decode(v_in)):
            img = frame.reformat(width=vs.width, height=vs.height, format="yuv420p")
            img.pts, img.time_base = i, Fraction(1) / rate
            out.mux(vs.encode(img))
        out.mux(vs.encode())
        if as_ is not None:
            for frame in (asrc or av.open(str(video))).decode(audio=0):
                frame.pts = None
                out.mux(as_.encode(frame))
            out.mux(as_.encode())
    src.close()
    if asrc:
        asrc.close()


def assemble(clip: dict, mirrors: Path, clips_dir: Path) -> Path:
    """The clip as ``clips_dir/NAME.mp4`` from its mirror (reused when already made from the same bytes)."""
    dest, stamp = clips_dir / f"{clip['short_name']}.mp4", clips_dir / f".{clip['short_name']}.src"
    key = f"{clip['sha256']} {clip.get('audio_sha256') or ''}"
    if dest.is_file() and stamp.is_file() and stamp.read_text() == key:
        return dest
    clips_dir.mkdir(parents=True, exist_ok=True)
    data = git_blob(clip, clip["path"], clip["sha256"], mirrors)
    if clip["path"].lower().endswith(".mp4") and not clip.get("audio_path"):
        dest.write_bytes(data)
    else:
        tmp_v = clips_dir / f".{clip['short_name']}.src{Path(clip['path']).suffix}"
        tmp_v.write_bytes(data)
        tmp_a = None
        if clip.get("audio_path"):
            tmp_a = clips_dir / f".{clip['short_name']}.audio{Path(clip['audio_path']).suffix}"
            tmp_a.write_bytes(git_blob(clip, clip["audio_path"], clip["audio_sha256"], mirrors))
        try:
            convert(tmp_v, tmp_a, dest)
        finally:
            tmp_v.unlink(missing_ok=True)
            if tmp_a:
                tmp_a.unlink(missing_ok=True)
    stamp.write_text(key)
    return dest


def audio_rms_db(path: Path) -> float | None:
    """RMS of the first audio stream in dBFS (mono mix); None without an audio stream."""
    with av.open(str(path)) as c:
        if not c.streams.audio:
            return None
        chunks = [f.to_ndarray().astype(np.float64) for f in c.decode(audio=0)]
    if not chunks:
        return None
    x = np.concatenate([ch.reshape(-1) if ch.shape[0] == 1 else ch.mean(0) for ch in chunks])
    x = x / 32768.0 if np.abs(x).max() > 2.0 else x        # integer sample formats
    return float(20 * np.log10(np.sqrt(np.mean(x ** 2)) + 1e-12))


def frames_gray(path: Path) -> tuple[list[np.ndarray], np.ndarray]:
    """``SAMPLES`` evenly spaced grey frames, and every frame's mean absolute difference to the one before
    (on a 64 × 64 thumbnail)."""
    grays, thumbs = [], []
    with av.open(str(path)) as c:
        for f in c.decode(video=0):
            g = f.to_ndarray(format="gray")
            grays.append(g)
            thumbs.append(f.reformat(width=64, height=64, format="gray").to_ndarray().astype(np.float32))
    idx = np.linspace(0, len(grays) - 1, SAMPLES).round().astype(int)
    diffs = np.array([np.abs(b - a).mean() for a, b in zip(thumbs, thumbs[1:])])
    return [grays[i] for i in idx], diffs


def scene_cut(diffs: np.ndarray) -> int | None:
    """Index of the first frame whose difference jumps far above its running median, else None."""
    for t in range(3, len(diffs)):
        med = float(np.median(diffs[max(0, t - CUT_WINDOW):t]))
        if diffs[t] > CUT_MIN and diffs[t] > CUT_FACTOR * max(med, 1.0):
            return t + 1
    return None


def face_counts(grays: list[np.ndarray]) -> list[int]:
    """Faces dlib's HOG detector finds per sampled frame (one upsampling when none is found at first)."""
    counts = []
    for g in grays:
        n = len(dlib_face.detect_faces(g, 0)) or len(dlib_face.detect_faces(g, 1))
        counts.append(n)
    return counts


def check(path: Path) -> tuple[str | None, dict]:
    """Why the clip is left out (None: kept), and what was measured."""
    rms = audio_rms_db(path)
    grays, diffs = frames_gray(path)
    counts = face_counts(grays)
    cut = scene_cut(diffs)
    m = dict(rms_db=None if rms is None else round(rms, 1), faces=counts, cut_frame=cut,
             max_diff=round(float(diffs.max()), 1) if len(diffs) else None)
    if rms is None:
        return "no audio stream", m
    if rms < MIN_RMS_DB:
        return f"no speech (audio RMS {rms:.1f} dBFS < {MIN_RMS_DB})", m
    if sum(c >= 1 for c in counts) < len(counts) / 2:
        return f"no face (dlib found one on {sum(c >= 1 for c in counts)} of {len(counts)} sampled frames)", m
    if cut is not None:
        return f"scene cut at frame {cut} (difference {diffs[cut - 1]:.1f} vs running median)", m
    if sum(c >= 2 for c in counts) > len(counts) / 2:
        return f"two faces on {sum(c >= 2 for c in counts)} of {len(counts)} sampled frames", m
    return None, m


def duration_s(path: Path) -> float:
    with av.open(str(path)) as c:
        return round(c.duration / 1e6, 2) if c.duration else 0.0


def totals(rows: list[dict]) -> dict:
    """People and minutes of the kept clips per licence class, for the shippable classes together, and all."""
    kept = [r for r in rows if r["kept"]]
    groups = {c: [r for r in kept if r["licence_class"] == c] for c in CLASSES}
    groups["shippable"] = [r for r in kept if r["licence_class"] in SHIPPABLE]
    groups["all"] = kept
    return {k: dict(clips=len(g), people=len({r["person"] for r in g}),
                    minutes=round(sum(r["duration_s"] for r in g) / 60, 2)) for k, g in groups.items()}


def run(clip: dict, mirrors: Path, clips_dir: Path, skip_missing: bool) -> dict:
    row = dict(clip=clip["short_name"], person=clip["person"], licence_class=clip["licence_class"], repo=clip["repo"],
               path=clip["path"], kept=False, reason=None, duration_s=0.0)
    try:
        path = assemble(clip, mirrors, clips_dir)
    except ValueError as e:
        if not skip_missing:
            raise SystemExit(f"natural_corpus: {clip['short_name']}: {e}") from None
        row["reason"] = f"not assembled: {e}"
        return row
    reason, measured = check(path)
    row.update(kept=reason is None, reason=reason, duration_s=duration_s(path), checks=measured)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mirrors", type=Path, default=MIRRORS, help=f"folder of the git mirrors, owner+name/repo (default {MIRRORS})")
    ap.add_argument("--out", type=Path, default=ROOT / "runs" / "natural_corpus",
                    help="output folder: clips/NAME.mp4 and corpus.json (default runs/natural_corpus)")
    ap.add_argument("--skip-missing", action="store_true", help="go on without a clip whose mirror is missing or whose "
                    "bytes do not match the manifest (it is recorded as left out, not assembled)")
    ap.add_argument("--only", nargs="+", choices=CLASSES, metavar="CLASS", help=f"licence classes to assemble ({', '.join(CLASSES)}; default all)")
    ap.add_argument("--manifest", type=Path, default=MANIFEST, help=f"the clip manifest (default {MANIFEST.relative_to(ROOT)})")
    a = ap.parse_args()
    out = a.out if a.out.is_absolute() else ROOT / a.out
    clips = [c for c in manifest(a.manifest) if not a.only or c["licence_class"] in a.only]
    rows = []
    for clip in clips:
        row = run(clip, a.mirrors, out / "clips", a.skip_missing)
        rows.append(row)
        print(f"{row['clip']}: {'kept' if row['kept'] else 'LEFT OUT: ' + row['reason']} "
              f"({row['person']}, {row['licence_class']}, {row['duration_s']:.1f} s)", flush=True)
    summary = dict(manifest=str(a.manifest), totals=totals(rows),
                   left_out={r["clip"]: r["reason"] for r in rows if not r["kept"]}, clips=rows)
    (out / "corpus.json").write_text(json.dumps(summary, indent=1, ensure_ascii=False) + "\n")
    for k, t in summary["totals"].items():
        print(f"{k:>13}: {t['people']:3d} people, {t['clips']:3d} clips, {t['minutes']:6.2f} min")
    print(f"wrote {out / 'corpus.json'}")


if __name__ == "__main__":
    main()
