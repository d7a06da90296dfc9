"""``lipsynth dvc-deps`` — derive each DVC stage's code dependencies from its imports.

A stage reruns when one of its declared deps changes, so its deps must name every project file
its command executes. Hand-kept lists drift; this module reads the imports instead: starting
from the module a stage's ``cmd`` runs (``python -m stages.x.y``), it follows every ``import``
and ``from … import`` statement (function-level ones included) that reaches a project module,
transitively, and lists those files (package ``__init__.py`` files included: Python runs them). A module that
runs other project modules as subprocesses names them in a module-level ``SUBPROCESS_MODULES``
tuple; their closures are deps too.

    lipsynth dvc-deps            # print the stages whose code deps differ from dvc.yaml
    lipsynth dvc-deps --write    # rewrite the code deps in dvc.yaml (data deps are kept)

It also checks the layers (``layer_violations``): ``pipeline`` imports no stage and no application;
a stage imports only ``pipeline`` and its own folder; only ``lipsynth`` (the applications) may
import across stages. Inside ``pipeline`` the rooms are ranked (``PIPELINE_ROOMS``): a module
imports its own room and rooms of lower rank only (``io`` never imports ``models``; ``face`` and
``audio`` never import each other), and no project modules import each other in a circle
(``import_cycles``).
"""
from __future__ import annotations

import argparse
import ast
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PROJECT_PACKAGES = ("pipeline", "stages", "lipsynth")
CODE_DEP = re.compile(r"^(pipeline|stages|lipsynth)/.*\.py$")
# pipeline's rooms and their rank: a module may import its own room and lower ranks only.
# "" = the modules at pipeline/'s top (errors, simd_level); "params" (the typed params.yaml) uses them only.
PIPELINE_ROOMS = {"": 0, "params": 1, "io": 2, "face": 3, "audio": 3, "video": 3, "models": 4, "measures": 5}


def pipeline_room(module: str) -> str | None:
    """``pipeline.models.x`` → "models", ``pipeline.params`` (a room's package) → "params",
    ``pipeline.errors`` → "", a non-pipeline module → None."""
    parts = module.split(".")
    if parts[0] != "pipeline":
        return None
    if len(parts) == 2 and parts[1] in PIPELINE_ROOMS:
        return parts[1]
    return parts[1] if len(parts) > 2 else ""


def module_file(module: str, root: Path = ROOT) -> Path | None:
    """The file of a project module (``a.b.c`` → a/b/c.py or a/b/c/__init__.py), or None."""
    if module.split(".")[0] not in PROJECT_PACKAGES:
        return None
    base = root.joinpath(*module.split("."))
    for f in (base.with_suffix(".py"), base / "__init__.py"):
        if f.is_file():
            return f
    return None


def imported_modules(path: Path, module: str) -> set[str]:
    """Every module name an import statement in ``path`` (module ``module``) may load.

    ``from a.b import c`` may load ``a.b`` and, when ``c`` is a submodule, ``a.b.c``; relative
    imports are resolved against ``module``. Parent packages are included (Python imports them).
    """
    tree = ast.parse(path.read_text(), str(path))
    is_pkg = path.name == "__init__.py"
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = module.split(".")
                base = parts if is_pkg else parts[:-1]
                base = base[:len(base) - (node.level - 1)]
                pkg = ".".join(base + ([node.module] if node.module else []))
            else:
                pkg = node.module
            names.add(pkg)
            names.update(f"{pkg}.{a.name}" for a in node.names)
    out = set()
    for n in names:
        parts = n.split(".")
        out.update(".".join(parts[:i]) for i in range(1, len(parts) + 1))
    return out


def subprocess_modules(path: Path) -> set[str]:
    """Modules ``path`` runs as ``python -m …`` (its module-level ``SUBPROCESS_MODULES`` tuple)."""
    out: set[str] = set()
    for node in ast.parse(path.read_text(), str(path)).body:
        if (isinstance(node, ast.Assign) and isinstance(node.value, (ast.Tuple, ast.List))
                and any(isinstance(t, ast.Name) and t.id == "SUBPROCESS_MODULES" for t in node.targets)):
            out.update(e.value for e in node.value.elts if isinstance(e, ast.Constant) and isinstance(e.value, str))
    return out


def module_closure(entry: str, root: Path = ROOT) -> dict[str, Path]:
    """All project modules ``entry`` loads, directly or not → their files."""
    seen: dict[str, Path] = {}
    todo = [entry] + [".".join(entry.split(".")[:i]) for i in range(1, entry.count(".") + 1)]
    while todo:
        m = todo.pop()
        if m in seen:
            continue
        f = module_file(m, root)
        if f is None:
            continue
        seen[m] = f
        run = {".".join(s.split(".")[:i]) for s in subprocess_modules(f) for i in range(1, s.count(".") + 2)}
        todo.extend((imported_modules(f, m) | run) - seen.keys())
    return seen


def entry_module(cmd: str) -> str | None:
    """``python -m stages.x.y [...]`` → ``stages.x.y``."""
    m = re.search(r"python3?\s+-m\s+([\w.]+)", cmd)
    return m.group(1) if m else None


def code_deps(cmd: str, root: Path = ROOT) -> list[str]:
    """Sorted project-relative files the stage command executes."""
    entry = entry_module(cmd)
    if entry is None:
        return []
    return sorted(f.relative_to(root).as_posix() for f in module_closure(entry, root).values())


def _load(path: Path):
    from ruamel.yaml import YAML
    yaml = YAML()
    yaml.preserve_quotes = True
    yaml.indent(mapping=2, sequence=4, offset=2)
    return yaml, yaml.load(path.read_text())


def stale_stages(dvc_yaml: Path = ROOT / "dvc.yaml", root: Path = ROOT) -> dict[str, tuple[list, list]]:
    """Stages whose declared code deps differ from the derived ones → (declared, derived)."""
    _, doc = _load(dvc_yaml)
    out = {}
    for name, stage in doc["stages"].items():
        declared = sorted(str(d) for d in (stage.get("deps") or []) if CODE_DEP.match(str(d)))
        derived = code_deps(stage["cmd"], root)
        if declared != derived:
            out[name] = (declared, derived)
    return out


def write_deps(dvc_yaml: Path = ROOT / "dvc.yaml", root: Path = ROOT) -> list[str]:
    """Rewrite every stage's code deps in place (data deps first, as written). Returns changed stages."""
    from ruamel.yaml.comments import CommentedSeq
    yaml, doc = _load(dvc_yaml)
    changed = []
    for name, stage in doc["stages"].items():
        data = [d for d in (stage.get("deps") or []) if not CODE_DEP.match(str(d))]
        derived = code_deps(stage["cmd"], root)
        new = CommentedSeq(data + derived)
        if [str(d) for d in (stage.get("deps") or [])] != [str(d) for d in new]:
            changed.append(name)
        stage["deps"] = new
    with open(dvc_yaml, "w") as f:
        yaml.dump(doc, f)
    return changed


def layer_violations(root: Path = ROOT) -> list[str]:
    """Imports that break the layers (see module doc), as 'file: imports module' lines."""
    bad = []
    for pkg in ("pipeline", "stages"):
        for f in sorted((root / pkg).rglob("*.py")):
            rel = f.relative_to(root)
            module = ".".join(rel.with_suffix("").parts)
            if module.endswith(".__init__"):
                module = module[:-len(".__init__")]
            for m in sorted(imported_modules(f, module)):
                top = m.split(".")[0]
                if top not in PROJECT_PACKAGES or module_file(m, root) is None:
                    continue
                if pkg == "pipeline" and top != "pipeline":
                    bad.append(f"{rel}: imports {m} (pipeline/ is the bottom layer)")
                elif pkg == "pipeline" and m.count(".") >= 1 and module_file(m, root).name != "__init__.py":
                    own, other = pipeline_room(module), pipeline_room(m)
                    if own not in PIPELINE_ROOMS:
                        bad.append(f"{rel}: pipeline/{own}/ is not a known room (add it to PIPELINE_ROOMS)")
                    elif other != own and PIPELINE_ROOMS.get(other, 99) >= PIPELINE_ROOMS[own]:
                        bad.append(f"{rel}: imports {m} (room {own or 'top'} may import only lower rooms, "
                                   f"not {other or 'top'})")
                elif pkg == "stages" and top == "lipsynth":
                    bad.append(f"{rel}: imports {m} (a stage may not import an application)")
                elif pkg == "stages" and top == "stages" and len(rel.parts) > 2:
                    own = rel.parts[1]
                    parts = m.split(".")
                    if len(parts) >= 2 and parts[1] != own:
                        bad.append(f"{rel}: imports {m} (a stage imports only pipeline/ and its own folder)")
    return bad


def import_cycles(root: Path = ROOT) -> list[list[str]]:
    """Circles of project modules importing each other (function-level imports included), each as
    the list of modules around it; empty when the import graph is a DAG."""
    graph: dict[str, set[str]] = {}
    for pkg in PROJECT_PACKAGES:
        for f in sorted((root / pkg).rglob("*.py")):
            module = ".".join(f.relative_to(root).with_suffix("").parts)
            if module.endswith(".__init__"):
                continue
            graph[module] = {m for m in imported_modules(f, module) if m != module and m.split(".")[0] in PROJECT_PACKAGES
                             and (mf := module_file(m, root)) is not None and mf.name != "__init__.py"}
    cycles, state = [], {}

    def visit(m, path):
        state[m] = "open"
        for n in sorted(graph.get(m, ())):
            if state.get(n) == "open":
                cycles.append(path[path.index(n):] + [n])
            elif n not in state:
                visit(n, path + [n])
        state[m] = "done"
    for m in sorted(graph):
        if m not in state:
            visit(m, [m])
    return cycles


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="lipsynth dvc-deps", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--write", action="store_true", help="rewrite the code deps in dvc.yaml")
    ap.add_argument("--dvc-yaml", type=Path, default=ROOT / "dvc.yaml")
    a = ap.parse_args(argv)
    bad = layer_violations(a.dvc_yaml.parent)
    for line in bad:
        print(f"layer violation: {line}", file=sys.stderr)
    if a.write:
        changed = write_deps(a.dvc_yaml, a.dvc_yaml.parent)
        print(f"updated code deps of: {', '.join(changed) or 'nothing (up to date)'}")
        return 1 if bad else 0
    stale = stale_stages(a.dvc_yaml, a.dvc_yaml.parent)
    for name, (declared, derived) in stale.items():
        print(f"{name}: missing {sorted(set(derived) - set(declared))}, extra {sorted(set(declared) - set(derived))}")
    if not stale:
        print("code deps of every stage are up to date")
    return 1 if stale or bad else 0


if __name__ == "__main__":
    raise SystemExit(main())
