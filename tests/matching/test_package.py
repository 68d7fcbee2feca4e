"""prismstereo.matching's layout: local matchers, segments/planes and the coop pipeline apart."""

from __future__ import annotations

import importlib

import pytest


@pytest.mark.parametrize("name", ["local.costs", "local.selection", "segments.planes", "coop.cooperative"])
def test_the_matching_modules_live_in_their_subpackages(name: str) -> None:
    mod = importlib.import_module(f"prismstereo.matching.{name}")
    assert mod.__name__ == f"prismstereo.matching.{name}"


@pytest.mark.parametrize("old", ["costs", "selection", "planes", "cooperative"])
def test_the_former_flat_names_are_gone(old: str) -> None:
    import prismstereo.matching as m

    with pytest.raises(AttributeError):
        getattr(m, old)
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module(f"prismstereo.matching.{old}")
