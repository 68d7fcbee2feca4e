"""``prismstereo depth --config run.json``: the inputs and the resolved configuration of an earlier run.

A depth run's ``run.json`` records the fully resolved configuration (``config``: every step's parameters and
every matcher parameter with its default), the rig as it was run (``rig``) and the input paths
(``inputs``). :func:`replay_options` turns it and the options of a new command line into the rig, the
inputs and the configuration of the new run: what the command line names overrides the record.
"""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from prismstereo.config import Rig, load_rig, rig_from_dict
from prismstereo.depth.pipeline import DepthConfig
from prismstereo.depth.presets import apply_preset
from prismstereo.errors import ConfigError

__all__ = ["DepthOptions", "read_run_config", "replay_options"]


@dataclass(frozen=True)
class DepthOptions:
    """The rig, the inputs and the (not yet validated) configuration of a depth run.

    Attributes
    ----------
    rig : Rig
    rig_path : str or None
        The rig file named on the command line or recorded (None: only the recorded rig).
    image_path : str
    gt : str or None
    config : DepthConfig
    preset : str or None
        The preset's name, for the report.
    """

    rig: Rig
    rig_path: str | None
    image_path: str
    gt: str | None
    config: DepthConfig
    preset: str | None


def read_run_config(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The record of a depth run (its ``run.json``): ``config``, ``rig`` and ``inputs``.

    Raises
    ------
    ConfigError
        A file that is not a depth run's ``run.json``.
    """
    try:
        data = json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise ConfigError(f"--config: expected a run.json of an earlier depth run, got no file {str(path)!r}") \
            from None
    except (ValueError, UnicodeDecodeError) as exc:
        raise ConfigError(f"--config: expected a JSON file (a depth run's run.json), got {str(path)!r} "
                          f"({exc})") from None
    if not isinstance(data, Mapping) or not isinstance(data.get("config"), Mapping):
        raise ConfigError(f"--config: expected a depth run's run.json with a 'config' table, got {str(path)!r}")
    return dict(data)


def replay_options(config_path: str | None, rig_path: str | None, image_path: str | None, *,
                   method: str | None = None, params: dict[str, Any] | None = None,
                   depth_range: tuple[float, float] | None = None, roi: tuple[int, int, int, int] | None = None,
                   views: tuple[int, int] | str | None = None, triangulation: str | None = None,
                   calibration: str | None = None, gt: str | None = None, refine: bool | None = None,
                   preset: str | None = None, min_confidence: float | None = None,
                   coarse_to_fine: str | None = None, max_memory: int | None = None,
                   refine_fill: bool | None = None) -> DepthOptions:
    """The options of a depth run: those given (not None) over the ``preset``'s profile
    (:func:`~prismstereo.depth.presets.apply_preset`; a preset named here, not the recorded one, whose
    settings the record holds resolved), over the recorded run's (``config_path``), over the defaults of
    :class:`~prismstereo.depth.pipeline.DepthConfig`.

    ``views`` is a pair (i, j), ``"all"`` or None. Naming another ``method`` than the recorded one starts
    from that matcher's defaults; the recorded rig (as it was run, even if its file changed since) is used
    unless a rig file is named.

    Raises
    ------
    ConfigError
        A bad record, or no rig or capture named anywhere.
    """
    base = DepthConfig()
    rig: Rig | None = None
    named = preset  # a preset named on this command line (a recorded one is already resolved in its record)
    if config_path is not None:
        record = read_run_config(config_path)
        base = DepthConfig.from_dict(record["config"])
        inputs = record.get("inputs") or {}
        image_path = image_path if image_path is not None else inputs.get("image")
        gt = gt if gt is not None else inputs.get("gt")
        if rig_path is None:
            rig_path = inputs.get("rig")
            if isinstance(record.get("rig"), Mapping):
                rig = rig_from_dict(record["rig"], name=Path(rig_path).stem if rig_path else "rig")
        if preset is None and method is None:
            preset = record.get("preset")
    if rig is None:
        if rig_path is None:
            raise ConfigError("expected a rig TOML (or --config run.json of an earlier run), got none")
        rig = load_rig(rig_path)
    if image_path is None:
        raise ConfigError("expected a capture image (or --config run.json of an earlier run), got none")
    options = {"depth_range": depth_range, "roi": roi, "triangulation": triangulation, "calibration": calibration,
               "refine": refine, "min_confidence": min_confidence, "coarse_to_fine": coarse_to_fine,
               "max_memory": max_memory, "refine_fill": refine_fill, "views": views, "method": method}
    if named is not None:
        given = [k for k, v in options.items() if v is not None] + (["matcher_params"] if params else [])
        base = apply_preset(base, named, given=given)
    changes: dict[str, Any] = {}
    if method is not None:
        changes["method"] = method
        if method.lower() != base.method:  # another matcher: the recorded parameters are not its own
            changes["matcher_params"] = {}
    if params:
        changes["matcher_params"] = {**changes.get("matcher_params", base.matcher_params), **params}
    for key, value in options.items():
        if value is not None and key != "method":
            changes[key] = value
    return DepthOptions(rig=rig, rig_path=None if rig_path is None else str(rig_path), image_path=str(image_path),
                        gt=None if gt is None else str(gt), config=dataclasses.replace(base, **changes),
                        preset=preset)
