"""``lipsynth render-mesh`` — an animated 3D lower face of the model's speaker for any audio.

    lipsynth render-mesh AUDIO --model models/karras --out face.mp4 [--fps 25] [--size 360] [--emotion K]

The model predicts mouth shapes (any family: ``pipeline.models.mouth_prediction``); the speaker's
lower-face mesh (its extended face surface from the model folder, a few thousand vertices) is
deformed by the predicted points' displacements (Karras models: the whole lower face — jaw, nose,
lips; other families: the lips) (thin-plate spline, depth from the surface) and
rendered off screen with pyvista (EGL): front and three-quarter views side by side, lips red,
the mouth opening dark. Output: H.264 + AAC MP4 with the audio, written atomically.
"""
from __future__ import annotations

import argparse

from pipeline.io.runner import run_main, setup_logging
from stages.render_mesh.render_mesh import render_mesh


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="lipsynth render-mesh", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("audio", help="audio or video file")
    ap.add_argument("--model", default="models/lstm", help="model folder of any family (default: models/lstm)")
    ap.add_argument("--out", required=True, help="output MP4")
    ap.add_argument("--fps", type=float, default=25.0)
    ap.add_argument("--size", type=int, default=360, help="height of each view (px)")
    ap.add_argument("--emotion", default=None,
                    help="Karras models: emotion candidate K or K1:K2:t (default: the model's default)")
    ap.add_argument("-v", "--verbose", action="store_true")
    a = ap.parse_args(argv)
    setup_logging(a.verbose)
    return run_main(lambda: render_mesh(a.audio, a.model, a.out, a.fps, a.size, emotion=a.emotion))


if __name__ == "__main__":
    raise SystemExit(main())
