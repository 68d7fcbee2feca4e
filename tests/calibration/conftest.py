"""Simulated board photos and captures of a small (512×384) misaligned, distorting rig."""

from __future__ import annotations

import dataclasses

import pytest

from prismstereo.apps.demo import scaled_rig
from prismstereo.config import thesis_biprism

DIST = (-0.10, 0.12, 0.0, 0.0, 0.0)
POSE = {"rotation": 1.4, "tilt": (1.0, -0.8), "decenter": (1.0, -0.5)}


@pytest.fixture(scope="session")
def small_nominal():
    return scaled_rig(thesis_biprism(), 2)


@pytest.fixture(scope="session")
def small_true(small_nominal):
    cam = dataclasses.replace(small_nominal.camera, distortion=DIST)
    return dataclasses.replace(small_nominal, camera=cam).with_prism(**POSE)


@pytest.fixture(scope="session")
def board_captures(small_true):
    """(poses, images): 5 captures of an 8x6-corner board with 5 mm squares through the true prism."""
    from prismstereo.simulate import render_capture
    from prismstereo.simulate.checkerboard import checkerboard_poses

    poses = checkerboard_poses(small_true, n_poses=5, squares=(9, 7), square_mm=5.0, distance_range=(600.0, 1000.0),
                               seed=3)
    images = [render_capture(small_true, dataclasses.replace(p.scene, noise=1.0, seed=i), supersample=2).image
              for i, p in enumerate(poses)]
    return poses, images


@pytest.fixture(scope="session")
def camera_photos(small_true):
    """8 photos of the board without the prism, 0.3–0.5 m."""
    from prismstereo.simulate import render_capture
    from prismstereo.simulate.checkerboard import camera_board_poses

    poses = camera_board_poses(small_true, n_poses=8, squares=(9, 7), square_mm=5.0, distance_range=(300.0, 500.0),
                               seed=0)
    return [render_capture(small_true, dataclasses.replace(p.scene, noise=1.0, seed=i), supersample=2,
                           prism=False).image for i, p in enumerate(poses)]
