"""``lipsynth render-mesh`` — the model's speaker as an animated, textured 3D head, for any audio.

    lipsynth render-mesh AUDIO --model models/karras --out head.mp4 [--export head/head] [--glb head.glb] [--size 512]
                        [--emotion K]

The model predicts face points for the audio (any family: ``pipeline.models.mouth_prediction``;
Karras models predict the whole lower face — jaw, nose, lips; the others the lips). The speaker's
head (its face surface and whole-face texture from the model folder: a ~5,000-vertex mesh, the
mouth cut open along the inner lips, a dark mouth cavity and teeth behind) follows them through a
bi-Laplacian deformation and is rendered off screen with pyvista (EGL), textured, lit and smooth
shaded: front and three-quarter views side by side. Output: H.264 + AAC MP4 with the audio,
written atomically. ``--export STEM`` also writes STEM.obj/.mtl/.png (the rest head, textured) and
STEM.pc2 (every frame's vertices: a point cache for Blender's Mesh Cache modifier and others), and
STEM.glb + STEM.wav. ``--glb FILE.glb`` writes the glTF 2.0 binary (textured head, morph targets and
a weights animation at --fps: plays in Blender, three.js, Unity, Unreal, <model-viewer>) with its audio
beside it (FILE.wav), and FILE.html: a page playing it in three.js (orbit, synced to the audio).
``--footage STORE`` (the frontalize store of the person's videos): the head blinks and turns as the
person does in that footage (``--no-blinks``, ``--no-head-motion`` turn either off).
"""
from __future__ import annotations

import argparse

from pipeline.io.runner import run_main, setup_logging
from pipeline.face.gltf_viewer import write_viewer_page
from stages.render_mesh.render_mesh import render_mesh


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="lipsynth render-mesh", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("audio", help="audio or video file")
    ap.add_argument("--model", default="models/karras", help="model folder of any family (default: models/karras)")
    ap.add_argument("--out", required=True, help="output MP4")
    ap.add_argument("--export", default=None, metavar="STEM",
                    help="also write the animated mesh: STEM.obj/.mtl/.png + STEM.pc2 point cache")
    ap.add_argument("--glb", default=None, metavar="FILE.glb",
                    help="also write the animated head as glTF 2.0 binary (+ FILE.wav audio, FILE.html viewer)")
    ap.add_argument("--footage", default=None, metavar="STORE",
                    help="the person's tracked footage (a frontalize store, e.g. store/frontalize.zarr): blink and "
                         "turn the head as they do there (default: eyes open, head still)")
    ap.add_argument("--no-blinks", action="store_true", help="with --footage: no blinks")
    ap.add_argument("--no-head-motion", action="store_true", help="with --footage: the head stays still")
    ap.add_argument("--fps", type=float, default=25.0)
    ap.add_argument("--size", type=int, default=512, help="height of each view (px; default 512)")
    ap.add_argument("--emotion", default=None,
                    help="Karras models: emotion candidate K or K1:K2:t (default: the model's default)")
    ap.add_argument("-v", "--verbose", action="store_true")
    a = ap.parse_args(argv)
    setup_logging(a.verbose)

    def go():
        figures = render_mesh(a.audio, a.model, a.out, a.fps, a.size, emotion=a.emotion, export=a.export, glb=a.glb,
                              footage=a.footage, blinks=not a.no_blinks, turns=not a.no_head_motion)
        if a.glb:
            write_viewer_page(a.glb)
        return figures

    return run_main(go)


if __name__ == "__main__":
    raise SystemExit(main())
