"""render_mesh — the Karras paper's product: an animated 3D lower face of the speaker for new audio.

The model folder's speaker surface (the frontalize stage's 3D landmark model extended over the
chin, Eqs. 7–8) is triangulated on a regular 2.5 mm grid (a few thousand vertices); each frame the
model's predicted face points (Karras: jaw, nose and lips; other families: the lips) move the
vertices by a thin-plate spline of their displacements, depth read from the surface; pyvista
renders it off screen (EGL), front and three-quarter views side by side, into an H.264 + AAC MP4
with the audio (``pipeline.face.face_mesh``). Stage: ``render_mesh.model`` saying
``synthesize.audio`` → ``render_mesh.out``; ``lipsynth render-mesh`` does the same for any audio.

Run: ``python -m stages.render_mesh.render_mesh``.
"""
from __future__ import annotations

import logging
import os
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from pipeline.face import face_mesh
from pipeline.io import media
from pipeline.face.canonical import Surface, TextureWindow
from pipeline.errors import LipsynthError
from pipeline.face.dlib_face import LIP_POINTS
from pipeline.models.model_folder import ModelError, load_speaker
from pipeline.models.mouth_prediction import check_emotion, load_audio, predict_mouth
from pipeline.io.runner import stage_main, write_timing

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


def driving_points(mouth: dict, window, shape3d: np.ndarray):
    """(rest (P, 2), moved (T, P, 2), lips (T, 18, 2), anchors (A, 2)), all mm on the canonical face.

    Models that predict the whole lower face (Karras: ``face_points``) drive the mesh with all of
    its points — the jaw and chin move too; the others with the 18 lip points. Anchors (points held
    still): the nose bridge and eye corners that are not driving points, and the mesh border.
    """
    if "face_points" in mouth:
        ids = [int(i) for i in mouth["face_point_ids"]]
        rest = window.to_mm(np.asarray(mouth["face_mean"], np.float64))
        moved = window.to_mm(np.asarray(mouth["face_points"], np.float64))
        lips = moved[:, [ids.index(p) for p in LIP_POINTS]]
    else:
        ids = list(LIP_POINTS)
        rest = window.to_mm(np.asarray(mouth["mean_shape"], np.float64))
        moved = lips = window.to_mm(np.asarray(mouth["lip_points"], np.float64))
    still = [a for a in face_mesh.ANCHOR_LANDMARKS if a not in ids]
    anchors = np.concatenate([shape3d[still, :2], face_mesh.border_anchors(X_MM, Y_MM)])
    return rest, moved, lips, anchors


def render_mesh(audio: str, model: str, out: str, fps: float = 25.0, size: int = 360, step_mm: float = 2.5,
                emotion=None, create_folder: bool = False) -> dict:
    """Render the animated mesh video; returns timing figures (ms per frame)."""
    surface, window, shape3d = speaker_surface(model)
    check_emotion(model, emotion)
    samples = load_audio(audio)
    mouth = predict_mouth(samples, model, fps, source=audio, emotion=emotion)
    rest, moved, lips, anchors = driving_points(mouth, window, shape3d)
    verts, tris = face_mesh.lower_face_mesh(surface, X_MM, Y_MM, step_mm)
    t0 = time.perf_counter()
    frames = face_mesh.animate(verts, surface, rest, moved, anchors)
    t1 = time.perf_counter()
    out_path = Path(out)
    if not out_path.parent.is_dir():
        if not create_folder:
            raise LipsynthError(f"{out}: output folder {out_path.parent} does not exist")
        out_path.parent.mkdir(parents=True)
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


def run(params) -> dict:
    r = params.render_mesh
    figures = render_mesh(params.synthesize.audio, r.model, r.out, r.fps, r.size, r.step_mm, r.emotion,
                          create_folder=True)
    write_timing("render_mesh", figures)
    return figures


def main(argv=None) -> int:
    return stage_main("lipsynth render-mesh (stage)", __doc__, run, argv)


if __name__ == "__main__":
    raise SystemExit(main())
