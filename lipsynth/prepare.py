"""``lipsynth prepare`` — preprocess a target video once, so ``live`` and ``speak`` start at once.

    lipsynth prepare face.mp4 [--model models/base] [--cache DIR]

Runs what ``speak`` runs before it needs any audio (``speak.prepare_target``): ingest → landmarks →
frontalize of the target into the content-keyed cache (``--cache``, as speak's), its identity against the
model's speaker, its 3D fit checked (a fit that fails is refused here, with the same line as speak's).
Prints the seconds it took and where the stores are. A target already prepared with these params and
this model is found at once.
"""
from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

from pipeline.errors import BadInputError
from pipeline.io.runner import run_main, setup_logging
from pipeline.params import Params, load_params

log = logging.getLogger("lipsynth.prepare")


def prepared(target: str, params: Params, model: str, cache: Path | None, prepared_only: bool):
    """The target's stores (``speak.prepare_target``), preprocessing only when allowed."""
    from lipsynth.speak import prepare_target
    from lipsynth.target import target_cluster, warm_up_worker
    from pipeline.io.parallel import SharedCluster
    if prepared_only:
        return prepare_target(target, params, model, cache, None, prepared_only=True)
    with SharedCluster(target_cluster(params.cluster, target), warm_up=warm_up_worker) as cluster:
        return prepare_target(target, params, model, cache, cluster)


def prepare(target: str, params_file, model: str | None, cache: Path | None) -> dict:
    from pipeline.models.mouth_prediction import open_model
    params = load_params(params_file)
    if not Path(target).is_file():
        raise BadInputError(target, "target video file not found")
    model = open_model(model or params.synthesize.model)     # checked once, passed on
    t0 = time.perf_counter()
    p, _, entry, report = prepared(target, params, model, cache, prepared_only=False)
    seconds = time.perf_counter() - t0
    print(f"prepared {target} ({entry['n_frames']} frames, {entry['n_frames'] / entry['fps']:.1f} s) in "
          f"{seconds:.1f} s: {Path(p.frontalize.out).parent}")
    return dict(seconds=seconds, report=report)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="lipsynth prepare", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("target", help="video of the person")
    ap.add_argument("--model", default=None, help="model folder it will be animated with (default: synthesize.model)")
    ap.add_argument("--cache", type=Path, default=None, help="folder of preprocessed targets (default: speak's)")
    ap.add_argument("--params", default=None, help="params file (default: ./params.yaml, else the installed one)")
    ap.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    a = ap.parse_args(argv)
    setup_logging(a.verbose)
    params = a.params or ("params.yaml" if Path("params.yaml").is_file() else Path(__file__).parents[1] / "params.yaml")
    return run_main(lambda: prepare(a.target, params, a.model, a.cache))


if __name__ == "__main__":
    raise SystemExit(main())
