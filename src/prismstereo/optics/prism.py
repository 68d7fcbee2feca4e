"""Tracing camera rays through an N-face pyramid prism (docs/rig.md).

Geometry, in the world (= real camera) frame: the apex is at (0, 0, apex_distance) and points at the
camera. Face k has outward horizontal direction u_k; the front surface is
``z = apex + tan(α) · max_k (p · u_k)`` up to ``z = apex + height``; glass fills the space from the front
surface to the back plane ``z = back``; the prism's lateral walls are ``max_k (p · u_k) = height / tan α``.
A camera ray enters through the face whose half-space it enters last (the front surface is convex), is
refracted into the glass, leaves through the back plane and is refracted again into the scene. Rays that
hit no glass, leave through a side wall or are totally internally reflected are invalid (NaN).

A misaligned prism (``tilt``, ``decenter``) is traced in the frame of the centred prism: the camera's
centre and ray directions are moved by the inverse of its pose, and the results moved back. Lens
distortion enters through :func:`rays_from_pixels` (each pixel's ray goes through its undistorted point).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from prismstereo.config import Rig
from prismstereo.optics.distortion import undistort_points
from prismstereo.optics.refraction import normalize, refract

_EPS = 1e-9


@dataclass(frozen=True)
class RayBundle:
    """Rays through the prism, one per input ray; all arrays share the leading shape ``S``.

    Attributes
    ----------
    origins : (*S, 3) float64
        Where each ray leaves the prism (on the back plane), mm, world frame; NaN where invalid.
    directions : (*S, 3) float64
        Unit direction of each ray in the scene after the prism; NaN where invalid.
    face : (*S,) int64
        Index of the face the ray entered through; −1 where invalid.
    valid : (*S,) bool
    entry_points : (*S, 3) float64
        Where the ray enters the glass (on a lateral face).
    glass_directions : (*S, 3) float64
        Unit direction inside the glass.
    """

    origins: np.ndarray
    directions: np.ndarray
    face: np.ndarray
    valid: np.ndarray
    entry_points: np.ndarray
    glass_directions: np.ndarray

    def point_at_depth(self, z: float | np.ndarray) -> np.ndarray:
        """Points where the rays reach world depth ``z`` (mm): (*S, 3)."""
        s = (np.asarray(z, dtype=np.float64) - self.origins[..., 2]) / self.directions[..., 2]
        return self.origins + s[..., None] * self.directions


def rays_from_pixels(pixels: np.ndarray, K: np.ndarray, dist: np.ndarray | tuple[float, ...] | None = None
                     ) -> np.ndarray:
    """Unit ray directions in the camera frame for pixels of a pinhole with optional lens distortion.

    Parameters
    ----------
    pixels : (..., 2) array of (u, v), pixel centres at integers.
    K : (3, 3) intrinsic matrix.
    dist : (k1, k2, p1, p2, k3), optional
        OpenCV distortion; the ray goes through the undistorted normalised point (docs/rig.md).

    Returns
    -------
    (..., 3) unit directions, d ∝ K⁻¹ [u, v, 1]ᵀ without distortion; NaN where undistortion fails.
    """
    px = np.asarray(pixels, dtype=np.float64)
    Kinv = np.linalg.inv(np.asarray(K, dtype=np.float64))
    hom = np.concatenate([px, np.ones(px.shape[:-1] + (1,))], axis=-1)
    if dist is None or not np.any(np.asarray(dist)):
        return normalize(hom @ Kinv.T)
    xy = (hom @ Kinv.T)[..., :2]
    und = undistort_points(xy, dist)
    return normalize(np.concatenate([und, np.ones(und.shape[:-1] + (1,))], axis=-1))


def trace_rays(
    rig: Rig, directions: np.ndarray, *, face: int | None = None, bounded: bool = True,
    origins: np.ndarray | None = None,
) -> RayBundle:
    """Trace rays leaving the real camera's optical centre (or ``origins``) through the prism.

    Parameters
    ----------
    rig : Rig
    directions : (..., 3) array
        Directions of the rays in the world frame (need not be unit); they start at the origin.
    face : int, optional
        Force refraction at this face's plane, whatever face the ray would really hit (used for the
        thesis's construction of the virtual optical axis through the apex, §3.2.1 step 5). The lateral
        wall checks still apply.
    bounded : bool
        If False, treat the faces and the back plane as unbounded planes (no face-height or side-wall
        checks). Used inside solvers whose iterates may stray outside the glass; callers check the final
        answer with a bounded trace.
    origins : (..., 3) array, optional
        Start points of the rays (world frame, mm, in front of the prism, e.g. points of a lens aperture);
        default the optical centre.

    Returns
    -------
    RayBundle
    """
    prism = rig.prism
    d = normalize(np.asarray(directions, dtype=np.float64))
    shape = d.shape[:-1]
    d = d.reshape(-1, 3)
    u = prism.face_directions()  # N×3
    t = prism.tan_alpha
    apex, back, n_glass = prism.apex_distance, prism.back_distance, prism.refractive_index
    posed = prism.is_posed
    o_rows = None if origins is None else np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    if o_rows is not None and o_rows.shape[0] != d.shape[0]:
        raise ValueError(f"expected one origin per direction, got {o_rows.shape[0]} and {d.shape[0]}")
    if posed:
        # Trace in the frame of the centred prism: the camera's centre and rays move by the inverse pose.
        M, apex_cam = prism.pose()
        a0 = np.array([0.0, 0.0, apex])
        o = M.T @ (-apex_cam) + a0
        if o_rows is not None:
            o_rows = (o_rows - apex_cam) @ M + a0
        d = d @ M  # Mᵀ d for row vectors

    # Half-space k of the convex front surface: z − t·(u_k·p) ≥ apex. Along p = o + s·d it is entered at
    # s_k = (apex − o_z + t·u_k·o) / (d_z − t·u_k·d); a ray with a non-positive denominator never enters it.
    denom = d[:, 2:3] - t * (d @ u.T)  # M×N
    with np.errstate(divide="ignore", invalid="ignore"):
        if o_rows is not None:
            s_k = np.where(denom > _EPS, (apex - o_rows[:, 2:3] + t * (o_rows @ u.T)) / denom, np.inf)
        elif posed:
            s_k = np.where(denom > _EPS, (apex - o[2] + t * (u @ o))[None, :] / denom, np.inf)
        else:
            s_k = np.where(denom > _EPS, apex / denom, np.inf)
    if face is None:
        k = np.argmax(s_k, axis=1)
        valid = np.all(denom > _EPS, axis=1)
    else:
        k = np.full(d.shape[0], int(face))
        valid = denom[:, face] > _EPS
    s = np.take_along_axis(s_k, k[:, None], axis=1)[:, 0]
    if o_rows is not None:
        entry = o_rows + s[:, None] * d
    else:
        entry = o + s[:, None] * d if posed else s[:, None] * d
    inradius = prism.inradius
    if bounded:
        valid &= entry[:, 2] <= apex + prism.face_height + 1e-9 * max(1.0, apex)

    normals = prism.face_normals()[k]
    inside, ok = refract(d, normals, 1.0, n_glass)
    valid &= ok & (inside[:, 2] > _EPS)
    with np.errstate(divide="ignore", invalid="ignore"):
        s2 = (back - entry[:, 2]) / inside[:, 2]
    exit_pt = entry + s2[:, None] * inside
    if bounded:
        lateral = np.max(exit_pt @ u.T, axis=1)
        valid &= lateral <= inradius + 1e-9 * max(1.0, inradius)

    out, ok = refract(inside, np.array([0.0, 0.0, 1.0]), n_glass, 1.0)
    valid &= ok & np.all(np.isfinite(out), axis=1)
    if posed:
        # back to the camera frame: p_cam = M (p − A0) + A
        exit_pt = (exit_pt - a0) @ M.T + apex_cam
        entry = (entry - a0) @ M.T + apex_cam
        out = out @ M.T
        inside = inside @ M.T

    nan3 = np.full(3, np.nan)
    origins = np.where(valid[:, None], exit_pt, nan3)
    out = np.where(valid[:, None], out, nan3)
    entry = np.where(valid[:, None], entry, nan3)
    inside = np.where(valid[:, None], inside, nan3)
    k = np.where(valid, k, -1).astype(np.int64)
    return RayBundle(
        origins=origins.reshape(shape + (3,)),
        directions=out.reshape(shape + (3,)),
        face=k.reshape(shape),
        valid=valid.reshape(shape),
        entry_points=entry.reshape(shape + (3,)),
        glass_directions=inside.reshape(shape + (3,)),
    )


def trace_pixels(
    rig: Rig, pixels: np.ndarray, *, face: int | None = None, bounded: bool = True
) -> RayBundle:
    """Trace the rays of real-image pixels through the prism (the exact generalised camera).

    Parameters
    ----------
    rig : Rig
    pixels : (..., 2) array of (u, v) in the real image, pixel centres at integers. With lens distortion
        (``rig.camera.distortion``) each pixel looks along the ray of its undistorted normalised point.
    face : int, optional
        Force refraction through this face (see :func:`trace_rays`).

    Returns
    -------
    RayBundle with leading shape ``pixels.shape[:-1]``.
    """
    cam = rig.camera
    dist = cam.distortion if cam.has_distortion else None
    return trace_rays(rig, rays_from_pixels(pixels, cam.K, dist), face=face, bounded=bounded)


def pixel_grid(width: int, height: int, *, step: float = 1.0) -> np.ndarray:
    """(H', W', 2) grid of (u, v) pixel centres covering the image with the given step."""
    us = np.arange(0.0, width, step)
    vs = np.arange(0.0, height, step)
    uu, vv = np.meshgrid(us, vs)
    return np.stack([uu, vv], axis=-1)


#: grid step of :func:`face_map`'s first pass, px
_FACE_MAP_STEP = 4


def face_map(rig: Rig) -> np.ndarray:
    """(H, W) int64 map of the face each real pixel looks through; −1 where the ray is invalid.

    The rays are traced on a grid of ``_FACE_MAP_STEP`` px first; a grid cell whose four corners look
    through the same face (or none) takes it, and only the cells that straddle an edge of a face's region
    are traced pixel by pixel (the edges are smooth curves, the regions far wider than a cell).
    """
    w, h = rig.camera.width, rig.camera.height
    step = _FACE_MAP_STEP
    gy = np.unique(np.append(np.arange(0, h, step), h - 1))
    gx = np.unique(np.append(np.arange(0, w, step), w - 1))
    if gy.size < 2 or gx.size < 2:
        return trace_pixels(rig, pixel_grid(w, h)).face
    uu, vv = np.meshgrid(gx.astype(np.float64), gy.astype(np.float64))
    corner = trace_pixels(rig, np.stack([uu, vv], axis=-1)).face
    c00, c10, c01, c11 = corner[:-1, :-1], corner[1:, :-1], corner[:-1, 1:], corner[1:, 1:]
    same = (c00 == c10) & (c00 == c01) & (c00 == c11)
    # cell of each pixel: grid line i up to line i + 1 (the last line closes the last cell)
    cy = np.minimum(np.searchsorted(gy, np.arange(h), side="right") - 1, gy.size - 2)
    cx = np.minimum(np.searchsorted(gx, np.arange(w), side="right") - 1, gx.size - 2)
    out = c00[cy][:, cx]
    ys, xs = np.nonzero(~same[cy][:, cx])
    if ys.size:
        out[ys, xs] = trace_pixels(rig, np.stack([xs, ys], axis=1).astype(np.float64)).face
    return out


def deviation_angle(rig: Rig, pixels: np.ndarray) -> np.ndarray:
    """Angle (degrees) between each pixel's camera ray and its ray after the prism: (...,)."""
    d0 = rays_from_pixels(pixels, rig.camera.K, rig.camera.distortion if rig.camera.has_distortion else None)
    b = trace_pixels(rig, pixels)
    cos = np.clip(np.einsum("...k,...k->...", d0, b.directions), -1.0, 1.0)
    return np.degrees(np.arccos(cos))
