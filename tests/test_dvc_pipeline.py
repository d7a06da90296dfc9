"""DVC: `dvc repro` builds the pipeline; editing a frontalize param reruns only frontalize."""
import json
import os
import shutil
import subprocess
import sys

import pytest
import yaml

from tests.conftest import ROOT


def dvc(proj, *args):
    env = dict(os.environ, PATH=os.path.dirname(sys.executable) + os.pathsep + os.environ["PATH"])
    r = subprocess.run([sys.executable, "-m", "dvc", *args], cwd=proj, env=env, capture_output=True, text=True,
                       timeout=900)
    assert r.returncode == 0, f"dvc {' '.join(args)} failed:\n{r.stdout}\n{r.stderr}"
    return r.stdout + r.stderr


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    """A copy of the project's pipeline with a tiny synthetic corpus, reproduced once."""
    proj = tmp_path_factory.mktemp("dvcproj")
    for name in ("pipeline", "stages"):
        shutil.copytree(ROOT / name, proj / name, ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("dvc.yaml", ".dvcignore"):
        shutil.copy(ROOT / name, proj / name)
    (proj / ".dvc").mkdir()
    shutil.copy(ROOT / ".dvc" / "config", proj / ".dvc" / "config")
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    params["synthetic_speaker"].update(n_videos=2, seconds_per_video=4.0)
    params["cluster"]["n_workers"] = 2
    (proj / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    subprocess.run(["git", "init", "-q"], cwd=proj, check=True)
    subprocess.run(["git", "-c", "user.email=t@t", "-c", "user.name=t", "commit", "-q", "--allow-empty", "-m", "x"],
                   cwd=proj, check=True)
    out = dvc(proj, "repro")
    for stage in ("synthetic_speaker", "ingest", "landmarks", "frontalize"):
        assert f"Running stage '{stage}'" in out
    return proj


@pytest.mark.slow
def test_repro_builds_all_stores(project):
    for name in ("ingest", "landmarks", "frontalize"):
        assert (project / "store" / f"{name}.zarr" / "zarr.json").exists()
    assert "up to date" in dvc(project, "status")


@pytest.mark.slow
def test_frontalize_param_reruns_only_frontalize(project):
    params = yaml.safe_load((project / "params.yaml").read_text())
    params["frontalize"]["inpaint_radius"] = params["frontalize"]["inpaint_radius"] + 1.0
    (project / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    status = json.loads(dvc(project, "status", "--json").strip().splitlines()[-1])
    assert set(status) == {"frontalize"}, status
    out = dvc(project, "repro")
    assert "Running stage 'frontalize'" in out
    for stage in ("synthetic_speaker", "ingest", "landmarks"):
        assert f"Running stage '{stage}'" not in out
        assert f"Stage '{stage}' didn't change, skipping" in out


@pytest.mark.slow
def test_cluster_param_invalidates_nothing(project):
    params = yaml.safe_load((project / "params.yaml").read_text())
    params["cluster"]["n_workers"] = 1
    (project / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    assert "up to date" in dvc(project, "status")
