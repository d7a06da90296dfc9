"""The shape of the code: no file over 400 lines and no function over 80 lines in pipeline/, stages/ and lipsynth/.

A function's length is ``end_lineno − lineno + 1`` of its ``def`` (methods and nested functions count on
their own; a nested function's lines also count toward the function that holds it).
"""
import ast

import pytest

from tests.conftest import ROOT

FOLDERS = ("pipeline", "stages", "lipsynth")
MAX_FILE_LINES = 400
MAX_FUNCTION_LINES = 80


def python_files() -> list:
    return sorted(p for folder in FOLDERS for p in (ROOT / folder).rglob("*.py"))


def long_functions(source: str, limit: int = MAX_FUNCTION_LINES) -> list[tuple[str, int, int]]:
    """(name, first line, length) of every def / async def longer than ``limit`` lines."""
    return [(node.name, node.lineno, node.end_lineno - node.lineno + 1) for node in ast.walk(ast.parse(source))
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
            and node.end_lineno - node.lineno + 1 > limit]


def test_the_folders_hold_python_files():
    assert {p.relative_to(ROOT).parts[0] for p in python_files()} == set(FOLDERS)


def test_no_file_is_over_400_lines():
    long = {str(p.relative_to(ROOT)): n for p in python_files()
            if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_FILE_LINES}
    assert not long, f"files over {MAX_FILE_LINES} lines: {long}"


def test_no_function_is_over_80_lines():
    long = [f"{p.relative_to(ROOT)}:{line} {name} ({n} lines)" for p in python_files()
            for name, line, n in long_functions(p.read_text(encoding="utf-8"))]
    assert not long, f"functions over {MAX_FUNCTION_LINES} lines: {long}"


@pytest.mark.parametrize("source, found", [
    ("def f():\n" + "    x = 1\n" * 80, [("f", 1, 81)]),
    ("def f():\n" + "    x = 1\n" * 79, []),
    ("class C:\n    async def m(self):\n" + "        x = 1\n" * 80, [("m", 2, 81)]),
    ("def outer():\n    def inner():\n" + "        x = 1\n" * 80,
     [("outer", 1, 82), ("inner", 2, 81)]),
])
def test_the_check_counts_methods_nested_and_async_functions(source, found):
    assert long_functions(source) == found
