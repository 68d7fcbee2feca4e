"""Exact projection of 3D points through a prism face: the inverse of tracing.

There is no closed form for the pixel that sees a point through two refracting planes, so it is solved
with Newton's method on the pixel (u, v): the residual is the offset, in the plane z = Z of the point,
between the traced ray and the point. The map from pixel to ray is smooth for a fixed face, so Newton
converges in a few iterations from the no-prism projection.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np

from prismstereo.config import Rig
from prismstereo.errors import GeometryError
from prismstereo.optics.distortion import distort_points
from prismstereo.optics.prism import trace_pixels


def _residual(rig: Rig, pixels: np.ndarray, points: np.ndarray, face: int) -> np.ndarray:
    """(..., 2) offset in the plane z = Z of each point between the traced ray of its pixel and the point;
    ``pixels`` (..., N, 2) broadcast against ``points`` (N, 3)."""
    b = trace_pixels(rig, pixels, face=face, bounded=False)
    s = (points[..., 2] - b.origins[..., 2]) / b.directions[..., 2]
    hit = b.origins + s[..., None] * b.directions
    return hit[..., :2] - points[..., :2]


def project_exact(
    rig: Rig,
    points_in_world: np.ndarray,
    *legacy: Any,
    face: int | None = None,
    tolerance_px: float = 1e-4,
    max_iterations: int = 30,
    initial_pixels: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Real-image pixels that see 3D points through one prism face (exact refraction).

    The argument order is :func:`~prismstereo.optics.trace_pixels`'s: the rig first, ``face`` by keyword.
    The order of releases up to 0.1.0, ``project_exact(points, rig, face)``, still works and warns
    (DeprecationWarning).

    Parameters
    ----------
    rig : Rig
    points_in_world : (N, 3) or (3,) array
        Points in the world frame, mm; they must lie beyond the back plane.
    face : int, keyword-only
        Face index, 0 ≤ face < rig.prism.faces.
    tolerance_px : float
        Newton stops when the last step is below this (px); points that do not get there fail.
    max_iterations : int
    initial_pixels : (N, 2) array, optional
        Where Newton starts (e.g. the detected pixels in a calibration); default: the point's projection
        without the prism.

    Returns
    -------
    pixels : (N, 2) float64
        (u, v) of the real pixel whose traced ray passes through each point; NaN where it failed.
    valid : (N,) bool
        True where Newton converged and the ray really enters through ``face`` (the bounded trace of
        the solution goes through that face). The pixel may still lie outside the sensor.

    Raises
    ------
    GeometryError
        If ``face`` is not a face of the rig.
    """
    if not isinstance(rig, Rig) and isinstance(points_in_world, Rig):
        warnings.warn("project_exact(points, rig, face) is deprecated: call project_exact(rig, points, face=face) "
                      "(the order of trace_pixels)", DeprecationWarning, stacklevel=2)
        rig, points_in_world = points_in_world, rig
        if legacy and face is None:
            face, legacy = legacy[0], legacy[1:]
    if legacy:
        raise TypeError(f"face: expected it by keyword, project_exact(rig, points, face=...), got "
                        f"{2 + len(legacy)} positional arguments")
    if face is None:
        raise TypeError("face: expected the face index, project_exact(rig, points, face=...), got none")
    if not 0 <= int(face) < rig.prism.faces:
        raise GeometryError(f"expected a face index in [0, {rig.prism.faces - 1}], got {face}")
    pts = np.atleast_2d(np.asarray(points_in_world, dtype=np.float64))
    n = pts.shape[0]
    cam = rig.camera
    K = cam.K
    if initial_pixels is not None:
        px = np.array(initial_pixels, dtype=np.float64).reshape(n, 2)
    elif cam.has_distortion:
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = distort_points(pts[:, :2] / pts[:, 2:3], cam.distortion)
        px = xy @ K[:2, :2].T + K[:2, 2]
    else:
        with np.errstate(divide="ignore", invalid="ignore"):
            proj = pts @ K.T
            px = proj[:, :2] / proj[:, 2:3]
    active = np.all(np.isfinite(pts), axis=1) & (pts[:, 2] > rig.prism.back_distance)
    px[~active] = np.nan
    converged = np.zeros(n, dtype=bool)
    h = 0.5
    # the pixel and its four central-difference neighbours, traced in one call
    offsets = np.array([[0.0, 0.0], [h, 0.0], [-h, 0.0], [0.0, h], [0.0, -h]])[:, None, :]
    for _ in range(max_iterations):
        idx = np.flatnonzero(active & ~converged)
        if idx.size == 0:
            break
        p, X = px[idx], pts[idx]
        res = _residual(rig, p[None] + offsets, X, face)
        r = res[0]
        ju = (res[1] - res[2]) / (2 * h)
        jv = (res[3] - res[4]) / (2 * h)
        det = ju[:, 0] * jv[:, 1] - jv[:, 0] * ju[:, 1]
        with np.errstate(divide="ignore", invalid="ignore"):
            step_u = (jv[:, 1] * r[:, 0] - jv[:, 0] * r[:, 1]) / det
            step_v = (-ju[:, 1] * r[:, 0] + ju[:, 0] * r[:, 1]) / det
        step = np.stack([step_u, step_v], axis=1)
        norm = np.linalg.norm(step, axis=1)
        # Far from the solution a full step can leave the region where the face's plane is hit at all.
        scale = np.where(norm > 500.0, 500.0 / np.maximum(norm, 1e-300), 1.0)
        px[idx] = p - step * scale[:, None]
        bad = ~np.isfinite(norm)
        active[idx[bad]] = False
        converged[idx[~bad & (norm < tolerance_px)]] = True
    px[~converged] = np.nan
    final = trace_pixels(rig, np.nan_to_num(px), bounded=True)
    valid = converged & (final.face == face)
    return px, valid
