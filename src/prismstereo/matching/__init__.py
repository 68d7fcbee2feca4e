"""Stereo matching: costs, aggregation (box, BPASW), selection, and a registry of methods.

Only light names are imported here; the numba kernels load with their modules
(:mod:`~prismstereo.matching.costs`, :mod:`~prismstereo.matching.aggregation`,
:mod:`~prismstereo.matching.selection`).
"""

from __future__ import annotations

from prismstereo.matching.api import match, validate_pair, validate_range
from prismstereo.matching.registry import (
    Matcher,
    MatchResult,
    available_matchers,
    get_matcher,
    register_matcher,
)

__all__ = [
    "MatchResult",
    "Matcher",
    "available_matchers",
    "get_matcher",
    "match",
    "register_matcher",
    "validate_pair",
    "validate_range",
]
