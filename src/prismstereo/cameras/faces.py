"""The prism's faces as the camera sees them: the pixels that look through each face, why a face may be unseen,
and the thesis's geometric virtual camera of a face (thesis §3.2.1, §4.1.2).
"""

from __future__ import annotations

import math
from itertools import combinations

import numpy as np

from prismstereo.cameras.pinhole import PinholeCamera, rotation_from_axis
from prismstereo.config import Rig
from prismstereo.errors import GeometryError
from prismstereo.optics import closest_points_between_lines, pixel_grid, trace_pixels

__all__ = ["check_face", "face_pixels", "max_corner_angle", "thesis_camera", "unseen_face_message"]


def face_pixels(rig: Rig, face: int, *, step: float = 8.0, margin: float = 0.0) -> np.ndarray:
    """(M, 2) pixels on a regular grid that look through ``face`` (optionally ``margin`` px inside)."""
    check_face(rig, face)
    grid = pixel_grid(rig.camera.width, rig.camera.height, step=step).reshape(-1, 2)
    grid = grid + (step - 1) / 2.0 * (step > 1)
    grid = grid[(grid[:, 0] <= rig.camera.width - 1) & (grid[:, 1] <= rig.camera.height - 1)]
    faces = trace_pixels(rig, grid).face
    keep = faces == face
    if margin > 0:
        for off in ((margin, 0), (-margin, 0), (0, margin), (0, -margin)):
            keep &= trace_pixels(rig, grid + np.array(off)).face == face
    pts = grid[keep]
    if pts.shape[0] < 8:
        raise GeometryError(unseen_face_message(rig, face, int(pts.shape[0])))
    return pts


def max_corner_angle(refractive_index: float) -> float:
    """Largest corner angle (degrees) at which a ray along the optical axis still crosses the prism.

    The ray meets a face at the corner angle α, bends to β = asin(sin α / n) and reaches the back plane at
    α − β from its normal; it is totally reflected there once n·sin(α − β) > 1 (solved by bisection).
    """
    n = refractive_index
    crit = math.asin(1.0 / n)
    lo, hi = 0.0, math.pi / 2
    for _ in range(60):
        a = (lo + hi) / 2
        if a - math.asin(math.sin(a) / n) < crit:
            lo = a
        else:
            hi = a
    return math.degrees(lo)


def unseen_face_message(rig: Rig, face: int, n: int) -> str:
    """One line naming the prism parameter that keeps ``face`` out of the picture, with its valid range."""
    p = rig.prism
    limit = max_corner_angle(p.refractive_index)
    if p.corner_angle >= limit - 2.0:
        return (f"[prism] corner_angle: expected degrees in (0, {limit:.1f}) for refractive_index "
                f"{p.refractive_index:g} (beyond, the camera's rays are totally reflected inside the prism), got "
                f"{p.corner_angle:g} (face {face} is seen by {n} sample pixels; docs/rig.md)")
    return (f"expected face {face} to be seen by the camera, got {n} sample pixels: check [prism] faces "
            f"({p.faces}), corner_angle ({p.corner_angle:g}°, at most {limit:.1f}° for n = "
            f"{p.refractive_index:g}), apex_distance ({p.apex_distance:g} mm) and rotation against the camera's "
            f"field of view (docs/rig.md)")


def check_face(rig: Rig, face: int) -> None:
    """Raise :class:`~prismstereo.errors.GeometryError` unless ``face`` indexes one of the rig's prism faces."""
    if not 0 <= int(face) < rig.prism.faces:
        raise GeometryError(f"expected a face index in [0, {rig.prism.faces - 1}], got {face}")


def thesis_camera(rig: Rig, face: int, *, n_rays: int = 16) -> PinholeCamera:
    """The thesis's geometric virtual camera of ``face`` (thesis §3.2.1 steps 1–6, §4.1.2).

    The optical centre is the average of the midpoints of the common perpendiculars between pairs of
    back-extended exit rays (thesis Appendix A) of ``n_rays`` pixels spread over the face's image region;
    the optical axis is the exit ray of the image centre refracted through this face (thesis Eqs.
    3.31–3.34, generalised to any face orientation); the intrinsics are the real camera's.
    """
    check_face(rig, face)
    pts = face_pixels(rig, face, step=16.0, margin=8.0)
    rng = np.random.default_rng(face)
    pick = pts[rng.choice(pts.shape[0], size=min(n_rays, pts.shape[0]), replace=False)]
    b = trace_pixels(rig, pick)
    pairs = np.array(list(combinations(range(pick.shape[0]), 2)))
    mids, _ = closest_points_between_lines(
        b.origins[pairs[:, 0]], b.directions[pairs[:, 0]], b.origins[pairs[:, 1]], b.directions[pairs[:, 1]]
    )
    centre = np.nanmean(mids, axis=0)
    axis_ray = trace_pixels(rig, np.array([rig.camera.center]), face=face, bounded=False)
    if not axis_ray.valid[0]:
        raise GeometryError(f"expected the image centre's ray to pass face {face}, got total internal reflection")
    R = rotation_from_axis(axis_ray.directions[0])
    return PinholeCamera(K=rig.camera.K, R=R, C=centre)
