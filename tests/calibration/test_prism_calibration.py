from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from prismstereo.calibration import Board, calibrate_prism, detect_in_subimages, parse_free
from prismstereo.errors import ConfigError, GeometryError, ImageError
from prismstereo.optics import project_exact


def test_corners_found_in_every_sub_image_with_consistent_labels(board_captures, small_true, small_nominal):
    poses, images = board_captures
    start = dataclasses.replace(small_nominal, camera=small_true.camera)
    found = detect_in_subimages(images[0], start, Board(8, 6, 5.0))
    assert all(c is not None for c in found)
    # both views label the corners alike (one of the board's two 180°-symmetric orders, the same in both)
    flips = []
    for face, c in enumerate(found):
        truth, _ = project_exact(small_true, poses[0].corners, face=face)
        direct, turned = np.abs(c - truth).max(), np.abs(c[::-1] - truth).max()
        assert min(direct, turned) < 0.3
        flips.append(turned < direct)
    assert flips[0] == flips[1]


def test_calibration_recovers_a_known_pose(board_captures, small_true, small_nominal):
    _, images = board_captures
    start = dataclasses.replace(small_nominal, camera=small_true.camera)
    res = calibrate_prism(start, images, Board(8, 6, 5.0))
    assert abs(res.estimates["rotation"] - 1.4) < 0.01
    # the target (0.2°); the fit measures 0.04° with std 0.05° here (5 captures at half resolution)
    assert abs(res.estimates["tilt_x"] - 1.0) < 0.2 and abs(res.estimates["tilt_y"] + 0.8) < 0.2
    assert res.std["tilt_x"] < 0.1 and res.std["tilt_y"] < 0.1
    assert res.rms_px < 0.1 and res.std["rotation"] < 0.01
    assert set(res.per_view_rms) == {f"capture{i}:{k}" for i in range(5) for k in range(2)}
    assert res.rig.prism.rotation == res.estimates["rotation"]
    # the focal lengths are refined by default (they start at the truth here and must stay there)
    f = small_true.camera.focal_px
    assert abs(res.estimates["fx"] / f - 1) < 0.002 and abs(res.estimates["fy"] / f - 1) < 0.002
    assert res.rig.camera.distortion == small_true.camera.distortion


def test_missing_board_in_a_sub_image_is_refused(board_captures, small_true, small_nominal):
    _, images = board_captures
    start = dataclasses.replace(small_nominal, camera=small_true.camera)
    blank = images[1].copy()
    blank[:, : blank.shape[1] // 2 - 30] = 115  # the left view (face 1) loses its board
    with pytest.raises(ImageError, match=r"got none in face\(s\) 1 of capture1"):
        calibrate_prism(start, [images[0], blank, images[2]], Board(8, 6, 5.0))


def test_ill_conditioned_fit_is_refused(board_captures, small_true, small_nominal):
    _, images = board_captures
    start = dataclasses.replace(small_nominal, camera=small_true.camera)
    # the index and the corner angle trade against each other (deviation ≈ (n − 1)·α): not separable
    with pytest.raises(GeometryError, match="expected a well-conditioned prism fit"):
        calibrate_prism(start, images[:3], Board(8, 6, 5.0), free="refractive_index,corner_angle")


def test_parse_free():
    assert parse_free(None) == ("rotation", "tilt_x", "tilt_y", "decenter_x", "decenter_y", "fx", "fy")
    assert parse_free("principal_point,k1") == ("cx", "cy", "k1")
    assert parse_free("rotation,apex_distance") == ("rotation", "apex_distance")
    with pytest.raises(ConfigError, match="^free: expected a comma list"):
        parse_free("rotation,spin")


def test_a_wrong_focal_length_is_refused_or_absorbed(board_captures, small_true, small_nominal):
    _, images = board_captures
    f = small_true.camera.focal_px * 1.01  # a camera calibration 1 % off
    cam = dataclasses.replace(small_true.camera, fx=f, fy=f)
    start = dataclasses.replace(small_nominal, camera=cam)
    # holding the focal length, the prism cannot explain the corners: refused, not silently wrong
    with pytest.raises(GeometryError, match="expected a"):
        calibrate_prism(start, images, Board(8, 6, 5.0), free="rotation,tilt,decenter")
    # with the focal length free (the default) it is recovered
    res = calibrate_prism(start, images, Board(8, 6, 5.0))
    assert abs(res.estimates["fx"] / small_true.camera.focal_px - 1) < 0.002
    assert abs(res.estimates["rotation"] - 1.4) < 0.1
