"""The dense 3D head (issue 34): does the rendered head move its mouth like the person did, and how fast?

For held-out (validation) clips of a corpus store, the model (Karras: jaw, nose, lips) speaks each
clip's own audio through ``render_mesh`` (dense textured head, front | three-quarter view, 512 px):

    opening corr   dlib re-tracks the front view; the inner-lip opening (÷ inter-ocular distance) is
                   correlated with the original clip's tracked opening (lag 0, and the best lag in ±2
                   frames), per clip — the yardstick's measure; median over clips and pooled
    vertex error   the paper's position term: the driving points as the mesh carries them (handle vertex
                   displacement added to the rest landmark) against the clip's tracked frontal landmarks,
                   mean distance (mm; the outer eye corners are 90 mm apart), and the same for the
                   network's raw prediction — the mesh should add nothing
    emotion        mean skin displacement (mm) between emotion candidates 0 and 1 of the model on the first
                   held-out clip, upper face (brows, eyes, forehead) and lower face: the network predicts
                   lower-face points only
    speed          render of the demo audio with the demo model: deform, render + encode (ms/frame),
                   medians of ``--repeats``

    python bench/head_render.py [--model runs/grid_s1/models/karras] [--store runs/grid_s1/store]
                                [--clips 12] [--repeats 3] [--page-only]

Writes results/head_render.json (commit, date, machine), results/head_render.jpg (frames: closed,
open and rounded mouth, original | front | three-quarter) and docs/head_render.md.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import tempfile
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]

from pipeline.face import dlib_face  # noqa: E402
from pipeline.io import media  # noqa: E402
from pipeline.io.store import open_group  # noqa: E402
from pipeline.measures.lipsync_measures import inner_opening  # noqa: E402
from pipeline.models import speaker_bank  # noqa: E402
from pipeline.models.model_folder import load_speaker  # noqa: E402
from stages.render_mesh.render_mesh import animate_head, render_mesh  # noqa: E402


def tracked_opening(frames: list[np.ndarray]) -> np.ndarray:
    """(N,) inner-lip opening ÷ inter-ocular distance per RGB frame (NaN where dlib finds no face)."""
    out = []
    for f in frames:
        g = cv2.cvtColor(f, cv2.COLOR_RGB2GRAY)
        found = dlib_face.detect_face(g, 1)
        if not found:
            out.append(np.nan)
            continue
        lm = dlib_face.predict_landmarks(g, found[0])[None]
        out.append(float(inner_opening(lm)[0] / dlib_face.interocular(lm)[0]))
    return np.array(out)


def correlation(a: np.ndarray, b: np.ndarray, lag: int = 0) -> float:
    """Pearson correlation of a[t] and b[t + lag] over the frames where both are finite."""
    n = min(len(a), len(b))
    a, b = a[:n], b[:n]
    a, b = (a[:n - lag], b[lag:]) if lag >= 0 else (a[-lag:], b[:n + lag])
    ok = np.isfinite(a) & np.isfinite(b)
    return float(np.corrcoef(a[ok], b[ok])[0, 1]) if ok.sum() > 3 else float("nan")


def clip_figures(video: dict, model: str, lmg, fr, tw, work: Path, footage: str | None = None) -> dict:
    """Render one held-out clip with its own audio; re-track; the vertex error of its frames. ``footage``: the
    frontalize store the head's blinks and turns are replayed from (None: a still head)."""
    out = work / f"{video['name']}{'-moving' if footage else ''}.mp4"
    render_mesh(video["path"], model, str(out), video["fps"], 512, footage=footage)
    frames = [f for _, f in media.iter_frames(str(out), "rgb24")]
    front = [f[:, : f.shape[1] // 2] for f in frames]
    a, b = video["first_frame"], video["first_frame"] + video["n_frames"]
    lms = np.asarray(lmg["landmarks"][a:b], np.float64)
    ok = np.asarray(lmg["valid"][a:b])
    truth = np.where(ok, inner_opening(lms) / dlib_face.interocular(lms), np.nan)
    rendered = tracked_opening(front)
    # vertex error (mm): driving points as the mesh moves them vs the tracked frontal landmarks
    head = animate_head(video["path"], model, video["fps"], footage=footage)
    ids, moved, h = head.point_ids, head.moved, head.handles
    carried = head.speaker.head_landmarks[ids][None] + (head.motion.skin[:, h, :2] - head.mesh.skin.vertices[None, h, :2])
    flm = np.asarray(fr["frontal_landmarks"][a:b], np.float64)[:, ids] * tw["mm_per_px"] + [tw["x0"], tw["y0"]]
    pose_ok = np.asarray(fr["pose_valid"][a:b])
    n = min(len(carried), len(flm))
    sel = pose_ok[:n]
    mesh_err = float(np.linalg.norm(carried[:n][sel] - flm[:n][sel], axis=-1).mean())
    pred_err = float(np.linalg.norm(moved[:n][sel] - flm[:n][sel], axis=-1).mean())
    faces = int(np.isfinite(rendered).sum())
    return dict(clip=video["name"], frames=len(frames), faces_found=faces,
                corr_lag0=correlation(truth, rendered, 0),
                corr_best=max(correlation(truth, rendered, k) for k in range(-2, 3)),
                vertex_error_mm=mesh_err, prediction_error_mm=pred_err,
                truth=truth.tolist(), rendered=rendered.tolist())


def pick_frames(rendered: np.ndarray, truth: np.ndarray) -> dict:
    """Frames with the mouth closed, open and (among the half-open) least wide — by the original's opening."""
    n = min(len(truth), len(rendered))
    truth, rendered = truth[:n], rendered[:n]
    t = np.where(np.isfinite(truth) & np.isfinite(rendered), truth, np.nan)
    closed, opened = int(np.nanargmin(t)), int(np.nanargmax(t))
    mid = np.flatnonzero(t > np.nanmedian(t))
    return dict(closed=closed, open=opened, mid=int(mid[len(mid) // 2]) if len(mid) else opened)


def emotion_effect(audio: str, model: str, fps: float) -> dict | None:
    """Mean skin displacement (mm) between emotion candidates 0 and 1: upper face (above the nose) and lower."""
    from pipeline.models.mouth_prediction import check_emotion
    try:
        check_emotion(model, 1)
    except Exception:
        return None
    h0, h1 = animate_head(audio, model, fps, emotion=0), animate_head(audio, model, fps, emotion=1)
    d = np.linalg.norm(h0.motion.skin - h1.motion.skin, axis=-1).mean(0)
    upper = h0.mesh.skin.vertices[:, 1] < 20.0                   # above the lower-face window: brows, eyes
    return dict(upper_face_mm=float(d[upper].mean()), lower_face_mm=float(d[~upper].mean()))


def speed(audio: str, model: str, repeats: int, work: Path) -> dict:
    runs = [render_mesh(audio, model, str(work / "speed.mp4"), 25.0, 512) for _ in range(repeats)]
    med = lambda k: float(np.median([r[k] for r in runs]))
    total = med("deform_ms") + med("render_ms")
    return dict(runs=runs, deform_ms=med("deform_ms"), render_encode_ms=med("render_ms"),
                frames_per_second=1000.0 / total, vertices=runs[0]["vertices"], triangles=runs[0]["triangles"])


def figure(video: dict, row: dict, out_png: Path, work: Path) -> None:
    src = [f for _, f in media.iter_frames(video["path"], "rgb24")]
    ren = [f for _, f in media.iter_frames(str(work / f"{video['name']}.mp4"), "rgb24")]
    picks = pick_frames(np.array(row["rendered"]), np.array(row["truth"]))
    rows = []
    for label, i in picks.items():
        h = ren[i].shape[0]
        s = cv2.resize(src[i], (int(src[i].shape[1] * h / src[i].shape[0]), h))
        strip = np.hstack([s, ren[i]])
        cv2.putText(strip, f"{label} (frame {i})", (8, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (255, 255, 255), 2)
        rows.append(strip)
    cv2.imwrite(str(out_png), cv2.cvtColor(np.vstack(rows), cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 92])


def write_page(res: dict, path: Path) -> None:
    s = res["speed"]
    lines = ["# The dense 3D head: measured", "",
             f"Written by `python bench/head_render.py` (commit {res['commit']}, {res['date']}, {res['machine']}); "
             "do not edit by hand.", "",
             f"Model `{res['model']}` ({res.get('model_steps')} training steps), {len(res['clips'])} held-out clips of "
             f"`{res['store']}`, own audio, "
             "front view re-tracked by dlib.", "",
             "| clip | frames | face found | opening corr lag 0 | best (±2) | with blinks and turns, lag 0 | "
             "vertex error mm | prediction error mm |",
             "|---|---|---|---|---|---|---|---|"]
    for c in res["clips"]:
        lines.append(f"| {c['clip']} | {c['frames']} | {c['faces_found']} | {c['corr_lag0']:.2f} | {c['corr_best']:.2f} | "
                     f"{c.get('moving_corr_lag0', float('nan')):.2f} | {c['vertex_error_mm']:.2f} | "
                     f"{c['prediction_error_mm']:.2f} |")
    lines += ["", f"Median opening correlation at lag 0: **{res['median_corr_lag0']:.2f}** (best lag "
                  f"{res['median_corr_best']:.2f}); pooled over all frames {res['pooled_corr_lag0']:.2f}. "
                  f"With the person's blinks and head turns replayed from the store's footage (`render_mesh.footage`): "
                  f"**{res.get('median_corr_lag0_moving', float('nan')):.2f}**. "
                  f"Mean vertex error {res['mean_vertex_error_mm']:.2f} mm (prediction alone "
                  f"{res['mean_prediction_error_mm']:.2f} mm).", "",
              f"Mesh: {s['vertices']} skin vertices, {s['triangles']} triangles; head texture "
              f"{res['texture'][1]} × {res['texture'][0]} px.", "",
              f"Speed (demo audio, demo Karras model, 512 px views, medians of {len(s['runs'])}): deform "
              f"{s['deform_ms']:.1f} ms/frame, render + encode {s['render_encode_ms']:.1f} ms/frame → "
              f"**{s['frames_per_second']:.1f} frames/s**.", ""]
    if res.get("emotion"):
        e = res["emotion"]
        lines += [f"Emotion 0 vs 1 ({res['clips'][0]['clip']}): the skin moves {e['lower_face_mm']:.2f} mm (lower face) and "
                  f"{e['upper_face_mm']:.2f} mm (upper face) on average — Karras' network here predicts the "
                  "42 lower-face points (jaw, nose, lips), so the emotion code can change only those.", ""]
    lines += ["Frames of the median clip at full size — original | front | three-quarter, mouth closed, open and "
              "half-open (by the original's opening):", "", "![frames](head_render.jpg)", ""]
    path.write_text("\n".join(lines))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default="runs/grid_s1/models/karras")
    ap.add_argument("--store", default="runs/grid_s1/store")
    ap.add_argument("--clips", type=int, default=12)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--speed-model", default="models/karras")
    ap.add_argument("--speed-audio", default="data/synthetic_speaker/speaker_03.mp4")
    ap.add_argument("--page-only", action="store_true", help="rewrite docs/head_render.md from results/head_render.json")
    a = ap.parse_args()
    os.chdir(ROOT)
    if a.page_only:
        write_page(json.loads((ROOT / "results" / "head_render.json").read_text()), ROOT / "docs" / "head_render.md")
        return 0
    store = Path(a.store)
    paths = [str(store / f"{n}.zarr") for n in ("ingest", "landmarks", "frontalize")]
    if "head_texture" not in (load_speaker(a.model) or {}):
        speaker_bank.add_head(a.model, *paths)              # a folder trained before the dense head
    lmg, fr = open_group(paths[1]), open_group(paths[2])
    tw = fr.attrs["texture_window"]
    val = [v for v in fr.attrs["videos"] if v["split"] == "val" and v["n_frames"] and not v.get("excluded")]
    val = [val[i] for i in np.unique(np.linspace(0, len(val) - 1, a.clips).round().astype(int))]
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        clips = []
        for v in val:
            clips.append(clip_figures(v, a.model, lmg, fr, tw, work))
            moving = clip_figures(v, a.model, lmg, fr, tw, work, footage=paths[2])
            clips[-1].update(moving_corr_lag0=moving["corr_lag0"], moving_corr_best=moving["corr_best"],
                             moving_faces_found=moving["faces_found"])
            print(f"{v['name']}: corr {clips[-1]['corr_lag0']:.2f} / {clips[-1]['corr_best']:.2f} (blinks and turns: "
                  f"{moving['corr_lag0']:.2f}), vertex error {clips[-1]['vertex_error_mm']:.2f} mm", flush=True)
        best = int(np.argsort([c["corr_lag0"] for c in clips])[len(clips) // 2])     # the median clip
        out_dir = ROOT / "results"
        out_dir.mkdir(exist_ok=True)
        figure(val[best], clips[best], out_dir / "head_render.jpg", work)
        sp = speed(a.speed_audio, a.speed_model, a.repeats, work)
    n = [min(len(c["truth"]), len(c["rendered"])) for c in clips]
    truth = np.concatenate([c["truth"][:k] for c, k in zip(clips, n)])
    rend = np.concatenate([c["rendered"][:k] for c, k in zip(clips, n)])
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    res = dict(commit=commit, date=datetime.datetime.now().isoformat(timespec="minutes"),
               machine=f"{platform.machine()}, {os.cpu_count()} cores", model=a.model, store=a.store,
               clips=clips, median_corr_lag0=float(np.nanmedian([c["corr_lag0"] for c in clips])),
               median_corr_best=float(np.nanmedian([c["corr_best"] for c in clips])),
               median_corr_lag0_moving=float(np.nanmedian([c["moving_corr_lag0"] for c in clips])),
               model_steps=json.loads((Path(a.model) / "config.json").read_text())["params"]["steps"],
               pooled_corr_lag0=correlation(truth, rend, 0),
               mean_vertex_error_mm=float(np.mean([c["vertex_error_mm"] for c in clips])),
               mean_prediction_error_mm=float(np.mean([c["prediction_error_mm"] for c in clips])),
               texture=list(load_speaker(a.model)["head_texture"].shape), speed=sp,
               emotion=emotion_effect(val[0]["path"], a.model, val[0]["fps"]))
    (ROOT / "results" / "head_render.json").write_text(json.dumps(res, indent=1) + "\n")
    page = ROOT / "docs" / "head_render.md"
    write_page(res, page)
    (ROOT / "docs" / "head_render.jpg").write_bytes((ROOT / "results" / "head_render.jpg").read_bytes())
    print(page.read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
