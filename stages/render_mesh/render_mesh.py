"""render_mesh — the Karras paper's product: the speaker's animated, textured 3D head for new audio.

The model folder's speaker (its extended face surface f*, Eqs. 7–8 of paper 000, and its whole-face
texture with the landmarks of a shut mouth) becomes a dense head mesh (``pipeline.face.head_mesh``:
a 2 mm grid over the face outline, ~5,000 vertices, cut open along the inner-lip line, a dark mouth
cavity and teeth behind it); each frame the model's predicted points (Karras: jaw, nose and lips;
other families: the lips) move it by a pre-factorised bi-Laplacian solve (``pipeline.face.bilaplacian``);
pyvista renders it off screen (EGL), textured and lit, front and three-quarter views side by side, into
an H.264 + AAC MP4 with the audio (``pipeline.face.face_mesh``); the animated mesh is exported as OBJ +
PC2 point cache (``pipeline.face.mesh_export``) and as glTF 2.0 binary with its audio beside
(``pipeline.face.gltf_export``: ``head.glb`` + ``head.wav``, morph targets + a weights animation).
Stage: ``render_mesh.model`` saying ``synthesize.audio`` → ``render_mesh.out`` and ``render_mesh.export``;
``lipsynth render-mesh`` does the same for any audio.

Run: ``python -m stages.render_mesh.render_mesh``.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path

from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from pipeline.errors import LipsynthError
from pipeline.face import face_mesh, gltf_export, head_motion, mesh_export
from pipeline.face.canonical import Surface, TextureWindow
from pipeline.face.dlib_face import LIP_POINTS
from pipeline.face.head_mesh import HeadMesh, head_mesh, smooth_surface
from pipeline.face.head_texture import HeadWindow
from pipeline.io import media
from pipeline.io.store import atomic_output
from pipeline.models.model_folder import ModelError, load_speaker
from pipeline.models.mouth_prediction import check_emotion, load_audio, predict_mouth
from pipeline.io.runner import stage_main, write_timing

log = logging.getLogger("lipsynth.render_mesh")


@dataclass
class Speaker3D:
    """What the model folder keeps for the head: surface f*, lower-face texture window, head texture and its landmarks."""

    surface: Surface
    window: TextureWindow
    head_window: HeadWindow
    head_texture: np.ndarray
    head_landmarks: np.ndarray


def speaker_head(model: str) -> Speaker3D:
    """The model folder's speaker head, or a ModelError naming the folder."""
    spk = load_speaker(model)
    if spk is None or "head_texture" not in spk:
        raise ModelError(f"{model}: the model folder has no 3D face (speaker.npz without a head texture; written by "
                         "the train stages since the dense head) — retrain it with `dvc repro` or `lipsynth personalize`")
    g, w = spk["surface_grid"], spk["texture_window"]
    surface = Surface(spk["surface_depth"].astype(np.float64), float(g[0]), float(g[1]), float(g[2]))
    return Speaker3D(smooth_surface(surface),
                     TextureWindow(float(w[0]), float(w[1]), float(w[2]), int(w[3])),
                     HeadWindow.from_array(spk["head_window"]), spk["head_texture"],
                     spk["head_landmarks"].astype(np.float64))


def driving_points(mouth: dict, window: TextureWindow) -> tuple[list[int], np.ndarray]:
    """(68-point ids (P,), positions (T, P, 2) mm on the canonical face) of the predicted points.

    Models that predict the whole lower face (Karras: ``face_points``) drive the head with all of them
    — jaw, nose and lips; the others with the 18 lip points.
    """
    if "face_points" in mouth:
        return [int(i) for i in mouth["face_point_ids"]], window.to_mm(np.asarray(mouth["face_points"], np.float64))
    return list(LIP_POINTS), window.to_mm(np.asarray(mouth["lip_points"], np.float64))


@dataclass
class HeadAnimation:
    """A head speaking some audio: the speaker, rest mesh, motion, audio, the driving points and their handles."""

    speaker: Speaker3D
    mesh: HeadMesh
    motion: face_mesh.HeadMotion
    samples: np.ndarray                  # 16 kHz mono
    point_ids: list[int]
    moved: np.ndarray                    # (T, P, 2) mm: predicted driving points
    handles: np.ndarray                  # (P,) their skin vertices
    deform_ms: float                     # per frame


def animate_head(audio: str, model: str, fps: float = 25.0, step_mm: float = 2.0, emotion=None,
                 footage: str | None = None, blinks: bool = True, turns: bool = True) -> HeadAnimation:
    """``model``'s speaker's head saying ``audio`` at ``fps``; with ``footage`` (the frontalize store), it
    blinks (``blinks``) and turns (``turns``) as the person does there (``pipeline.face.head_motion``)."""
    spk = speaker_head(model)
    check_emotion(model, emotion)
    samples = load_audio(audio)
    mouth = predict_mouth(samples, model, fps, source=audio, emotion=emotion)
    ids, moved = driving_points(mouth, spk.window)
    mesh = head_mesh(spk.surface, spk.head_window, spk.head_landmarks, step_mm)
    t0 = time.perf_counter()
    deformer = face_mesh.deformer_for(mesh, spk.head_landmarks, ids)
    motion = face_mesh.animate(mesh, spk.surface, spk.head_landmarks, ids, moved, deformer)
    if footage and (blinks or turns):
        tracks = head_motion.footage_tracks(footage, len(moved), fps)
        motion = face_mesh.with_footage(motion, mesh, spk.surface, spk.head_landmarks,
                                        tracks.closure if blinks else None, tracks.rotation if turns else None)
    return HeadAnimation(spk, mesh, motion, samples, ids, moved, deformer.handles,
                         1000 * (time.perf_counter() - t0) / len(moved))


def render_mesh(audio: str, model: str, out: str, fps: float = 25.0, size: int = 512, step_mm: float = 2.0,
                emotion=None, create_folder: bool = False, export: str | None = None, glb: str | None = None,
                footage: str | None = None, blinks: bool = True, turns: bool = True) -> dict:
    """Render the animated head video (front | three-quarter view, audio muxed); returns timing figures.

    ``export``: also write the animated mesh there (OBJ + MTL + PNG texture + PC2 point cache,
    ``pipeline.face.mesh_export``, and ``export``.glb + .wav). ``glb``: the glTF 2.0 binary's path
    (default with ``export``: ``export``.glb), its audio beside it (same stem, .wav); checked writable
    before any work. ``footage``, ``blinks``, ``turns``: as ``animate_head``.
    """
    glb = glb or (f"{export}.glb" if export else None)
    if glb:
        gltf_export.check_writable(glb)
    out_path = Path(out)
    if not out_path.parent.is_dir():
        if not create_folder:
            raise LipsynthError(f"{out}: output folder {out_path.parent} does not exist")
        out_path.parent.mkdir(parents=True)
    head = animate_head(audio, model, fps, step_mm, emotion, footage, blinks, turns)
    mesh, motion = head.mesh, head.motion
    n = len(motion.skin)
    t1 = time.perf_counter()
    renderer = face_mesh.HeadRenderer(mesh, head.speaker.head_texture, size)
    try:
        with atomic_output(out_path, suffix=out_path.suffix) as tmp, \
                media.VideoWriter(tmp, fps, audio=head.samples, sample_rate=16000) as w:
            for t in tqdm(range(n), desc="render-mesh", unit="frame", leave=False):
                w.write(renderer.render(motion, t))
    finally:
        renderer.close()
    t2 = time.perf_counter()
    if export:
        mesh_export.write_animated_mesh(export, mesh.skin, motion.posed(motion.skin), head.speaker.head_texture, fps)
    gltf = gltf_export.write_glb(glb, mesh, motion, head.speaker.head_texture, fps, head.samples) if glb else {}
    log.info("wrote %s: %d frames at %.3f fps, head %d vertices / %d triangles; deform %.1f ms/frame, render + "
             "encode %.1f ms/frame", out_path, n, fps, len(mesh.skin.vertices), len(mesh.skin.triangles), head.deform_ms,
             1000 * (t2 - t1) / n)
    if gltf:
        log.info("wrote %s (%.1f MB): %d morph targets, worst vertex %.3f mm from the rendered motion; audio %s",
                 gltf["glb"], gltf["bytes"] / 1e6, gltf["morph_targets"], gltf["max_error_mm"], gltf["audio"])
    return dict(frames=n, vertices=len(mesh.skin.vertices), triangles=len(mesh.skin.triangles),
                deform_ms=round(head.deform_ms, 2), render_ms=round(1000 * (t2 - t1) / n, 2),
                **{f"glb_{k}": v for k, v in gltf.items() if k in ("morph_targets", "max_error_mm", "bytes")})


def run(params) -> dict:
    r = params.render_mesh
    figures = render_mesh(params.synthesize.audio, r.model, r.out, r.fps, r.size, r.step_mm, r.emotion,
                          create_folder=True, export=str(Path(r.export) / "head"), footage=r.footage, blinks=r.blinks,
                          turns=r.head_motion)
    write_timing("render_mesh", figures)
    return figures


def main(argv=None) -> int:
    return stage_main("lipsynth render-mesh (stage)", __doc__, run, argv)


if __name__ == "__main__":
    raise SystemExit(main())
