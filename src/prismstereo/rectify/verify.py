"""Epipolar verification of a rectification on exact correspondences (thesis §3.3, §4.3 experiments).

A true correspondence is one 3D point seen through two faces: a real pixel of face a is traced exactly
(:func:`~prismstereo.optics.trace_pixels`), a point on its ray at a random depth is projected exactly
through face b (:func:`~prismstereo.optics.project_exact`). Mapped into a rectified pair, both pixels
must lie on the same row; the residual vertical disparity y_left − y_right measures the rectification.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from prismstereo.config import Rig
from prismstereo.errors import GeometryError
from prismstereo.optics import project_exact, trace_pixels
from prismstereo.rectify.rectification import RectifiedPair
from prismstereo.rectify.regions import ViewRegion, view_regions

DEPTH_RANGE_MM = (800.0, 2500.0)


@dataclass(frozen=True)
class Correspondences:
    """True correspondences between two faces: (N, 2) real pixels of each and the (N, 3) world points."""

    face_a: int
    face_b: int
    pixels_a: np.ndarray
    pixels_b: np.ndarray
    points: np.ndarray


@dataclass(frozen=True)
class VerticalResidual:
    """Residual vertical disparity of a rectified pair on true correspondences (px)."""

    rms: float
    p95: float
    max: float
    mean: float
    n: int
    depth_range: tuple[float, float]


def _in_region(pixels: np.ndarray, region: ViewRegion) -> np.ndarray:
    h, w = region.mask.shape
    u = np.rint(np.nan_to_num(pixels[:, 0], nan=-1.0)).astype(np.int64)
    v = np.rint(np.nan_to_num(pixels[:, 1], nan=-1.0)).astype(np.int64)
    ok = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    out = np.zeros(pixels.shape[0], dtype=bool)
    out[ok] = region.mask[v[ok], u[ok]]
    return out


def true_correspondences(
    rig: Rig,
    face_a: int,
    face_b: int,
    *,
    n: int = 4000,
    depth_range: tuple[float, float] = DEPTH_RANGE_MM,
    regions: list[ViewRegion] | None = None,
    seed: int = 0,
) -> Correspondences:
    """Exact correspondences between two faces for points at world depths in ``depth_range`` (mm).

    ``n`` real pixels are drawn uniformly in face a's region; each gets a uniform random depth; those
    whose point is seen through face b inside its region are kept (the common view).

    Raises
    ------
    GeometryError
        If no point in the depth range is seen by both faces.
    """
    regions = view_regions(rig) if regions is None else regions
    rng = np.random.default_rng(seed)
    ys, xs = np.nonzero(regions[face_a].mask)
    idx = rng.choice(xs.size, size=n)
    px = np.stack([xs[idx], ys[idx]], axis=1).astype(np.float64) + rng.uniform(-0.5, 0.5, (n, 2))
    b = trace_pixels(rig, px)
    z = rng.uniform(depth_range[0], depth_range[1], size=n)
    X = b.point_at_depth(z)
    pb, ok = project_exact(rig, X, face=face_b)
    ok &= b.face == face_a
    ok &= _in_region(pb, regions[face_b])
    if not ok.any():
        raise GeometryError(f"expected faces {face_a} and {face_b} to see common points at "
                            f"{depth_range[0]:g}–{depth_range[1]:g} mm, got none")
    return Correspondences(face_a=face_a, face_b=face_b, pixels_a=px[ok], pixels_b=pb[ok], points=X[ok])


def vertical_residual(pair: RectifiedPair, corr: Correspondences) -> tuple[VerticalResidual, np.ndarray]:
    """Residual vertical disparity y_left − y_right (px) of true correspondences in a rectified pair.

    Returns
    -------
    VerticalResidual and the (N,) residuals.
    """
    if {corr.face_a, corr.face_b} != {pair.left_face, pair.right_face}:
        raise GeometryError(f"expected correspondences between faces {pair.left_face} and {pair.right_face}, "
                            f"got {corr.face_a} and {corr.face_b}")
    pl, pr = (corr.pixels_a, corr.pixels_b) if corr.face_a == pair.left_face else (corr.pixels_b, corr.pixels_a)
    yl = pair.real_to_rectified(pl, "left")[:, 1]
    yr = pair.real_to_rectified(pr, "right")[:, 1]
    dy = yl - yr
    dy = dy[np.isfinite(dy)]
    z = corr.points[:, 2]
    res = VerticalResidual(rms=float(np.sqrt(np.mean(dy**2))), p95=float(np.percentile(np.abs(dy), 95)),
                           max=float(np.max(np.abs(dy))), mean=float(np.mean(dy)), n=int(dy.size),
                           depth_range=(float(z.min()), float(z.max())))
    return res, dy


def common_depth_range(pair: RectifiedPair) -> tuple[float, float]:
    """World depths (mm) at which the two rectified views can see a common point.

    From the footprints: a point is seen by both when d = x_left − x_right lies between the smallest and
    largest disparity the valid regions allow; Z ≈ f B / d along the rectified axis (thesis Eq. 7.22).
    """
    cols_l = np.flatnonzero(pair.valid_left.any(axis=0))
    cols_r = np.flatnonzero(pair.valid_right.any(axis=0))
    # image disparities plus the pair's offset are the true ones
    d_max = cols_l.max() - cols_r.min() + pair.disparity_offset
    d_min = max(cols_l.min() - cols_r.max() + pair.disparity_offset, 1e-6)
    if d_max <= 0:
        raise GeometryError(f"expected faces {pair.left_face} and {pair.right_face} to share a view, got none")
    fb = pair.focal_px * pair.baseline_mm
    return float(fb / d_max), float(fb / d_min)
