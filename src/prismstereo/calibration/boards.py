"""Checkerboard geometry and detection shared by the camera and prism calibrations.

A board is named by its inner corners, ``COLSxROWS`` (OpenCV's ``patternSize``), and its square side in
mm. Detection uses OpenCV's sector-based detector (``cv2.findChessboardCornersSB``), which finds the board
robustly and refuses partial boards; blurred boards are rejected by OpenCV's edge-width measure
(``cv2.estimateChessboardSharpness``). Its corners are then refined by point symmetry
(:func:`refine_corners`): on small, foreshortened boards the detector's own sub-pixel positions are off by
up to 0.2 px, in a pattern that alternates from corner to corner and does not average out.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage

from prismstereo.errors import ConfigError
from prismstereo.io.images import as_image

#: edge width (px, 10–90 % rise) above which a board is too blurred to calibrate from
MAX_EDGE_WIDTH_PX = 4.0
#: symmetry window radius of :func:`refine_corners`, as a fraction of the distance to the nearest corner
REFINE_RADIUS = 0.5
#: a refined corner that moved farther than this (px) from the detector's is dropped back to the detector's
REFINE_MAX_SHIFT_PX = 1.0


@dataclass(frozen=True)
class Board:
    """A checkerboard: ``cols`` × ``rows`` inner corners, squares of ``square`` mm."""

    cols: int
    rows: int
    square: float

    def __post_init__(self) -> None:
        if min(self.cols, self.rows) < 2:
            raise ConfigError(f"board: expected at least 2x2 inner corners, got {self.cols}x{self.rows}")
        if not np.isfinite(self.square) or self.square <= 0:
            raise ConfigError(f"square: expected a positive size in mm, got {self.square!r}")

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
        raise ConfigError(f"board: expected inner corners as COLSxROWS like 8x6, got {text!r}")
    return Board(int(m.group(1)), int(m.group(2)), float(square))


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


def _neighbour_spacing(corners: np.ndarray, board: Board) -> np.ndarray:
    """(M,) distance (px) from each corner to its nearest neighbour along the board's rows and columns."""
    grid = corners.reshape(board.rows, board.cols, 2)
    along = np.linalg.norm(np.diff(grid, axis=1), axis=2)  # (rows, cols - 1)
    across = np.linalg.norm(np.diff(grid, axis=0), axis=2)  # (rows - 1, cols)
    d = np.full((board.rows, board.cols), np.inf)
    d[:, :-1] = np.minimum(d[:, :-1], along)
    d[:, 1:] = np.minimum(d[:, 1:], along)
    d[:-1, :] = np.minimum(d[:-1, :], across)
    d[1:, :] = np.minimum(d[1:, :], across)
    return d.ravel()


def refine_corners(
    gray: np.ndarray, corners: np.ndarray, board: Board, *, radius: float = REFINE_RADIUS,
    iterations: int = 20, max_shift: float = REFINE_MAX_SHIFT_PX,
) -> np.ndarray:
    """Sub-pixel checkerboard corners as the centres of point symmetry of the image.

    Around an inner corner the board's image is point-symmetric: I(c + x) = I(c − x) for the ideal corner
    under any locally affine view (perspective, prism, lens) and any point-symmetric blur (lens, pixel
    area). Each corner c minimises Σ_x w(x) (I(c + x) − I(c − x))² over a disc of radius ``radius`` × the
    distance to its nearest neighbouring corner, with Gaussian weights w (σ = half the radius), by
    Gauss–Newton on a cubic-spline interpolation of the image (exact sample positions, no fixed-point
    maps). The estimate needs no model of the edge profile, so it is unbiased wherever that profile is
    symmetric.

    Parameters
    ----------
    gray : (H, W) uint8 or float image
    corners : (M, 2) float64 starting corners (px), OpenCV order
    board : Board
    radius : float
        Window radius as a fraction of the corner's nearest-neighbour spacing (≤ 0.5 keeps neighbouring
        corners out of the window).
    iterations : int
    max_shift : float
        A corner whose refinement fails or moves it farther than this (px) keeps its starting position.

    Returns
    -------
    (M, 2) float64 refined corners (px)
    """
    img = np.asarray(gray, dtype=np.float64)
    c0 = np.asarray(corners, dtype=np.float64).reshape(-1, 2)
    r = np.maximum(radius * _neighbour_spacing(c0, board), 2.0)
    gy, gx = np.gradient(img)
    coeffs = [ndimage.spline_filter(a, order=3) for a in (img, gx, gy)]
    R = int(np.ceil(min(float(r.max()), 64.0)))
    yy, xx = np.mgrid[-R:R + 1, -R:R + 1]
    off = np.stack([xx.ravel(), yy.ravel()], axis=1).astype(np.float64)
    off = off[(off[:, 1] > 0) | ((off[:, 1] == 0) & (off[:, 0] > 0))]  # one of each ±x pair
    d2 = np.sum(off**2, axis=1)
    w = np.exp(-0.5 * d2[None, :] / (0.5 * r[:, None]) ** 2) * (d2[None, :] <= r[:, None] ** 2)

    def sample(k: int, q: np.ndarray) -> np.ndarray:
        return ndimage.map_coordinates(coeffs[k], [q[..., 1].ravel(), q[..., 0].ravel()], order=3,
                                       prefilter=False, mode="nearest").reshape(q.shape[:2])

    c = c0.copy()
    for _ in range(iterations):
        plus, minus = c[:, None, :] + off[None], c[:, None, :] - off[None]
        res = sample(0, plus) - sample(0, minus)  # (M, K)
        jx = sample(1, plus) - sample(1, minus)  # d res / d cx
        jy = sample(2, plus) - sample(2, minus)
        a, b, d = (np.sum(w * u * v, axis=1) for u, v in ((jx, jx), (jx, jy), (jy, jy)))
        ex, ey = np.sum(w * jx * res, axis=1), np.sum(w * jy * res, axis=1)
        det = a * d - b * b
        with np.errstate(divide="ignore", invalid="ignore"):
            step = -np.stack([(d * ex - b * ey) / det, (a * ey - b * ex) / det], axis=1)
        step = np.nan_to_num(step, nan=0.0, posinf=0.0, neginf=0.0)
        norm = np.linalg.norm(step, axis=1, keepdims=True)
        step *= np.minimum(1.0, 0.5 / np.maximum(norm, 1e-12))  # trust region of half a pixel per step
        c += step
        if float(np.max(np.abs(step))) < 1e-5:
            break
    bad = ~np.all(np.isfinite(c), axis=1) | (np.linalg.norm(c - c0, axis=1) > max_shift)
    c[bad] = c0[bad]
    return c


def detect_board(
    image: np.ndarray, board: Board, *, max_edge_width: float = MAX_EDGE_WIDTH_PX, refine: bool = True
) -> Detection:
    """Find the board's inner corners in an image (partial or blurred boards are rejected).

    Parameters
    ----------
    image : (H, W) or (H, W, 3) uint8
    board : Board
    max_edge_width : float
        Boards whose edges are wider than this (px) are rejected as blurred.
    refine : bool
        Refine the detector's corners by point symmetry (:func:`refine_corners`).

    Returns
    -------
    Detection
    """
    gray = as_image(image, channels=1)
    flags = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
    found, corners = cv2.findChessboardCornersSB(gray, board.pattern_size, flags=flags)
    if not found or corners is None:
        return Detection(None, float("nan"), "board not found (missing, partial or too small)")
    corners = corners.reshape(-1, 2).astype(np.float64)
    sharp, _ = cv2.estimateChessboardSharpness(gray, board.pattern_size, corners.astype(np.float32))
    width = float(np.ravel(sharp)[0])
    if not np.isfinite(width) or width > max_edge_width:
        return Detection(None, width, f"board blurred (edge width {width:.1f} px > {max_edge_width:g})")
    if refine:
        corners = refine_corners(gray, corners, board)
    return Detection(canonical_order(corners, board), width)
