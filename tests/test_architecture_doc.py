"""docs/architecture.md is the one architecture text, and it matches the tree (issue 49).

The rule (also written at the end of the page):
- its rooms table names every room of ``pipeline/`` (a folder with an ``__init__.py``) and every module
  of each room (a ``.py`` file other than ``__init__.py``), and nothing else; ``pipeline/`` itself is
  the rank-0 row with the top-level modules;
- each room's rank equals ``lipsynth.dvc_deps.PIPELINE_ROOMS``;
- every path in code on the page (inline code or a fenced block: a word with a ``/``, or ending in
  ``.py``) exists, relative to the project root, ``docs/`` or ``pipeline/`` (``<name>`` stands for any
  folder), and every dotted ``pipeline.…`` name is a module or package of ``pipeline/``;
- each room's API page ``docs/api/<room>.md`` renders (``::: …``) the room's package and exactly its modules;
- README.md, docs/index.md and ``pipeline/__init__.py`` point to the page and do not copy the room lists.
"""
import ast
import re

import pytest

from lipsynth.dvc_deps import PIPELINE_ROOMS
from tests.conftest import ROOT

PAGE = ROOT / "docs" / "architecture.md"
ROW = re.compile(r"^\| *(\d+) *\| *\[`(\w+)/`\]\(api/(\w+)\.md\) *\| *([^|]*)\|", re.M)


def real_rooms():
    """{room: sorted module stems}; "pipeline" is the top level."""
    top = ROOT / "pipeline"
    rooms = {"pipeline": sorted(p.stem for p in top.glob("*.py") if p.name != "__init__.py")}
    for d in sorted(top.iterdir()):
        if d.is_dir() and (d / "__init__.py").is_file():
            rooms[d.name] = sorted(p.stem for p in d.glob("*.py") if p.name != "__init__.py")
    return rooms


def table():
    """{room: (rank, api page stem, [module stems as written])} from the page's rooms table."""
    rows = ROW.findall(PAGE.read_text())
    assert rows, "docs/architecture.md has no rooms table (rows like | 2 | [`io/`](api/io.md) | `media.py`, … | … |)"
    out = {}
    for rank, room, page, cell in rows:
        assert room not in out, f"docs/architecture.md names room {room}/ twice"
        out[room] = (int(rank), page, re.findall(r"`([\w]+)\.py`", cell))
    return out


def test_the_rooms_table_names_every_room_and_module_of_pipeline_and_nothing_else():
    real, doc = real_rooms(), table()
    assert set(doc) == set(real), (f"rooms missing from docs/architecture.md: {sorted(set(real) - set(doc))}; "
                                   f"named but absent: {sorted(set(doc) - set(real))}")
    for room, (_, _, mods) in doc.items():
        where = "pipeline/" if room == "pipeline" else f"pipeline/{room}/"
        assert len(mods) == len(set(mods)), f"{where}: a module is named twice in docs/architecture.md"
        missing, absent = sorted(set(real[room]) - set(mods)), sorted(set(mods) - set(real[room]))
        assert not missing and not absent, (f"docs/architecture.md, row {where}: modules missing {missing}, "
                                            f"named but absent {absent}")


def test_each_rooms_rank_is_the_one_the_layer_check_enforces():
    ranks = {room: rank for room, (rank, _, _) in table().items()}
    enforced = {(room or "pipeline"): rank for room, rank in PIPELINE_ROOMS.items()}
    assert ranks == enforced, f"docs/architecture.md ranks {ranks} ≠ lipsynth/dvc_deps.py PIPELINE_ROOMS {enforced}"


def code_words(text):
    """The words in code on a markdown page: inline code spans and fenced blocks (the table's module
    cells included; a link's target is not code)."""
    words = []
    for block in re.findall(r"^```[^\n]*\n(.*?)^```", text, re.M | re.S):
        words += block.split()
    outside = re.sub(r"^```[^\n]*\n.*?^```", "", text, flags=re.M | re.S)
    for span in re.findall(r"`([^`\n]+)`", outside):
        words += span.split()
    return [w.strip("()[],;:.…'\"") if not w.endswith(".py") else w.strip("()[],;:'\"") for w in words]


def path_exists(word):
    pattern = re.sub(r"<[^>/]+>", "*", word.rstrip("/"))
    for base in (ROOT, ROOT / "docs", ROOT / "pipeline"):
        hits = list(base.glob(pattern)) if "*" in pattern else [base / pattern] if (base / pattern).exists() else []
        if any(h.is_dir() or not word.endswith("/") for h in hits):
            return True
    if "/" not in word:                       # a bare module name, e.g. `errors.py`: somewhere in the code layers
        return any(any((ROOT / layer).rglob(word)) for layer in ("pipeline", "stages", "lipsynth"))
    return False


def test_every_path_and_module_the_page_names_exists():
    words = code_words(PAGE.read_text())
    paths = [w for w in words if re.fullmatch(r"[\w.<>-]*(/[\w.<>-]*)+|[\w<>-]+\.py", w) and "//" not in w]
    assert len(paths) > 20, paths                    # the check reads the page
    bad = [w for w in paths if not path_exists(w)]
    assert not bad, f"docs/architecture.md names paths that do not exist: {bad}"
    dotted = [w for w in words if re.fullmatch(r"pipeline(\.\w+)+", w)]
    bad = [w for w in dotted if not (ROOT / (w.replace(".", "/") + ".py")).is_file()
           and not (ROOT / w.replace(".", "/") / "__init__.py").is_file()]
    assert not bad, f"docs/architecture.md names modules that do not exist: {bad}"


def test_a_path_that_does_not_exist_is_caught():
    assert path_exists("pipeline/io/store.py") and path_exists("stages/<name>/") and path_exists("errors.py")
    assert path_exists("api/<room>.md")
    assert not path_exists("params.py") and not path_exists("pipeline/params.py") and not path_exists("io/nothing.py")


@pytest.mark.parametrize("room", sorted(real_rooms()))
def test_each_room_has_an_api_page_rendering_exactly_its_modules(room):
    page = table()[room][1]
    api = ROOT / "docs" / "api" / f"{page}.md"
    assert api.is_file(), f"{api.relative_to(ROOT)} is missing (the API reference of {room})"
    pkg = "pipeline" if room == "pipeline" else f"pipeline.{room}"
    rendered = re.findall(r"^::: *([\w.]+)", api.read_text(), re.M)
    assert pkg in rendered, f"{api.relative_to(ROOT)} does not render the package {pkg}"
    mods = sorted(m[len(pkg) + 1:] for m in rendered if m.startswith(pkg + "."))
    assert mods == real_rooms()[room], f"{api.relative_to(ROOT)} renders {mods}, the room holds {real_rooms()[room]}"
    assert set(rendered) == {pkg} | {f"{pkg}.{m}" for m in mods}, rendered


def module_stems():
    return {m for mods in real_rooms().values() for m in mods}


def copied_names(text):
    """The modules of pipeline/ a text names (the distinctive ones: a stem with an underscore, as
    ``audio_features`` — ``store`` or ``flow`` are also ordinary words)."""
    return sorted(m for m in module_stems() if "_" in m and re.search(rf"\b{m}\b", text))


@pytest.mark.parametrize("rel, link", [("README.md", "(docs/architecture.md)"), ("docs/index.md", "(architecture.md)")])
def test_readme_and_overview_point_to_the_page_and_copy_no_room_list(rel, link):
    text = (ROOT / rel).read_text()
    assert link in text, f"{rel} does not link to the architecture page {link}"
    assert len(copied_names(text)) <= 3, f"{rel} names modules of pipeline/ {copied_names(text)}: a copy of the rooms table?"


def test_pipeline_package_docstring_points_to_the_page():
    doc = ast.get_docstring(ast.parse((ROOT / "pipeline" / "__init__.py").read_text()))
    assert "docs/architecture.md" in doc
    named = copied_names(doc) + [r for r in real_rooms() if r != "pipeline" and re.search(rf"\b{r}/", doc)]
    assert not named, f"pipeline/__init__.py's docstring lists modules again: {named}"
