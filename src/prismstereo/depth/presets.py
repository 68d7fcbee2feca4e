"""Presets: named profiles of a depth run (``fast``, ``balanced``, ``accurate``).

A preset is the matcher (:data:`prismstereo.matching.PRESETS`) and the depth settings that go with what a
run may cost: :data:`PROFILES` holds one :class:`Preset` per name. :func:`apply_preset` resolves a preset
into a :class:`~prismstereo.depth.pipeline.DepthConfig`; settings the caller gives explicitly win over the
preset's. :func:`preset_record` is what a run records of it (``run.json``'s ``preset_profile``).

``balanced`` and ``accurate`` set nothing beyond their matcher: they run the configuration's defaults (the
refinement and confidence defaults serve their precision). ``fast`` is a video frame's profile: its own
refinement and confidence values, every one set explicitly (they do not follow the defaults), chosen for
a frame's CPU time (docs/EXPERIMENTS.md, issue 30, stop 34): one 11×11 refinement window with its sub-pixel
left–right check, no wider retry window, no fill or growth from the matcher's dense map (which the matcher
then skips): a sixth to a half of the default refinement's CPU, at a similar median error and within-1 % share and
less coverage on weak texture.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from prismstereo.depth.pipeline import DepthConfig
from prismstereo.errors import ConfigError
from prismstereo.matching.registry import PRESETS

__all__ = ["PROFILES", "Preset", "apply_preset", "config_with_preset", "get_preset", "preset_record"]


@dataclass(frozen=True)
class Preset:
    """A named profile: the matcher and the depth settings it implies.

    Attributes
    ----------
    name : str
        The preset's name (a key of :data:`prismstereo.matching.PRESETS`).
    method : str
        The matcher it runs.
    settings : tuple of (field, value)
        Fields of :class:`~prismstereo.depth.pipeline.DepthConfig` it sets (beyond ``method``); empty: the
        configuration's defaults.
    """

    name: str
    method: str
    settings: tuple[tuple[str, Any], ...] = ()

    def __post_init__(self) -> None:
        fields = {f.name for f in dataclasses.fields(DepthConfig)} - {"method", "matcher_params"}
        unknown = sorted(k for k, _ in self.settings if k not in fields)
        if unknown:
            raise ConfigError(f"preset {self.name!r}: expected settings among the depth configuration's fields, "
                              f"got {unknown}")
        DepthConfig(method=self.method, **self.as_dict())  # the values are in range

    def as_dict(self) -> dict[str, Any]:
        """The settings as a dict (field -> value)."""
        return dict(self.settings)


#: the presets by name; ``fast``'s settings name every refinement and confidence field it relies on
PROFILES: dict[str, Preset] = {
    "fast": Preset("fast", PRESETS["fast"], (
        ("refine", True),
        ("refine_radius", 5),
        ("refine_iterations", 6),
        ("refine_max_shift", 0.85),
        ("refine_min_texture", 0.01),
        ("refine_max_lr_gap", 0.45),
        ("refine_prefilter", 0.7),
        ("refine_fill", False),
        ("refine_fill_agree", None),
        ("refine_retry_radius", None),
        ("refine_retry_below", 0.95),
        ("refine_retry_drop", False),
        ("refine_third_radius", None),
        ("refine_third_below", 0.95),
        ("refine_grow_radius", None),
        ("refine_grow_agree", 0.2),
        ("refine_grow_sigma", 8.0),
        ("refine_grow_spread", 0.35),
        ("refine_grow_passes", 2),
        ("refine_grow_fit", "plane"),
        ("refine_grow_inlier", 1.0),
        ("refine_grow_share", 0.9),
        ("refine_grow_agree_depth", 0.0022),
        ("refine_grow_second_radius", 5),
        ("refine_grow_min_confidence", 0.3),
        ("refine_grow_cut", 1.5),
        ("refine_grow_gap", 1.5),
        ("refine_interp_sigma", None),
        ("refine_interp_support", 0.3),
        ("refine_interp_share", 0.95),
        ("refine_interp_spread", 0.3),
        ("refine_interp_agree", 0.5),
        ("refine_interp_passes", 2),
        ("refine_smoothed_below", None),
        ("refine_smoothed_retry_below", 0.99),
        ("refine_smoothed_fill_agree", 1.0),
        ("refine_smoothed_third_radius", None),
        ("refine_smoothed_grow_fit", "mean"),
        ("refine_smoothed_grow_agree", 0.3),
        ("refine_smoothed_grow_spread", 0.5),
        ("refine_smoothed_interp", False),
        ("min_confidence", 0.5),
        ("speckle_fraction", 0.001),
    )),
    "balanced": Preset("balanced", PRESETS["balanced"]),
    "accurate": Preset("accurate", PRESETS["accurate"]),
}


def get_preset(name: str | Preset) -> Preset:
    """The :class:`Preset` of a name (case-insensitive), or the preset itself.

    Raises
    ------
    ConfigError
        An unknown name.
    """
    if isinstance(name, Preset):
        return name
    key = str(name).lower()
    if key not in PROFILES:
        raise ConfigError(f"preset: expected one of {', '.join(PROFILES)}, got {name!r}")
    return PROFILES[key]


def apply_preset(config: DepthConfig, preset: str | Preset, *, given: Iterable[str] = ()) -> DepthConfig:
    """``config`` with the preset's matcher and settings, except the fields named in ``given`` (what the
    caller set explicitly: those keep ``config``'s values).

    Another matcher than ``config``'s starts from that matcher's defaults (``matcher_params`` emptied)
    unless ``matcher_params`` is among ``given``.

    Raises
    ------
    ConfigError
        An unknown preset, or ``method`` among ``given`` (a preset names its matcher: a preset or a method).
    """
    p = get_preset(preset)
    keep = set(given)
    if "method" in keep:
        raise ConfigError(f"preset: expected a preset or a method, got both (preset {p.name!r} means method "
                          f"{p.method!r})")
    changes: dict[str, Any] = {k: v for k, v in p.settings if k not in keep}
    if p.method != config.method:
        changes["method"] = p.method
        if "matcher_params" not in keep:
            changes["matcher_params"] = {}  # another matcher: the base's parameters are not its own
    return dataclasses.replace(config, **changes)


def config_with_preset(method: str, preset: str | Preset | None, given: Mapping[str, Any]) -> DepthConfig:
    """The :class:`~prismstereo.depth.pipeline.DepthConfig` of the options ``given`` (field -> value, set
    explicitly) and ``method``, with the ``preset``'s settings (None: none) for the fields ``given`` does not
    name."""
    config = DepthConfig(method=method, **given)
    return config if preset is None else apply_preset(config, preset, given=given)


def preset_record(preset: str | Preset, config: Mapping[str, Any] | DepthConfig) -> dict[str, Any]:
    """What a run records of its preset: the name, the matcher, each of the preset's settings with the
    value the run resolved (``config``: the configuration run, or its :meth:`~DepthConfig.to_dict`) and
    the settings whose value the caller gave instead (``overridden``)."""
    p = get_preset(preset)
    c = config.to_dict() if isinstance(config, DepthConfig) else dict(config)
    want = DepthConfig(method=p.method, **p.as_dict()).to_dict()
    resolved = {k: c.get(k) for k, _ in p.settings}
    return {"name": p.name, "method": p.method, "settings": resolved,
            "overridden": sorted(k for k in resolved if resolved[k] != want[k])}
