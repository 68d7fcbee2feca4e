"""Stereo matching: costs, aggregation (box, BPASW), selection, and a registry of methods.

Only light names are imported here; the numba kernels load with their modules
(:mod:`~prismstereo.matching.local.costs`, :mod:`~prismstereo.matching.local.aggregation`,
:mod:`~prismstereo.matching.local.selection`).
"""

from __future__ import annotations

import importlib
from types import ModuleType

from prismstereo.matching.api import match, validate_pair, validate_range
from prismstereo.matching.registry import (
    PRESETS,
    Matcher,
    MatchResult,
    available_matchers,
    get_matcher,
    register_matcher,
    resolve_preset,
)

#: former module names -> their module since matching/ was grouped into local/, segments/ and coop/
_MOVED = {**{m: f"prismstereo.matching.local.{m}" for m in ("costs", "aggregation", "selection", "matchers", "sgbm",
                                                             "sgm")},
          **{m: f"prismstereo.matching.segments.{m}" for m in ("segmentation", "planes")},
          **{m: f"prismstereo.matching.coop.{m}" for m in ("coopcost", "cooperative", "slanted")}}


def __getattr__(name: str) -> ModuleType:
    if name in _MOVED:
        return importlib.import_module(_MOVED[name])
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "PRESETS",
    "MatchResult",
    "Matcher",
    "available_matchers",
    "get_matcher",
    "match",
    "register_matcher",
    "resolve_preset",
    "validate_pair",
    "validate_range",
]
