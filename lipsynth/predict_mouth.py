"""``lipsynth predict-mouth`` — per-frame mouth shapes for an audio file, from a trained model folder.

    lipsynth predict-mouth AUDIO --model models/lstm [--fps 29.97] [--out shapes.npz] [--chunk-seconds 2]

AUDIO is any file PyAV reads (wav, mp3, m4a, the audio of a video...), any rate and channel
count. Output (.npz): coeffs (T, 20) PCA coefficients, lip_points (T, 18, 2) canonical texture
pixels, frame_time (T,) s, fps, pca_fingerprint — for T = round(duration · fps) frames; Karras
models also write face_points (T, 42, 2), the whole lower face, and the emotion vector used.
"""
from __future__ import annotations

import argparse
import logging
from pathlib import Path

import numpy as np

from pipeline.models.mouth_prediction import load_audio, predict_mouth
from pipeline.io.runner import run_main, setup_logging
from pipeline.io.store import atomic_output

log = logging.getLogger("lipsynth.predict")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="lipsynth predict-mouth", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("audio", help="audio or video file")
    ap.add_argument("--model", default="models/lstm", help="model folder (default: models/lstm)")
    ap.add_argument("--fps", type=float, default=25.0, help="output frame rate (25, 29.97, 30, ...)")
    ap.add_argument("--out", default=None, help="output .npz (default: AUDIO stem + .mouth.npz)")
    ap.add_argument("--chunk-seconds", type=float, default=None, help="stream the LSTM in chunks of this length")
    ap.add_argument("--device", default="auto")
    ap.add_argument("--emotion", default=None,
                    help="Karras models: emotion candidate K, or K1:K2:t (interpolation, t in [0, 1]); "
                         "default: the model's default (candidate 0). `lipsynth emotions --model DIR` lists them")
    ap.add_argument("-v", "--verbose", action="store_true")
    a = ap.parse_args(argv)
    setup_logging(a.verbose)

    def go():
        result = predict_mouth(load_audio(a.audio), a.model, a.fps, a.chunk_seconds, a.device, source=a.audio,
                               emotion=a.emotion)
        out = Path(a.out or Path(a.audio).with_suffix(".mouth.npz"))
        with atomic_output(out, suffix=".npz") as tmp:
            np.savez(tmp, **{k: v for k, v in result.items() if k != "coeffs_100hz"})
        log.info("%d frames at %.3f fps → %s", len(result["coeffs"]), a.fps, out)
    return run_main(go)


if __name__ == "__main__":
    raise SystemExit(main())
