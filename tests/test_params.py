"""Every parameter dataclass checks itself in ``__post_init__`` (issue 28): a value out of range is a
ConfigError naming ``<Class>.<field>``, at construction, whoever builds it. The matchers' dataclasses (the
registry's ``sad`` … ``sgm``) are parameter dataclasses too."""

from __future__ import annotations

import dataclasses
import importlib
import math
import pkgutil

import pytest

import prismstereo
from prismstereo.checks import check_fields
from prismstereo.errors import ConfigError
from prismstereo.matching import registry


def _params_classes() -> list[type]:
    """The frozen dataclasses of the package whose name ends in ``Params``, ``Config`` or ``Matcher``."""
    found: dict[str, type] = {}
    for info in pkgutil.walk_packages(prismstereo.__path__, "prismstereo."):
        if ".apps" in info.name or info.name.endswith("__main__"):
            continue
        module = importlib.import_module(info.name)
        for obj in vars(module).values():
            if (isinstance(obj, type) and dataclasses.is_dataclass(obj) and obj.__module__ == module.__name__
                    and obj.__name__.endswith(("Params", "Config", "Matcher"))
                    and obj.__dataclass_params__.frozen):  # type: ignore[attr-defined]
                found[f"{obj.__module__}.{obj.__qualname__}"] = obj
    return [found[k] for k in sorted(found)]


CLASSES = _params_classes()
#: the registered matchers that are dataclasses (the others, e.g. coop's, take the Params above)
MATCHERS = sorted((f for f in (registry.get_matcher(n).__class__ for n in registry.available_matchers())
                   if dataclasses.is_dataclass(f)), key=lambda c: c.__name__)


def _bad_value(default: object) -> object | None:
    """An out-of-range value for a numeric field (NaN for a float, a huge negative integer for an int)."""
    if isinstance(default, bool):
        return "yes"
    if isinstance(default, int):
        return -10**9
    if isinstance(default, float):
        return math.nan
    return None


def _numeric_fields(cls: type) -> dict[str, object]:
    inst = cls()
    return {f.name: getattr(inst, f.name) for f in dataclasses.fields(cls)
            if _bad_value(getattr(inst, f.name)) is not None}


def test_the_walk_finds_the_params() -> None:
    names = {c.__name__ for c in CLASSES}
    assert {"CoopParams", "PlaneParams", "SegmentationParams", "CostParams", "DepthConfig", "SweepParams",
            "PostParams", "LocalMultiViewParams", "GlobalMultiViewParams", "StepParams"} <= names, names
    assert {"SADMatcher", "SSDMatcher", "NCCMatcher", "SHDMatcher", "BPASWMatcher", "SGBMMatcher",
            "SGMMatcher"} <= {c.__name__ for c in MATCHERS}
    assert set(MATCHERS) <= set(CLASSES), "a registered dataclass matcher is not walked"


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: c.__name__)
def test_every_params_dataclass_rejects_an_out_of_range_value(cls: type) -> None:
    assert any("__post_init__" in vars(k) for k in cls.__mro__[:-1]), f"{cls.__name__} does not check itself"
    cls()  # the defaults are valid
    rejected = []
    for name, default in _numeric_fields(cls).items():
        try:
            cls(**{name: _bad_value(default)})
        except ConfigError as exc:
            assert str(exc).startswith(f"{cls.__name__}.") or name in str(exc), str(exc)
            rejected.append(name)
    if _numeric_fields(cls):
        assert rejected, f"{cls.__name__} accepts NaN / -1e9 / 'yes' in every field"


#: the dataclasses that check every field (issue 28), and every registered dataclass matcher
FULLY_CHECKED = ("CoopParams", "CostParams", "PlaneParams", "SegmentationParams", "DepthConfig", "PostParams",
                 "LocalMultiViewParams", "GlobalMultiViewParams", "SlantedParams",
                 *(c.__name__ for c in MATCHERS))


@pytest.mark.parametrize("cls", [c for c in CLASSES if c.__name__ in FULLY_CHECKED], ids=lambda c: c.__name__)
def test_every_field_is_checked(cls: type) -> None:
    for name, default in _numeric_fields(cls).items():
        with pytest.raises(ConfigError, match=rf"^{cls.__name__}\.{name}: expected "):
            cls(**{name: _bad_value(default)})


@pytest.mark.parametrize(("cls_name", "field", "value"), [
    ("DepthConfig", "min_confidence", 5.0),
    ("DepthConfig", "refine_radius", 0),
    ("DepthConfig", "max_gap_mm", 0.0),
    ("DepthConfig", "depth_range", (2000.0, 1000.0)),
    ("DepthConfig", "roi", (0, 0, 0, 10)),
    ("DepthConfig", "triangulation", "nearest"),
    ("CoopParams", "kappa", -0.5),
    ("CoopParams", "data_trunc", 0.0),
    ("CostParams", "census_rx", 8),
    ("CostParams", "eps", 0.0),
    ("PlaneParams", "gamma_segment", 1.5),
    ("SegmentationParams", "hr", 0.0),
    ("SegmentationParams", "max_level", 9),
    ("BPASWMatcher", "omega", 1.5),
    ("BPASWMatcher", "dilation", 0),
    ("BPASWMatcher", "kernel", "gauss"),
    ("SHDMatcher", "census_window", (7, 10)),
    ("SGBMMatcher", "block_size", 4),
    ("SGBMMatcher", "p2_factor", 8),
    ("SGBMMatcher", "mode", "fast"),
    ("SGMMatcher", "uniqueness", 100),
    ("SGMMatcher", "p2", 4),
    ("SGMMatcher", "census_window", (9, 9)),
    ("SGMMatcher", "cost", "mi"),
])
def test_targeted_ranges(cls_name: str, field: str, value: object) -> None:
    cls = next(c for c in CLASSES if c.__name__ == cls_name)
    with pytest.raises(ConfigError, match=rf"^{cls_name}\.{field}: expected .*, got "):
        cls(**{field: value})


def test_the_census_window_fits_in_64_bits() -> None:
    cls = next(c for c in CLASSES if c.__name__ == "CostParams")
    cls(census_rx=4, census_ry=3)
    with pytest.raises(ConfigError, match="at most 65 pixels, got 11x7"):
        cls(census_rx=5, census_ry=3)


def test_the_replaced_config_is_checked_again() -> None:
    cfg = next(c for c in CLASSES if c.__name__ == "DepthConfig")()
    with pytest.raises(ConfigError, match="^DepthConfig.speckle_fraction: expected a number in \\[0, 1\\], got 2"):
        dataclasses.replace(cfg, speckle_fraction=2)


@dataclasses.dataclass(frozen=True)
class _Example:
    n: int = 3
    x: float | None = 1.0
    on: bool = True


@pytest.mark.parametrize(("changes", "message"), [
    ({"n": 3.5}, "_Example.n: expected an integer in [1, 10], got 3.5"),
    ({"n": True}, "_Example.n: expected an integer in [1, 10], got True"),
    ({"x": -1.0}, "_Example.x: expected a number > 0, got -1.0"),
    ({"x": math.inf}, "_Example.x: expected a number > 0, got inf"),
    ({"on": 1}, "_Example.on: expected True or False, got 1"),
])
def test_check_fields_messages(changes: dict[str, object], message: str) -> None:
    ex = dataclasses.replace(_Example(), **changes)
    check_fields(_Example(), {"n": (1, 10)}, positive=("x",))  # the defaults pass
    with pytest.raises(ConfigError) as info:
        check_fields(ex, {"n": (1, 10)}, positive=("x",))
    assert str(info.value) == message
    check_fields(dataclasses.replace(_Example(), x=None), {"n": (1, 10)}, positive=("x",))  # optional
