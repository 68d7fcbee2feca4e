"""The working depth range of a rig: the depths at which two faces' views share a field.

A prism's views overlap only over some depths: a weak bi-prism (the thesis's 6.4°) from ~0.3 m to infinity,
a strong one (20°) only around where its converging views cross (~250–400 mm), a tri-prism's three views
near 0.3–0.8 m. The virtual cameras are fitted, and a pair rectified, over these depths rather than over a
fixed range, so that the models are accurate where the scene can be matched at all.

For a pair of faces the exact ray of every pixel of a grid over face a's sub-image is followed to a depth
and projected exactly into face b (:func:`~prismstereo.optics.project_exact`); the share of those points
that face b sees inside the image is the overlap at that depth. The working range is where the overlap is at
least :data:`OVERLAP_FRACTION` of its largest value, cut at the depth where one pixel of disparity spans more
than :data:`DEPTH_STEP_LIMIT` of the depth (Z ≤ DEPTH_STEP_LIMIT · f · B): a weak prism's views keep
overlapping to infinity, but beyond that depth the rig no longer measures depth.

The virtual cameras are fitted over a narrower range: from the depth at which the views share
:data:`MODEL_FRACTION` of their best overlap (nearer, the views' rays cross the glass at their most
different angles and a pinhole fits them worst, while little of the scene is seen twice) to the far end
(the thesis bi-prism: 0.66–5.1 m; the 20° bi-prism: 258–331 mm; the thesis tri-prism: 0.3–3.0 m).
"""

from __future__ import annotations

from itertools import combinations

import numpy as np

from prismstereo.cameras.faces import thesis_camera
from prismstereo.config import Rig
from prismstereo.errors import GeometryError
from prismstereo.optics import RayBundle, pixel_grid, project_exact, trace_pixels

__all__ = ["DEPTH_STEP_LIMIT", "FAR_MM", "MODEL_FRACTION", "OVERLAP_FRACTION", "face_overlap", "overlap_depths",
           "overlap_span", "working_depth_range"]

#: a depth can be matched when the views share at least this share of their best overlap (also the rectified
#: search of :mod:`prismstereo.depth.search_range`)
OVERLAP_FRACTION = 0.25
#: the virtual cameras are fitted from the depth where the views share this share of their best overlap
MODEL_FRACTION = 0.8
#: farthest depth of the working range: one pixel of disparity at most this share of the depth
DEPTH_STEP_LIMIT = 0.04
#: farthest depth looked at, mm (here and in :mod:`prismstereo.depth.search_range`)
FAR_MM = 100_000.0


def face_overlap(rig: Rig, face_a: int, face_b: int, depths_mm: np.ndarray, *, step: float | None = None
                 ) -> np.ndarray:
    """(D,) share of face a's sampled pixels whose point at each world depth face b sees inside the image.

    ``step``: grid spacing of the sampled pixels (default 768 samples over the image, at most 32 px).
    """
    w, h = rig.camera.width, rig.camera.height
    if step is None:
        step = float(np.clip(np.sqrt(w * h / 768.0), 1.0, 32.0))
    grid = pixel_grid(w, h, step=step).reshape(-1, 2) + (step - 1) / 2.0
    grid = grid[(grid[:, 0] <= w - 1) & (grid[:, 1] <= h - 1)]
    b = trace_pixels(rig, grid)
    sel = b.face == face_a
    if sel.sum() < 8:
        raise GeometryError(f"expected face {face_a} to be seen by the camera, got {int(sel.sum())} sample pixels")
    z = np.asarray(depths_mm, dtype=np.float64)
    X = b.point_at_depth(z[:, None])[:, sel]  # (D, Na, 3)
    px, ok = _project_into_face(rig, grid, b, face_b, z, X, tolerance_px=0.05)
    ok &= (px[..., 0] >= 0) & (px[..., 0] <= w - 1) & (px[..., 1] >= 0) & (px[..., 1] <= h - 1)
    return ok.mean(axis=1)


def _cubic_terms(q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The 10 bivariate cubic monomials of (..., 2) points and their x and y derivatives, (..., 10) each."""
    x, y = q[..., 0], q[..., 1]
    one, zero = np.ones_like(x), np.zeros_like(x)
    phi = np.stack([one, x, y, x * x, x * y, y * y, x ** 3, x * x * y, x * y * y, y ** 3], axis=-1)
    dx = np.stack([zero, one, zero, 2 * x, y, zero, 3 * x * x, 2 * x * y, y * y, zero], axis=-1)
    dy = np.stack([zero, zero, one, zero, x, 2 * y, zero, x * x, 2 * x * y, 3 * y * y], axis=-1)
    return phi, dx, dy


def _project_into_face(rig: Rig, pixels: np.ndarray, grid: RayBundle, face: int, depths: np.ndarray, X: np.ndarray, *,
                       tolerance_px: float, max_iterations: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """:func:`~prismstereo.optics.project_exact` of points (D, N, 3), each row at one world depth, into
    ``face``: pixels (D, N, 2) and validity (D, N). ``pixels`` (M, 2) is a sample grid and ``grid`` its
    traced rays.

    The sample grid's rays through ``face`` give, at each depth, where the face's pixels land; a
    cubic fitted to that (plane point → pixel) starts each point close to its pixel and its derivative
    stands in for the Jacobian, so that each iteration traces once instead of five times (Newton's
    finite differences). Points that this does not settle within ``max_iterations`` are solved by
    :func:`~prismstereo.optics.project_exact` itself.
    """
    D, N = X.shape[:2]
    mine = grid.face == face
    if mine.sum() < 20:
        flat, ok = project_exact(rig, X.reshape(-1, 3), face=face, tolerance_px=tolerance_px)
        return flat.reshape(D, N, 2), ok.reshape(D, N)
    Q = grid.point_at_depth(depths[:, None])[:, mine, :2]  # (D, Nb, 2)
    targets = pixels[mine]
    centre = Q.mean(axis=1, keepdims=True)
    scale = Q.std(axis=1, keepdims=True) + 1e-12
    phi_b, _, _ = _cubic_terms((Q - centre) / scale)
    coef = np.stack([np.linalg.lstsq(phi_b[i], targets, rcond=None)[0] for i in range(D)])  # (D, 10, 2)
    q = (X[..., :2] - centre) / scale
    phi, dphx, dphy = _cubic_terms(q)
    guess = np.einsum("dnk,dkc->dnc", phi, coef)
    # M = d pixel / d plane point (D, N, 2, 2), columns: x, y
    M = np.stack([np.einsum("dnk,dkc->dnc", dphx, coef) / scale[..., 0:1],
                  np.einsum("dnk,dkc->dnc", dphy, coef) / scale[..., 1:2]], axis=-1)
    p = guess.reshape(-1, 2).copy()
    Mf = M.reshape(-1, 2, 2)
    Xf = X.reshape(-1, 3)
    active = np.all(np.isfinite(p), axis=1) & np.all(np.isfinite(Xf), axis=1) & (Xf[:, 2] > rig.prism.back_distance)
    converged = np.zeros(p.shape[0], dtype=bool)
    for _ in range(max_iterations):
        idx = np.flatnonzero(active & ~converged)
        if idx.size == 0:
            break
        bb = trace_pixels(rig, p[idx], face=face, bounded=False)
        s = (Xf[idx, 2] - bb.origins[:, 2]) / bb.directions[:, 2]
        r = bb.origins[:, :2] + s[:, None] * bb.directions[:, :2] - Xf[idx, :2]
        step = np.einsum("nij,nj->ni", Mf[idx], r)
        norm = np.linalg.norm(step, axis=1)
        p[idx] = p[idx] - step
        bad = ~np.isfinite(norm)
        active[idx[bad]] = False
        converged[idx[~bad & (norm < tolerance_px)]] = True
    rest = np.flatnonzero(~converged)
    out = np.full(p.shape, np.nan)
    out[converged] = p[converged]
    valid = np.zeros(p.shape[0], dtype=bool)
    if converged.any():
        final = trace_pixels(rig, p[converged], bounded=True)
        valid[converged] = final.face == face
    if rest.size:
        out[rest], valid[rest] = project_exact(rig, Xf[rest], face=face, tolerance_px=tolerance_px)
    return out.reshape(D, N, 2), valid.reshape(D, N)


def overlap_depths(back_mm: float, n: int = 32, *, margin: float = 1.05) -> np.ndarray:
    """(n,) depths, mm, at which a rig's overlap is sampled: geometric from ``margin`` times the prism's back
    distance ``back_mm`` to :data:`FAR_MM` (the working range here, the rectified search of
    :mod:`prismstereo.depth.search_range`)."""
    return np.geomspace(back_mm * margin, FAR_MM, n)


def overlap_span(depths: np.ndarray, frac: np.ndarray, *, fraction: float = OVERLAP_FRACTION,
                 interpolate: bool = True) -> tuple[float, float]:
    """(near, far) mm where the overlap ``frac`` sampled at ``depths`` (increasing) is at least ``fraction`` of
    its largest value: the one depth-range search of the working range (:func:`pair_depth_range`, on the real
    faces) and of the rectified search (:mod:`prismstereo.depth.search_range`, on a rectified pair).

    ``interpolate`` True: the depths where ``frac`` crosses the level, log-linear between samples; False: the
    nearest and farthest samples at or above it."""
    level = fraction * float(frac.max())
    if not interpolate:
        keep = np.flatnonzero(frac >= level)
        return float(depths[keep[0]]), float(depths[keep[-1]])
    return _crossings(depths, frac, level)


def _crossings(depths: np.ndarray, frac: np.ndarray, level: float) -> tuple[float, float]:
    """Near and far depth where ``frac`` crosses ``level`` (log-linear interpolation between samples)."""
    keep = np.flatnonzero(frac >= level)
    i0, i1 = int(keep[0]), int(keep[-1])
    lz = np.log(depths)

    def cross(i: int, j: int) -> float:
        f0, f1 = frac[i], frac[j]
        t = 0.0 if f1 == f0 else (level - f0) / (f1 - f0)
        return float(np.exp(lz[i] + np.clip(t, 0.0, 1.0) * (lz[j] - lz[i])))

    near = float(depths[i0]) if i0 == 0 else cross(i0 - 1, i0)
    far = float(depths[i1]) if i1 == len(depths) - 1 else cross(i1, i1 + 1)
    return near, far


def _baseline(rig: Rig, face_a: int, face_b: int) -> float:
    return float(np.linalg.norm(thesis_camera(rig, face_a).C - thesis_camera(rig, face_b).C))


def pair_depth_range(rig: Rig, face_a: int, face_b: int, *, near_fraction: float = OVERLAP_FRACTION,
                     n_depths: int = 32, depth_step_cap: bool = True) -> tuple[float, float] | None:
    """(near, far) mm of the working range of one face pair (module docstring), or None if they never overlap.

    ``depth_step_cap`` False keeps every depth where the views overlap (no cut at the depth-resolution limit).
    """
    depths = overlap_depths(rig.prism.back_distance, n_depths)
    frac = face_overlap(rig, face_a, face_b, depths)
    if not (frac > 0).any():
        return None
    near, _ = overlap_span(depths, frac, fraction=near_fraction)
    _, far = overlap_span(depths, frac)
    if far <= near * 1.05:
        # a narrow overlap between two samples: resample finely around it
        fine = np.geomspace(near / 1.5, far * 1.5, n_depths)
        fine = fine[fine > rig.prism.back_distance * 1.02]
        f2 = face_overlap(rig, face_a, face_b, fine)
        near, _ = overlap_span(fine, f2, fraction=near_fraction)
        _, far = overlap_span(fine, f2)
    if depth_step_cap:
        far = min(far, DEPTH_STEP_LIMIT * rig.camera.focal_px * _baseline(rig, face_a, face_b))
    return near, max(far, near * 1.05)


def working_depth_range(rig: Rig, faces: tuple[int, ...] | None = None, *,
                        near_fraction: float = OVERLAP_FRACTION) -> tuple[float, float]:
    """(near, far) mm: the union of the working ranges of the face pairs among ``faces`` (default all)."""
    fs = tuple(range(rig.prism.faces)) if faces is None else tuple(faces)
    ranges = [r for a, b in combinations(fs, 2)
              if (r := pair_depth_range(rig, a, b, near_fraction=near_fraction)) is not None]
    if not ranges:
        raise GeometryError(f"expected faces {fs} to share a view at some depth, got views that never overlap")
    return min(r[0] for r in ranges), max(r[1] for r in ranges)
