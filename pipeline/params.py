"""Load ``params.yaml`` — one section per stage plus ``data`` and ``cluster``."""
from __future__ import annotations

import os
from pathlib import Path

import yaml

from .errors import ParameterError

PARAMS_FILE = Path(os.environ.get("LIPSYNTH_PARAMS", "params.yaml"))


def load_params(path: str | os.PathLike | None = None) -> dict:
    """Return the whole params tree as nested dicts."""
    path = Path(path) if path is not None else PARAMS_FILE
    if not path.exists():
        raise ParameterError(f"{path}: params file not found (run from the project root)")
    with open(path) as f:
        tree = yaml.safe_load(f) or {}
    if not isinstance(tree, dict):
        raise ParameterError(f"{path}: expected a mapping of sections")
    return tree


def section(name: str, path: str | os.PathLike | None = None) -> dict:
    """Return one section of params.yaml, failing with a clear message if it is absent."""
    tree = load_params(path)
    if name not in tree:
        raise ParameterError(f"{path or PARAMS_FILE}: missing section '{name}'")
    return tree[name]


def require(params: dict, key: str, kind=None, where: str = "params"):
    """Fetch ``params[key]``; raise ParameterError naming ``where.key`` if absent or mistyped."""
    if key not in params:
        raise ParameterError(f"{where}.{key} is missing")
    value = params[key]
    if kind is not None and not isinstance(value, kind):
        raise ParameterError(f"{where}.{key}={value!r}: expected {kind}")
    return value
