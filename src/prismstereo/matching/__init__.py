"""Stereo matching: costs, aggregation (box, BPASW), selection, and a registry of methods.

Only light names are imported here; the numba kernels load with their modules
(:mod:`~prismstereo.matching.local.costs`, :mod:`~prismstereo.matching.local.aggregation`,
:mod:`~prismstereo.matching.local.selection`).
"""

from __future__ import annotations

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
