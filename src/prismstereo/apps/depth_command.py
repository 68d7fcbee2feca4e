"""What ``prismstereo depth`` and ``prismstereo demo`` do, kept out of cli.py (no algorithm code there).

Input checks happen before any heavy work, in this order: the rig file, the output folder (must be
creatable and writable), the options (:func:`prismstereo.api.depth` checks the configuration before it
reads the image), the image file (exists, non-empty, decodable), the image size against the rig; the
geometry (views that do not overlap) is checked by rectification before matching.
``--config run.json`` replays an earlier run (:mod:`prismstereo.apps.replay`).
"""

from __future__ import annotations

import dataclasses
import logging
from typing import Any

from prismstereo import api
from prismstereo.apps.demo import run_demo
from prismstereo.apps.replay import replay_options
from prismstereo.depth.pipeline import DepthConfig
from prismstereo.errors import ConfigError
from prismstereo.evaluation.depth_metrics import format_accuracy
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
                  self_calibrate: bool = False, min_confidence: float | None = None,
                  coarse_to_fine: str | None = None, max_memory: int | None = None,
                  refine_fill: bool | None = None) -> str:
    """Run ``prismstereo depth`` (:func:`prismstereo.api.depth`, then its ``save``) and return the lines to
    print (``preset``: its name, for the report; ``self_calibrate``: refine the prism's pose from the capture's
    own feature matches first; the refined rig is the one recorded in run.json, so a replay does not
    calibrate again)."""
    opts = replay_options(config_path, rig_path, image_path, method=method, params=params, depth_range=depth_range,
                          roi=roi, views=_resolve_views(views), triangulation=triangulation, calibration=calibration,
                          gt=gt, refine=refine, preset=preset, min_confidence=min_confidence,
                          coarse_to_fine=coarse_to_fine, max_memory=max_memory, refine_fill=refine_fill)
    check_output_dir(out_dir)
    found = api.depth(opts.rig, opts.image_path, config=opts.config, ground_truth=opts.gt,
                      self_calibrate=self_calibrate)
    found = dataclasses.replace(found, preset=opts.preset,
                                inputs={"rig": opts.rig_path, "image": opts.image_path, "gt": opts.gt})
    res, config = found.run, found.config
    pre = [] if found.calibration is None else ["self-calibration from the capture:", found.calibration.summary()]
    lines = [] if res.accuracy is None else [format_accuracy(res.accuracy)]
    outputs = found.save(out_dir)
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
    if opts.preset is not None:
        lines.append(f"preset {opts.preset}: method {config.method}")
    lines.append(f"wrote {', '.join(outputs)} to {out_dir}")
    return "\n".join(pre + lines)


def _share(res: Any) -> str:
    """The points' share of the common view, in words (:attr:`DepthRun.coverage`)."""
    c = res.counts()
    if res.coverage is None:
        return f"{100.0 * c['points'] / max(c['region_pixels'], 1):.1f} % of the view"
    return f"{100.0 * res.coverage.share:.1f} % of {res.coverage.describe(res.depth_range)}"


def demo_command(out_dir: str, *, method: str = "bpasw") -> str:
    """Run ``prismstereo demo`` and return the lines to print."""
    check_output_dir(out_dir)
    return run_demo(out_dir, config=DepthConfig(method=method)).summary()
