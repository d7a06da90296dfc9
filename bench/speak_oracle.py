"""How good can `lipsynth speak` be when the mouth shapes are perfect? (issue 9 diagnostic)

Runs the real `speak` path with one change: the model's predicted lip points are replaced by the
target's own tracked frontal lip points (the "oracle" shapes; the audio must be the target's own
track, so the frame counts agree). Everything else — identity, 3D fit, candidate pool, weighted
median, teeth, jaw correction, blending, self-check — is what users run. Scoring the result with
`../shared/tools/lipsync_yardstick.py` then gives the floor that the render path and the yardstick's
own landmark noise put under any audio → shape model:

    python ../shared/tools/lipsync_yardstick.py --make ".venv/bin/python bench/speak_oracle.py \
        --model runs/grid_s1/models/lstm --audio {audio} --target {target} --out {out}" --json O.json CLIPS

`--blend F` mixes the oracle with the model's prediction (lip points = F · oracle + (1 − F) ·
prediction), to see how the yardstick responds to shape accuracy between the two.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)
import numpy as np

from lipsynth import speak as speak_app
from pipeline.face.dlib_face import LIP_POINTS
from pipeline.params import load_params
from pipeline.io.runner import run_main, setup_logging
from stages.synthesize import synthesize


def oracle_run(blend: float):
    """A `synthesize.run` whose prediction is replaced by the target's tracked lips."""
    real_run, real_predict = synthesize.run, synthesize.predict_mouth

    def run(params, out, stores, entry, mouth=None):
        fr = stores["frontalize"]
        sl = slice(entry["first_frame"], entry["first_frame"] + entry["n_frames"])
        tracked = np.asarray(fr["frontal_landmarks"][sl], np.float64)[:, LIP_POINTS]
        ok = synthesize.usable(fr, stores["landmarks"], entry) - entry["first_frame"]

        def oracle(mouth):
            lips = mouth["lip_points"].astype(np.float64)
            n = min(len(lips), len(tracked))
            good = np.zeros(len(lips), bool)
            good[ok[ok < n]] = True
            lips[good] = blend * tracked[:n][good[:n]] + (1 - blend) * lips[good]
            print(f"oracle: {good.sum()} of {len(lips)} frames use the tracked lips (blend {blend})")
            if blend == 1.0:
                # the tracked lips are in the target store's texture pixels already: no rescaling to the
                # store's scale, no re-targeting onto the target's mean mouth (those are for a model's shapes)
                params.synthesize.retarget = "never"
                return dict(mouth, lip_points=lips.astype(np.float32), iod_px=0.0)
            return dict(mouth, lip_points=lips.astype(np.float32))

        if mouth is not None:                   # speak predicted the shapes already (during preprocessing)
            return real_run(params, out, stores, entry, mouth=oracle(mouth))
        synthesize.predict_mouth = lambda *args, **kw: oracle(real_predict(*args, **kw))
        try:
            return real_run(params, out, stores, entry)
        finally:
            synthesize.predict_mouth = real_predict
    return run


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--audio", required=True)
    ap.add_argument("--target", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--model", required=True)
    ap.add_argument("--blend", type=float, default=1.0, help="share of the oracle in the lip points (0…1)")
    ap.add_argument("--cache", type=Path, default=Path("/tmp/speak_cache"))
    ap.add_argument("--params", default="params.yaml")
    a = ap.parse_args(argv)
    setup_logging(False)
    synthesize.run = oracle_run(a.blend)
    return run_main(lambda: speak_app.speak(a.audio, a.target, a.out, load_params(a.params), a.model, False, a.cache))


if __name__ == "__main__":
    raise SystemExit(main())
