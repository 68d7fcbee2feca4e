"""Rectification of the virtual cameras (thesis §3.2.2, §4.1.3, §4.2): sub-image split, rectifying
transforms and remap tables, epipolar verification, and the conventional calibration baseline."""

from __future__ import annotations

from prismstereo.rectify.rectification import (
    REMAPS,
    RectifiedPair,
    RectifiedViews,
    common_view,
    disparity_range,
    rectify_pair,
    rectify_views,
    rectifying_rotation,
    view_overlap,
)
from prismstereo.rectify.regions import SubImage, ViewRegion, check_image_size, split_capture, view_regions
from prismstereo.rectify.verify import (
    Correspondences,
    VerticalResidual,
    common_depth_range,
    true_correspondences,
    vertical_residual,
)

__all__ = [
    "REMAPS",
    "Correspondences",
    "RectifiedPair",
    "RectifiedViews",
    "SubImage",
    "VerticalResidual",
    "ViewRegion",
    "check_image_size",
    "common_depth_range",
    "common_view",
    "disparity_range",
    "rectify_pair",
    "rectify_views",
    "rectifying_rotation",
    "split_capture",
    "true_correspondences",
    "vertical_residual",
    "view_overlap",
    "view_regions",
]
