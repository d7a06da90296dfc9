"""``lipsynth speak`` — new audio + any video of the speaker → lip-synced MP4, outside DVC.

Runs the same code as the DVC stages: the target video is preprocessed on the fly (ingest →
landmarks → frontalize, with the params file's settings) into a cache folder keyed by the
file's content and those settings, so a second run with the same target starts at once; then
synthesize (mouth shapes from the model, re-timing, mouth texture) and composite (jaw
correction, layers, render-back, pyramid blend, H.264 + AAC).

The candidate pool is the target video's own frames: the longer the target, the more mouth
shapes it covers (the paper's targets are minutes long).

Examples
--------
  lipsynth speak --audio new_speech.wav --target speaker.mp4 --out result.mp4
  lipsynth speak --audio a.m4a --target t.mp4 --out o.mp4 --model models/lstm --no-retime
"""
from __future__ import annotations

import argparse
import logging
import shutil
import tempfile
from pathlib import Path

from lipsynth.target import default_cache, preprocess_target
from pipeline.errors import BadInputError, ParameterError
from pipeline.mouth_prediction import load_audio
from pipeline.params import Params, load_params
from pipeline.runner import run_main, setup_logging
from stages.composite import composite
from stages.synthesize import synthesize

log = logging.getLogger("lipsynth.speak")


def speak(audio: str, target: str, out: str, params: Params, model: str | None = None, retime: bool = True,
          cache: Path | None = None, diagnostic: bool = False) -> dict:
    """Write ``out`` (MP4): the speaker of ``target`` saying ``audio``. Returns ms/frame per phase."""
    for path, what in ((audio, "audio"), (target, "target video")):
        if not Path(path).is_file():
            raise BadInputError(path, f"{what} file not found")
    if not str(out).lower().endswith(".mp4"):
        raise ParameterError(f"--out {out}: expected an .mp4 file name")
    load_audio(audio)                          # a bad audio file fails now, not after preprocessing
    p = preprocess_target(Path(target), params, cache or default_cache())
    p.synthesize.audio, p.synthesize.retime = str(audio), retime
    p.synthesize.model = model or params.synthesize.model
    p.composite.diagnostic = diagnostic
    stores = synthesize.open_stores(p, pca=False)
    entry = dict(stores["frontalize"].attrs["videos"][0], path=str(target))     # messages name the user's file
    work = Path(tempfile.mkdtemp(prefix=".lipsynth-speak-", dir=Path(out).absolute().parent))
    try:
        ms = synthesize.run(p, str(work / "synthesize.zarr"), stores, entry)
        ms.update(composite.run(p, str(work / "synthesize.zarr"), out, p.frontalize.out, str(target), str(audio)))
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return ms


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="lipsynth speak", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--audio", required=True, help="new speech: any audio or video file (any rate, channels)")
    ap.add_argument("--target", required=True, help="video of the speaker to put the speech into")
    ap.add_argument("--out", required=True, help="output MP4 (replaced only when the run succeeds)")
    ap.add_argument("--model", default=None, help="model folder (default: synthesize.model of the params file)")
    ap.add_argument("--no-retime", action="store_true",
                    help="keep the target's timing (paper §3.3 off; for evaluation against ground truth)")
    ap.add_argument("--diagnostic", action="store_true",
                    help="also write OUT.diagnostic.mp4: target | result | synthesized texture")
    ap.add_argument("--params", default=None,
                    help="params file (default: ./params.yaml, else the one installed with lipsynth)")
    ap.add_argument("--cache", type=Path, default=None,
                    help=f"folder for preprocessed targets (default: {default_cache()})")
    ap.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    a = ap.parse_args(argv)
    setup_logging(a.verbose)
    params = a.params or ("params.yaml" if Path("params.yaml").is_file() else Path(__file__).parents[1] / "params.yaml")
    return run_main(lambda: speak(a.audio, a.target, a.out, load_params(params), a.model,
                                  not a.no_retime, a.cache, a.diagnostic))


if __name__ == "__main__":
    raise SystemExit(main())
