from __future__ import annotations

import cv2
import numpy as np
import pytest

from prismstereo.calibration import Board, canonical_order, detect_board, parse_board
from prismstereo.calibration.boards import refine_corners
from prismstereo.errors import ConfigError


def test_parse_board():
    b = parse_board("8x6", 3.0)
    assert b.pattern_size == (8, 6) and b.n_corners == 48
    obj = b.object_points()
    assert obj.shape == (48, 3) and obj[1, 0] == 3.0 and obj[8, 1] == 3.0
    for bad in ("8", "8x", "ax6", "8*6"):
        with pytest.raises(ConfigError, match="^board: expected inner corners as COLSxROWS"):
            parse_board(bad, 3.0)
    with pytest.raises(ConfigError, match="^board: expected at least 2x2"):
        parse_board("1x6", 3.0)
    with pytest.raises(ConfigError, match="^square: expected a positive size"):
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


def _checker_image(board: Board, A: np.ndarray, origin: np.ndarray, size: tuple[int, int], ss: int = 8,
                   blur: float = 0.7) -> np.ndarray:
    """A board mapped to the image by p = origin + A·(s, t) (mm → px), integrated over each pixel's area with
    ss × ss samples, then blurred (a lens): the inner corners are exactly at origin + A·corner."""
    h, w = size
    g = (np.arange(ss) + 0.5) / ss - 0.5
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    px = (xx[..., None, None] + g[None, None, None, :]).reshape(h, w, -1)
    py = (yy[..., None, None] + g[None, None, :, None]).reshape(h, w, -1)
    inv = np.linalg.inv(A)
    s = inv[0, 0] * (px - origin[0]) + inv[0, 1] * (py - origin[1])
    t = inv[1, 0] * (px - origin[0]) + inv[1, 1] * (py - origin[1])
    i, j = np.floor(s / board.square), np.floor(t / board.square)
    inside = (i >= -1) & (i <= board.cols - 1) & (j >= -1) & (j <= board.rows - 1)
    val = np.where(inside, np.where((i + j) % 2 == 0, 30.0, 220.0), 220.0).mean(axis=2)
    return np.clip(np.rint(cv2.GaussianBlur(val, (0, 0), blur)), 0, 255).astype(np.uint8)


def test_refine_corners_finds_the_exact_corners_of_a_skewed_board():
    b = Board(6, 4, 3.0)
    rng = np.random.default_rng(5)
    # a foreshortened, turned view (squares ~14 x 10 px, edges 7° off the pixel axes), sub-pixel origin
    A = np.array([[4.6, -0.9], [0.6, 3.4]])
    origin = np.array([45.0, 35.0]) + rng.uniform(0, 1, 2)
    truth = origin + b.object_points()[:, :2] @ A.T
    img = _checker_image(b, A, origin, (110, 160))
    start = truth + rng.uniform(-0.4, 0.4, truth.shape)
    refined = refine_corners(img, start, b)
    assert np.sqrt(np.mean((refined - truth) ** 2)) < 0.02 and np.abs(refined - truth).max() < 0.05
    # the detector's own positions on the same image are several times farther off
    det = detect_board(img, b, refine=False)
    assert det.found
    assert np.sqrt(np.mean((refined - truth) ** 2)) < 0.5 * np.sqrt(np.mean((det.corners - truth) ** 2))
    # a corner that cannot be refined (flat image) keeps its starting position
    flat = np.full_like(img, 128)
    assert np.array_equal(refine_corners(flat, start, b), start)


def test_refined_corners_through_the_prism_match_the_exact_projection(board_captures, small_true, small_nominal):
    import dataclasses

    from prismstereo.calibration import detect_in_subimages
    from prismstereo.optics import project_exact

    poses, images = board_captures
    start = dataclasses.replace(small_nominal, camera=small_true.camera)
    errs = []
    for pose, img in list(zip(poses, images, strict=True))[2:4]:
        for face, c in enumerate(detect_in_subimages(img, start, Board(8, 6, 5.0))):
            truth, _ = project_exact(small_true, pose.corners, face=face)
            errs.append(min(np.sqrt(np.mean((c - truth) ** 2)), np.sqrt(np.mean((c[::-1] - truth) ** 2))))
    assert max(errs) < 0.05  # the detector's own corners: 0.10–0.15 px RMS on these boards
