"""One place per parameter: each key's meaning sits beside its default in pipeline/params/, and
docs/parameters_reference.md is rendered from there (a stale reference fails here)."""
import dataclasses
import typing

import yaml

from lipsynth import params_doc
from pipeline.params import Params
from tests.conftest import ROOT


def sections():
    """(dotted name, dataclass) of every section, nested ones (cluster.security) included."""
    todo = [(f.name, typing.get_type_hints(Params)[f.name]) for f in dataclasses.fields(Params)]
    while todo:
        name, cls = todo.pop(0)
        yield name, cls
        hints = typing.get_type_hints(cls)
        todo += [(f"{name}.{f.name}", hints[f.name]) for f in dataclasses.fields(cls)
                 if dataclasses.is_dataclass(hints[f.name])]


def test_every_field_has_a_one_line_help():
    bad = []
    for name, cls in sections():
        for f in dataclasses.fields(cls):
            text = f.metadata.get("help")
            if not isinstance(text, str) or not text.strip() or "\n" in text or len(text) > 160:
                bad.append(f"{name}.{f.name}: {text!r}")
            if set(f.metadata) - {"help", "advanced", "min", "max"} or f.metadata.get("advanced", True) is not True:
                bad.append(f"{name}.{f.name}: unexpected metadata {dict(f.metadata)}")
            default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
            for bound in ("min", "max"):
                if bound in f.metadata and not isinstance(default, (int, float)) and default != "auto":
                    bad.append(f"{name}.{f.name}: a {bound} on a non-numeric key")
            lo, hi = f.metadata.get("min", float("-inf")), f.metadata.get("max", float("inf"))
            if isinstance(default, (int, float)) and not lo <= default <= hi:
                bad.append(f"{name}.{f.name}: default {default} outside its bounds [{lo}, {hi}]")
    assert not bad, "fields without a proper one-line help:\n" + "\n".join(bad)


def test_the_committed_reference_is_current():
    committed = (ROOT / "docs" / "parameters_reference.md").read_text()
    assert committed == params_doc.reference_markdown(), \
        "docs/parameters_reference.md is stale — run `lipsynth params-doc --write`"
    assert params_doc.main(["--check"]) == 0


def test_every_key_of_params_yaml_is_in_the_reference():
    reference = params_doc.reference_markdown()
    shipped = yaml.safe_load((ROOT / "params.yaml").read_text())
    missing = [f"{s}.{k}" for s, keys in shipped.items() for k in keys if f"| `{s}.{k}` |" not in reference]
    assert not missing, missing
    for s, keys in shipped.items():
        assert f"## `{s}`" in reference
    assert "| `cluster.security.tls_ca_file` |" in reference


def test_choices_and_advanced_keys_are_marked():
    reference = params_doc.reference_markdown()
    row = next(line for line in reference.splitlines() if line.startswith("| `data.on_bad_input` |"))
    assert "`error`, `skip`" in row
    row = next(line for line in reference.splitlines() if line.startswith("| `ingest.shard_frames` |"))
    assert row.endswith("| yes |")


def test_check_fails_with_one_line_when_the_reference_differs(tmp_path, monkeypatch, capsys):
    stale = tmp_path / "parameters_reference.md"
    stale.write_text(params_doc.reference_markdown().replace("master seed", "the seed"))
    monkeypatch.setattr(params_doc, "REFERENCE", stale)
    monkeypatch.setattr(params_doc, "ROOT", tmp_path)
    assert params_doc.main(["--check"]) == 1
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "params-doc --write" in err
    assert params_doc.main(["--write"]) == 0 and params_doc.main(["--check"]) == 0
