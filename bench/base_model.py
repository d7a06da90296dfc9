"""Build a base model that transfers: the main corpus plus other people's footage (issue 23).

    python bench/base_model.py runs/grid_s1/params.yaml --out runs/base \
        --person obama=../shared/data/obama --person hdtf=../shared/data/hdtf [--repeat 20]

The main corpus' stores must exist (``bench/report.py configs/grid_s1.yaml`` or the stages run with
that params file). Every ``--person NAME=VIDEOS`` (a video, a folder of videos or a glob) is
preprocessed by the pipeline's own stages — ingest → landmarks → frontalize → whisper, with the
main params (on bad input: skip) — into ``<out>/people/NAME/``; then ``stages.train.train`` trains
the main params' model with ``train.extra_corpora`` = those folders (``stages/train/extra_corpora``:
each clip's own mouth motion about the main speaker's mean shape, in the main PCA basis), writing
the model folder ``<out>/model`` and its metrics ``<out>/train.json``. A person's stores are
reused when they exist. Prints the seconds per step.

Keep people out of the base whom you will evaluate on as other voices or personalize later
(GRID s4, Macron, Lieu here): ``bench/cross_speaker.py --model <out>/model`` then measures
transfer on people neither model saw.
"""
from __future__ import annotations

import argparse
import subprocess
import time
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import yaml

ROOT = Path(__file__).resolve().parents[1]

from pipeline.params import as_dict, front_end_store, parse  # noqa: E402
from stages import registry  # noqa: E402

PERSON_STAGES = ("ingest", "landmarks", "frontalize", "whisper")   # another person's stores (no PCA: the main corpus')


def person_params(main: dict, videos: str, folder: Path) -> dict:
    """The main params with this person's videos and every store inside ``folder``."""
    tree = yaml.safe_load(yaml.safe_dump(main))
    tree["data"].update(videos=videos, on_bad_input="skip", val_fraction=0.0)
    for stage in PERSON_STAGES:
        tree[stage]["out"] = str(folder / f"{stage}.zarr")
    return as_dict(parse(tree, str(folder / "params.yaml")))


def person_stores(main: dict, spec: str, people: Path) -> str:
    """Preprocess ``spec`` (``NAME=VIDEOS``) with the main params into ``people/NAME/`` (stores kept when
    they exist); the folder, for ``train.extra_corpora``."""
    name, _, videos = spec.partition("=")
    folder = (people / name).resolve()
    folder.mkdir(parents=True, exist_ok=True)
    pfile = folder / "params.yaml"
    pfile.write_text(yaml.safe_dump(person_params(main, videos, folder), sort_keys=False))
    for stage in PERSON_STAGES:
        if (folder / f"{stage}.zarr").exists():
            print(f"== {name} {stage}: exists, kept", flush=True)
            continue
        print(f"== {name} {stage}: {run(stage, pfile):.0f} s", flush=True)
    return str(folder)


def run(stage: str, params_file: Path) -> float:
    """Run the registered stage ``stage`` on ``params_file`` as a subprocess; its seconds."""
    t0 = time.perf_counter()
    subprocess.run(registry.stage(stage).argv(params_file), cwd=ROOT, check=True)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("params", type=Path, help="the main corpus' params file (its stores must exist)")
    ap.add_argument("--person", action="append", default=[], metavar="NAME=VIDEOS", required=True,
                    help="another person's footage (repeatable)")
    ap.add_argument("--out", type=Path, default=ROOT / "runs" / "base")
    ap.add_argument("--repeat", type=int, default=20, help="each extra video appears this many times per epoch")
    ap.add_argument("--steps", type=int, default=None, help="training budget (default: the params file's)")
    a = ap.parse_args()
    main_params = yaml.safe_load(a.params.read_text())
    for spec in a.person:
        if not all(spec.partition("=")[::2]):
            ap.error(f"--person {spec!r}: write NAME=VIDEOS")
    folders = [person_stores(main_params, spec, a.out / "people") for spec in a.person]
    tree = yaml.safe_load(yaml.safe_dump(main_params))
    tree["train"].update(extra_corpora=folders, extra_repeat=a.repeat, baselines=False,
                         out=str((a.out / "model").resolve()), metrics=str((a.out / "train.json").resolve()),
                         plots=str((a.out / "train_loss.csv").resolve()))
    if a.steps:
        tree["train"]["steps"] = a.steps
    tree["train"]["feature_store"] = front_end_store(tree)
    tfile = a.out / "params.yaml"
    tfile.write_text(yaml.safe_dump(as_dict(parse(tree, str(tfile))), sort_keys=False))
    print(f"== base model: {run('train', tfile):.0f} s → {a.out / 'model'}", flush=True)


if __name__ == "__main__":
    main()
