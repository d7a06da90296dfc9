"""The stage registry (stages/registry.py) is the one list of stages: dvc.yaml agrees with it, the
CLI offers it, and no other file spells a stage's module."""
import importlib.util
import re
import subprocess

import pytest
import yaml

from lipsynth import cli
from stages import registry
from tests.conftest import ROOT


def dvc_stages() -> dict:
    return yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]


def test_dvc_yaml_has_the_registered_stages_in_order_each_running_its_module():
    stages = dvc_stages()
    assert list(stages) == [s.name for s in registry.STAGES]
    for s in registry.STAGES:
        assert stages[s.name]["cmd"] == f"python -m {s.module}", s.name


def test_each_stage_declares_exactly_its_registered_outputs():
    for s in registry.STAGES:
        declared = [next(iter(e)) if isinstance(e, dict) else e
                    for key in ("outs", "metrics", "plots") for e in dvc_stages()[s.name].get(key, [])]
        assert declared == [f"${{{key}}}" for key in s.outputs], s.name
        assert all(key.split(".")[0] == s.section for key in s.outputs), s.name


def test_each_stage_module_exists_with_a_main_and_its_section_is_in_params_yaml():
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    for s in registry.STAGES:
        assert importlib.util.find_spec(s.module) is not None, s.module
        assert re.search(r"^def main\(", (ROOT / (s.module.replace(".", "/") + ".py")).read_text(), re.M), s.module
        assert s.section in params, s.name
    assert set(registry.PREPROCESSING) <= set(registry.BY_NAME)


def test_the_cli_offers_every_stage_command_and_runs_its_module():
    for s in registry.STAGES:
        if s.command:
            assert cli.COMMANDS[s.command] == (s.module, s.description)
    assert not set(cli.APPLICATIONS) & {s.command for s in registry.STAGES}   # no application shadows a stage
    text = cli.usage()
    assert all(s.command in text for s in registry.STAGES if s.command) and "personalize" in text


def test_unknown_stage_names_the_known_ones():
    with pytest.raises(KeyError, match="no stage 'trian'.*train_brand"):
        registry.stage("trian")


def test_argv_runs_the_module_with_the_params_file(tmp_path):
    argv = registry.stage("train_brand").argv(tmp_path / "p.yaml")
    assert argv[1:] == ["-m", "stages.train_brand.train_brand", "--params", str(tmp_path / "p.yaml")]


def test_no_other_python_file_spells_a_stage_module():
    """git grep for a stage's module finds the registry, the stage's own folder and dvc.yaml only (and this
    test, and a stage's ``SUBPROCESS_MODULES``: the literal tuple dvc-deps reads to follow a subprocess)."""
    files = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard", "*.py"], cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()
    assert "stages/registry.py" in files
    offenders = []
    for s in registry.STAGES:
        own = s.module.rsplit(".", 1)[0].replace(".", "/") + "/"
        for f in files:
            if f in ("stages/registry.py", "tests/test_stage_registry.py") or f.startswith(own):
                continue
            text = re.sub(r"^SUBPROCESS_MODULES = \(.*?\)$", "", (ROOT / f).read_text(), flags=re.M)
            if re.search(rf"['\"]{re.escape(s.module)}['\"]", text):
                offenders.append(f"{f}: {s.module}")
    assert not offenders, offenders


def test_the_stages_page_describes_exactly_the_registered_stages_in_order():
    """docs/stages.md's table (the long description of each stage) rows = the registry, in order, each naming
    its module's file as its entry point; its stage count and the README's agree with the registry."""
    page = (ROOT / "docs" / "stages.md").read_text()
    rows = re.findall(r"^\| `(\w+)` \| .* \| `([\w/]+\.py)`", page, re.M)
    assert [name for name, _ in rows] == [s.name for s in registry.STAGES]
    for (name, entry), s in zip(rows, registry.STAGES):
        assert entry == s.module.replace(".", "/") + ".py", name
    n = len(registry.STAGES)
    assert f"holds {n} stages" in page and f"The {n} stages" in (ROOT / "README.md").read_text()
