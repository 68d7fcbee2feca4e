"""Checkerboard poses: exact corners on the board plane, visible in every view, found by OpenCV."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from prismstereo.config import Rig
from prismstereo.errors import ConfigError
from prismstereo.simulate import board_corners, board_rectangle, checkerboard_poses, render_capture


def test_corners_lie_on_the_board_plane(small_biprism: Rig) -> None:
    poses = checkerboard_poses(small_biprism, n_poses=4, squares=(9, 7), seed=1)
    assert len(poses) == 4
    for p in poses:
        assert p.corners.shape == (48, 3) and p.pattern_size == (8, 6)
        n = p.board.normal
        dist = (p.corners - np.asarray(p.board.center)) @ n
        np.testing.assert_allclose(dist, 0.0, atol=1e-9)
        np.testing.assert_allclose(p.origin + p.object_points @ p.rotation.T, p.corners, atol=1e-9)
        np.testing.assert_allclose(np.linalg.norm(np.diff(p.corners[:8], axis=0), axis=1), p.square, rtol=1e-12)
        assert 600.0 <= p.board.center[2] <= 1500.0


def test_poses_are_deterministic(small_biprism: Rig) -> None:
    a = checkerboard_poses(small_biprism, n_poses=3, seed=4)
    b = checkerboard_poses(small_biprism, n_poses=3, seed=4)
    for p, q in zip(a, b, strict=True):
        np.testing.assert_array_equal(p.corners, q.corners)


def test_rendered_corners_match_opencv_detection(small_biprism: Rig) -> None:
    board = board_rectangle((3.0, -2.0, 400.0), (12.0, -15.0, 5.0), squares=(7, 5), square_mm=6.0)
    corners, _ = board_corners(board)
    from prismstereo.simulate import Scene

    cap = render_capture(small_biprism, Scene(objects=(board,), background=(0.4, 0.4, 0.4)), supersample=4,
                         prism=False)
    gray = cv2.cvtColor(cap.image, cv2.COLOR_RGB2GRAY)
    found, det = cv2.findChessboardCorners(gray, (6, 4))
    assert found
    det = cv2.cornerSubPix(gray, det, (5, 5), (-1, -1),
                           (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)).reshape(-1, 2)
    proj = corners @ small_biprism.camera.K.T
    proj = proj[:, :2] / proj[:, 2:]
    if np.linalg.norm(det[0] - proj[0]) > np.linalg.norm(det[0] - proj[-1]):
        det = det[::-1]
    assert np.max(np.linalg.norm(det - proj, axis=1)) < 0.15


def test_bad_arguments(small_biprism: Rig) -> None:
    with pytest.raises(ConfigError):
        checkerboard_poses(small_biprism, n_poses=0)
    with pytest.raises(ConfigError):
        checkerboard_poses(small_biprism, distance_range=(100.0, 50.0))
