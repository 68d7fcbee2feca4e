"""Checkerboard geometry and detection shared by the camera and prism calibrations.

A board is named by its inner corners, ``COLSxROWS`` (OpenCV's ``patternSize``), and its square side in
mm. Detection uses OpenCV's sector-based detector (``cv2.findChessboardCornersSB``), which is accurate to
a few hundredths of a pixel on sharp images and refuses partial boards; blurred boards are rejected by
OpenCV's edge-width measure (``cv2.estimateChessboardSharpness``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import cv2
import numpy as np

from prismstereo.errors import ConfigError, ImageError

#: edge width (px, 10–90 % rise) above which a board is too blurred to calibrate from
MAX_EDGE_WIDTH_PX = 4.0


@dataclass(frozen=True)
class Board:
    """A checkerboard: ``cols`` × ``rows`` inner corners, squares of ``square`` mm."""

    cols: int
    rows: int
    square: float

    def __post_init__(self) -> None:
        if min(self.cols, self.rows) < 2:
            raise ConfigError(f"--board: expected at least 2x2 inner corners, got {self.cols}x{self.rows}")
        if not np.isfinite(self.square) or self.square <= 0:
            raise ConfigError(f"--square: expected a positive size in mm, got {self.square!r}")

    @property
    def pattern_size(self) -> tuple[int, int]:
        return (self.cols, self.rows)

    @property
    def n_corners(self) -> int:
        return self.cols * self.rows

    def object_points(self) -> np.ndarray:
        """(cols·rows, 3) float64 corners in the board frame, mm, z = 0, OpenCV order (x fastest)."""
        jj, ii = np.meshgrid(np.arange(self.rows), np.arange(self.cols), indexing="ij")
        obj = np.zeros((self.n_corners, 3))
        obj[:, 0] = ii.ravel() * self.square
        obj[:, 1] = jj.ravel() * self.square
        return obj


def parse_board(text: str, square: float) -> Board:
    """``"8x6"`` and a square size (mm) → :class:`Board`; a clear ConfigError otherwise."""
    m = re.fullmatch(r"\s*(\d+)\s*[xX×]\s*(\d+)\s*", str(text))
    if m is None:
        raise ConfigError(f"--board: expected inner corners as COLSxROWS like 8x6, got {text!r}")
    return Board(int(m.group(1)), int(m.group(2)), float(square))


def to_gray(image: np.ndarray) -> np.ndarray:
    """(H, W) uint8 grey image of an RGB/grey uint8 or uint16 image."""
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img[..., :3], cv2.COLOR_RGB2GRAY)
    if img.ndim != 2:
        raise ImageError(f"expected an H×W or H×W×3 image, got shape {img.shape}")
    if img.dtype == np.uint16:
        img = (img / 257.0).round().astype(np.uint8)
    elif img.dtype != np.uint8:
        img = np.clip(np.nan_to_num(img), 0, 255).round().astype(np.uint8)
    return img


@dataclass(frozen=True)
class Detection:
    """Inner corners found in one image (or sub-image).

    Attributes
    ----------
    corners : (cols·rows, 2) float64 or None
        Pixels of the corners, OpenCV order, canonical orientation (:func:`canonical_order`); None if the
        board was not found or rejected.
    edge_width : float
        OpenCV's sharpness measure (px); NaN when not found.
    reason : str
        Why the board was rejected ("" when accepted).
    """

    corners: np.ndarray | None
    edge_width: float
    reason: str = ""

    @property
    def found(self) -> bool:
        return self.corners is not None


def canonical_order(corners: np.ndarray, board: Board) -> np.ndarray:
    """Resolve the board's 180° ambiguity: order the corners so that the last one is to the right of the
    first (or below it, for a board seen turned by 90°).

    A board with an odd number of squares per side looks the same turned by 180°, and OpenCV may start
    at either end. The views of a prism see the same board turned by nearly the same angle (the faces
    deviate the rays by a few degrees), so the same image rule labels every view of a capture alike.
    """
    c = np.asarray(corners, dtype=np.float64).reshape(board.n_corners, 2)
    v = c[-1] - c[0]
    flip = v[0] < 0 if abs(v[0]) > 1e-6 * (1.0 + abs(v[1])) else v[1] < 0
    return c[::-1].copy() if flip else c


def detect_board(
    image: np.ndarray, board: Board, *, max_edge_width: float = MAX_EDGE_WIDTH_PX
) -> Detection:
    """Find the board's inner corners in an image (partial or blurred boards are rejected).

    Parameters
    ----------
    image : (H, W) or (H, W, 3) uint8
    board : Board
    max_edge_width : float
        Boards whose edges are wider than this (px) are rejected as blurred.

    Returns
    -------
    Detection
    """
    gray = to_gray(image)
    flags = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
    found, corners = cv2.findChessboardCornersSB(gray, board.pattern_size, flags=flags)
    if not found or corners is None:
        return Detection(None, float("nan"), "board not found (missing, partial or too small)")
    corners = corners.reshape(-1, 2).astype(np.float64)
    sharp, _ = cv2.estimateChessboardSharpness(gray, board.pattern_size, corners.astype(np.float32))
    width = float(np.ravel(sharp)[0])
    if not np.isfinite(width) or width > max_edge_width:
        return Detection(None, width, f"board blurred (edge width {width:.1f} px > {max_edge_width:g})")
    return Detection(canonical_order(corners, board), width)
