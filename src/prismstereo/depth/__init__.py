"""Depth recovery: triangulation (thesis §7.2) and the end-to-end pipeline behind ``prismstereo depth``."""

from __future__ import annotations

from prismstereo.depth.pipeline import (
    DepthConfig,
    DepthRun,
    DepthSetup,
    default_views,
    prepare_depth,
    run_depth,
    run_depth_frame,
    validate_image,
    validate_inputs,
)
from prismstereo.depth.triangulation import (
    TRIANGULATIONS,
    Triangulation,
    depth_from_disparity,
    rectified_to_world,
    reproject_disparity,
    triangulate_dlt,
    triangulate_exact,
    triangulate_matches,
    triangulate_midpoint,
)

__all__ = [
    "TRIANGULATIONS",
    "DepthConfig",
    "DepthRun",
    "DepthSetup",
    "Triangulation",
    "default_views",
    "depth_from_disparity",
    "rectified_to_world",
    "prepare_depth",
    "reproject_disparity",
    "run_depth",
    "run_depth_frame",
    "triangulate_dlt",
    "triangulate_exact",
    "triangulate_matches",
    "triangulate_midpoint",
    "validate_image",
    "validate_inputs",
]
