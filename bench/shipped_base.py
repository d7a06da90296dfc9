"""Rebuild the shipped base model ``models/base/`` from the GRID s1 corpus (one command).

    python bench/shipped_base.py [--corpus ../shared/data/grid_s1/video] [--steps 6300] [--out models/base]

The base model is what ``lipsynth personalize`` starts from on a fresh clone: the shipped front end's
LSTM (``params.yaml``'s ``train.features``, ``feature_norm``, ``delay``) trained on GRID speaker 1's
900 read sentences (45 min, CC BY 4.0; ``configs/grid_s1.yaml`` names the corpus), with the
paper-length budget of that config. Steps:

1. ``configs/grid_s1.yaml`` merged into params.yaml with the shipped front-end keys, written to
   ``runs/grid_s1/params_base.yaml``; the stores under ``runs/grid_s1/store/`` (ingest → landmarks
   → frontalize → pca → whisper) are made when absent (≈ 10 min on 2 cores), reused otherwise;
2. ``stages.train.train`` into ``runs/grid_s1/base_shipped/``, with early stopping (``PATIENCE``
   validations without a gain; the best weights kept: the encoder's states let the LSTM overfit one
   speaker's 45 minutes well before the paper's 300 epochs);
3. the model's three files (weights, config, arrays — no candidate bank, no face: a base carries
   no person) copied into ``--out`` with ``MANIFEST.json``: their SHA-256 (checked at every load,
   ``pipeline.models.base_model``), the corpus, its licence, the commit and the date.

People you will evaluate or personalize on stay out of the base (GRID s4, Obama, HDTF, Macron, Lieu).

A candidate base on part of the corpus plus another person's footage (``--every 3 --person
'obama=../shared/data/obama/obama_0[123468].mp4'``: a third of GRID s1 and six public-domain Obama clips,
his held-out 05 and 07 left out) is built the same way; ``--out`` elsewhere to compare it first
(``bench/base_transfer.py``: which base transfers to the strangers).
"""
from __future__ import annotations

import argparse
import datetime
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import yaml

ROOT = Path(__file__).resolve().parents[1]

from bench.base_model import person_stores, run  # noqa: E402  (one stage as a subprocess; another person's stores)
from pipeline.models.base_model import MODEL_FILES, write_manifest  # noqa: E402
from pipeline.params import as_dict, front_end_store, parse  # noqa: E402
from stages.registry import PREPROCESSING  # noqa: E402

PATIENCE = 10            # validations (of 21 steps) without a gain: the whisper LSTM overfits GRID s1 long before 300 epochs
FRONT_END_KEYS = ("features", "feature_norm", "delay", "vtlp_warps", "pitch_shifts")
LICENCE = ("GRID audiovisual sentence corpus, speaker 1 (Cooke, Barker, Cunningham & Shao 2006), "
           "CC BY 4.0")


DAMAGED = {"pbio7a"}      # GRID s1's clip damaged at the source (the face is lost in half its frames)
PERSON_LICENCES = {"obama": "the weekly addresses are works of the US federal government, public domain"}


def every_nth(corpus: Path, n: int, folder: Path) -> Path:
    """A folder of links to every ``n``-th clip of ``corpus`` (sorted by name, DAMAGED left out)."""
    clips = [c for c in sorted(corpus.glob("*.mp4")) if c.stem not in DAMAGED][::n]
    folder.mkdir(parents=True, exist_ok=True)
    for clip in clips:
        link = folder / clip.name
        if not link.is_symlink():
            link.symlink_to(clip.resolve())
    return folder


def corpus_line(corpus: str, people: list[str]) -> str:
    """The MANIFEST's corpus line: GRID s1's clips and minutes, plus the other people's names."""
    clips = sorted(Path(corpus).glob("*.mp4"))
    line = f"GRID s1 ({len(clips)} clips, {len(clips) * 3 / 60:.0f} min of read sentences)"
    return line + "".join(f" + {spec.partition('=')[0]} ({spec.partition('=')[2]})" for spec in people)


def base_params(corpus: str, steps: int, run_dir: Path, whisper_layers: list[int] | None = None,
                overrides: list[str] = ()) -> dict:
    """params.yaml + configs/grid_s1.yaml + the shipped front end (``whisper_layers``: another choice of encoder
    layers; ``overrides``: ``SECTION.KEY=VALUE`` settings), outputs under ``run_dir``."""
    shipped = yaml.safe_load((ROOT / "params.yaml").read_text())
    tree = yaml.safe_load((ROOT / "params.yaml").read_text())
    for section, values in yaml.safe_load((ROOT / "configs" / "grid_s1.yaml").read_text()).items():
        tree[section].update(values or {})
    tree["data"]["videos"] = corpus
    if whisper_layers:
        tree["whisper"]["layers"] = sorted(whisper_layers)
    for stage in PREPROCESSING:
        tree[stage]["out"] = str(run_dir / "store" / f"{stage}.zarr")
    tree["train"].update({k: shipped["train"][k] for k in FRONT_END_KEYS}, baselines=False, steps=steps, patience=PATIENCE,
                         out=str(run_dir / "base_shipped" / "model"),
                         metrics=str(run_dir / "base_shipped" / "train.json"),
                         plots=str(run_dir / "base_shipped" / "train_loss.csv"))
    for item in overrides:
        key, eq, value = item.partition("=")
        section, dot, name = key.partition(".")
        if not (eq and dot and section in tree and name in tree[section]):
            raise SystemExit(f"bench/shipped_base.py: --set {item!r}: write SECTION.KEY=VALUE with a key of params.yaml")
        tree[section][name] = yaml.safe_load(value)
    tree["train"]["feature_store"] = front_end_store(tree)
    return as_dict(parse(tree, "bench/shipped_base.py"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--corpus", default="../shared/data/grid_s1/video", help="GRID s1 videos (default: ../shared)")
    ap.add_argument("--steps", type=int, default=6300, help="optimizer steps (default 6300 = 300 epochs of GRID s1)")
    ap.add_argument("--run-dir", type=Path, default=ROOT / "runs" / "grid_s1", help="stores and training outputs")
    ap.add_argument("--out", type=Path, default=ROOT / "models" / "base", help="the shipped folder to write")
    ap.add_argument("--every", type=int, default=1, help="every N-th clip of the corpus (sorted; damaged clips left out)")
    ap.add_argument("--person", action="append", default=[], metavar="NAME=VIDEOS",
                    help="another person's footage trained on too (train.extra_corpora; repeatable); only footage "
                         "whose licence lets the weights ship")
    ap.add_argument("--repeat", type=int, default=20, help="each --person video appears this many times per epoch")
    ap.add_argument("--whisper-layers", type=int, nargs="+", default=None, metavar="K",
                    help="encoder layers the front end reads (whisper.layers; default: params.yaml's)")
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="override one parameter of the training run (YAML value; repeatable), e.g. "
                         "train.velocity_weight=10")
    a = ap.parse_args()
    a.run_dir.mkdir(parents=True, exist_ok=True)
    corpus = a.corpus if a.every == 1 else str(every_nth(Path(a.corpus), a.every, a.run_dir / f"corpus_every_{a.every}"))
    params = base_params(corpus, a.steps, a.run_dir.resolve(), a.whisper_layers, a.set)
    pfile = a.run_dir / "params_base.yaml"
    pfile.write_text(yaml.safe_dump(params, sort_keys=False))
    for stage in PREPROCESSING:
        if Path(params[stage]["out"]).exists():
            print(f"== {stage}: {params[stage]['out']} exists, kept", flush=True)
            continue
        print(f"== {stage}: {run(stage, pfile):.0f} s", flush=True)
    if a.person:
        params["train"].update(extra_corpora=[person_stores(params, spec, a.run_dir / "people") for spec in a.person],
                               extra_repeat=a.repeat)
        pfile.write_text(yaml.safe_dump(params, sort_keys=False))
    print(f"== train: {run('train', pfile):.0f} s", flush=True)
    ship(Path(params["train"]["out"]), Path(params["train"]["metrics"]), a.out, corpus, a.person, a.steps,
         " ".join(["python bench/shipped_base.py", *sys.argv[1:]]))


def ship(model: Path, metrics: Path, out: Path, corpus: str, people: list[str], steps: int, recipe: str) -> None:
    """Copy the trained ``model``'s three files and its ``metrics`` into ``out`` with MANIFEST.json (their
    SHA-256, the corpus, the licences, the ``recipe`` that rebuilds it, the commit, the date), atomically."""
    tmp = out.with_name(out.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    for name in MODEL_FILES:
        shutil.copy(model / name, tmp / name)
    shutil.copy(metrics, tmp / "train_metrics.json")
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    licences = "".join(f"; {spec.partition('=')[0]}: {PERSON_LICENCES.get(spec.partition('=')[0], 'see its source')}"
                       for spec in people)
    write_manifest(tmp, dict(corpus=corpus_line(corpus, people), licence=LICENCE + licences, recipe=recipe, steps=steps,
                             commit=commit, step_kept=json.loads(metrics.read_text())["step_kept"],
                             date=datetime.date.today().isoformat()))
    shutil.rmtree(out, ignore_errors=True)
    tmp.rename(out)
    print(f"shipped base written to {out}")


if __name__ == "__main__":
    main()
