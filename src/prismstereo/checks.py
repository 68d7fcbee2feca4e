"""Range checks for the parameter dataclasses' ``__post_init__``: one message shape for every parameter.

``check_fields(self, {"kappa": (0, None), "max_iter": (1, 500)}, positive=("eps",))`` raises
:class:`~prismstereo.errors.ConfigError` ``"CoopParams.kappa: expected a number >= 0, got -1"`` for the first
field out of range. A field annotated ``int`` must be an integer, one annotated ``bool`` a bool, a float a
finite number; ``... | None`` fields may be None.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Iterable, Mapping
from typing import Any

from prismstereo.errors import ConfigError

__all__ = ["check_fields", "fail"]

Range = tuple[float | None, float | None]


def fail(owner: object, name: str, expected: str, got: Any) -> None:
    """Raise ``ConfigError("<Class>.<name>: expected <expected>, got <got>")``."""
    raise ConfigError(f"{type(owner).__name__}.{name}: expected {expected}, got {got!r}")


def _describe(integer: bool, lo: float | None, hi: float | None, lo_open: bool) -> str:
    kind = "an integer" if integer else "a number"
    if lo is not None and hi is not None:
        return f"{kind} in {'(' if lo_open else '['}{lo:g}, {hi:g}]"
    if lo is not None:
        return f"{kind} {'>' if lo_open else '>='} {lo:g}"
    if hi is not None:
        return f"{kind} <= {hi:g}"
    return f"a finite {kind[2:] if integer else 'number'}"


def check_fields(obj: object, ranges: Mapping[str, Range], *, positive: Iterable[str] = ()) -> None:
    """Check the dataclass ``obj``: its bool fields are bools, and every field named in ``ranges`` (closed
    ``(lo, hi)``, None = unbounded) or in ``positive`` (> 0, or in ``(0, hi]`` with ``ranges``'s hi) is a
    finite number in range, an integer where the field is annotated ``int``.

    Raises
    ------
    ConfigError
        The first field out of range, named ``<Class>.<field>``.
    """
    strict = set(positive)
    types = {f.name: str(f.type) for f in dataclasses.fields(obj)}  # type: ignore[arg-type]
    for name, annotation in types.items():
        value = getattr(obj, name)
        if annotation == "bool" and type(value).__name__ not in ("bool", "bool_"):
            fail(obj, name, "True or False", value)
    for name in [*ranges, *(n for n in strict if n not in ranges)]:
        value = getattr(obj, name)
        annotation = types[name]
        if value is None and "None" in annotation:
            continue
        integer = annotation.split("|")[0].strip() == "int"
        lo, hi = ranges.get(name, (0.0, None))
        lo_open = name in strict
        if lo_open and lo is None:
            lo = 0.0
        ok = isinstance(value, numbers.Real) and not isinstance(value, bool)
        ok = ok and (isinstance(value, numbers.Integral) if integer else math.isfinite(float(value)))
        ok = ok and (lo is None or (value > lo if lo_open else value >= lo)) and (hi is None or value <= hi)
        if not ok:
            fail(obj, name, _describe(integer, lo, hi, lo_open), value)
