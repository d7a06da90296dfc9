"""``lipsynth render-mesh`` — an animated 3D lower face of the model's speaker for any audio.

    lipsynth render-mesh AUDIO --model models/brand --out face.mp4 [--fps 25] [--size 360]

The model predicts mouth shapes (any family: ``pipeline.mouth_prediction``); the speaker's
lower-face mesh (its extended face surface from the model folder, a few thousand vertices) is
deformed by the lip points' displacements (thin-plate spline, depth from the surface) and
rendered off screen with pyvista (EGL): front and three-quarter views side by side, lips red,
the mouth opening dark. Output: H.264 + AAC MP4 with the audio, written atomically.
"""
from __future__ import annotations

import argparse
import logging
import os
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from pipeline import face_mesh, media
from pipeline.canonical import Surface, TextureWindow
from pipeline.errors import LipsynthError
from pipeline.model_folder import ModelError, load_speaker
from pipeline.mouth_prediction import load_audio, predict_mouth
from pipeline.runner import run_main, setup_logging

log = logging.getLogger("lipsynth.render_mesh")
X_MM, Y_MM = (-75.0, 75.0), (-10.0, 170.0)


def speaker_surface(model: str):
    """(Surface, TextureWindow, shape3d) of the model folder's speaker, or a ModelError naming the folder."""
    spk = load_speaker(model)
    if spk is None or "surface_depth" not in spk:
        raise ModelError(f"{model}: the model folder has no speaker surface (written by train/train_brand "
                         "since the mesh render) — retrain with `dvc repro`")
    g, w = spk["surface_grid"], spk["texture_window"]
    return (Surface(spk["surface_depth"].astype(np.float64), float(g[0]), float(g[1]), float(g[2])),
            TextureWindow(float(w[0]), float(w[1]), float(w[2]), int(w[3])), spk["shape3d"])


def render_mesh(audio: str, model: str, out: str, fps: float = 25.0, size: int = 360, step_mm: float = 2.5) -> dict:
    """Render the animated mesh video; returns timing figures (ms per frame)."""
    surface, window, shape3d = speaker_surface(model)
    samples = load_audio(audio)
    mouth = predict_mouth(samples, model, fps, source=audio)
    lips = window.to_mm(mouth["lip_points"].astype(np.float64))
    rest = window.to_mm(mouth["mean_shape"].astype(np.float64))
    verts, tris = face_mesh.lower_face_mesh(surface, X_MM, Y_MM, step_mm)
    anchors = np.concatenate([shape3d[list(face_mesh.ANCHOR_LANDMARKS), :2], face_mesh.border_anchors(X_MM, Y_MM)])
    t0 = time.perf_counter()
    frames = face_mesh.animate(verts, surface, rest, lips, anchors)
    t1 = time.perf_counter()
    out_path = Path(out)
    if not out_path.parent.is_dir():
        raise LipsynthError(f"{out}: output folder {out_path.parent} does not exist")
    tmp = out_path.with_name(out_path.stem + ".tmp" + out_path.suffix)
    renderer = face_mesh.MeshRenderer(verts, tris, size)
    try:
        with media.VideoWriter(tmp, fps, audio=samples, sample_rate=16000) as w:
            for pts, lp in tqdm(zip(frames, lips), total=len(frames), desc="render-mesh", unit="frame", leave=False):
                w.write(renderer.render(pts, lp))
    finally:
        renderer.close()
    os.replace(tmp, out_path)
    t2 = time.perf_counter()
    n = len(frames)
    log.info("wrote %s: %d frames at %.3f fps, mesh %d vertices / %d triangles; deform %.1f ms/frame, render + "
             "encode %.1f ms/frame", out_path, n, fps, len(verts), len(tris), 1000 * (t1 - t0) / n, 1000 * (t2 - t1) / n)
    return dict(frames=n, vertices=len(verts), deform_ms=1000 * (t1 - t0) / n, render_ms=1000 * (t2 - t1) / n)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="lipsynth render-mesh", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("audio", help="audio or video file")
    ap.add_argument("--model", default="models/lstm", help="model folder of any family (default: models/lstm)")
    ap.add_argument("--out", required=True, help="output MP4")
    ap.add_argument("--fps", type=float, default=25.0)
    ap.add_argument("--size", type=int, default=360, help="height of each view (px)")
    ap.add_argument("-v", "--verbose", action="store_true")
    a = ap.parse_args(argv)
    setup_logging(a.verbose)
    return run_main(lambda: render_mesh(a.audio, a.model, a.out, a.fps, a.size))


if __name__ == "__main__":
    raise SystemExit(main())
