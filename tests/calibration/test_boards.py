from __future__ import annotations

import cv2
import numpy as np
import pytest

from prismstereo.calibration import Board, canonical_order, detect_board, parse_board
from prismstereo.errors import ConfigError


def test_parse_board():
    b = parse_board("8x6", 3.0)
    assert b.pattern_size == (8, 6) and b.n_corners == 48
    obj = b.object_points()
    assert obj.shape == (48, 3) and obj[1, 0] == 3.0 and obj[8, 1] == 3.0
    for bad in ("8", "8x", "ax6", "8*6"):
        with pytest.raises(ConfigError, match="--board: expected inner corners as COLSxROWS"):
            parse_board(bad, 3.0)
    with pytest.raises(ConfigError, match="--board: expected at least 2x2"):
        parse_board("1x6", 3.0)
    with pytest.raises(ConfigError, match="--square: expected a positive size"):
        parse_board("8x6", -1.0)


def test_canonical_order_undoes_a_reversed_detection():
    b = Board(4, 3, 1.0)
    grid = b.object_points()[:, :2] * 20 + 50
    assert np.array_equal(canonical_order(grid[::-1], b), grid)
    assert np.array_equal(canonical_order(grid, b), grid)


def test_detect_board_rejects_partial_and_blurred(camera_photos):
    b = Board(8, 6, 5.0)
    img = camera_photos[0]
    det = detect_board(img, b)
    assert det.found and det.corners.shape == (48, 2) and det.edge_width < 4.0
    blurred = cv2.GaussianBlur(img, (0, 0), 4.0)
    bad = detect_board(blurred, b)
    assert not bad.found and ("blurred" in bad.reason or "not found" in bad.reason)
    # cut the board in half: no partial board is accepted
    xs = det.corners[:, 0]
    cut = img.copy()
    cut[:, int(np.median(xs)):] = 115
    assert not detect_board(cut, b).found
