"""Regenerate a corpus report (``reports/<name>/``) from a committed configuration.

    python bench/report.py configs/grid_s1.yaml [--clips 20] [--skip-existing] [--no-sweep] [--no-voices] [--set karras.steps=1770]

``configs/<name>.yaml`` holds overrides of params.yaml (the corpus, its output folders). This
merges them into ``runs/<name>/params.yaml`` (validated like any params file), runs the stages
ingest → landmarks → frontalize → pca → whisper → train → train_brand → train_karras → delay_sweep with
``--params`` that file; the shipped front end's LSTM (``train`` with params.yaml's front-end keys) and
the base model (``bench/base_model.py``: the main corpus + the ``--base-people``) beside it; then
``bench/cross_speaker.py`` on the three LSTMs (other people's voices), then
``bench/synthesis_quality.py`` on ``--clips`` validation clips (candidates from other videos
only, then with the target's own frames), and copies into ``reports/<name>/``:
train_metrics.json, train_loss.csv, delay_sweep.csv, cross_speaker.json, synthesis_quality.json,
synthesis_quality_target_in_pool.json, synthesis_quality_speak.json (``lipsynth speak`` on the
validation clips' files), then the ``evaluate`` and ``report`` stages and index.html + videos/
(the HTML page). Run from the project root.
"""
from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pipeline  # noqa: F401  (before NumPy: caps every numeric library at one SIMD level)

import yaml

ROOT = Path(__file__).resolve().parents[1]

from pipeline.params import as_dict, front_end_store, parse  # noqa: E402
from stages import registry  # noqa: E402
from stages.registry import PREPROCESSING  # noqa: E402

STAGES = (*PREPROCESSING, "train", "train_brand", "train_karras", "delay_sweep")
FRONT_END_KEYS = ("features", "feature_norm", "delay", "vtlp_warps", "pitch_shifts")   # the shipped LSTM's front end
BASE_PEOPLE = ("obama=../shared/data/obama", "hdtf=../shared/data/hdtf")             # GRID s4, Macron, Lieu stay unseen
PAGE = ("evaluate", "report")   # after the benches


def merged(config: Path, overrides: list[str] = ()) -> dict:
    """params.yaml with the config's sections merged in (key by key), then ``section.key=value``
    overrides (values parsed as YAML), as a validated plain tree."""
    tree = yaml.safe_load((ROOT / "params.yaml").read_text())
    for section, values in (yaml.safe_load(config.read_text()) or {}).items():
        tree.setdefault(section, {}).update(values or {})
    for item in overrides:
        key, eq, value = item.partition("=")
        section, dot, name = key.partition(".")
        if not eq or not dot or section not in tree:
            raise SystemExit(f"--set {item!r}: write section.key=value with a section of params.yaml")
        tree[section][name] = yaml.safe_load(value)
    return as_dict(parse(tree, str(config)))


def output_of(params: dict, stage: str) -> Path:
    """The stage's first output (its registry's first key), as ``params`` names it."""
    section, key = registry.stage(stage).outputs[0].split(".")
    return Path(params[section][key])


def run_stage(stage: str, params: dict, params_file: Path, skip_existing: bool) -> None:
    if skip_existing and output_of(params, stage).exists():
        print(f"== {stage}: {output_of(params, stage)} exists, skipped", flush=True)
        return
    t0 = time.perf_counter()
    print(f"== {stage}", flush=True)
    subprocess.run(registry.stage(stage).argv(params_file), cwd=ROOT, check=True)
    print(f"== {stage}: {time.perf_counter() - t0:.0f} s", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("config", type=Path, help="configs/<name>.yaml")
    ap.add_argument("--clips", type=int, default=20, help="validation clips for synthesis quality")
    ap.add_argument("--skip-existing", action="store_true", help="do not rerun a stage whose output exists")
    ap.add_argument("--no-sweep", action="store_true", help="leave the delay sweep out")
    ap.add_argument("--no-voices", action="store_true",
                    help="leave other people's voices out (the shipped-front-end LSTM, the base model, bench/cross_speaker.py)")
    ap.add_argument("--base-people", nargs="*", default=list(BASE_PEOPLE), metavar="NAME=VIDEOS",
                    help="other people in the base model (default: Obama and HDTF; none: no base model)")
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="override one param of the config (repeatable; e.g. a shorter budget: --set karras.steps=1770)")
    a = ap.parse_args()
    name = a.config.stem
    run_dir, report = ROOT / "runs" / name, ROOT / "reports" / name
    run_dir.mkdir(parents=True, exist_ok=True)
    report.mkdir(parents=True, exist_ok=True)
    params = merged(a.config, a.set)
    params["train"]["feature_store"] = front_end_store(params)
    params_file = run_dir / "params.yaml"
    params_file.write_text(yaml.safe_dump(params, sort_keys=False))
    for stage in STAGES:
        if stage == "delay_sweep" and a.no_sweep:
            continue
        run_stage(stage, params, params_file, a.skip_existing)
    if a.no_voices:
        (report / "cross_speaker.json").unlink(missing_ok=True)       # not from this run: not shown
    elif a.skip_existing and (report / "cross_speaker.json").exists():
        print("== cross_speaker: exists, skipped", flush=True)
    else:
        models = voices_models(params, run_dir, a.base_people, a.skip_existing)
        cmd = [sys.executable, str(ROOT / "bench" / "cross_speaker.py"), "--out", str(report / "cross_speaker.json")]
        for model, metrics in models:
            cmd += ["--model", model, "--metrics", metrics]
        subprocess.run(cmd, cwd=ROOT, check=True)
    params["report"]["benches"] = str(report.relative_to(ROOT))
    params_file.write_text(yaml.safe_dump(params, sort_keys=False))
    shutil.copy(params["train"]["metrics"], report / "train_metrics.json")
    shutil.copy(params["karras"]["metrics"], report / "train_karras_metrics.json")
    shutil.copy(params["train"]["plots"], report / "train_loss.csv")
    shutil.copy(params["brand"]["metrics"], report / "train_brand_metrics.json")
    shutil.copy(params["brand"]["plots"], report / "train_brand.csv")
    if a.no_sweep:
        (report / "delay_sweep.csv").unlink(missing_ok=True)          # not from this run: not shown
    else:
        shutil.copy(params["delay_sweep"]["plots"], report / "delay_sweep.csv")
    for flags, name, out in ((["--exclude-target"], "quality", "synthesis_quality.json"),
                             ([], "quality_in_pool", "synthesis_quality_target_in_pool.json"),
                             (["--path", "speak"], "quality_speak", "synthesis_quality_speak.json")):
        work = run_dir / name
        if a.skip_existing and (work / "quality.json").exists():
            print(f"== {name}: exists, skipped", flush=True)
        else:
            cmd = [sys.executable, str(ROOT / "bench" / "synthesis_quality.py"), "--params", str(params_file),
                   "--clips", str(a.clips), "--out", str(work)] + flags
            subprocess.run(cmd, cwd=ROOT, check=True)
        shutil.copy(work / "quality.json", report / out)
    # the HTML page (evaluate → report), copied in
    for stage in PAGE:
        run_stage(stage, params, params_file, a.skip_existing)
    page = Path(params["report"]["out"])
    shutil.copy(page / "index.html", report / "index.html")
    shutil.rmtree(report / "videos", ignore_errors=True)
    shutil.copytree(page / "videos", report / "videos")
    print(f"report written to {report} (open {report / 'index.html'})")


def voices_models(params: dict, run_dir: Path, base_people: list[str], skip_existing: bool) -> list[tuple[str, str]]:
    """(model folder, metrics) of the LSTMs compared on other voices: the config's, the shipped
    front end's (params.yaml's front-end keys on this corpus) and the base model (more faces)."""
    shipped = yaml.safe_load((ROOT / "params.yaml").read_text())["train"]
    out = [(params["train"]["out"], params["train"]["metrics"])]
    tree = yaml.safe_load(yaml.safe_dump(params))
    tree["train"].update({k: shipped[k] for k in FRONT_END_KEYS}, baselines=False,
                         out=str(run_dir / "models" / "lstm_shipped"), metrics=str(run_dir / "metrics" / "train_shipped.json"),
                         plots=str(run_dir / "plots" / "train_shipped.csv"))
    tree["train"]["feature_store"] = front_end_store(tree)
    pfile = run_dir / "params_shipped.yaml"
    pfile.write_text(yaml.safe_dump(tree, sort_keys=False))
    if (tree["train"]["features"], tree["train"]["delay"]) != (params["train"]["features"], params["train"]["delay"]):
        if not (skip_existing and Path(tree["train"]["out"]).exists()):
            run_stage("train", tree, pfile, False)
        out.append((tree["train"]["out"], tree["train"]["metrics"]))
    if base_people:
        base = run_dir / "base"
        if not (skip_existing and (base / "model").exists()):
            cmd = [sys.executable, str(ROOT / "bench" / "base_model.py"), str(run_dir / "params_shipped.yaml"),
                   "--out", str(base)]
            for person in base_people:
                cmd += ["--person", person]
            subprocess.run(cmd, cwd=ROOT, check=True)
        out.append((str(base / "model"), str(base / "train.json")))
    return out


if __name__ == "__main__":
    main()
