"""Prism-capture simulator: textured scenes, exact ray tracing through the prism, ground truth."""

from __future__ import annotations

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

__all__ = [
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
