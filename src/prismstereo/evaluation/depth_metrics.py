"""Depth accuracy of a run against the simulator's ground truth.

How the ground truth is brought to the rectified left view (where the depth map lives): every
rectified-left pixel is mapped back to its REAL pixel (``pair.rectified_to_real``), that pixel's exact ray
through the prism is traced, and the ground-truth point is where this ray meets the scene:

- with the :class:`~prismstereo.simulate.Scene` at hand (demo, tables, tests), by intersecting the ray
  with the scene exactly (:func:`~prismstereo.simulate.intersect_scene`), so there is no interpolation;
- with only the simulator's ``depth_gt.pfm`` (world Z per real pixel), by interpolating Z bilinearly at the
  fractional real pixel where its four neighbours agree to 0.5 % (no depth edge there) and taking the
  ray's point at that Z.

The estimate is compared by its world Z: relative error ``|Z − Z_gt| / Z_gt``.

The COMMON VIEW is the set of rectified-left pixels (inside the ROI and the left view's valid region)
whose ground-truth point (a) lies within the run's depth range, (b) is seen through the right face by a
real pixel inside the image, with nothing in front of it (the right pixel's own ray hits the same point
within 0.1 %), and (c) falls inside the valid region of the rectified right view. Coverage is the share
of the common view that has a reconstructed point.

An all-view run (``views="all"``) has its depth on the real capture's grid: its pixels are their own real
pixels, the region is the reference face's, (b) asks for at least one of the other faces, and there is no
rectified right view for (c).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

import numpy as np

from prismstereo.config import Rig
from prismstereo.depth.pipeline import DepthRun
from prismstereo.errors import ConfigError
from prismstereo.io import read_pfm
from prismstereo.optics import project_exact, trace_pixels
from prismstereo.simulate import intersect_scene

__all__ = ["DepthGroundTruth", "depth_accuracy", "evaluate_depth", "format_accuracy", "ground_truth_for_run",
           "read_depth_gt"]


@dataclass(frozen=True)
class DepthGroundTruth:
    """Ground truth on the rectified left grid.

    Attributes
    ----------
    points : (h, w, 3) float64
        Scene point seen by each rectified-left pixel, world frame, mm; NaN where none.
    common : (h, w) bool
        The common view (see the module docstring).
    """

    points: np.ndarray
    common: np.ndarray

    @property
    def depth(self) -> np.ndarray:
        """(h, w) world Z of the ground-truth points, mm."""
        return self.points[..., 2]


def read_depth_gt(path: str | os.PathLike[str], rig: Rig) -> np.ndarray:
    """Read a ground-truth depth map (simulate's ``depth_gt.pfm``: world Z in mm per real pixel, NaN none).

    Raises
    ------
    ConfigError
        If the map's size is not the rig's sensor size.
    """
    depth_gt = read_pfm(path)
    if depth_gt.shape != (rig.camera.height, rig.camera.width):
        raise ConfigError(f"ground_truth: expected a {rig.camera.width}×{rig.camera.height} depth map, got "
                          f"{depth_gt.shape[1]}×{depth_gt.shape[0]}")
    return np.asarray(depth_gt, dtype=np.float64)


def _bilinear_depth(depth_gt: np.ndarray, px: np.ndarray, *, agree: float = 0.005) -> np.ndarray:
    h, w = depth_gt.shape
    u, v = px[:, 0], px[:, 1]
    ok = np.isfinite(u) & np.isfinite(v) & (u >= 0) & (v >= 0) & (u <= w - 1) & (v <= h - 1)
    out = np.full(px.shape[0], np.nan)
    if not ok.any():
        return out
    uu, vv = u[ok], v[ok]
    u0 = np.minimum(np.floor(uu).astype(np.int64), w - 2)
    v0 = np.minimum(np.floor(vv).astype(np.int64), h - 2)
    fu, fv = uu - u0, vv - v0
    z00 = depth_gt[v0, u0].astype(np.float64)
    z01 = depth_gt[v0, u0 + 1].astype(np.float64)
    z10 = depth_gt[v0 + 1, u0].astype(np.float64)
    z11 = depth_gt[v0 + 1, u0 + 1].astype(np.float64)
    stack = np.stack([z00, z01, z10, z11], axis=1)
    z = (1 - fv) * ((1 - fu) * z00 + fu * z01) + fv * ((1 - fu) * z10 + fu * z11)
    with np.errstate(invalid="ignore"):
        spread = (np.max(stack, axis=1) - np.min(stack, axis=1)) / np.min(stack, axis=1)
    z = np.where(np.isfinite(spread) & (spread <= agree), z, np.nan)
    out[ok] = z
    return out


def _gt_points(rig: Any, real_px: np.ndarray, *, scene: Any = None, depth_gt: np.ndarray | None = None
               ) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        rays = trace_pixels(rig, np.nan_to_num(real_px, nan=-1e6))
    n = real_px.shape[0]
    pts = np.full((n, 3), np.nan)
    ok = rays.valid & np.all(np.isfinite(real_px), axis=1)
    if not ok.any():
        return pts
    if scene is not None:
        hits = intersect_scene(rays.origins[ok], rays.directions[ok], scene, shading=0.0)
        pts[ok] = hits.points
    elif depth_gt is not None:
        z = _bilinear_depth(np.asarray(depth_gt, dtype=np.float64), real_px[ok])
        s = (z - rays.origins[ok, 2]) / rays.directions[ok, 2]
        pts[ok] = rays.origins[ok] + s[:, None] * rays.directions[ok]
    else:
        raise ValueError("expected a scene or a ground-truth depth map, got neither")
    return pts


def ground_truth_for_run(result: DepthRun, *, scene: Any = None, depth_gt: np.ndarray | None = None
                         ) -> DepthGroundTruth:
    """Ground truth of a finished :class:`~prismstereo.depth.DepthRun` on its grid.

    Parameters
    ----------
    result : DepthRun
    scene : Scene, optional
        The simulated scene (exact ground truth).
    depth_gt : (H, W) array, optional
        World Z per real pixel, mm, NaN where none (the simulator's ``depth_gt.pfm``).
    """
    rig, pair = result.rig, result.pair
    if pair is not None:
        # every valid left pixel of the ROI (not the pipeline's own common-view estimate: no circularity)
        region = np.asarray(pair.valid_masks()[0], dtype=bool).copy()
        h, w = region.shape
        if result.config.roi is not None:
            x, y, rw, rh = result.config.roi
            roi = np.zeros((h, w), dtype=bool)
            roi[y:y + rh, x:x + rw] = True
            region &= roi
        other_faces: tuple[int, ...] = (int(pair.right_face),)
    else:  # all views: the reference face's region (geometry only)
        region = np.asarray(result.roi_mask, dtype=bool)
        h, w = region.shape
        other_faces = tuple(int(f) for f in result.faces[1:])
    ys, xs = np.nonzero(region)
    left_px = np.stack([xs, ys], axis=1).astype(np.float64)
    real_l = result.grid_to_real(left_px)
    gt = _gt_points(rig, real_l, scene=scene, depth_gt=depth_gt)
    points = np.full((h, w, 3), np.nan)
    points[ys, xs] = gt

    # (a) inside the depth range
    zmin, zmax = result.depth_range
    z = gt[:, 2]
    with np.errstate(invalid="ignore"):
        cand = np.isfinite(z) & (z >= zmin) & (z <= zmax)
    common = np.zeros((h, w), dtype=bool)
    idx = np.flatnonzero(cand)
    if idx.size:
        # (b) seen through another face, inside the image, unoccluded
        ok = np.zeros(idx.size, dtype=bool)
        for face in other_faces:
            ok |= _seen_through(rig, face, gt[idx], scene=scene, depth_gt=depth_gt)
        # (c) inside the rectified right view (rectified right camera projection)
        sub = np.flatnonzero(ok)
        if sub.size and pair is not None:
            P = np.asarray(pair.P_right, dtype=np.float64)
            X = np.concatenate([gt[idx[sub]], np.ones((sub.size, 1))], axis=1) @ P.T
            xr = X[:, 0] / X[:, 2]
            yr = X[:, 1] / X[:, 2]
            vr = np.asarray(pair.valid_masks()[1], dtype=bool)
            ri, ci = np.rint(yr).astype(np.int64), np.rint(xr).astype(np.int64)
            inb = (ri >= 0) & (ri < vr.shape[0]) & (ci >= 0) & (ci < vr.shape[1])
            inb[inb] &= vr[ri[inb], ci[inb]]
            ok[sub] = inb
        common[ys[idx[ok]], xs[idx[ok]]] = True
    return DepthGroundTruth(points=points, common=common)


#: points projected per call in :func:`_seen_through`: the exact projection traces five rays per point with
#: several (N, 3) float64 temporaries each, about 1.5 kB per point at once (10 GB for a 12-megapixel capture)
_PROJECT_BLOCK = 1 << 18


def _seen_through(rig: Rig, face: int, target: np.ndarray, *, scene: Any, depth_gt: np.ndarray | None
                  ) -> np.ndarray:
    """(N,) bool: the points are seen through ``face`` by a real pixel inside the image, unoccluded."""
    if target.shape[0] > _PROJECT_BLOCK:  # in blocks: the same answer per point, bounded memory
        return np.concatenate([_seen_through(rig, face, target[i:i + _PROJECT_BLOCK], scene=scene, depth_gt=depth_gt)
                               for i in range(0, target.shape[0], _PROJECT_BLOCK)])
    pr, ok = project_exact(rig, target, face=face)
    W, H = rig.camera.width, rig.camera.height
    ok &= (pr[:, 0] >= 0) & (pr[:, 0] <= W - 1) & (pr[:, 1] >= 0) & (pr[:, 1] <= H - 1)
    sub = np.flatnonzero(ok)
    if sub.size:
        seen = _gt_points(rig, pr[sub], scene=scene, depth_gt=depth_gt)
        tgt = target[sub]
        err = np.linalg.norm(seen - tgt, axis=1) / np.linalg.norm(tgt, axis=1)
        if scene is None:  # depth maps are float32: allow for their rounding
            vis = np.abs(seen[:, 2] - tgt[:, 2]) / tgt[:, 2] < 0.005
        else:
            vis = err < 1e-3
        ok[sub] = np.where(np.isfinite(err), vis, False)
    return np.asarray(ok, dtype=bool)


def depth_accuracy(depth: np.ndarray, valid: np.ndarray, gt: DepthGroundTruth) -> dict[str, Any]:
    """Relative depth error statistics of a depth map against ground truth.

    Parameters
    ----------
    depth : (h, w) array — estimated world Z, mm.
    valid : (h, w) bool — reconstructed pixels.
    gt : DepthGroundTruth

    Returns
    -------
    dict with ``median_rel``, ``p95_rel``, ``mean_rel`` (fractions), ``within_1pct`` (share of
    reconstructed points within 1 %), ``coverage`` (share of the common view reconstructed),
    ``mean_abs_mm``, ``n_points`` (reconstructed with ground truth), ``n_common``.
    """
    zgt = gt.depth
    m = np.asarray(valid, dtype=bool) & np.isfinite(zgt) & np.isfinite(depth)
    rel = np.abs(depth[m].astype(np.float64) - zgt[m]) / zgt[m]
    n_common = int(gt.common.sum())
    if rel.size == 0:
        return {"median_rel": float("nan"), "p95_rel": float("nan"), "mean_rel": float("nan"),
                "within_1pct": 0.0, "coverage": 0.0, "mean_abs_mm": float("nan"), "n_points": 0,
                "n_common": n_common}
    cov = float((gt.common & np.asarray(valid, dtype=bool)).sum() / n_common) if n_common else 0.0
    return {
        "median_rel": float(np.median(rel)),
        "p95_rel": float(np.percentile(rel, 95)),
        "mean_rel": float(np.mean(rel)),
        "within_1pct": float(np.mean(rel <= 0.01)),
        "coverage": cov,
        "mean_abs_mm": float(np.mean(np.abs(depth[m].astype(np.float64) - zgt[m]))),
        "n_points": int(rel.size),
        "n_common": n_common,
    }


def evaluate_depth(result: DepthRun, *, scene: Any = None, depth_gt: np.ndarray | None = None,
                   gt: DepthGroundTruth | None = None) -> dict[str, Any]:
    """Accuracy of a finished run (pair or all views) against the simulator's ground truth.

    Give ``scene`` (exact), ``depth_gt`` (simulate's ``depth_gt.pfm``) or an already computed ``gt``
    (:func:`ground_truth_for_run`). The run's ``run.json`` records it when the caller attaches it:
    ``dataclasses.replace(result, accuracy=evaluate_depth(result, ...))``.

    Returns
    -------
    dict
        :func:`depth_accuracy`'s statistics (fractions) and ``ground_truth``: how it was found.
    """
    if gt is None:
        gt = ground_truth_for_run(result, scene=scene, depth_gt=depth_gt)
    acc = depth_accuracy(result.depth, result.valid, gt)
    acc["ground_truth"] = "scene rays (exact)" if scene is not None else "depth_gt map (bilinear)"
    return acc


def format_accuracy(acc: dict[str, Any]) -> str:
    """The four accuracy lines the demo prints."""
    return "\n".join([
        f"median relative depth error: {100 * acc['median_rel']:.3f} %",
        f"95th percentile relative depth error: {100 * acc['p95_rel']:.3f} %",
        f"points within 1 %: {100 * acc['within_1pct']:.1f} % of {acc['n_points']}",
        f"coverage of the common view: {100 * acc['coverage']:.1f} % of {acc['n_common']} px",
    ])
