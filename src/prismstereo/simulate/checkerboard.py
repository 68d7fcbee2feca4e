"""Checkerboard poses for calibration experiments, with exact 3D corner positions.

Each pose is a flat board (a :class:`Rectangle` with a finite :class:`CheckerTexture` and a white margin
one square wide) placed near the optical axis, moderately tilted, and checked with exact refraction
(:func:`prismstereo.optics.project_exact`) to be wholly visible through every face of the prism, so that
each virtual view sees all its corners (OpenCV's ``findChessboardCorners`` + Zhang calibration per view).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from prismstereo.cameras.pinhole import project_points
from prismstereo.config import Rig
from prismstereo.errors import ConfigError, GeometryError
from prismstereo.optics import project_exact
from prismstereo.simulate.scene import CheckerTexture, Rectangle, Scene

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class BoardPose:
    """One checkerboard pose.

    Attributes
    ----------
    board : Rectangle
        The board (checker pattern with a white margin of one square).
    corners : (M, 3) float64
        World positions (mm) of the inner corners, M = (nx − 1)(ny − 1), in OpenCV order (x fastest:
        row j = 0 … ny − 2, then column i = 0 … nx − 2).
    object_points : (M, 3) float64
        The same corners in the board frame (mm, z = 0, first inner corner at the origin, x along the
        board's s axis, y along its t axis): OpenCV ``objectPoints``.
        ``corners = origin + object_points @ rotation.T``.
    rotation : (3, 3) float64
        Board-to-world rotation (columns: board x, y, z axes; z points away from the camera).
    origin : (3,) float64
        World position of the first inner corner.
    pattern_size : (int, int)
        Inner corners per row and column, (nx − 1, ny − 1), as OpenCV's ``patternSize``.
    square : float
        Square side, mm.
    scene : Scene
        The board alone in front of a plain grey background, ready for :func:`render_capture`.
    """

    board: Rectangle
    corners: np.ndarray
    object_points: np.ndarray
    rotation: np.ndarray
    origin: np.ndarray
    pattern_size: tuple[int, int]
    square: float
    scene: Scene


def board_rectangle(
    center: np.ndarray | tuple[float, float, float],
    rotation: tuple[float, float, float],
    *,
    squares: tuple[int, int] = (9, 7),
    square_mm: float = 10.0,
) -> Rectangle:
    """A checkerboard rectangle of ``squares`` = (nx, ny) squares with a one-square white margin."""
    nx, ny = squares
    tex = CheckerTexture(square=square_mm, squares=(nx, ny), margin=square_mm)
    c = np.asarray(center, dtype=np.float64)
    return Rectangle(center=(float(c[0]), float(c[1]), float(c[2])),
                     size=((nx + 2) * square_mm, (ny + 2) * square_mm), rotation=rotation, texture=tex,
                     name="checkerboard")


def board_corners(board: Rectangle) -> tuple[np.ndarray, np.ndarray]:
    """Inner corners of a checkerboard rectangle.

    Parameters
    ----------
    board : Rectangle with a finite :class:`CheckerTexture`.

    Returns
    -------
    corners : (M, 3) world mm, OpenCV order (x fastest).
    object_points : (M, 3) board-frame mm (z = 0, first inner corner at the origin).
    """
    tex = board.texture
    if not isinstance(tex, CheckerTexture) or tex.squares is None:
        raise ConfigError(f"expected a rectangle with a finite checker texture, got {type(tex).__name__}")
    nx, ny = tex.squares
    jj, ii = np.meshgrid(np.arange(1, ny), np.arange(1, nx), indexing="ij")
    st = np.stack([tex.margin + ii.ravel() * tex.square, tex.margin + jj.ravel() * tex.square], axis=1)
    corners = board.surface_to_world(st.astype(np.float64))
    obj = np.zeros((st.shape[0], 3))
    obj[:, 0] = (ii.ravel() - 1) * tex.square
    obj[:, 1] = (jj.ravel() - 1) * tex.square
    return corners, obj


def _check_points(board: Rectangle) -> np.ndarray:
    """Outline samples (outer edge incl. margin) of a board, world mm: (K, 3)."""
    w, h = board.size
    t = np.linspace(0.0, 1.0, 9)
    st = np.concatenate([
        np.stack([t * w, np.zeros_like(t)], 1), np.stack([t * w, np.full_like(t, h)], 1),
        np.stack([np.zeros_like(t), t * h], 1), np.stack([np.full_like(t, w), t * h], 1),
    ])
    return board.surface_to_world(st)


def board_visible(rig: Rig, board: Rectangle, *, border_px: float = 4.0) -> bool:
    """Whether the whole board (its outline) is seen through every face, inside the image.

    Uses exact refraction (:func:`project_exact`): every outline point must project through each face to
    a pixel at least ``border_px`` inside the image.
    """
    pts = _check_points(board)
    W, H = rig.camera.width, rig.camera.height
    for face in range(rig.prism.faces):
        px, ok = project_exact(rig, pts, face=face)
        if not np.all(ok):
            return False
        u, v = px[:, 0], px[:, 1]
        if not np.all((u >= border_px) & (u <= W - 1 - border_px) & (v >= border_px) & (v <= H - 1 - border_px)):
            return False
    return True


def _largest_square(rig: Rig, squares: tuple[int, int], distance: float) -> float:
    """Largest square size (mm) whose fronto-parallel board at (0, 0, distance) is seen by every face."""
    lo, hi = 0.0, distance * max(rig.camera.width, rig.camera.height) / rig.camera.focal_px / min(squares)
    for _ in range(18):
        mid = 0.5 * (lo + hi)
        if board_visible(rig, board_rectangle((0.0, 0.0, distance), (0.0, 0.0, 0.0), squares=squares,
                                              square_mm=mid)):
            lo = mid
        else:
            hi = mid
    return lo


def checkerboard_poses(
    rig: Rig,
    *,
    n_poses: int = 12,
    squares: tuple[int, int] = (9, 7),
    square_mm: float | None = None,
    distance_range: tuple[float, float] = (600.0, 1500.0),
    max_tilt: float = 30.0,
    max_spin: float = 15.0,
    seed: int = 0,
    background: tuple[float, float, float] = (0.45, 0.45, 0.45),
    max_tries: int = 400,
) -> list[BoardPose]:
    """Random checkerboard poses that every virtual view of the rig sees whole, with exact corners.

    Parameters
    ----------
    rig : Rig
    n_poses : int
    squares : (nx, ny)
        Squares per row and column (OpenCV pattern size = (nx − 1, ny − 1) inner corners).
    square_mm : float, optional
        Square side. Default: 70 % of the largest square for which a fronto-parallel board at the nearest
        distance fits in the prism's common view (a tilted, off-centre board then still fits).
    distance_range : (near, far)
        Board-centre depth range, mm.
    max_tilt : float
        Maximum tilt about the world X and Y axes, degrees (uniform in ±max_tilt).
    max_spin : float
        Maximum rotation about the optical axis, degrees.
    seed : int
        The poses are a deterministic function of the arguments.
    background : RGB in [0, 1]
        Colour of the plain background in each pose's scene.
    max_tries : int
        Random draws per pose before giving up.

    Returns
    -------
    list of BoardPose

    Raises
    ------
    ConfigError
        For impossible arguments; GeometryError if no visible pose is found (board too large).
    """
    if n_poses < 1:
        raise ConfigError(f"n_poses: expected a positive integer, got {n_poses!r}")
    if len(squares) != 2 or min(squares) < 2:
        raise ConfigError(f"squares: expected (nx, ny) with both >= 2, got {squares!r}")
    near, far = (float(x) for x in distance_range)
    if not (np.isfinite(near) and np.isfinite(far)) or near <= rig.prism.back_distance or far < near:
        raise ConfigError(
            f"distance_range: expected (near, far) with back_distance < near <= far, got {distance_range!r}"
        )
    sq = 0.7 * _largest_square(rig, squares, near) if square_mm is None else float(square_mm)
    if not np.isfinite(sq) or sq <= 0:
        raise ConfigError(f"square_mm: expected a positive size, got {square_mm!r}")
    rng = np.random.default_rng(seed)
    poses: list[BoardPose] = []
    board_w = (squares[0] + 2) * sq
    board_h = (squares[1] + 2) * sq
    for k in range(n_poses):
        for _ in range(max_tries):
            z = rng.uniform(near, far)
            rx, ry = rng.uniform(-max_tilt, max_tilt, size=2)
            rz = rng.uniform(-max_spin, max_spin)
            cx, cy = rng.uniform(-0.15, 0.15, size=2) * (board_w, board_h)
            board = board_rectangle((cx, cy, z), (float(rx), float(ry), float(rz)), squares=squares, square_mm=sq)
            if board_visible(rig, board):
                break
        else:
            raise GeometryError(
                f"expected a checkerboard pose visible through all {rig.prism.faces} faces, got none in {max_tries} "
                f"tries for pose {k} (square {sq:g} mm); use a smaller square_mm, tilt or a farther distance_range"
            )
        corners, obj = board_corners(board)
        R = board.matrix
        poses.append(BoardPose(
            board=board, corners=corners, object_points=obj, rotation=R, origin=corners[0].copy(),
            pattern_size=(squares[0] - 1, squares[1] - 1), square=sq,
            scene=Scene(objects=(board,), background=background, name=f"checkerboard{k}"),
        ))
    log.info("%d checkerboard poses, square %.3g mm, %d-%d mm", n_poses, sq, near, far)
    return poses



def camera_board_poses(
    rig: Rig,
    *,
    n_poses: int = 12,
    squares: tuple[int, int] = (9, 7),
    square_mm: float = 3.0,
    distance_range: tuple[float, float] = (250.0, 400.0),
    max_tilt: float = 35.0,
    max_spin: float = 20.0,
    seed: int = 0,
    background: tuple[float, float, float] = (0.45, 0.45, 0.45),
    max_tries: int = 400,
) -> list[BoardPose]:
    """Random checkerboard poses for calibrating the bare camera (no prism), spread over the whole image.

    Board centres are drawn so that their images cover the sensor out to the corners (where the lens
    distortion is strongest); each pose is whole inside the image (distorting projection, 4 px border).
    Same parameters as :func:`checkerboard_poses`.
    """

    if n_poses < 1:
        raise ConfigError(f"n_poses: expected a positive integer, got {n_poses!r}")
    near, far = (float(x) for x in distance_range)
    if not (np.isfinite(near) and np.isfinite(far)) or near <= 0 or far < near:
        raise ConfigError(f"distance_range: expected (near, far) with 0 < near <= far, got {distance_range!r}")
    cam = rig.camera
    W, H = cam.width, cam.height
    rng = np.random.default_rng(seed)
    poses: list[BoardPose] = []
    fx, fy = cam.focal_xy
    cx, cy = cam.center
    for k in range(n_poses):
        for _ in range(max_tries):
            z = rng.uniform(near, far)
            u, v = rng.uniform([0.1 * W, 0.1 * H], [0.9 * W, 0.9 * H])
            centre = ((u - cx) / fx * z, (v - cy) / fy * z, z)
            rx, ry = rng.uniform(-max_tilt, max_tilt, size=2)
            rz = rng.uniform(-max_spin, max_spin)
            board = board_rectangle(centre, (float(rx), float(ry), float(rz)), squares=squares, square_mm=square_mm)
            px = project_points(_check_points(board), cam.K, np.eye(3), np.zeros(3), np.asarray(cam.distortion))
            if np.all(np.isfinite(px)) and np.all((px >= 4) & (px <= np.array([W - 5, H - 5]))):
                break
        else:
            raise GeometryError(f"expected a checkerboard pose inside the image, got none in {max_tries} tries")
        corners, obj = board_corners(board)
        poses.append(BoardPose(
            board=board, corners=corners, object_points=obj, rotation=board.matrix, origin=corners[0].copy(),
            pattern_size=(squares[0] - 1, squares[1] - 1), square=square_mm,
            scene=Scene(objects=(board,), background=background, name=f"camera-board{k}"),
        ))
    return poses
