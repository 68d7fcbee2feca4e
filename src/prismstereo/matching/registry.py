"""Registry of stereo matchers by name, and the :class:`MatchResult` they return.

A matcher is a class whose constructor takes its tuning parameters as keyword-only arguments with
defaults, and whose ``compute(left, right, *, max_disp, min_disp=0)`` returns a :class:`MatchResult`.
Matchers register with :func:`register_matcher`; :func:`get_matcher` imports the modules that define the
built-in ones lazily (so importing :mod:`prismstereo.matching` stays light).
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, TypeVar

import numpy as np

from prismstereo.errors import ConfigError

__all__ = ["PRESETS", "MatchResult", "Matcher", "available_matchers", "get_matcher", "register_matcher",
           "resolve_preset", "resolved_params"]


@dataclass(frozen=True)
class MatchResult:
    """Output of a matcher.

    Attributes
    ----------
    disparity : ndarray, float32, (H, W)
        Disparity of the left image in pixels, ``d = x_left - x_right``; NaN = invalid.
    valid : ndarray, bool, (H, W)
        True where the left–right check passed (thesis Eq. 6.7); all True when no check was run.
    disparity_raw : ndarray, float32, (H, W) or None
        The map before hole filling (invalid pixels NaN), or None when no filling was done.
    timings : dict[str, float]
        Seconds per stage.
    extras : dict[str, Any]
        Debug arrays and values (e.g. ``"cost"``: the aggregated cost volume when asked to keep it).
    """

    disparity: np.ndarray
    valid: np.ndarray
    disparity_raw: np.ndarray | None = None
    timings: dict[str, float] = field(default_factory=dict)
    extras: dict[str, Any] = field(default_factory=dict)


class Matcher(Protocol):
    def compute(self, left: np.ndarray, right: np.ndarray, *, max_disp: int,
                min_disp: int = 0) -> MatchResult: ...


_REGISTRY: dict[str, Callable[..., Matcher]] = {}
#: speed/accuracy presets of ``depth`` and ``batch``: preset name -> matcher name
PRESETS: dict[str, str] = {"fast": "sgm", "balanced": "bpasw", "accurate": "coop"}
#: modules that register built-in matchers when imported
_BUILTIN_MODULES = ("prismstereo.matching.local.matchers", "prismstereo.matching.local.sgbm",
                    "prismstereo.matching.local.sgm")
#: modules that register matchers whose import compiles or loads many numba kernels (coop): imported only
#: when a name is not among the light ones, so that ``get_matcher("sad")`` does not pay for them
_HEAVY_MODULES = ("prismstereo.matching.coop",)
_loaded = False
_heavy_loaded = False

T = TypeVar("T")


def register_matcher(name: str) -> Callable[[T], T]:
    """Class decorator registering a matcher factory under ``name`` (lower case)."""
    key = name.lower()

    def deco(factory: T) -> T:
        _REGISTRY[key] = factory  # type: ignore[assignment]
        return factory

    return deco


def _load_builtins(*, heavy: bool = True) -> None:
    """Import the modules that register matchers; the heavy ones (:data:`_HEAVY_MODULES`) with ``heavy``."""
    global _loaded, _heavy_loaded
    if not _loaded:
        for mod in _BUILTIN_MODULES:
            importlib.import_module(mod)
        _loaded = True
    if heavy and not _heavy_loaded:
        for mod in _HEAVY_MODULES:
            importlib.import_module(mod)
        _heavy_loaded = True


def available_matchers() -> list[str]:
    """Sorted names of the registered matchers."""
    _load_builtins()
    return sorted(_REGISTRY)


def get_matcher(name: str, **params: Any) -> Matcher:
    """Build the matcher registered as ``name`` with its keyword tuning parameters.

    Raises
    ------
    ConfigError
        Unknown name, or a parameter the matcher does not take.
    """
    key = str(name).lower()
    _load_builtins(heavy=False)
    if key not in _REGISTRY:
        _load_builtins()
    if key not in _REGISTRY:
        raise ConfigError(f"expected a method among {', '.join(sorted(_REGISTRY))}, got {name!r}")
    factory = _REGISTRY[key]
    try:
        sig: inspect.Signature | None = inspect.signature(factory)
    except (TypeError, ValueError):
        sig = None
    if sig is not None and not any(p.kind is inspect.Parameter.VAR_KEYWORD for p in sig.parameters.values()):
        unknown = sorted(set(params) - set(sig.parameters))
        if unknown:
            allowed = ", ".join(p for p in sig.parameters if p != "self")
            raise ConfigError(f"expected parameters of method {key!r} among {allowed}, got {unknown}")
    _check_param_types(key, factory, params)
    try:
        return factory(**params)
    except (TypeError, ValueError) as exc:
        if isinstance(exc, ConfigError):
            raise
        raise ConfigError(f"expected valid parameters for method {key!r}, got {params} ({exc})") from None


def _check_param_types(key: str, factory: Callable[..., Matcher], params: dict[str, Any]) -> None:
    """For dataclass matchers: each value must have the type of the field's default (int for float ok)."""
    if not dataclasses.is_dataclass(factory):
        return
    defaults = {f.name: f.default for f in dataclasses.fields(factory)
                if f.default is not dataclasses.MISSING}
    for name, value in params.items():
        if name not in defaults or defaults[name] is None:
            continue
        want = type(defaults[name])
        ok = isinstance(value, want)
        if want is float:
            ok = isinstance(value, int | float) and not isinstance(value, bool)
        elif want is int:
            ok = isinstance(value, int) and not isinstance(value, bool)
        elif want is tuple:
            ok = isinstance(value, tuple | list)
        if not ok:
            raise ConfigError(f"expected parameter {name!r} of method {key!r} to be {want.__name__}, "
                              f"got {value!r}")


def resolve_preset(preset: str | None, method: str | None, *, default: str = "bpasw") -> tuple[str, str | None]:
    """The matcher to run for a ``--preset`` / ``--method`` pair, and the preset's name (None if none).

    Parameters
    ----------
    preset : str or None
        A key of :data:`PRESETS`.
    method : str or None
        An explicit matcher name; naming both is a conflict.
    default : str
        Method used when neither is given.

    Raises
    ------
    ConfigError
        Unknown preset, or both a preset and a method.
    """
    if preset is None:
        return (default if method is None else method), None
    key = str(preset).lower()
    if key not in PRESETS:
        raise ConfigError(f"preset: expected one of {', '.join(PRESETS)}, got {preset!r}")
    if method is not None:
        raise ConfigError(f"preset: expected a preset or a method, got both (preset {key!r} means method "
                          f"{PRESETS[key]!r})")
    return PRESETS[key], key


def resolved_params(name: str, **params: Any) -> dict[str, Any]:
    """Every tuning parameter of matcher ``name`` with ``params`` applied: the given values and the defaults.

    This is what a run records (``run.json``), so that it can be replayed after a default changes:
    ``get_matcher(name, **resolved_params(name, **params))`` builds the same matcher. Lists (a parameter
    read back from JSON) become tuples where the default is a tuple. A parameter whose default is None (a
    matcher that builds its own default object) stays None.

    Raises
    ------
    ConfigError
        As :func:`get_matcher`.
    """
    key = str(name).lower()
    get_matcher(key, **params)  # checks the name, the parameter names and their types
    factory = _REGISTRY[key]
    if dataclasses.is_dataclass(factory):
        defaults: dict[str, Any] = {}
        for f in dataclasses.fields(factory):
            if not f.init:
                continue
            if f.default is not dataclasses.MISSING:
                defaults[f.name] = f.default
            elif f.default_factory is not dataclasses.MISSING:
                defaults[f.name] = f.default_factory()
    else:
        defaults = {p.name: p.default for p in inspect.signature(factory).parameters.values()
                    if p.default is not inspect.Parameter.empty}
    out = {**defaults, **params}
    for k, v in out.items():
        if isinstance(defaults.get(k), tuple) and isinstance(v, list):
            out[k] = tuple(v)
    return out
