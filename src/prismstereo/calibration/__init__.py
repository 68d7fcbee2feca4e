"""Calibration of real rigs: the camera's intrinsics and distortion, and the prism's pose."""

from __future__ import annotations

from prismstereo.calibration.boards import Board, Detection, canonical_order, detect_board, parse_board
from prismstereo.calibration.camera import CameraCalibration, calibrate_camera, camera_toml
from prismstereo.calibration.prism import PrismCalibration, calibrate_prism, detect_in_subimages, parse_free

__all__ = [
    "Board",
    "CameraCalibration",
    "Detection",
    "PrismCalibration",
    "calibrate_camera",
    "calibrate_prism",
    "camera_toml",
    "canonical_order",
    "detect_board",
    "detect_in_subimages",
    "parse_board",
    "parse_free",
]
