"""OpenCV's 5-term lens distortion (k1, k2, p1, p2, k3) on normalised image coordinates, and its inverse.

A real pixel (u, v) of a distorting lens looks along the ray through the undistorted normalised point
(x, y, 1) with ``distort(x, y) = ((u − cx)/fx, (v − cy)/fy)`` (Brown–Conrady, OpenCV's order and signs).
The inverse has no closed form; it is solved with Newton's method and the analytic Jacobian, to ~1e-15 for
the distortions of real lenses (OpenCV's ``undistortPoints`` uses a fixed number of fixed-point steps
instead, which leaves ~1e-6 for strong distortion).
"""

from __future__ import annotations

import numpy as np


def _coefficients(dist: np.ndarray | tuple[float, ...]) -> tuple[float, float, float, float, float]:
    d = np.zeros(5)
    v = np.asarray(dist, dtype=np.float64).ravel()[:5]
    d[: v.size] = v
    return float(d[0]), float(d[1]), float(d[2]), float(d[3]), float(d[4])


def distort_points(xy: np.ndarray, dist: np.ndarray | tuple[float, ...]) -> np.ndarray:
    """Distorted normalised coordinates of undistorted ones (OpenCV model).

    Parameters
    ----------
    xy : (..., 2) undistorted normalised coordinates (x/z, y/z).
    dist : (k1, k2, p1, p2, k3), fewer terms are zero-padded.

    Returns
    -------
    (..., 2) distorted normalised coordinates.
    """
    k1, k2, p1, p2, k3 = _coefficients(dist)
    p = np.asarray(xy, dtype=np.float64)
    x, y = p[..., 0], p[..., 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.stack([xd, yd], axis=-1)


def undistort_points(
    xy_distorted: np.ndarray, dist: np.ndarray | tuple[float, ...], *, iterations: int = 20, tolerance: float = 1e-15
) -> np.ndarray:
    """Undistorted normalised coordinates of distorted ones: the inverse of :func:`distort_points`.

    Parameters
    ----------
    xy_distorted : (..., 2) distorted normalised coordinates ((u − cx)/fx, (v − cy)/fy).
    dist : (k1, k2, p1, p2, k3).
    iterations : int
        Newton iterations at most (it stops earlier when every step is below ``tolerance``).

    Returns
    -------
    (..., 2) undistorted normalised coordinates; NaN where Newton did not converge (the distortion folds
    back on itself far outside the calibrated field).
    """
    k1, k2, p1, p2, k3 = _coefficients(dist)
    target = np.asarray(xy_distorted, dtype=np.float64)
    shape = target.shape
    t = target.reshape(-1, 2)
    xy = t.copy()
    done = np.zeros(t.shape[0], dtype=bool)
    for _ in range(iterations):
        idx = np.flatnonzero(~done)
        if idx.size == 0:
            break
        x, y = xy[idx, 0], xy[idx, 1]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        dradial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d radial / d r2
        fx = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) - t[idx, 0]
        fy = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y - t[idx, 1]
        a = radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x  # d xd / d x
        b = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y  # d xd / d y  (= d yd / d x)
        c = radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x  # d yd / d y
        det = a * c - b * b
        with np.errstate(divide="ignore", invalid="ignore"):
            sx = (c * fx - b * fy) / det
            sy = (a * fy - b * fx) / det
        xy[idx, 0] = x - sx
        xy[idx, 1] = y - sy
        step = np.abs(sx) + np.abs(sy)
        done[idx[~(step > tolerance * (1.0 + np.abs(x) + np.abs(y)))]] = True
    # A root beyond the fold of the polynomial (where the Jacobian turns over) is not the lens's point.
    check = distort_points(xy, (k1, k2, p1, p2, k3)) - t
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    dradial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
    a = radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x
    b = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
    c = radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x
    bad = ~(np.all(np.abs(check) < 1e-9, axis=1) & (a * c - b * b > 0) & (a > 0) & (radial > 0))
    xy[bad] = np.nan
    return xy.reshape(shape)
