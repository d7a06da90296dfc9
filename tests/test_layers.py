"""The house's rooms: derived DVC code deps are current, and imports respect the layers."""
import textwrap

import yaml

from lipsynth import dvc_deps
from tests.conftest import ROOT


def test_dvc_yaml_code_deps_equal_the_imports_of_each_stage():
    stale = dvc_deps.stale_stages()
    assert not stale, "dvc.yaml code deps are out of date — run `lipsynth dvc-deps --write`:\n" + "\n".join(
        f"  {name}: missing {sorted(set(d) - set(c))}, extra {sorted(set(c) - set(d))}"
        for name, (c, d) in stale.items())


def test_layers_pipeline_imports_no_stage_and_stages_import_only_their_own_folder():
    assert dvc_deps.layer_violations() == []


def test_every_project_module_a_stage_runs_is_a_declared_dep():
    """Independent of the generator: walk each stage's imports by executing them in a fresh
    interpreter and compare the project files Python actually loaded with dvc.yaml."""
    import json
    import subprocess
    import sys
    stages = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]
    for name, stage in stages.items():
        entry = dvc_deps.entry_module(stage["cmd"])
        code = ("import importlib, json, sys; importlib.import_module(%r); "
                "print(json.dumps(sorted(m.__file__ for m in list(sys.modules.values()) "
                "if getattr(m, '__file__', None))))" % entry)
        r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, r.stderr
        loaded = {p for p in json.loads(r.stdout.splitlines()[-1]) if p.startswith(str(ROOT) + "/")}
        loaded = {str(p)[len(str(ROOT)) + 1:] for p in loaded}
        loaded = {p for p in loaded if p.split("/")[0] in ("pipeline", "stages", "lipsynth")}
        declared = {d for d in stage["deps"] if d.endswith(".py")}
        assert loaded <= declared, f"{name}: imports {sorted(loaded - declared)} at load time but does not depend on them"


def make_project(root, files):
    for rel, text in files.items():
        p = root / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(textwrap.dedent(text))


def test_closure_follows_function_level_relative_and_submodule_imports(tmp_path):
    make_project(tmp_path, {
        "pipeline/__init__.py": "",
        "pipeline/a.py": "from .b import thing\n",
        "pipeline/b.py": "thing = 1\n",
        "pipeline/unused.py": "",
        "stages/__init__.py": "",
        "stages/x/__init__.py": "",
        "stages/x/run.py": "import numpy\nfrom pipeline import a\ndef f():\n    from stages.x import helper\n",
        "stages/x/helper.py": "",
    })
    deps = dvc_deps.code_deps("python -m stages.x.run --flag", tmp_path)
    assert deps == ["pipeline/__init__.py", "pipeline/a.py", "pipeline/b.py", "stages/__init__.py",
                    "stages/x/__init__.py", "stages/x/helper.py", "stages/x/run.py"]


def test_layer_check_catches_a_stage_importing_another_stage_and_pipeline_importing_up(tmp_path):
    make_project(tmp_path, {
        "pipeline/__init__.py": "",
        "pipeline/a.py": "def f():\n    from stages.y import z\n",
        "stages/__init__.py": "",
        "stages/x/__init__.py": "",
        "stages/x/run.py": "from stages.y.z import g\nfrom stages.x import own\n",
        "stages/x/own.py": "",
        "stages/y/__init__.py": "",
        "stages/y/z.py": "def g():\n    pass\n",
        "lipsynth/__init__.py": "",
    })
    bad = dvc_deps.layer_violations(tmp_path)
    assert any(b.startswith("pipeline/a.py: imports stages.y") for b in bad), bad
    assert any(b.startswith("stages/x/run.py: imports stages.y") for b in bad), bad
    assert not any("stages.x.own" in b for b in bad), bad


def test_modules_run_as_subprocesses_are_deps_but_not_imports(tmp_path):
    make_project(tmp_path, {
        "pipeline/__init__.py": "",
        "pipeline/a.py": "",
        "stages/__init__.py": "",
        "stages/x/__init__.py": "",
        "stages/x/run.py": "SUBPROCESS_MODULES = ('stages.y.main',)\nNOT_THIS = ('stages.z.other',)\n",
        "stages/y/__init__.py": "",
        "stages/y/main.py": "from pipeline import a\n",
        "stages/z/__init__.py": "",
        "stages/z/other.py": "",
    })
    deps = dvc_deps.code_deps("python -m stages.x.run", tmp_path)
    assert deps == ["pipeline/__init__.py", "pipeline/a.py", "stages/__init__.py", "stages/x/__init__.py",
                    "stages/x/run.py", "stages/y/__init__.py", "stages/y/main.py"]
    assert dvc_deps.layer_violations(tmp_path) == []         # running a stage is not importing it


def test_pipeline_rooms_import_only_lower_rooms_and_nothing_imports_in_a_circle(tmp_path):
    assert dvc_deps.import_cycles() == []
    rooms = {p.name for p in (ROOT / "pipeline").iterdir() if p.is_dir() and (p / "__init__.py").is_file()}
    assert rooms == set(dvc_deps.PIPELINE_ROOMS) - {""}, rooms
    make_project(tmp_path, {
        "pipeline/__init__.py": "",
        "pipeline/errors.py": "",
        "pipeline/io/__init__.py": "",
        "pipeline/io/store.py": "from pipeline.errors import E\ndef f():\n    from pipeline.models import m\n",
        "pipeline/face/__init__.py": "",
        "pipeline/face/geo.py": "from pipeline.audio import feat\nfrom pipeline.io import store\n",
        "pipeline/audio/__init__.py": "",
        "pipeline/audio/feat.py": "",
        "pipeline/models/__init__.py": "",
        "pipeline/models/m.py": "from pipeline.face import geo\nfrom pipeline.models import n\n",
        "pipeline/models/n.py": "def g():\n    from pipeline.models import m\n",
        "stages/__init__.py": "",
    })
    bad = dvc_deps.layer_violations(tmp_path)
    assert any(b.startswith("pipeline/io/store.py: imports pipeline.models.m") for b in bad), bad
    assert any(b.startswith("pipeline/face/geo.py: imports pipeline.audio.feat") for b in bad), bad
    assert not any("pipeline.io.store" in b or "pipeline.errors" in b or "pipeline.face.geo" in b for b in bad), bad
    cycles = dvc_deps.import_cycles(tmp_path)
    assert ["pipeline.models.m", "pipeline.models.n", "pipeline.models.m"] in cycles, cycles
