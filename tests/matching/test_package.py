"""prismstereo.matching's layout: local matchers, segments/planes and the coop pipeline apart, former names kept."""

from __future__ import annotations

import importlib

import pytest


@pytest.mark.parametrize(("old", "new"), [("costs", "local.costs"), ("selection", "local.selection"),
                                          ("planes", "segments.planes"), ("cooperative", "coop.cooperative")])
def test_former_module_names_are_the_moved_modules(old: str, new: str) -> None:
    import prismstereo.matching as m

    assert getattr(m, old) is importlib.import_module(f"prismstereo.matching.{new}")
    with pytest.raises(AttributeError):
        m.no_such_module  # noqa: B018
