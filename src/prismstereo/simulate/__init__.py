"""Prism-capture simulator: textured scenes, exact ray tracing through the prism, ground truth."""

from __future__ import annotations

from prismstereo.simulate.builtin import panel_texture_image, robot_objects, robot_scene
from prismstereo.simulate.checkerboard import (
    BoardPose,
    board_corners,
    board_rectangle,
    board_visible,
    checkerboard_poses,
)
from prismstereo.simulate.folder import SimulationResult, simulate_to_folder, write_capture
from prismstereo.simulate.render import Capture, SceneHits, intersect_scene, render_capture, sample_offsets
from prismstereo.simulate.scene import (
    Box,
    CheckerTexture,
    ImageTexture,
    NoiseTexture,
    Plane,
    Rectangle,
    Scene,
    SceneObject,
    SolidTexture,
    Sphere,
    Texture,
    euler_to_matrix,
    matrix_to_euler,
    rotation_from_normal,
)
from prismstereo.simulate.scene_toml import load_scene, scene_from_dict, scene_to_dict, scene_to_toml

__all__ = [
    "BoardPose",
    "SimulationResult",
    "board_corners",
    "board_rectangle",
    "board_visible",
    "checkerboard_poses",
    "load_scene",
    "panel_texture_image",
    "robot_objects",
    "robot_scene",
    "scene_from_dict",
    "scene_to_dict",
    "scene_to_toml",
    "simulate_to_folder",
    "write_capture",
    "Box",
    "Capture",
    "CheckerTexture",
    "ImageTexture",
    "NoiseTexture",
    "Plane",
    "Rectangle",
    "Scene",
    "SceneHits",
    "SceneObject",
    "SolidTexture",
    "Sphere",
    "Texture",
    "euler_to_matrix",
    "intersect_scene",
    "matrix_to_euler",
    "render_capture",
    "rotation_from_normal",
    "sample_offsets",
]
