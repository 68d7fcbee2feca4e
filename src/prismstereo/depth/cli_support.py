"""What ``prismstereo depth`` and ``prismstereo demo`` do, kept out of cli.py (no algorithm code there).

Input checks happen before any heavy work, in this order: the rig file, the output folder (must be
creatable and writable), the image file (exists, non-empty, decodable), the image size against the rig,
the options; the geometry (views that do not overlap) is checked by rectification before matching.
"""

from __future__ import annotations

import logging
from dataclasses import replace
from typing import Any

from prismstereo.errors import ConfigError
from prismstereo.io.atomic import check_output_dir

__all__ = ["check_output_dir", "demo_command", "depth_command"]

log = logging.getLogger(__name__)


def _resolve_views(views: Any, faces: int) -> tuple[int, int] | None:
    if views is None or views == "all":  # "all" with N >= 3 faces is handled before (all-view sweep)
        return None
    if len(views) != 2:
        raise ConfigError(f"--views: expected two faces I,J, got {','.join(map(str, views))}")
    return int(views[0]), int(views[1])


def depth_command(rig_path: str, image_path: str, out_dir: str, *, method: str = "bpasw",
                  params: dict[str, Any] | None = None, depth_range: tuple[float, float] | None = None,
                  roi: tuple[int, int, int, int] | None = None, views: Any = None,
                  triangulation: str = "exact", calibration: str = "fit", gt: str | None = None,
                  refine: bool = True, preset: str | None = None, min_confidence: float | None = None) -> str:
    """Run ``prismstereo depth`` and return the lines to print (``preset``: its name, for the report).

    ``min_confidence`` None keeps :class:`~prismstereo.depth.pipeline.DepthConfig`'s default threshold.
    """
    from prismstereo.config import load_rig
    from prismstereo.depth.outputs import write_depth_outputs
    from prismstereo.depth.pipeline import DepthConfig, run_depth, validate_inputs
    from prismstereo.evaluation.depth_metrics import evaluate_depth, format_accuracy, read_depth_gt
    from prismstereo.io import read_image
    from prismstereo.matching import get_matcher

    rig = load_rig(rig_path)
    check_output_dir(out_dir)
    image = read_image(image_path, expected_size=(rig.camera.width, rig.camera.height),
                       what="capture (the rig's camera size)")
    if views == "all" and rig.prism.faces >= 3:
        # every face at once: plane sweep in a reference view + exact multi-ray triangulation (multiview)
        from prismstereo.depth.pipeline import validate_image
        from prismstereo.multiview.prism import all_views_command

        img = validate_image(rig, image)
        notes = []
        if depth_range is None:
            from prismstereo.depth.pipeline import default_views
            from prismstereo.depth.search_range import auto_search_range_of_capture

            found = auto_search_range_of_capture(rig, img, faces=default_views(rig), calibration=calibration)
            for w in found.warnings:
                log.warning("%s", w)
            depth_range = found.depth_mm
            notes.append(f"depth range {depth_range[0]:.0f}–{depth_range[1]:.0f} mm (from the {found.source}; "
                         "--depth-range MIN,MAX to set it)")
        elif not 0 < depth_range[0] < depth_range[1]:
            raise ConfigError(f"--depth-range: expected 0 < MIN < MAX mm, got {depth_range[0]:g},{depth_range[1]:g}")
        return "\n".join(notes + [all_views_command(rig_path, image_path, out_dir, depth_range=depth_range,
                                                     calibration=calibration, gt=gt)])
    config = DepthConfig(method=method, matcher_params=dict(params or {}), depth_range=depth_range, roi=roi,
                         views=_resolve_views(views, rig.prism.faces), triangulation=triangulation,
                         calibration=calibration, refine=refine)
    if min_confidence is not None:
        config = replace(config, min_confidence=min_confidence)
    validate_inputs(rig, image, config)
    get_matcher(config.method, **config.matcher_params)  # parameters checked before the heavy work
    depth_gt = None
    if gt is not None:
        depth_gt = read_depth_gt(gt, rig)
    res = run_depth(rig, image, config=config)
    lines = []
    if depth_gt is not None:
        acc = evaluate_depth(res, depth_gt=depth_gt)
        lines.append(format_accuracy(acc))
    outputs = write_depth_outputs(res, out_dir, extra={"inputs": {"rig": str(rig_path), "image": str(image_path),
                                                                 "gt": gt},
                                                                 "preset": preset})
    c = res.counts()
    t = res.timings
    zr = res.depth_range
    how = "given" if res.depth_range_source == "given" else f"from the {res.depth_range_source}"
    lines.insert(0, f"depth range {zr[0]:.0f}–{zr[1]:.0f} mm ({how}; --depth-range MIN,MAX to set it)")
    lines.insert(1, f"depth: faces {res.faces[0]} (left) and {res.faces[1]} (right), "
                    f"d in [{res.disparity_range[0]}, {res.disparity_range[1]}] px, {c['points']} points "
                    f"({100.0 * c['points'] / max(c['region_pixels'], 1):.1f} % of the view), {t['total']:.1f} s "
                    f"(" + ", ".join(f"{k} {v:.1f}" for k, v in t.items() if k not in ("total", "validate")) + ")")
    if preset is not None:
        lines.append(f"preset {preset}: method {config.method}")
    lines.append(f"wrote {', '.join(p.name for p in outputs.values())} to {out_dir}")
    return "\n".join(lines)


def demo_command(out_dir: str, *, method: str = "bpasw") -> str:
    """Run ``prismstereo demo`` and return the lines to print."""
    from prismstereo.depth.demo import run_demo
    from prismstereo.depth.pipeline import DepthConfig

    check_output_dir(out_dir)
    return run_demo(out_dir, config=DepthConfig(method=method)).summary()
