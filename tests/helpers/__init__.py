"""Helpers shared by the test modules: a copied DVC project, dvc commands, one-line errors."""
import json
import os
import shutil
import subprocess
import sys

import yaml

from tests.conftest import ROOT


def dvc(proj, *args, env: dict | None = None):
    """Run ``dvc ARGS`` in ``proj`` (this interpreter's environment first on PATH, ``env`` added); its output."""
    env = dict(os.environ, PATH=os.path.dirname(sys.executable) + os.pathsep + os.environ["PATH"], **(env or {}))
    r = subprocess.run([sys.executable, "-m", "dvc", *args], cwd=proj, env=env, capture_output=True, text=True,
                       timeout=2400)        # a whole repro: ~5 min alone on 2 cores, far more on a loaded machine
    assert r.returncode == 0, f"dvc {' '.join(args)} failed:\n{r.stdout}\n{r.stderr}"
    return r.stdout + r.stderr


def copy_project(proj, overrides: dict):
    """A git + DVC project in ``proj`` with this project's code, dvc.yaml and params.yaml (its
    sections updated with ``overrides``); nothing is run yet."""
    proj.mkdir(parents=True, exist_ok=True)
    for name in ("pipeline", "stages", "lipsynth"):
        shutil.copytree(ROOT / name, proj / name, ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("dvc.yaml", ".dvcignore"):
        shutil.copy(ROOT / name, proj / name)
    shutil.copytree(ROOT / "models" / "base", proj / "models" / "base")      # the shipped base, as a clone has it
    (proj / ".dvc").mkdir()
    shutil.copy(ROOT / ".dvc" / "config", proj / ".dvc" / "config")
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    for section, values in overrides.items():
        params[section].update(values)
    (proj / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    subprocess.run(["git", "init", "-q"], cwd=proj, check=True)
    subprocess.run(["git", "-c", "user.email=t@t", "-c", "user.name=t", "commit", "-q", "--allow-empty", "-m", "x"],
                   cwd=proj, check=True)
    return proj


def dvc_status(proj) -> dict:
    """``dvc status --json`` of ``proj``: {stage: changes} of the stages that would rerun."""
    return json.loads(dvc(proj, "status", "--json").strip().splitlines()[-1])


def one_error_line(r):
    """The one ``lipsynth: error`` line of a finished CLI run that exited with code 2."""
    lines = [line for line in r.stderr.strip().splitlines() if line.startswith("lipsynth: error")]
    assert r.returncode == 2 and len(lines) == 1, r.stderr
    return lines[0]
