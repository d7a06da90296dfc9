"""Figures in the docs come from bench-written pages (issue 49, item 8): no link to the hand-typed lab
notebook, no stale test-times page, and every page of the Benchmarks table is written by the script it names."""
import re

import pytest

from tests.conftest import ROOT

DOC_FILES = sorted((ROOT / "docs").rglob("*.md")) + [ROOT / "README.md", ROOT / "mkdocs.yml"]
BENCH_TABLE = re.compile(r"^\| \[[^\]]+\]\((?P<page>[^)#]+)\) \| `(?P<script>bench/[^`]+\.py)`", re.M)


def mentions(needle: str) -> list[str]:
    return [f"{p.relative_to(ROOT)}:{i}" for p in DOC_FILES
            for i, line in enumerate(p.read_text().splitlines(), 1) if needle in line.lower()]


@pytest.mark.parametrize("needle", ["results/notebook.md", "lab notebook"])
def test_no_docs_page_quotes_the_hand_typed_notebook(needle):
    assert mentions(needle) == [], f"figures come from bench-written pages (docs/benchmarks.md), not {needle}"


def test_the_test_times_page_is_gone_and_unlinked():
    assert not (ROOT / "docs" / "test_times.md").exists(), "CI cannot commit a rewritten test-times page"
    assert mentions("test_times.md") == []


def test_every_benchmarks_page_is_written_by_the_script_it_names():
    rows = BENCH_TABLE.findall((ROOT / "docs" / "benchmarks.md").read_text())
    assert len(rows) >= 10
    for page, script in rows:
        head = "\n".join((ROOT / "docs" / page).read_text().splitlines()[:5])
        assert script.split("/")[-1] in head, f"docs/{page} does not say it is written by {script}"
        assert page.removesuffix(".md") in (ROOT / script).read_text(), f"{script} does not write docs/{page}"


def test_a_page_marked_bench_written_names_an_existing_bench():
    for p in sorted((ROOT / "docs").glob("*.md")):
        if m := re.match(r"<!-- written by (bench/\S+\.py)", p.read_text()):
            assert (ROOT / m[1]).exists(), f"{p.name}: {m[1]} does not exist"
