"""Learning curves of a new person (issue 24): each model family trained on 20 / 40 / 60 s / all of
the person's training clips, scored on the same held-out clips (in-store validation).

    python bench/learning_curve.py [--videos ../shared/data/grid_s4] [--run runs/s4]
        [--families lstm lstm_base brand karras] [--base runs/grid_s1/base/model]

Preprocesses ``--videos`` once into ``<run>/store`` (ingest → landmarks → frontalize → pca → whisper,
``data.val_fraction`` 0.25 split by clip), then per family and length trains with the stage's own
``train_seconds`` (a seeded subset of the training clips):
  lstm       the time-delayed LSTM from scratch, 600 steps;
  lstm_base  the same fine-tuned from ``--base`` (all weights; ``train.init_from``);
  brand      Voice Puppetry, 30 EM iterations;
  karras     Karras et al., 240 steps at lr 3e-3.
Prints ratio to the mean shape / median opening correlation per cell and writes
``<run>/learning_curve.json``. Existing models are reused (delete ``<run>/models`` to retrain).
"""
from __future__ import annotations

import argparse
import json
import subprocess
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import yaml

ROOT = Path(__file__).resolve().parents[1]

from pipeline.params import front_end_store  # noqa: E402
from stages import registry  # noqa: E402
from stages.registry import PREPROCESSING  # noqa: E402

LENGTHS = (20, 40, 60, None)
FAMILIES = {"lstm": registry.stage("train"), "lstm_base": registry.stage("train"),
            "brand": registry.stage("train_brand"), "karras": registry.stage("train_karras")}


def base_params(videos: str, run: Path) -> dict:
    t = yaml.safe_load((ROOT / "params.yaml").read_text())
    t["data"].update(videos=videos, val_fraction=0.25, on_bad_input="skip")
    for stage in ("ingest", "landmarks", "frontalize", "pca", "phonetic", "whisper"):
        t[stage]["out"] = str(run / "store" / f"{stage}.zarr")
    return t


def cell(t: dict, family: str, secs, run: Path, base: str) -> dict:
    section = FAMILIES[family].section
    tag = f"{family}_{secs or 'all'}"
    s = t[section]
    s.update(out=str(run / "models" / tag), metrics=str(run / "metrics" / f"{tag}.json"),
             plots=str(run / "plots" / f"{tag}.csv"), train_seconds=secs)
    if section == "train":
        s.update(steps=600, val_every=30, patience=None, baselines=False,
                 init_from=base if family == "lstm_base" else None, fine_tune="all")
    elif family == "brand":
        s.update(iterations=30, baseline=False)
    else:
        s.update(steps=240, lr=0.003)
    return t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--videos", default="../shared/data/grid_s4")
    ap.add_argument("--run", type=Path, default=Path("runs/s4"))
    ap.add_argument("--families", nargs="+", default=list(FAMILIES), choices=list(FAMILIES))
    ap.add_argument("--base", default="runs/grid_s1/base/model", help="base model folder for lstm_base")
    a = ap.parse_args()
    a.run.mkdir(parents=True, exist_ok=True)
    prep = a.run / "params.yaml"
    if not prep.exists():
        prep.write_text(yaml.safe_dump(base_params(a.videos, a.run), sort_keys=False))
    for name in PREPROCESSING:
        if not Path(yaml.safe_load(prep.read_text())[name]["out"]).exists():
            subprocess.run(registry.stage(name).argv(prep), cwd=ROOT, check=True)
    table = {}
    for family in a.families:
        for secs in LENGTHS:
            t = cell(yaml.safe_load(prep.read_text()), family, secs, a.run, a.base)
            t["train"]["feature_store"] = front_end_store(t)
            pfile = a.run / f"p_{family}_{secs or 'all'}.yaml"
            pfile.write_text(yaml.safe_dump(t, sort_keys=False))
            metrics = Path(t[FAMILIES[family].section]["metrics"])
            if not metrics.exists():
                subprocess.run(FAMILIES[family].argv(pfile), cwd=ROOT, check=True,
                               stdout=subprocess.DEVNULL)
            m = json.loads(metrics.read_text())
            val = m["val"] if "val" in m else m["entropic"]["val"]
            table[f"{family} {secs or 'all'}"] = dict(ratio=m["ratio_to_mean_shape"], corr=val["median_opening_corr"],
                                                      error_iod_pct=val["mouth_error_iod_pct"])
            print(f"{family:<10} {str(secs or 'all'):>4} s: ratio {m['ratio_to_mean_shape']:.3f}  corr "
                  f"{val['median_opening_corr']:.3f}  error {val['mouth_error_iod_pct']:.3f} % IOD", flush=True)
    (a.run / "learning_curve.json").write_text(json.dumps(table, indent=2))
    print("\n| family | " + " | ".join(f"{s or 'all'} s" for s in LENGTHS) + " |\n|---|" + "---|" * len(LENGTHS))
    for family in a.families:
        cells = [table[f"{family} {s or 'all'}"] for s in LENGTHS]
        print(f"| {family} | " + " | ".join(f"{c['ratio']:.3f} / {c['corr']:.3f}" for c in cells) + " |")

if __name__ == "__main__":
    main()
