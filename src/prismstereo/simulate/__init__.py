"""Prism-capture simulator: textured scenes, exact ray tracing through the prism, ground truth.

* Scene model (:mod:`.scene`): :class:`Rectangle`, :class:`Box`, :class:`Sphere`, :class:`Plane` with
  :class:`SolidTexture`, :class:`CheckerTexture`, :class:`NoiseTexture`, :class:`ImageTexture`, in a
  :class:`Scene`; poses as Euler angles (:func:`euler_to_matrix`) or a facing normal
  (:func:`rotation_from_normal`).
* Photographed scenes (:mod:`.rgbd`): :class:`RGBDSurface`, a colour image and its depth map (or a
  disparity map with its calibration) rendered as a triangulated height field, ground truth unknown on the
  skin across depth jumps; :func:`middlebury_rgbd` reads a Middlebury folder.
* :func:`intersect_scene` — nearest hit, point, object and colour of N rays (numba).
* :func:`render_capture` — the real camera's image through the prism with s × s supersampling, plus depth,
  face map, hit points and object ids of the pixel-centre rays (:class:`Capture`).
* Scene files (:mod:`.scene_toml`): :func:`load_scene`, :func:`scene_from_dict`, :func:`scene_to_toml`
  (``prismstereo simulate`` writes its folder with :func:`prismstereo.apps.simulate_folder.simulate_to_folder`).
* :func:`checkerboard_poses` — boards seen whole through every face, with exact corners (:class:`BoardPose`).
* :func:`robot_scene` — the built-in bi-prism scene of ``examples/biprism_robot.toml``.
"""

from __future__ import annotations

from prismstereo.simulate.builtin import panel_texture_image, robot_objects, robot_scene
from prismstereo.simulate.checkerboard import (
    BoardPose,
    board_corners,
    board_rectangle,
    board_visible,
    checkerboard_poses,
)
from prismstereo.simulate.render import Capture, SceneHits, intersect_scene, render_capture, sample_offsets
from prismstereo.simulate.rgbd import depth_from_disparity, middlebury_rgbd
from prismstereo.simulate.scene import (
    Box,
    CheckerTexture,
    ImageTexture,
    NoiseTexture,
    Plane,
    Rectangle,
    RGBDSurface,
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
    "board_corners",
    "board_rectangle",
    "board_visible",
    "checkerboard_poses",
    "depth_from_disparity",
    "load_scene",
    "middlebury_rgbd",
    "panel_texture_image",
    "robot_objects",
    "robot_scene",
    "scene_from_dict",
    "scene_to_dict",
    "scene_to_toml",
    "Box",
    "Capture",
    "CheckerTexture",
    "ImageTexture",
    "NoiseTexture",
    "Plane",
    "Rectangle",
    "RGBDSurface",
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
