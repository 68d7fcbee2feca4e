"""What ``prismstereo depth`` and ``prismstereo demo`` do, kept out of cli.py (no algorithm code there).

Input checks happen before any heavy work, in this order: the rig file, the output folder (must be
creatable and writable), the image file (exists, non-empty, decodable), the image size against the rig,
the options; the geometry (views that do not overlap) is checked by rectification before matching.
``--config run.json`` replays an earlier run (:mod:`prismstereo.apps.replay`).
"""

from __future__ import annotations

import dataclasses
import logging
from typing import Any

from prismstereo.apps.demo import run_demo
from prismstereo.apps.replay import replay_options
from prismstereo.calibration.from_scene import calibrate_from_scene
from prismstereo.calibration.scene_uncertainty import uncertainty_warnings, unobserved_depth_error
from prismstereo.depth.outputs import write_depth_outputs
from prismstereo.depth.pipeline import DepthConfig, run_depth, validate_inputs
from prismstereo.errors import ConfigError
from prismstereo.evaluation.depth_metrics import evaluate_depth, format_accuracy, read_depth_gt
from prismstereo.io import read_image
from prismstereo.io.atomic import check_output_dir

__all__ = ["check_output_dir", "demo_command", "depth_command"]

log = logging.getLogger(__name__)


def _resolve_views(views: Any) -> tuple[int, int] | str | None:
    if views is None or views == "all":  # "all": every face of an N >= 3 prism, a bi-prism's pair
        return views
    if len(views) != 2:
        raise ConfigError(f"--views: expected two faces I,J, got {','.join(map(str, views))}")
    return int(views[0]), int(views[1])


def depth_command(rig_path: str | None, image_path: str | None, out_dir: str, *, method: str | None = None,
                  params: dict[str, Any] | None = None, depth_range: tuple[float, float] | None = None,
                  roi: tuple[int, int, int, int] | None = None, views: Any = None,
                  triangulation: str | None = None, calibration: str | None = None, gt: str | None = None,
                  refine: bool | None = None, preset: str | None = None, config_path: str | None = None,
                  self_calibrate: bool = False, min_confidence: float | None = None) -> str:
    """Run ``prismstereo depth`` and return the lines to print (``preset``: its name, for the report;
    ``self_calibrate``: refine the prism's pose from the capture's own feature matches first; the refined
    rig is the one recorded in run.json, so a replay does not calibrate again)."""
    opts = replay_options(config_path, rig_path, image_path, method=method, params=params, depth_range=depth_range,
                          roi=roi, views=_resolve_views(views), triangulation=triangulation, calibration=calibration,
                          gt=gt, refine=refine, preset=preset, min_confidence=min_confidence)
    rig, gt, preset = opts.rig, opts.gt, opts.preset
    if self_calibrate and opts.config.views == "all" and rig.prism.faces >= 3:
        raise ConfigError("--self-calibrate: expected a face pair (--views I,J), got --views all")
    check_output_dir(out_dir)
    image = read_image(opts.image_path, expected_size=(rig.camera.width, rig.camera.height),
                       what="capture (the rig's camera size)")
    _, config = validate_inputs(rig, image, opts.config)  # matcher and parameters too, before the heavy work
    pre: list[str] = []
    extra: dict[str, Any] = {}
    refined = None
    if self_calibrate:
        refined, pre, extra = _self_calibrate(rig, image)
        rig = refined
    depth_gt = None
    if gt is not None:
        depth_gt = read_depth_gt(gt, rig)
    res = run_depth(rig, image, config=config)
    lines = []
    if depth_gt is not None:
        acc = evaluate_depth(res, depth_gt=depth_gt)
        res = dataclasses.replace(res, accuracy=acc)
        lines.append(format_accuracy(acc))
    # the refined rig is staged with the other files, so that all of them appear together or none
    save_rig = None if refined is None else (lambda stage: refined.save(stage / "rig_refined.toml"))
    outputs = write_depth_outputs(res, out_dir, extra={"inputs": {"rig": opts.rig_path, "image": opts.image_path,
                                                                 "gt": gt},
                                                                 "preset": preset, **extra}, also=save_rig)
    c = res.counts()
    t = res.timings
    zr = res.depth_range
    how = "given" if res.depth_range_source == "given" else f"from the {res.depth_range_source}"
    lines.insert(0, f"depth range {zr[0]:.0f}–{zr[1]:.0f} mm ({how}; --depth-range MIN,MAX to set it)")
    lines.insert(1, f"depth: faces {res.faces[0]} (left) and {res.faces[1]} (right), "
                    f"d in [{res.disparity_range[0]}, {res.disparity_range[1]}] px, {c['points']} points "
                    f"({_share(res)}), {t['total']:.1f} s "
                    f"(" + ", ".join(f"{k} {v:.1f}" for k, v in t.items() if k not in ("total", "validate")) + ")")
    if res.pair is None:  # every face: a plane sweep, no left/right pair nor disparity range
        lines[1] = (f"depth (all views): reference face {res.faces[0]}, views {list(res.faces[1:])}, "
                    f"{res.sweep.get('n', 0)} depth hypotheses, {c['points']} points "
                    f"({100.0 * c['points'] / max(c['region_pixels'], 1):.1f} % of the view), {t['total']:.1f} s")
    if preset is not None:
        lines.append(f"preset {preset}: method {config.method}")
    names = [p.name for p in outputs.values()] + ([] if refined is None else ["rig_refined.toml"])
    lines.append(f"wrote {', '.join(names)} to {out_dir}")
    return "\n".join(pre + lines)


def _share(res: Any) -> str:
    """The points' share of the common view, in words (:attr:`DepthResult.coverage`)."""
    c = res.counts()
    if res.coverage is None:
        return f"{100.0 * c['points'] / max(c['region_pixels'], 1):.1f} % of the view"
    return f"{100.0 * res.coverage.share:.1f} % of {res.coverage.describe(res.depth_range)}"


def _self_calibrate(rig: Any, image: Any) -> tuple[Any, list[str], dict[str, Any]]:
    """Refine the prism's pose from the capture (``depth --self-calibrate``): the rig, lines, run.json entry."""
    cal = calibrate_from_scene(rig, [image])
    lines = ["self-calibration from the capture:", cal.summary()]
    report = {k: v for k, v in cal.report().items() if k != "rig"}
    # what the parameters the scene did not observe can do to the depth, at the scene's depths
    unobserved = unobserved_depth_error(cal)
    warnings = uncertainty_warnings(unobserved)
    report["depth_error_unobserved"] = unobserved
    report["warnings"] = warnings
    for line in warnings:
        log.warning("%s", line)
    return cal.rig, lines, {"self_calibration": report}


def demo_command(out_dir: str, *, method: str = "bpasw") -> str:
    """Run ``prismstereo demo`` and return the lines to print."""
    check_output_dir(out_dir)
    return run_demo(out_dir, config=DepthConfig(method=method)).summary()
