"""What every params section shares: value rules checked by ``validate()``.

Types are checked by ``loading.check``; a section's ``validate()`` then checks values: the
choices of ``CHOICES``, the ``"auto"`` of ``AUTO`` keys, bounds written once in a field's
metadata (``metadata["min"]`` / ``["max"]``, inclusive) and the section's own rules across keys
(a subclass extends ``validate`` and calls ``super().validate()`` first). A broken rule raises
``ParameterError("key=value: what is wrong")``; ``loading.check`` adds the file and section.
"""
from __future__ import annotations

import dataclasses
from typing import ClassVar

from ..errors import ParameterError


def bad(key: str, value, problem: str) -> ParameterError:
    """The one-line error of a broken rule: ``key=value: problem``."""
    return ParameterError(f"{key}={value!r}: {problem}")


class Section:
    """Base of the params dataclasses (one per section of params.yaml)."""

    CHOICES: ClassVar[dict] = {}     # key -> allowed values
    AUTO: ClassVar[tuple] = ()       # keys that take an int or the string "auto"

    def validate(self) -> None:
        """Check values (choices, auto, field bounds); raise ParameterError naming the key."""
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, str) and f.name in self.AUTO and value != "auto":
                raise bad(f.name, value, "expected an int or auto")
            choices = self.CHOICES.get(f.name)
            if choices and value not in choices:
                raise bad(f.name, value, f"choose one of {', '.join(choices)}")
            if isinstance(value, (int, float)) and not isinstance(value, bool):
                lo, hi = f.metadata.get("min"), f.metadata.get("max")
                if lo is not None and value < lo:
                    raise bad(f.name, value, f"must be at least {lo}" if hi is None else f"must be in [{lo}, {hi}]")
                if hi is not None and value > hi:
                    raise bad(f.name, value, f"must be at most {hi}" if lo is None else f"must be in [{lo}, {hi}]")
