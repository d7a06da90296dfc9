"""Reading params.yaml into ``Params``: unknown keys and sections, types, then each section's
``validate()``; every error is one line naming ``file: section.key``."""
from __future__ import annotations

import dataclasses
import os
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from ..errors import ParameterError
from .preprocess import Cluster, Data, Frontalize, Ingest, Landmarks, Pca, Phonetic, SyntheticSpeaker, Whisper
from .synthesis import Composite, Evaluate, Report, Speak, Synthesize
from .training import Brand, DelaySweep, Karras, RenderMesh, Train

PARAMS_FILE = Path(os.environ.get("LIPSYNTH_PARAMS", "params.yaml"))


@dataclass
class Params:
    """The whole params file: one attribute per section."""

    synthetic_speaker: SyntheticSpeaker = field(default_factory=SyntheticSpeaker)
    data: Data = field(default_factory=Data)
    cluster: Cluster = field(default_factory=Cluster)
    ingest: Ingest = field(default_factory=Ingest)
    landmarks: Landmarks = field(default_factory=Landmarks)
    frontalize: Frontalize = field(default_factory=Frontalize)
    pca: Pca = field(default_factory=Pca)
    phonetic: Phonetic = field(default_factory=Phonetic)
    whisper: Whisper = field(default_factory=Whisper)
    train: Train = field(default_factory=Train)
    brand: Brand = field(default_factory=Brand)
    karras: Karras = field(default_factory=Karras)
    render_mesh: RenderMesh = field(default_factory=RenderMesh)
    delay_sweep: DelaySweep = field(default_factory=DelaySweep)
    synthesize: Synthesize = field(default_factory=Synthesize)
    composite: Composite = field(default_factory=Composite)
    speak: Speak = field(default_factory=Speak)
    evaluate: Evaluate = field(default_factory=Evaluate)
    report: Report = field(default_factory=Report)


SECTIONS = {f.name: f.default_factory for f in dataclasses.fields(Params)}
FEATURE_STORE_OF = {"whisper": "whisper", "phonetic": "phonetic", "mfcc+phonetic": "phonetic", "mfcc": "ingest"}


def front_end_store(params) -> str:
    """The store ``train.features`` reads — the path ``train.feature_store`` must name: ``whisper.out``,
    ``phonetic.out`` or ``ingest.out`` (MFCC). ``params``: a ``Params`` or a params dict."""
    get = (lambda s, k: params[s][k]) if isinstance(params, dict) else (lambda s, k: getattr(getattr(params, s), k))
    return get(FEATURE_STORE_OF[get("train", "features")], "out")


def _type_ok(value, kind) -> bool:
    """Does ``value`` (from YAML) fit the annotation ``kind``? ints are accepted for floats."""
    if kind is typing.Any:
        return True
    origin = typing.get_origin(kind)
    if origin in (typing.Union, types.UnionType):
        return any(_type_ok(value, k) for k in typing.get_args(kind))
    if kind is type(None):
        return value is None
    if kind is bool:
        return isinstance(value, bool)
    if kind is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if kind is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if kind is list or origin is list:
        return isinstance(value, (list, tuple))
    return isinstance(value, kind)


def _type_name(kind) -> str:
    if typing.get_origin(kind) in (typing.Union, types.UnionType):
        return " or ".join(_type_name(k) for k in typing.get_args(kind))
    return "null" if kind is type(None) else getattr(kind, "__name__", str(kind))


def check(section, name: str, where: str = "params") -> None:
    """Validate one section object (types, then its ``validate()``); raise ParameterError naming the key.
    A key whose type is itself a section (``cluster.security``) is checked the same way."""
    hints = typing.get_type_hints(type(section))
    for f in dataclasses.fields(section):
        value = getattr(section, f.name)
        if dataclasses.is_dataclass(hints[f.name]):
            if not isinstance(value, hints[f.name]):
                raise ParameterError(f"{where}: {name}.{f.name}={value!r}: expected a mapping of keys")
            check(value, f"{name}.{f.name}", where)
            continue
        if not _type_ok(value, hints[f.name]):
            raise ParameterError(f"{where}: {name}.{f.name}={value!r}: expected {_type_name(hints[f.name])}")
    try:
        section.validate()
    except ParameterError as exc:
        raise ParameterError(f"{where}: {name}.{exc}") from None


def parse(tree: dict, where: str = "params") -> Params:
    """Typed ``Params`` from a nested dict (a loaded params.yaml); see the module doc."""
    if not isinstance(tree, dict):
        raise ParameterError(f"{where}: expected a mapping of sections")
    unknown = sorted(set(tree) - set(SECTIONS))
    if unknown:
        raise ParameterError(f"{where}: unknown section '{unknown[0]}' (sections: {', '.join(SECTIONS)})")
    sections = {}
    for name, make in SECTIONS.items():
        values = tree.get(name) or {}
        if not isinstance(values, dict):
            raise ParameterError(f"{where}: section '{name}' must be a mapping of keys, got {values!r}")
        section = _fill(make(), values, name, where)
        check(section, name, where)
        sections[name] = section
    return Params(**sections)


def _fill(section, values: dict, name: str, where: str):
    """``section`` with the keys of ``values`` set; a nested section (``cluster.security``) is
    filled from its own mapping. Unknown keys stop with one line naming them."""
    known = {f.name for f in dataclasses.fields(section)}
    bad = sorted(set(values) - known)
    if bad:
        raise ParameterError(f"{where}: unknown key {name}.{bad[0]} (known keys: {', '.join(sorted(known))})")
    for k, v in values.items():
        current = getattr(section, k)
        if dataclasses.is_dataclass(current) and isinstance(v, dict):
            v = _fill(type(current)(), v, f"{name}.{k}", where)
        elif dataclasses.is_dataclass(current) and v is None:
            v = type(current)()                # `security:` left empty = the defaults
        setattr(section, k, v)
    return section


def load_params(path: str | os.PathLike | None = None) -> Params:
    """Read and validate a params file (default ``$LIPSYNTH_PARAMS`` or ./params.yaml)."""
    path = Path(path) if path is not None else PARAMS_FILE
    if not path.exists():
        raise ParameterError(f"{path}: params file not found (run from the project root)")
    try:
        tree = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as exc:
        raise ParameterError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None
    return parse(tree, str(path))


def as_dict(section) -> dict:
    """A section (or the whole tree) as plain dicts, e.g. to record it beside a model."""
    return dataclasses.asdict(section)
