"""Triangulation: 3D points from correspondences (thesis §7.2, Eqs. 7.19–7.23, Appendix A).

Four ways to turn a match into a point, all pure functions on arrays:

- :func:`triangulate_midpoint` — midpoint of the common perpendicular of two rays (thesis Eq. 7.19 and
  Appendix A, the "mid-point theorem"); works for any rays, pinhole or not.
- :func:`triangulate_dlt` — linear (DLT) triangulation from two 3×4 projection matrices.
- :func:`reproject_disparity` / :func:`depth_from_disparity` — the rectified-pair shortcut with the
  reprojection matrix Q (thesis Eqs. 7.21–7.23).
- :func:`triangulate_exact` — exact refractive triangulation: the two REAL-image pixels of a match are
  traced through the prism (vector Snell's law, :func:`~prismstereo.optics.trace_pixels`) and the point
  is the midpoint of the two exact rays. No pinhole approximation is involved, so with exact
  correspondences it recovers the scene point to machine precision.

Conventions (docs/conventions.md): world frame = real camera frame, mm; pixels (u, v) with centres at integers;
disparity ``d = x_left − x_right`` in pixels, NaN = invalid.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from prismstereo.cameras import VirtualView
from prismstereo.config import Rig
from prismstereo.errors import ConfigError
from prismstereo.optics import trace_pixels
from prismstereo.rectify import RectifiedPair

__all__ = [
    "TRIANGULATIONS",
    "RayTable",
    "Triangulation",
    "depth_from_disparity",
    "points_on_grid",
    "ray_table",
    "rectified_to_world",
    "reproject_disparity",
    "triangulate_dlt",
    "triangulate_exact",
    "triangulate_matches",
    "triangulate_midpoint",
    "triangulate_table",
]

#: triangulation methods of a rectified match: exact refractive rays, midpoint / DLT of the virtual
#: pinholes, Q of the pair
TRIANGULATIONS = ("exact", "midpoint", "dlt", "q")


@dataclass(frozen=True)
class Triangulation:
    """Triangulated points with their quality.

    Attributes
    ----------
    points : (*S, 3) float64
        Points in the world frame, mm; NaN where invalid.
    gaps : (*S,) float64
        Length of the common perpendicular between the two rays, mm (0 for rays that meet; NaN where
        invalid). A large gap means the two pixels do not see one point (a bad match, or a vertical
        rectification error).
    valid : (*S,) bool
        Both rays exist (no total internal reflection, inside the glass), they are not parallel, and the
        point lies in front of both ray origins.
    """

    points: np.ndarray
    gaps: np.ndarray
    valid: np.ndarray


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("...k,...k->...", a, b)


def triangulate_midpoint(
    origins_a: np.ndarray,
    directions_a: np.ndarray,
    origins_b: np.ndarray,
    directions_b: np.ndarray,
) -> Triangulation:
    """Midpoint of the common perpendicular of two rays (thesis Eq. 7.19, Appendix A).

    Solves ``a·d_a − b·d_b + c·(d_a × d_b) = o_b − o_a`` (Eq. 7.19 written for arbitrary origins) in closed
    form; the point is the middle of the segment joining ``o_a + a·d_a`` and ``o_b + b·d_b``.

    Parameters
    ----------
    origins_a, directions_a : (*S, 3) array
        Ray origins (mm) and directions (any length) of the first view.
    origins_b, directions_b : (*S, 3) array
        Same for the second view. All four broadcast together.

    Returns
    -------
    Triangulation
        ``valid`` is False for parallel rays, non-finite inputs and points behind either origin
        (a, b ≤ 0).
    """
    oa = np.asarray(origins_a, dtype=np.float64)
    da = np.asarray(directions_a, dtype=np.float64)
    ob = np.asarray(origins_b, dtype=np.float64)
    db = np.asarray(directions_b, dtype=np.float64)
    oa, da, ob, db = np.broadcast_arrays(oa, da, ob, db)
    w = oa - ob
    a = _dot(da, da)
    b = _dot(da, db)
    c = _dot(db, db)
    d = _dot(da, w)
    e = _dot(db, w)
    den = a * c - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        sa = (b * e - c * d) / den
        sb = (a * e - b * d) / den
    ok = np.isfinite(sa) & np.isfinite(sb) & (np.abs(den) > 1e-14 * np.maximum(a * c, 1e-300))
    ok &= (sa > 0) & (sb > 0)
    qa = oa + sa[..., None] * da
    qb = ob + sb[..., None] * db
    pts = 0.5 * (qa + qb)
    gaps = np.linalg.norm(qa - qb, axis=-1)
    nan3 = np.full(3, np.nan)
    return Triangulation(
        points=np.where(ok[..., None], pts, nan3),
        gaps=np.where(ok, gaps, np.nan),
        valid=ok,
    )


def triangulate_dlt(
    P_a: np.ndarray,
    P_b: np.ndarray,
    pixels_a: np.ndarray,
    pixels_b: np.ndarray,
) -> np.ndarray:
    """Linear (DLT) triangulation of pixel pairs from two pinhole cameras.

    For each pair the homogeneous point X minimises ``‖A X‖`` with ``‖X‖ = 1``, where A stacks
    ``u·P₃ − P₁`` and ``v·P₃ − P₂`` of both views (Hartley & Zisserman, §12.2); each row of A is
    normalised first for conditioning. Distortion is not modelled: undistort the pixels first.

    Parameters
    ----------
    P_a, P_b : (3, 4) array
        Projection matrices ``K [R | −R C]`` (docs/conventions.md).
    pixels_a, pixels_b : (*S, 2) array
        Matching pixels (u, v) in each view.

    Returns
    -------
    (*S, 3) float64 world points, mm; NaN for non-finite pixels or points at infinity.
    """
    Pa = np.asarray(P_a, dtype=np.float64)
    Pb = np.asarray(P_b, dtype=np.float64)
    xa = np.asarray(pixels_a, dtype=np.float64)
    xb = np.asarray(pixels_b, dtype=np.float64)
    xa, xb = np.broadcast_arrays(xa, xb)
    shape = xa.shape[:-1]
    xa = xa.reshape(-1, 2)
    xb = xb.reshape(-1, 2)
    out = np.full((xa.shape[0], 3), np.nan)
    ok = np.all(np.isfinite(xa), axis=1) & np.all(np.isfinite(xb), axis=1)
    if np.any(ok):
        ua, ub = xa[ok], xb[ok]
        A = np.stack(
            [
                ua[:, 0:1] * Pa[2] - Pa[0],
                ua[:, 1:2] * Pa[2] - Pa[1],
                ub[:, 0:1] * Pb[2] - Pb[0],
                ub[:, 1:2] * Pb[2] - Pb[1],
            ],
            axis=1,
        )  # M×4×4
        A /= np.linalg.norm(A, axis=2, keepdims=True)
        # Smallest right singular vector = eigenvector of AᵀA with the smallest eigenvalue.
        _, vecs = np.linalg.eigh(np.einsum("mki,mkj->mij", A, A))
        X = vecs[:, :, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            pts = X[:, :3] / X[:, 3:4]
        out[ok] = np.where(np.abs(X[:, 3:4]) > 1e-15, pts, np.nan)
    return out.reshape(shape + (3,))


def depth_from_disparity(
    disparity: np.ndarray, *, focal_px: float, baseline_mm: float
) -> np.ndarray:
    """Depth along the rectified optical axis, ``Z = λ f / d`` (thesis Eq. 7.21).

    Parameters
    ----------
    disparity : (H, W) array
        ``d = x_left − x_right`` in pixels; NaN or d ≤ 0 give NaN.
    focal_px : float
        Focal length of the rectified cameras in pixels.
    baseline_mm : float
        Distance λ between the rectified optical centres, mm.

    Returns
    -------
    (H, W) float64 depth in mm in the rectified left camera's frame (not the world Z).
    """
    d = np.asarray(disparity, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = focal_px * baseline_mm / d
    return np.where(d > 0, z, np.nan)


def reproject_disparity(disparity: np.ndarray, Q: np.ndarray, *, origin: tuple[float, float] = (0.0, 0.0)
                        ) -> np.ndarray:
    """3D points of a disparity map with the reprojection matrix Q (thesis Eq. 7.23).

    ``[X, Y, Z, W]ᵀ = Q [x, y, d, 1]ᵀ`` and the point is ``(X, Y, Z) / W``. With the thesis's
    ``Q = [[1, 0, 0, −cx], [0, 1, 0, −cy], [0, 0, 0, f], [0, 0, 1/λ, 0]]`` this is ``Z = λ f / d``
    (Eq. 7.22); OpenCV's Q (``cv2.stereoRectify``, with its sign of 1/Tx) works the same.

    Parameters
    ----------
    disparity : (H, W) array
        Disparity of the rectified left image, pixels; NaN = invalid.
    Q : (4, 4) array
    origin : (x0, y0)
        Rectified-image coordinates of ``disparity[0, 0]`` (for a cropped region of interest).

    Returns
    -------
    (H, W, 3) float64 points in the rectified LEFT camera frame, mm; NaN where d is invalid or ≤ 0.
    Use :func:`rectified_to_world` to express them in the world frame.
    """
    d = np.asarray(disparity, dtype=np.float64)
    Qm = np.asarray(Q, dtype=np.float64)
    h, w = d.shape
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    hom = np.stack([xs + origin[0], ys + origin[1], d, np.ones_like(d)], axis=-1)
    out = hom @ Qm.T
    with np.errstate(divide="ignore", invalid="ignore"):
        pts = out[..., :3] / out[..., 3:4]
    ok = np.isfinite(d) & (d > 0) & np.all(np.isfinite(pts), axis=-1)
    return np.where(ok[..., None], pts, np.nan)


def rectified_to_world(points: np.ndarray, R: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Points in a rectified camera frame → world frame: ``X_w = Rᵀ x + C`` (R world-to-rectified).

    Parameters
    ----------
    points : (..., 3) array, mm.
    R : (3, 3) world-to-rectified rotation; C : (3,) that camera's optical centre, mm.
    """
    pts = np.asarray(points, dtype=np.float64)
    return pts @ np.asarray(R, dtype=np.float64) + np.asarray(C, dtype=np.float64)


def triangulate_exact(rig: Rig, pixels_a: np.ndarray, pixels_b: np.ndarray, *,
                      faces: tuple[int, int] | None = None) -> Triangulation:
    """Exact refractive triangulation of real-image pixel pairs.

    Each pixel's ray is traced through the prism exactly (vector Snell's law at the face and at the back
    plane, :func:`~prismstereo.optics.trace_pixels`), and the point is the midpoint of the common
    perpendicular of the two exit rays (thesis Eq. 7.19 / Appendix A, applied to the true rays instead of
    the rays of approximate virtual pinholes).

    Parameters
    ----------
    rig : Rig
    pixels_a, pixels_b : (*S, 2) array
        Matching pixels (u, v) of the REAL image, one seen through each face (fractional allowed).
    faces : (face_a, face_b), optional
        If given, a pixel whose ray goes through another face (or no face) is invalid: it cannot be
        the match it claims to be.

    Returns
    -------
    Triangulation
    """
    xa = np.asarray(pixels_a, dtype=np.float64)
    xb = np.asarray(pixels_b, dtype=np.float64)
    xa, xb = np.broadcast_arrays(xa, xb)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        ra = trace_pixels(rig, np.nan_to_num(xa, nan=-1e6))
        rb = trace_pixels(rig, np.nan_to_num(xb, nan=-1e6))
    tri = triangulate_midpoint(ra.origins, ra.directions, rb.origins, rb.directions)
    ok = tri.valid & ra.valid & rb.valid
    ok &= np.all(np.isfinite(xa), axis=-1) & np.all(np.isfinite(xb), axis=-1)
    if faces is not None:
        ok &= (ra.face == faces[0]) & (rb.face == faces[1])
    return Triangulation(
        points=np.where(ok[..., None], tri.points, np.nan),
        gaps=np.where(ok, tri.gaps, np.nan),
        valid=ok,
    )


def triangulate_matches(rig: Rig, pair: RectifiedPair, ys: np.ndarray, xs: np.ndarray, d: np.ndarray, *,
                        method: str, views: Sequence[VirtualView], rays: RayTable | None = None) -> Triangulation:
    """Triangulate rectified-left matches (x, y) ↔ (x − d, y) of a rectified pair with ``method``.

    Parameters
    ----------
    rig : Rig
    pair : RectifiedPair
        The rectification the matches were found in.
    ys, xs : (N,) int
        Rectified-left pixels.
    d : (N,) float64
        Their disparities, px.
    method : {"exact", "midpoint", "dlt", "q"}, keyword-only
        Exact refractive rays of the real pixels (:func:`triangulate_exact`), the virtual pinholes' rays
        (:func:`triangulate_midpoint`, thesis Eq. 7.19) or projection matrices (:func:`triangulate_dlt`),
        or the pair's Q (thesis Eq. 7.23).
    views : sequence of VirtualView, keyword-only
        The virtual cameras used by ``midpoint`` and ``dlt`` (by face).
    rays : RayTable, optional, keyword-only
        ``pair``'s exact-ray table (:func:`ray_table`): ``exact`` reads the rays from it
        (:func:`triangulate_table`) instead of tracing them.

    Returns
    -------
    Triangulation
        (N,) points in the world frame.

    Raises
    ------
    ConfigError
        Unknown method.
    """
    n = ys.size
    if method == "exact" and rays is not None:
        return triangulate_table(rays, ys, xs, d)
    if method == "q":
        # thesis Eq. 7.23 on the listed (x, y, d), then from the rectified left frame to the world
        Q = np.asarray(pair.Q, dtype=np.float64)
        hom = np.stack([xs.astype(np.float64), ys.astype(np.float64), d, np.ones(n)], axis=1) @ Q.T
        with np.errstate(divide="ignore", invalid="ignore"):
            pts_rect = hom[:, :3] / hom[:, 3:4]
        pts = rectified_to_world(pts_rect, pair.R_left, pair.C_left)
        ok = np.all(np.isfinite(pts), axis=1) & (d > 0)
        return Triangulation(np.where(ok[:, None], pts, np.nan), np.full(n, np.nan), ok)
    left_px = np.stack([xs, ys], axis=1).astype(np.float64)
    right_px = np.stack([xs - d, ys], axis=1).astype(np.float64)
    pl, pr = pair.rectified_to_real(left_px, "left"), pair.rectified_to_real(right_px, "right")
    fl, fr = int(pair.left_face), int(pair.right_face)
    if method == "exact":
        return triangulate_exact(rig, pl, pr, faces=(fl, fr))
    by_face = {v.face: v for v in views}
    cam_l, cam_r = by_face[fl].camera, by_face[fr].camera
    finite = np.all(np.isfinite(pl), axis=1) & np.all(np.isfinite(pr), axis=1)
    pl0, pr0 = np.where(finite[:, None], pl, 0.0), np.where(finite[:, None], pr, 0.0)
    if method == "midpoint":
        ol, dl = cam_l.unproject(pl0)
        orr, dr = cam_r.unproject(pr0)
        tri = triangulate_midpoint(ol, dl, orr, dr)
        ok = tri.valid & finite
        return Triangulation(np.where(ok[:, None], tri.points, np.nan), np.where(ok, tri.gaps, np.nan), ok)
    if method == "dlt":
        ul = cam_l.undistort_pixels(pl0) @ cam_l.K[:2, :2].T + cam_l.K[:2, 2]
        ur = cam_r.undistort_pixels(pr0) @ cam_r.K[:2, :2].T + cam_r.K[:2, 2]
        pts = triangulate_dlt(cam_l.P, cam_r.P, ul, ur)
        ok = finite & np.all(np.isfinite(pts), axis=1)
        return Triangulation(np.where(ok[:, None], pts, np.nan), np.full(n, np.nan), ok)
    raise ConfigError(f"triangulation: expected one of {', '.join(TRIANGULATIONS)}, got {method!r}")


# --------------------------------------------------------------------------- per-rig table of exact rays
@dataclass(frozen=True, eq=False)
class RayTable:
    """The exact refractive ray of every pixel of a rectified pair's two views, computed once per rig.

    Exact triangulation of a rectified match (x, y) ↔ (x − d, y) intersects the ray of the left pixel with
    the ray of the right pixel (thesis Eq. 7.19 on the rays traced through the prism, as
    :func:`triangulate_exact`). Both rays depend on the rig and the rectification alone: this table holds
    them for every rectified pixel (the real pixel of its remap table traced through its face), so a
    frame's triangulation is one gather and the midpoint formula per match (:func:`triangulate_table`):
    the point of the left pixel at any disparity, without tracing a ray.

    The left pixel is always a table entry (integer x, y). The right pixel ``x − d`` is fractional: its
    ray is interpolated linearly between the rays of the two columns beside it (``np.floor(x − d)`` and
    the next), where :func:`triangulate_exact` traces the ray of the real pixel that the remap table gives
    by bilinear interpolation (:meth:`~prismstereo.rectify.RectifiedPair.rectified_to_real`). The two
    agree at the columns and differ in between by a second-order term, the equivalent of at most about
    2e-5 px of disparity; as a relative depth error that is d-times smaller at disparity d
    (tests/depth/test_triangulation.py, the demo bi-prism rig, 512×384, over its common view at random
    disparities of its search range): at most 6e-7 to 3 m, 6e-6 to 10 m, 1e-5 to 20 m (d ≥ 2 px), 5e-5 at
    100 m (d ≈ 0.8 px); on the thesis rig's 1024×768 sensor 1.5e-7 to 3 m and 4e-6 at 100 m. The same
    points are valid as with :func:`triangulate_exact` (the table marks a ray invalid exactly where tracing
    does; a right pixel between a valid and an invalid column is invalid in both).

    Attributes
    ----------
    left_origins, left_directions : (h, w, 3) float64
        Exit point on the prism's back plane (mm) and direction of the ray of each rectified-left pixel,
        NaN where the pixel has no real pixel, the ray is invalid or does not pass through the left face.
    right_origins, right_directions : (h, w, 3) float64
        The same for the rectified-right pixels and the right face.
    """

    left_origins: np.ndarray
    left_directions: np.ndarray
    right_origins: np.ndarray
    right_directions: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.left_origins.shape[0]), int(self.left_origins.shape[1]))

    @property
    def nbytes(self) -> int:
        return int(sum(a.nbytes for a in (self.left_origins, self.left_directions, self.right_origins,
                                          self.right_directions)))

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The table as plain arrays (for an ``.npz``; :meth:`from_arrays` reads them back)."""
        return {"rays_left_o": self.left_origins, "rays_left_d": self.left_directions,
                "rays_right_o": self.right_origins, "rays_right_d": self.right_directions}

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> RayTable:
        """Read :meth:`to_arrays` back (ValueError where the arrays do not fit together)."""
        parts = [np.ascontiguousarray(arrays[k], dtype=np.float64)
                 for k in ("rays_left_o", "rays_left_d", "rays_right_o", "rays_right_d")]
        if any(p.ndim != 3 or p.shape != parts[0].shape or p.shape[2] != 3 for p in parts):
            raise ValueError("ray table arrays of different shapes")
        return cls(*parts)


#: pixels traced at a time by :func:`ray_table` (bounds its temporaries to a few hundred MB at any size)
_RAY_BLOCK_PX = 1 << 19


def _view_rays(rig: Rig, real_map: np.ndarray, face: int) -> tuple[np.ndarray, np.ndarray]:
    """(h, w, 3) origins and directions of the exact rays of a remap table's real pixels through ``face``,
    traced a block of rows at a time."""
    h, w = real_map.shape[:2]
    origins = np.full((h, w, 3), np.nan)
    directions = np.full((h, w, 3), np.nan)
    rows = max(1, _RAY_BLOCK_PX // max(w, 1))
    for r0 in range(0, h, rows):
        px = np.asarray(real_map[r0:r0 + rows], dtype=np.float64)
        finite = np.all(np.isfinite(px), axis=-1)
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            rays = trace_pixels(rig, np.where(finite[..., None], px, -1e6))
        ok = finite & rays.valid & (rays.face == face)
        origins[r0:r0 + rows][ok] = rays.origins[ok]
        directions[r0:r0 + rows][ok] = rays.directions[ok]
    return origins, directions


def ray_table(rig: Rig, pair: RectifiedPair) -> RayTable:
    """Trace the exact ray of every pixel of both rectified views of ``pair`` (:class:`RayTable`).

    Parameters
    ----------
    rig : Rig
    pair : RectifiedPair
        With its remap tables (``map_left``/``map_right``: the real pixel of each rectified pixel).

    Returns
    -------
    RayTable
        96 bytes per rectified pixel (about 44 MB for the thesis rig's 1024×768 capture).
    """
    lo, ld = _view_rays(rig, pair.map_left, int(pair.left_face))
    ro, rd = _view_rays(rig, pair.map_right, int(pair.right_face))
    return RayTable(left_origins=lo, left_directions=ld, right_origins=ro, right_directions=rd)


@njit(cache=True, parallel=True, nogil=True)
def _table_kernel(lo: np.ndarray, ld: np.ndarray, ro: np.ndarray, rd: np.ndarray, ys: np.ndarray, xs: np.ndarray,
                  d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - numba
    """Midpoint of the left ray of (xs, ys) and the right ray at (xs − d, ys), linear between columns
    (the arithmetic of :func:`triangulate_midpoint`)."""
    n = ys.size
    w = ro.shape[1]
    pts = np.full((n, 3), np.nan)
    gaps = np.full(n, np.nan)
    valid = np.zeros(n, dtype=np.bool_)
    for i in prange(n):
        y = ys[i]
        xr = xs[i] - d[i]
        if not np.isfinite(xr):
            continue
        x0 = int(np.floor(xr))
        t = xr - x0
        if x0 < 0 or x0 > w - 1 or (t > 0.0 and x0 + 1 > w - 1):
            continue
        x1 = x0 + 1 if t > 0.0 else x0
        oa = lo[y, xs[i]]
        da = ld[y, xs[i]]
        ob = np.empty(3)
        db = np.empty(3)
        for k in range(3):
            ob[k] = (1.0 - t) * ro[y, x0, k] + t * ro[y, x1, k]
            db[k] = (1.0 - t) * rd[y, x0, k] + t * rd[y, x1, k]
        a = b = c = dd = e = 0.0
        for k in range(3):
            wk = oa[k] - ob[k]
            a += da[k] * da[k]
            b += da[k] * db[k]
            c += db[k] * db[k]
            dd += da[k] * wk
            e += db[k] * wk
        den = a * c - b * b
        if not (np.isfinite(den) and abs(den) > 1e-14 * max(a * c, 1e-300)):
            continue
        sa = (b * e - c * dd) / den
        sb = (a * e - b * dd) / den
        if not (np.isfinite(sa) and np.isfinite(sb) and sa > 0.0 and sb > 0.0):
            continue
        g2 = 0.0
        for k in range(3):
            qa = oa[k] + sa * da[k]
            qb = ob[k] + sb * db[k]
            pts[i, k] = 0.5 * (qa + qb)
            g2 += (qa - qb) * (qa - qb)
        gaps[i] = np.sqrt(g2)
        valid[i] = True
    return pts, gaps, valid


def triangulate_table(table: RayTable, ys: np.ndarray, xs: np.ndarray, d: np.ndarray) -> Triangulation:
    """Exact triangulation of rectified matches (x, y) ↔ (x − d, y) from a :class:`RayTable`.

    The same points as :func:`triangulate_matches` with ``method="exact"`` within the table's
    interpolation error (:class:`RayTable`), without tracing a ray.

    Parameters
    ----------
    table : RayTable
    ys, xs : (N,) int
        Rectified-left pixels (inside the table).
    d : (N,) float
        Their disparities, px.

    Returns
    -------
    Triangulation
        (N,) points in the world frame; invalid where either ray is missing or the right pixel is off the
        view, the rays are parallel or the point lies behind either origin.
    """
    pts, gaps, valid = _table_kernel(table.left_origins, table.left_directions, table.right_origins,
                                     table.right_directions, np.asarray(ys, dtype=np.int64),
                                     np.asarray(xs, dtype=np.int64), np.asarray(d, dtype=np.float64))
    return Triangulation(points=pts, gaps=gaps, valid=valid)


@njit(cache=True)
def _on_grid(h: int, w: int, ys: np.ndarray, xs: np.ndarray, points: np.ndarray, gaps: np.ndarray,
             keep: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - numba
    """:func:`points_on_grid` in one pass over the kept points."""
    grid = np.full((h, w, 3), np.nan)
    depth = np.full((h, w), np.nan, dtype=np.float32)
    gap = np.full((h, w), np.nan, dtype=np.float32)
    valid = np.zeros((h, w), dtype=np.bool_)
    for i in range(ys.size):
        if not keep[i]:
            continue
        y, x = ys[i], xs[i]
        for k in range(3):
            grid[y, x, k] = points[i, k]
        depth[y, x] = np.float32(points[i, 2])
        gap[y, x] = np.float32(gaps[i])
        valid[y, x] = True
    return grid, depth, gap, valid


def points_on_grid(shape: tuple[int, int], ys: np.ndarray, xs: np.ndarray, points: np.ndarray, gaps: np.ndarray,
                   keep: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The kept points of pixels ``(ys, xs)`` on the (h, w) grid they come from.

    Parameters
    ----------
    shape : (h, w)
    ys, xs : (N,) int
        Distinct pixels inside the grid.
    points : (N, 3) float
        Their points (mm).
    gaps : (N,) float
        Their rays' gaps (mm).
    keep : (N,) bool
        The points to place.

    Returns
    -------
    points : (h, w, 3) float64
        NaN where no point is kept.
    depth : (h, w) float32
        The points' z, NaN where none.
    gaps : (h, w) float32
        NaN where none.
    valid : (h, w) bool
    """
    h, w = int(shape[0]), int(shape[1])
    return _on_grid(h, w, np.asarray(ys, dtype=np.int64), np.asarray(xs, dtype=np.int64),
                    np.ascontiguousarray(points, dtype=np.float64), np.asarray(gaps, dtype=np.float64),
                    np.asarray(keep, dtype=np.bool_))
