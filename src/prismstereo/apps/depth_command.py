"""What ``prismstereo depth`` and ``prismstereo demo`` do, kept out of cli.py (no algorithm code there).

Input checks happen before any heavy work, in this order: the rig file, the output folder (must be
creatable and writable), the image file (exists, non-empty, decodable), the image size against the rig,
the options; the geometry (views that do not overlap) is checked by rectification before matching.

``--config run.json`` replays a run: the rig (as recorded in the run.json), the capture, the ground truth
and the fully resolved configuration recorded in a ``run.json`` are used unless the command line names them
again.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from prismstereo.apps.demo import run_demo
from prismstereo.config import Rig, load_rig, rig_from_dict
from prismstereo.depth.outputs import write_depth_outputs
from prismstereo.depth.pipeline import DepthConfig, run_depth, validate_inputs
from prismstereo.errors import ConfigError
from prismstereo.evaluation.depth_metrics import evaluate_depth, format_accuracy, read_depth_gt
from prismstereo.io import read_image
from prismstereo.io.atomic import check_output_dir

__all__ = ["check_output_dir", "demo_command", "depth_command", "read_run_config"]

log = logging.getLogger(__name__)


def _resolve_views(views: Any) -> tuple[int, int] | str | None:
    if views is None or views == "all":
        return views
    if len(views) != 2:
        raise ConfigError(f"--views: expected two faces I,J, got {','.join(map(str, views))}")
    return int(views[0]), int(views[1])


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


def depth_command(rig_path: str | None, image_path: str | None, out_dir: str, *, method: str | None = None,
                  params: dict[str, Any] | None = None, depth_range: tuple[float, float] | None = None,
                  roi: tuple[int, int, int, int] | None = None, views: Any = None,
                  triangulation: str | None = None, calibration: str | None = None, gt: str | None = None,
                  refine: bool | None = None, preset: str | None = None, config_path: str | None = None) -> str:
    """Run ``prismstereo depth`` and return the lines to print (``preset``: its name, for the report).

    The options left None take the replayed run's values (``config_path``, a ``run.json``), else the
    defaults of :class:`~prismstereo.depth.pipeline.DepthConfig`.
    """
    base = DepthConfig()
    rig: Rig | None = None
    if config_path is not None:
        record = read_run_config(config_path)
        base = DepthConfig.from_dict(record["config"])
        inputs = record.get("inputs") or {}
        image_path = image_path if image_path is not None else inputs.get("image")
        gt = gt if gt is not None else inputs.get("gt")
        if rig_path is None:
            rig_path = inputs.get("rig")
            if isinstance(record.get("rig"), Mapping):  # the rig as it was run, even if its file changed since
                rig = rig_from_dict(record["rig"], name=Path(rig_path).stem if rig_path else "rig")
        if preset is None and method is None:
            preset = record.get("preset")
    if rig is None:
        if rig_path is None:
            raise ConfigError("expected a rig TOML (or --config run.json of an earlier run), got none")
        rig = load_rig(rig_path)
    if image_path is None:
        raise ConfigError("expected a capture image (or --config run.json of an earlier run), got none")
    check_output_dir(out_dir)
    image = read_image(image_path, expected_size=(rig.camera.width, rig.camera.height),
                       what="capture (the rig's camera size)")
    changes: dict[str, Any] = {}
    if method is not None:
        changes["method"] = method
        if method.lower() != base.method:  # another matcher: the replayed run's parameters are not its own
            changes["matcher_params"] = {}
    if params:
        changes["matcher_params"] = {**changes.get("matcher_params", base.matcher_params), **params}
    for key, value in (("depth_range", depth_range), ("roi", roi), ("triangulation", triangulation),
                       ("calibration", calibration), ("refine", refine)):
        if value is not None:
            changes[key] = value
    if views is not None:
        changes["views"] = _resolve_views(views)
    config = dataclasses.replace(base, **changes)
    _, config = validate_inputs(rig, image, config)  # everything checked before the heavy work
    depth_gt = read_depth_gt(gt, rig) if gt is not None else None
    res = run_depth(rig, image, config=config)
    lines = []
    if depth_gt is not None:
        acc = evaluate_depth(res, depth_gt=depth_gt)
        res = dataclasses.replace(res, accuracy=acc)
        lines.append(format_accuracy(acc))
    outputs = write_depth_outputs(res, out_dir, extra={
        "inputs": {"rig": None if rig_path is None else str(rig_path), "image": str(image_path),
                   "gt": None if gt is None else str(gt)},
        "preset": preset})
    c = res.counts()
    t = res.timings
    zr = res.depth_range
    how = "given" if res.depth_range_source == "given" else f"from the {res.depth_range_source}"
    lines.insert(0, f"depth range {zr[0]:.0f}–{zr[1]:.0f} mm ({how}; --depth-range MIN,MAX to set it)")
    steps = ", ".join(f"{k} {v:.1f}" for k, v in t.items() if k not in ("total", "validate"))
    if res.pair is not None:
        lines.insert(1, f"depth: faces {res.faces[0]} (left) and {res.faces[1]} (right), "
                        f"d in [{res.disparity_range[0]}, {res.disparity_range[1]}] px, {c['points']} points "
                        f"({100.0 * c['points'] / max(c['region_pixels'], 1):.1f} % of the view), "
                        f"{t['total']:.1f} s ({steps})")
    else:
        lines.insert(1, f"depth (all views): reference face {res.faces[0]}, views {list(res.faces[1:])}, "
                        f"{res.sweep.get('n', 0)} depth hypotheses, {c['points']} points "
                        f"({100.0 * c['points'] / max(c['region_pixels'], 1):.1f} % of the view), "
                        f"{t['total']:.1f} s ({steps})")
    if preset is not None:
        lines.append(f"preset {preset}: method {config.method}")
    lines.append(f"wrote {', '.join(p.name for p in outputs.values())} to {out_dir}")
    return "\n".join(lines)


def demo_command(out_dir: str, *, method: str = "bpasw") -> str:
    """Run ``prismstereo demo`` and return the lines to print."""
    check_output_dir(out_dir)
    return run_demo(out_dir, config=DepthConfig(method=method)).summary()
