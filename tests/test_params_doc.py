"""One place per parameter: each key's default sits in its dataclass in pipeline/params/, its meaning
once in pipeline/params/help.yaml; docs/parameters_reference.md and params.yaml's comments are
rendered from there (a stale one fails here)."""
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


def test_every_field_has_a_one_line_help_and_help_yaml_names_only_fields():
    bad, help_ = [], params_doc.meanings()
    fields = {(name, f.name) for name, cls in sections() for f in dataclasses.fields(cls)}
    stale = {(s, k) for s, keys in help_.items() for k in keys} - fields
    assert not stale, f"help.yaml explains keys no section has: {sorted(stale)}"
    for name, cls in sections():
        for f in dataclasses.fields(cls):
            entry = help_.get(name, {}).get(f.name, {})
            text = entry.get("help")
            if not isinstance(text, str) or not text.strip() or "\n" in text or len(text) > 160:
                bad.append(f"{name}.{f.name}: {text!r}")
            if set(entry) - {"help", "advanced"} or not isinstance(entry.get("advanced", False), bool):
                bad.append(f"{name}.{f.name}: unexpected help.yaml entry {entry}")
            if set(f.metadata) - {"min", "max"}:
                bad.append(f"{name}.{f.name}: unexpected metadata {dict(f.metadata)} (meanings belong in help.yaml)")
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
    for s in shipped:
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
    params = tmp_path / "params.yaml"
    params.write_text((ROOT / "params.yaml").read_text())
    monkeypatch.setattr(params_doc, "REFERENCE", stale)
    monkeypatch.setattr(params_doc, "PARAMS_YAML", params)
    monkeypatch.setattr(params_doc, "ROOT", tmp_path)
    assert params_doc.main(["--check"]) == 1
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "parameters_reference.md" in err and "params-doc --write" in err
    assert params_doc.main(["--write"]) == 0 and params_doc.main(["--check"]) == 0


def test_params_yaml_comments_are_rendered_from_help_yaml_and_values_kept():
    original = (ROOT / "params.yaml").read_text()
    help_ = params_doc.meanings()
    help_["synthetic_speaker"]["seed"]["help"] = "a new meaning " + "word " * 30
    help_["cluster.security"]["tls_ca_file"]["help"] = "the CA file"
    text = params_doc.commented_params(original, help_)
    assert yaml.safe_load(text) == yaml.safe_load(original)           # values unchanged
    lines = text.splitlines()
    seed = next(i for i, line in enumerate(lines) if line.startswith("  seed:"))
    assert lines[seed].index("#") == params_doc.COMMENT_COLUMN and "a new meaning" in lines[seed]
    following = next(i for i, line in enumerate(lines) if line.startswith("  n_videos:"))
    assert following - seed >= 2                                       # wrapped onto continuation lines
    assert all(line.strip().startswith("#   word") for line in lines[seed + 1:following])
    assert all(len(line) <= params_doc.WIDTH for line in lines[seed:following])
    assert any(line.startswith("    tls_ca_file: null") and line.endswith("# the CA file") for line in lines)
    assert params_doc.commented_params(text, help_) == text           # rendering twice changes nothing
    keyed = [line for line in lines if params_doc._KEY_LINE.match(line)]
    assert keyed and all("#" in line for line in keyed)                # every key has its meaning beside it
