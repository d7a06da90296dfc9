"""Regenerate a corpus report (``reports/<name>/``) from a committed configuration.

    python bench/report.py configs/grid_s1.yaml [--clips 20] [--skip-existing] [--no-sweep]

``configs/<name>.yaml`` holds overrides of params.yaml (the corpus, its output folders). This
merges them into ``runs/<name>/params.yaml`` (validated like any params file), runs the stages
ingest → landmarks → frontalize → pca → phonetic → whisper → train → delay_sweep with ``--params`` that file, then
``bench/synthesis_quality.py`` on ``--clips`` validation clips (candidates from other videos
only, then with the target's own frames), and copies into ``reports/<name>/``:
train_metrics.json, train_loss.csv, delay_sweep.csv, synthesis_quality.json,
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

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pipeline.params import as_dict, parse  # noqa: E402

STAGES = [("ingest", "stages.ingest.ingest"), ("landmarks", "stages.landmarks.landmarks"),
          ("frontalize", "stages.frontalize.frontalize"), ("pca", "stages.pca.pca"),
          ("phonetic", "stages.phonetic.phonetic"), ("whisper", "stages.whisper.whisper"), ("train", "stages.train.train"),
          ("brand", "stages.train_brand.train_brand"), ("delay_sweep", "stages.train.sweep")]
PAGE = [("evaluate", "stages.evaluate.evaluate"), ("report", "stages.report.report")]   # after the benches


def merged(config: Path) -> dict:
    """params.yaml with the config's sections merged in (key by key), as a validated plain tree."""
    tree = yaml.safe_load((ROOT / "params.yaml").read_text())
    for section, values in (yaml.safe_load(config.read_text()) or {}).items():
        tree.setdefault(section, {}).update(values or {})
    return as_dict(parse(tree, str(config)))


def output_of(params: dict, stage: str) -> Path:
    return Path(params["delay_sweep"]["plots"] if stage == "delay_sweep" else params[stage]["out"])


def run_stage(stage: str, module: str, params: dict, params_file: Path, skip_existing: bool) -> None:
    if skip_existing and output_of(params, stage).exists():
        print(f"== {stage}: {output_of(params, stage)} exists, skipped", flush=True)
        return
    t0 = time.perf_counter()
    print(f"== {stage}", flush=True)
    subprocess.run([sys.executable, "-m", module, "--params", str(params_file)], cwd=ROOT, check=True)
    print(f"== {stage}: {time.perf_counter() - t0:.0f} s", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("config", type=Path, help="configs/<name>.yaml")
    ap.add_argument("--clips", type=int, default=20, help="validation clips for synthesis quality")
    ap.add_argument("--skip-existing", action="store_true", help="do not rerun a stage whose output exists")
    ap.add_argument("--no-sweep", action="store_true", help="leave the delay sweep out")
    a = ap.parse_args()
    name = a.config.stem
    run_dir, report = ROOT / "runs" / name, ROOT / "reports" / name
    run_dir.mkdir(parents=True, exist_ok=True)
    report.mkdir(parents=True, exist_ok=True)
    params = merged(a.config)
    params_file = run_dir / "params.yaml"
    params_file.write_text(yaml.safe_dump(params, sort_keys=False))
    for stage, module in STAGES:
        if stage == "delay_sweep" and a.no_sweep:
            continue
        run_stage(stage, module, params, params_file, a.skip_existing)
    shutil.copy(params["train"]["metrics"], report / "train_metrics.json")
    shutil.copy(params["train"]["plots"], report / "train_loss.csv")
    shutil.copy(params["brand"]["metrics"], report / "train_brand_metrics.json")
    shutil.copy(params["brand"]["plots"], report / "train_brand.csv")
    if not a.no_sweep:
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
    # the HTML page (evaluate → report), copied in. The page shows logs/*.timing.json: set the
    # project's own aside so that it shows this corpus's (evaluate's last clip), then put them back
    logs = ROOT / "logs"
    kept = {p: p.read_bytes() for p in (logs / f"{s}.timing.json" for s in ("synthesize", "composite", "evaluate"))
            if p.is_file()}
    for p in kept:
        p.unlink()
    try:
        for stage, module in PAGE:
            run_stage(stage, module, params, params_file, a.skip_existing)
    finally:
        for p, data in kept.items():
            p.write_bytes(data)
    page = Path(params["report"]["out"])
    shutil.copy(page / "index.html", report / "index.html")
    shutil.rmtree(report / "videos", ignore_errors=True)
    shutil.copytree(page / "videos", report / "videos")
    print(f"report written to {report} (open {report / 'index.html'})")


if __name__ == "__main__":
    main()
