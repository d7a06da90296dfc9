"""Tight crops and turned heads: ``lipsynth speak`` on LRS2 / VoxCeleb2-style clips of public repositories.

    python bench/tight_crops.py [--clips NAME ...] [--model models/base] [--reuse] [--skip-missing]
        [--mirrors /work/.mirror]

The clips (``bench/tight_crops_manifest.tsv``: repository, commit, path, SHA-256, size, duration, licence, what
each shows) are 160 × 160 LRS2 demo clips of smeetrs/deep_avsr and 224 × 224 VoxCeleb2-style demo clips of
Hangz-nju-cuhk/Talking-Face_PC-AVS: faces cut by the frame's top, faces filling most of the frame, and heads
turned from frontal to near profile. They are taken from git snapshots of those repositories
(``git --git-dir=MIRROR show COMMIT:PATH``; a mirror is ``MIRRORS/owner+name/repo``) into
``bench/results/tight_crops/clips/`` (gitignored) and checked against the manifest's SHA-256; a missing mirror
or a mismatch stops the bench with one line naming the clip (``--skip-missing``: go on without it).

Licence: the repositories' licences (MIT for deep_avsr, CC-BY-4.0 for PC-AVS) cover the repositories. The
clips themselves are LRS2 (BBC) material and VoxCeleb2-style interview footage, not separately licensed by
either repository: they may be used to measure, never to train weights that ship, and the footage never goes
into git (only the manifest, with its hashes, does).

Each clip gets its own audio through ``lipsynth speak --no-retime --report`` into itself (the paper's Video J
setting). Recorded per clip: the exit code, the last error line, the target's 3D fit (faces found, frames
posed, reprojection error over the inter-ocular distance) and the self-check's fallbacks, and the share of
frames with lip sync made: 1 − (fallen back + not posed) / frames, 0 when ``speak`` refused before writing a
report. Every output written (``speak`` writes one even when it then exits 2 for too many fallbacks) is scored
by the independent yardstick (``../shared/tools/lipsync_yardstick.py``'s ``compare``: dlib on the output
against the original; inner-lip opening correlation at lag 0 and at the best lag within ±5 frames, sharpness
and flicker as output ÷ original). Where most frames fell back, that score measures the original, not
lipsynth: the summary's median correlation counts only clips made on ≥ 95 % of their frames.

Writes ``results/tight_crops.json`` (commit, date, machine, rows, summary) and ``docs/tight_crops.md``.
"""
from __future__ import annotations

import argparse
import csv
import importlib.util
import json
import re
import subprocess
import sys
import time
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import numpy as np

from bench.bench_results import publish, stamp
from bench.git_mirror import git_blob, sha256

ROOT = Path(__file__).resolve().parents[1]
MANIFEST = ROOT / "bench" / "tight_crops_manifest.tsv"
YARDSTICK = ROOT.parent / "shared" / "tools" / "lipsync_yardstick.py"
MIRRORS = ROOT.parent / ".mirror"
WORK = ROOT / "bench" / "results" / "tight_crops"
MADE_AT_LEAST = 0.95         # a clip measures lipsynth when lip sync was made on this share of its frames
FIT_KEYS = ("frames", "face", "posed", "reprojection_iod", "max_jump_deg", "method")
CHECK_KEYS = ("frames", "fallen_back", "not_posed", "failed_by")
CAUSES = dict(face_error="rendered nose and chin off the target's", mouth_error="dlib reads another mouth",
              sharpness="rendered mouth far sharper", not_posed="head pose not found")


def yardstick():
    """The yardstick module (it shares no code with the project: imported from its file)."""
    spec = importlib.util.spec_from_file_location("lipsync_yardstick", YARDSTICK)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def manifest() -> list[dict]:
    """The manifest's rows (a plain TSV with a header row; fields hold quotes, so no CSV quoting)."""
    with MANIFEST.open(newline="") as f:
        return list(csv.DictReader(f, delimiter="\t", quoting=csv.QUOTE_NONE))


def assemble(clip: dict, mirrors: Path) -> Path:
    """The clip in WORK/clips, taken from its repository's git mirror at the manifest's commit and checked
    against the manifest's SHA-256; raises ValueError with one line naming what is wrong."""
    dest = WORK / "clips" / f"{clip['short_name']}.mp4"
    if dest.is_file() and sha256(dest.read_bytes()) == clip["sha256"]:
        return dest
    data = git_blob(clip, clip["path"], clip["sha256"], mirrors)
    dest.parent.mkdir(parents=True, exist_ok=True)
    dest.write_bytes(data)
    return dest


def made_share(check: dict | None) -> float:
    """Share of output frames where lip sync was made (neither the self-check's fallback nor unposed); 0 without
    a self-check (``speak`` refused before writing its report)."""
    if not check or not check.get("frames"):
        return 0.0
    return 1.0 - (check["fallen_back"] + check.get("not_posed", 0)) / check["frames"]


def main_cause(check: dict | None) -> tuple[list[str], int] | None:
    """The commonest reasons frames were not made (``lipsynth.speak.lip_sync_verdict`` names the first of a tie),
    and their count."""
    if not check or not check.get("frames") or made_share(check) >= 1.0:
        return None
    counts = dict(check.get("failed_by") or {}, not_posed=check.get("not_posed", 0))
    top = max(counts.values())
    return [cause for cause, n in counts.items() if n == top], top


def run_clip(name: str, clip: Path, model: str) -> dict:
    """``lipsynth speak`` of the clip's audio into itself; the row of what it did."""
    out, rep = WORK / "out" / f"{name}.mp4", WORK / "out" / f"{name}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    for f in (out, rep):
        f.unlink(missing_ok=True)
    cmd = [sys.executable, "-m", "lipsynth.cli", "speak", "--model", model, "--audio", str(clip), "--target", str(clip),
           "--out", str(out), "--no-retime", "--cache", str(WORK / "cache"), "--report", str(rep)]
    t0 = time.perf_counter()
    r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    (WORK / "out" / f"{name}.log").write_text(r.stderr)
    lines = r.stderr.strip().splitlines()
    errors = [ln for ln in lines if ln.startswith("lipsynth: error:")]
    row = dict(clip=name, rc=r.returncode, seconds=round(time.perf_counter() - t0, 1),
               error=(errors or lines or [None])[-1] if r.returncode else None,
               warnings=[ln.split(" WARNING: ", 1)[1] for ln in lines if " WARNING: " in ln], output=out.is_file())
    report = json.loads(rep.read_text()) if rep.is_file() else {}
    row["fit"] = {k: v for k, v in (report.get("fit") or {}).items() if k in FIT_KEYS} or None
    row["self_check"] = {k: v for k, v in (report.get("self_check") or {}).items() if k in CHECK_KEYS} or None
    row["made_share"] = made_share(row["self_check"])
    return row


def score(ys, row: dict, clip: Path) -> None:
    out = WORK / "out" / f"{row['clip']}.mp4"
    if out.is_file():
        y = ys.compare(str(clip), str(out))
        row["yardstick"] = {k: y[k] for k in ("corr", "corr_best", "offset", "sharp", "flicker", "error") if k in y}


def summarize(rows: list[dict]) -> dict:
    ran = [r for r in rows if "missing" not in r]
    made = [r for r in ran if r["made_share"] >= MADE_AT_LEAST]
    scored = [r for r in made if "corr" in (r.get("yardstick") or {})]
    med = lambda key: float(np.median([r["yardstick"][key] for r in scored])) if scored else None
    return dict(clips=len(ran), skipped=len(rows) - len(ran), made_95=len(made), scored_made_95=len(scored),
                median_corr=med("corr"), median_corr_best=med("corr_best"))


def fmt(x, spec=".2f") -> str:
    return "–" if x is None or (isinstance(x, float) and not np.isfinite(x)) else format(x, spec)


def yaw_framing(what: str) -> str:
    """Framing (the description's first clause) and the visual yaw estimates (``N-M deg``, in order)."""
    yaws = re.findall(r"~?\d+(?:-\d+)? deg", what)
    return f"{what.split(':')[0]}; yaw {' → '.join(y.replace(' deg', '°') for y in yaws) or '?'}"


def cause_cell(r: dict) -> str:
    if "missing" in r:
        return f"not assembled: {r['missing']}"
    if r["self_check"] is None:
        return re.sub(r"^lipsynth: error: \S+: ", "", r["error"] or "no report") + " (no output)"
    found = main_cause(r["self_check"])
    if found is None:
        return "–"
    causes, n = found
    return f"{' / '.join(CAUSES.get(c, c) for c in causes)} ({n} frames{' each' if len(causes) > 1 else ''})"


def table(rows: list[dict], clips: dict[str, dict]) -> list[str]:
    lines = ["| clip | source repo | size | yaw / framing (visual estimate) | rc | lip sync made | main cause when not | "
             "fit: posed / frames | reprojection × IOD | yardstick corr lag 0 / best |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        c = clips[r["clip"]]
        fit, check, y = r.get("fit") or {}, r.get("self_check") or {}, r.get("yardstick") or {}
        made = "–" if "missing" in r else f"{r['made_share']:.0%}" + (
            f" ({check['frames'] - check['fallen_back'] - check['not_posed']}/{check['frames']})" if check else "")
        ys = y.get("error") or (f"{fmt(y.get('corr'))} / {fmt(y.get('corr_best'))}" if y else "–")
        posed = f"{fit['posed']} / {fit['frames']}" if fit else "–"
        lines.append(f"| {r['clip']} | {c['repo']} | {c['width_x_height'].replace('x', '×')}, {float(c['duration_s']):.1f} s | "
                     f"{yaw_framing(c['what'])} | {r.get('rc', '–')} | {made} | {cause_cell(r)} | {posed} | "
                     f"{fmt(fit.get('reprojection_iod'), '.3f')} | {ys} |")
    return lines


def page(summary: dict, clips: dict[str, dict]) -> str:
    s, m = summary, summary["summary"]
    lines = ["<!-- Written by `python bench/tight_crops.py`; do not edit. -->", "# Tight crops and turned heads", "",
             f"Measured {s['date']} on commit `{s['commit']}` ({s['machine']}) by `bench/tight_crops.py` with "
             f"`{s['model']}`. Each clip of `bench/tight_crops_manifest.tsv` — 160 × 160 LRS2 demo clips and 224 × 224 "
             "VoxCeleb2-style demo clips of two public repositories, with the forehead or hair cut by the frame's top, the "
             "face filling most of the frame and the head from frontal to near profile — gets its own audio through "
             "`lipsynth speak --no-retime --report` into itself. *Lip sync made* is the share of output frames that are "
             "not the untouched target (1 − (fallen back + not posed) / frames; 0 when `speak` refused before its report); "
             "*main cause* is the self-check's commonest reason for the rest; the fit columns are the target's 3D fit "
             "(frames posed of all, mean reprojection error over the inter-ocular distance). Every output written — "
             "`speak` writes one even when it exits 2 for too many fallbacks — is scored by the independent yardstick "
             "(`../shared/tools/lipsync_yardstick.py`: dlib on the output against the original, inner-lip opening "
             "correlation at lag 0 and the best lag within ±5 frames); where most frames fell back that score is the "
             "original's, not lipsynth's. Yaw and framing are visual estimates from the manifest. "
             f"Lip sync was made on ≥ {MADE_AT_LEAST:.0%} of the frames of **{m['made_95']} of {m['clips']} clips**"
             + (f" ({m['skipped']} not assembled)" if m["skipped"] else "")
             + f"; their median yardstick correlation is {fmt(m['median_corr'])} at lag 0, {fmt(m['median_corr_best'])} "
             "at the best lag.", ""]
    lines += table(s["rows"], clips)
    lines += ["", "Clip sources (taken from git snapshots at these commits, checked by SHA-256; the footage is not in git; "
              "the licences cover the repositories, the clips are LRS2 (BBC) / interview footage they do not separately "
              "license: used here to measure, never to train shipped weights):", ""]
    for (repo, commit), group in groupby_source(s["rows"], clips).items():
        licence = clips[group[0]]["licence"].split(" (")[0]
        paths = ", ".join(f"`{clips[n]['path']}`" for n in group)
        lines.append(f"- [{repo}](https://github.com/{repo}) at `{commit[:12]}` ({licence}): {paths}")
    return "\n".join(lines)


def groupby_source(rows: list[dict], clips: dict[str, dict]) -> dict[tuple[str, str], list[str]]:
    out: dict[tuple[str, str], list[str]] = {}
    for r in rows:
        c = clips[r["clip"]]
        out.setdefault((c["repo"], c["commit"]), []).append(r["clip"])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--clips", nargs="+", metavar="NAME", help="short names of the manifest to run (default: all; the "
                    "results and page then hold only these)")
    ap.add_argument("--model", default="models/base", help="model folder (default: the shipped base)")
    ap.add_argument("--mirrors", type=Path, default=MIRRORS, help="folder of the git mirrors, owner+name/repo "
                    f"(default {MIRRORS})")
    ap.add_argument("--skip-missing", action="store_true", help="go on without a clip whose mirror is missing or "
                    "whose bytes do not match the manifest (it is listed as not assembled)")
    ap.add_argument("--reuse", action="store_true", help="keep a clip's existing output in bench/results/tight_crops "
                    "(and its recorded run) instead of running speak again (same code and params only)")
    a = ap.parse_args()
    if not YARDSTICK.is_file():
        raise SystemExit(f"{YARDSTICK}: the yardstick is not there (../shared/tools beside the project)")
    clips = {c["short_name"]: c for c in manifest()}
    unknown = sorted(set(a.clips or []) - set(clips))
    if unknown:
        raise SystemExit(f"tight_crops: not in {MANIFEST.name}: {', '.join(unknown)} (there: {', '.join(clips)})")
    names = [n for n in clips if not a.clips or n in a.clips]
    paths, missing = {}, {}
    for name in names:
        try:
            paths[name] = assemble(clips[name], a.mirrors)
        except ValueError as e:
            if not a.skip_missing:
                raise SystemExit(f"tight_crops: {name}: {e}") from None
            missing[name] = str(e)
            print(f"tight_crops: {name}: {e}; skipped", file=sys.stderr)
    ys = yardstick()
    rows = []
    for name in names:
        if name not in paths:
            rows.append(dict(clip=name, missing=missing[name]))
            continue
        saved = WORK / "out" / f"{name}.row.json"
        row = json.loads(saved.read_text()) if a.reuse and saved.is_file() else None
        if row is None or row["output"] != (WORK / "out" / f"{name}.mp4").is_file():
            row = run_clip(name, paths[name], a.model)
            score(ys, row, paths[name])
            saved.write_text(json.dumps(row, indent=1) + "\n")
        rows.append(row)
        y = row.get("yardstick") or {}
        print(f"{name}: rc {row['rc']}, lip sync made on {row['made_share']:.0%} ({row['seconds']} s), yardstick "
              f"{y.get('error') or fmt(y.get('corr')) + ' / ' + fmt(y.get('corr_best'))}"
              + (f"; {row['error']}" if row["error"] else ""), flush=True)
    summary = dict(stamp(), model=a.model, summary=summarize(rows), rows=rows)
    print(json.dumps(summary["summary"]))
    publish("tight_crops", summary, page(summary, clips))


if __name__ == "__main__":
    main()
