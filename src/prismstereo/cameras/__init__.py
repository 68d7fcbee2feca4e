"""Cameras: the pinhole model and the virtual cameras of a prism rig (thesis, fit and exact models)."""

from __future__ import annotations

from prismstereo.cameras.faces import face_pixels, thesis_camera
from prismstereo.cameras.pinhole import PinholeCamera, project_points, rotation_from_axis
from prismstereo.cameras.virtual import (
    METHODS,
    ExactCamera,
    VirtualView,
    calibrate_rig,
    cameras_table,
    fit_camera,
    read_cameras_json,
    reprojection_error,
    sample_points,
    virtual_view,
    write_cameras_json,
)

__all__ = [
    "METHODS",
    "ExactCamera",
    "PinholeCamera",
    "VirtualView",
    "calibrate_rig",
    "cameras_table",
    "face_pixels",
    "fit_camera",
    "project_points",
    "read_cameras_json",
    "reprojection_error",
    "rotation_from_axis",
    "sample_points",
    "thesis_camera",
    "virtual_view",
    "write_cameras_json",
]
