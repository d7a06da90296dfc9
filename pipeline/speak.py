"""``lipsynth speak`` — new audio + any video of the speaker → lip-synced MP4, outside DVC.

Runs the same code as the DVC stages: the target video is preprocessed on the fly (ingest →
landmarks → frontalize, with the params file's settings) into a cache folder keyed by the
file's identity and those settings, so a second run with the same target starts at once; then
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
import copy
import hashlib
import json
import logging
import os
import shutil
import tempfile
from pathlib import Path

from pipeline.errors import BadInputError, ParameterError
from pipeline.parallel import client_for
from pipeline.params import load_params
from pipeline.runner import run_main, setup_logging

log = logging.getLogger("lipsynth.speak")

PREPROCESS = ("ingest", "landmarks", "frontalize")


def default_cache() -> Path:
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "lipsynth" / "targets"


def cache_key(video: Path, params: dict) -> str:
    """Identity of a preprocessed target: the file (path, size, mtime) and the preprocessing params."""
    st = video.stat()
    ident = {"path": str(video.absolute()), "size": st.st_size, "mtime_ns": st.st_mtime_ns,
             "params": {k: params[k] for k in PREPROCESS}}
    return hashlib.sha1(json.dumps(ident, sort_keys=True, default=str).encode()).hexdigest()[:12]


def preprocess_target(video: Path, params: dict, cache: Path) -> dict:
    """Params whose ingest/landmarks/frontalize outputs hold ``video`` alone (computed once, then cached)."""
    from stages.frontalize import frontalize
    from stages.ingest import ingest
    from stages.landmarks import landmarks
    p = copy.deepcopy(params)
    folder = cache / f"{video.stem}-{cache_key(video, params)}"
    p["data"].update(videos=[str(video.absolute())], val_fraction=0.0, on_bad_input="error")
    for stage in PREPROCESS:
        p[stage]["out"] = str(folder / f"{stage}.zarr")
    if (folder / "frontalize.zarr").is_dir():
        log.info("target %s: preprocessed stores found in %s", video, folder)
        return p
    log.info("target %s: preprocessing into %s (ingest → landmarks → frontalize)", video, folder)
    run = copy.deepcopy(p)
    with client_for(p["cluster"]) as client:          # one cluster for the three stages
        run["cluster"]["address"] = client.scheduler.address
        ingest.run(run, p["ingest"]["out"])
        landmarks.run(run, p["ingest"]["out"], p["landmarks"]["out"])
        frontalize.run(run, p["ingest"]["out"], p["landmarks"]["out"], p["frontalize"]["out"])
    return p


def speak(audio: str, target: str, out: str, params: dict, model: str | None = None, retime: bool = True,
          cache: Path | None = None, diagnostic: bool = False) -> dict:
    """Write ``out`` (MP4): the speaker of ``target`` saying ``audio``. Returns ms/frame per phase."""
    from stages.composite import composite
    from stages.synthesize import synthesize
    for path, what in ((audio, "audio"), (target, "target video")):
        if not Path(path).is_file():
            raise BadInputError(path, f"{what} file not found")
    if not str(out).lower().endswith(".mp4"):
        raise ParameterError(f"--out {out}: expected an .mp4 file name")
    from stages.train.predict import load_audio
    load_audio(audio)                          # a bad audio file fails now, not after preprocessing
    p = preprocess_target(Path(target), params, cache or default_cache())
    p["synthesize"].update(audio=str(audio), target=str(Path(target).absolute()), retime=retime,
                           model=model or params["synthesize"]["model"])
    p["composite"]["diagnostic"] = diagnostic
    stores = synthesize.open_stores(p, pca=False)
    entry = stores["frontalize"].attrs["videos"][0]
    work = Path(tempfile.mkdtemp(prefix=".lipsynth-speak-", dir=Path(out).absolute().parent))
    try:
        ms = synthesize.run(p, str(work / "synthesize.zarr"), stores, entry)
        ms.update(composite.run(p, str(work / "synthesize.zarr"), out))
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
