"""Vector refraction (Snell's law) and ray–plane intersection.

The thesis derives the refracted rays with scalar angle formulas whose signs depend on the figure
(thesis Eqs. 3.11–3.29); here the same physics is written once in vector form, which holds for any
face orientation:

    t = η d + (η cos θᵢ − cos θₜ) n,   η = n₁ / n₂,   cos θᵢ = −n·d,   sin² θₜ = η² (1 − cos² θᵢ)

with ``n`` the unit normal facing the incoming ray. Total internal reflection (sin² θₜ > 1) is
reported as invalid and its direction is NaN, never silently wrong.
"""

from __future__ import annotations

import numpy as np


def normalize(vectors: np.ndarray) -> np.ndarray:
    """Unit vectors along the last axis of ``vectors`` (..., 3); zero vectors become NaN."""
    v = np.asarray(vectors, dtype=np.float64)
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return v / norm


def refract(
    directions: np.ndarray,
    normals: np.ndarray,
    n_in: float | np.ndarray,
    n_out: float | np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Refract rays at an interface (vector Snell's law).

    Parameters
    ----------
    directions : (..., 3) array
        Unit directions of the incoming rays.
    normals : (..., 3) array
        Unit normals of the interface at the hit points (either orientation; flipped internally to face
        the incoming ray). Broadcasts against ``directions``.
    n_in, n_out : float or array
        Refractive indices of the medium the ray comes from and goes into.

    Returns
    -------
    refracted : (..., 3) array
        Unit directions of the refracted rays; NaN where the ray is totally internally reflected.
    valid : (...,) bool array
        False where total internal reflection occurs (or the input was NaN).
    """
    d = np.asarray(directions, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    n = np.broadcast_to(n, d.shape)
    cos_i = -np.einsum("...k,...k->...", n, d)
    flip = cos_i < 0
    n = np.where(flip[..., None], -n, n)
    cos_i = np.abs(cos_i)
    eta = np.asarray(n_in, dtype=np.float64) / np.asarray(n_out, dtype=np.float64)
    sin2_t = eta**2 * np.maximum(0.0, 1.0 - cos_i**2)
    valid = sin2_t <= 1.0
    cos_t = np.sqrt(np.where(valid, 1.0 - sin2_t, np.nan))
    eta_b = np.broadcast_to(eta, cos_i.shape)[..., None]
    out = eta_b * d + (eta_b[..., 0] * cos_i - cos_t)[..., None] * n
    out = normalize(out)
    valid = valid & np.all(np.isfinite(out), axis=-1)
    out[~valid] = np.nan
    return out, valid


def intersect_plane(
    origins: np.ndarray,
    directions: np.ndarray,
    plane_normal: np.ndarray,
    plane_offset: float | np.ndarray,
) -> np.ndarray:
    """Ray parameter s at which ``origin + s·direction`` meets the plane ``normal·p = offset``.

    Parameters
    ----------
    origins, directions : (..., 3) arrays
    plane_normal : (3,) or (..., 3) array
    plane_offset : float or (...,) array

    Returns
    -------
    s : (...,) array; NaN where the ray is parallel to the plane.
    """
    o = np.asarray(origins, dtype=np.float64)
    d = np.asarray(directions, dtype=np.float64)
    nrm = np.asarray(plane_normal, dtype=np.float64)
    denom = np.einsum("...k,...k->...", np.broadcast_to(nrm, d.shape), d)
    num = np.asarray(plane_offset) - np.einsum("...k,...k->...", np.broadcast_to(nrm, o.shape), o)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = num / denom
    return np.where(np.abs(denom) > 1e-15, s, np.nan)


def closest_points_between_lines(
    origins_a: np.ndarray,
    directions_a: np.ndarray,
    origins_b: np.ndarray,
    directions_b: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Midpoint of the common perpendicular of two lines, and its length (thesis Appendix A, Eq. 7.19).

    Parameters
    ----------
    origins_a, directions_a, origins_b, directions_b : (..., 3) arrays

    Returns
    -------
    midpoints : (..., 3) array
        Midpoint of the shortest segment between the lines; NaN for parallel lines.
    gaps : (...,) array
        Length of that segment (0 when the lines intersect).
    """
    pa, da = np.asarray(origins_a, float), np.asarray(directions_a, float)
    pb, db = np.asarray(origins_b, float), np.asarray(directions_b, float)
    w = pa - pb
    a = np.einsum("...k,...k->...", da, da)
    b = np.einsum("...k,...k->...", da, db)
    c = np.einsum("...k,...k->...", db, db)
    d = np.einsum("...k,...k->...", da, w)
    e = np.einsum("...k,...k->...", db, w)
    den = a * c - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        sa = (b * e - c * d) / den
        sb = (a * e - b * d) / den
    bad = np.abs(den) <= 1e-15 * np.maximum(a * c, 1e-300)
    sa = np.where(bad, np.nan, sa)
    sb = np.where(bad, np.nan, sb)
    qa = pa + sa[..., None] * da
    qb = pb + sb[..., None] * db
    return 0.5 * (qa + qb), np.linalg.norm(qa - qb, axis=-1)
