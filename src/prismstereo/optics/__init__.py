"""Optics: vector refraction, planes and tracing through N-face pyramid prisms (pure functions)."""

from __future__ import annotations

from prismstereo.optics.distortion import distort_points, undistort_points
from prismstereo.optics.prism import (
    RayBundle,
    deviation_angle,
    face_map,
    pixel_grid,
    rays_from_pixels,
    trace_pixels,
    trace_rays,
)
from prismstereo.optics.projection import project_exact
from prismstereo.optics.refraction import (
    closest_points_between_lines,
    intersect_plane,
    normalize,
    refract,
)

__all__ = [
    "RayBundle",
    "closest_points_between_lines",
    "distort_points",
    "deviation_angle",
    "face_map",
    "intersect_plane",
    "normalize",
    "pixel_grid",
    "project_exact",
    "rays_from_pixels",
    "refract",
    "trace_pixels",
    "trace_rays",
    "undistort_points",
]
