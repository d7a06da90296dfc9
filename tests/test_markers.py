"""Every test that reads real footage from ../shared/data carries the ``real`` marker (directly or through its
module's ``pytestmark``), so ``pytest -m 'not real'`` is a complete run on a machine without the data."""
import ast
from pathlib import Path

TESTS = Path(__file__).parent


def marks(decorators) -> set[str]:
    """``pytest.mark.NAME`` names among decorators (or a ``pytestmark`` value)."""
    found = set()
    for d in decorators:
        for node in ast.walk(d):
            if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Attribute) and node.value.attr == "mark":
                found.add(node.attr)
    return found


def names_used(fn) -> set[str]:
    return {n.id for n in ast.walk(fn) if isinstance(n, ast.Name)} | {a.arg for a in fn.args.args}


def real_data_users(tree, real: set[str]) -> set[str]:
    """Module-level functions that reach ``shared``/``SHARED`` or a real-data fixture, directly or via another."""
    fns = {f.name: f for f in tree.body if isinstance(f, ast.FunctionDef)}
    users = set(real)
    while True:
        more = {name for name, f in fns.items() if name not in users and names_used(f) & users}
        if not more:
            return users
        users |= more


def data_names(tree) -> set[str]:
    """``shared``/``SHARED`` when the module defines or imports them (a local variable of that name is not the data)."""
    names = set()
    for node in ast.walk(tree):                          # imports inside functions count too
        if isinstance(node, ast.ImportFrom):
            names |= {a.asname or a.name for a in node.names}
    for node in tree.body:
        if isinstance(node, ast.FunctionDef):
            names.add(node.name)
        elif isinstance(node, ast.Assign):
            names |= {getattr(t, "id", "") for t in node.targets}
    return names & {"shared", "SHARED"}


def is_fixture(f) -> bool:
    return any("fixture" in ast.unparse(d) for d in f.decorator_list)


def unmarked_real_tests() -> list[str]:
    trees = {p: ast.parse(p.read_text()) for p in sorted(TESTS.glob("*.py"))}
    conftest = trees[TESTS / "conftest.py"]
    real_fixtures = {f.name for f in conftest.body if isinstance(f, ast.FunctionDef) and is_fixture(f)
                     and f.name in real_data_users(conftest, data_names(conftest))}
    missing = []
    for path, tree in trees.items():
        users = real_data_users(tree, data_names(tree) | real_fixtures)
        module_marks = set()
        for node in tree.body:
            if isinstance(node, ast.Assign) and any(getattr(t, "id", "") == "pytestmark" for t in node.targets):
                module_marks |= marks([node.value])
        for f in tree.body:
            if isinstance(f, ast.FunctionDef) and f.name.startswith("test_") and f.name in users:
                if "real" not in marks(f.decorator_list) | module_marks:
                    missing.append(f"{path.name}::{f.name}")
    return missing


def test_every_test_reading_shared_data_is_marked_real():
    assert unmarked_real_tests() == []


def test_the_check_sees_a_real_data_fixture_used_by_an_unmarked_test(tmp_path):
    tree = ast.parse("def fix():\n    return shared('x')\n\ndef test_a(fix):\n    pass\n\ndef test_b():\n    pass\n")
    assert real_data_users(tree, {"shared"}) >= {"fix", "test_a"} and "test_b" not in real_data_users(tree, {"shared"})
