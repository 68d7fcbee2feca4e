"""The epipolar curves of a rectified pair of prism views: the row offset of a match, from exact refraction.

A face of a prism is not a pinhole (thesis §3.1.3): the rectification turns the views' fitted pinholes to a
common orientation, so a scene point's two rectified images lie on the same row only where the pinholes fit
the faces exactly. Elsewhere the match of the left pixel (x, y) at disparity d lies at (x − d, y + δy) in the
right view, with δy(x, y, d) a smooth function known from the optics: the scene point on the left pixel's
exact ray (traced through the left face, :func:`~prismstereo.optics.trace_pixels`) at the depth that gives
disparity d, projected through the right face (:func:`~prismstereo.optics.project_exact`) and into the
rectified right view through the pair's own remap table (the one the right image was made with).

:class:`EpipolarTable` holds δy on a coarse grid of left pixels × regularly spaced disparities, for a lookup
by trilinear interpolation; :func:`epipolar_table` builds it once per rectified pair.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit, prange
from scipy.ndimage import distance_transform_edt

from prismstereo.optics import project_exact, trace_pixels
from prismstereo.rectify.rectification import RectifiedPair

__all__ = ["EpipolarTable", "epipolar_table"]

#: farthest depth sampled, mm (the row offset changes little beyond)
_FAR_MM = 20000.0


@dataclass(frozen=True, eq=False)
class EpipolarTable:
    """Row offset δy of the match of a rectified-left pixel, on a grid of pixels × disparities.

    Attributes
    ----------
    offsets : (n_d, gh, gw) float32
        δy (right row − left row, px) at left pixel ``(i·step, j·step)`` (row i, column j) and disparity
        ``d_start + k·d_step`` (layer k).
    step : int
        Grid spacing of the left pixels, px.
    d_start, d_step : float
        Disparity of the first layer and the spacing of the layers, px.
    """

    offsets: np.ndarray
    step: int
    d_start: float
    d_step: float

    def row_offset(self, ys: np.ndarray, xs: np.ndarray, d: np.ndarray) -> np.ndarray:
        """(N,) float64 δy of left pixels ``(xs, ys)`` matched at disparities ``d`` (trilinear; pixels and
        disparities beyond the table take its nearest entries; NaN where ``d`` is not finite)."""
        dd = np.asarray(d, dtype=np.float64).ravel()
        yy = np.broadcast_to(np.asarray(ys, dtype=np.float64), np.shape(d)).ravel()
        xx = np.broadcast_to(np.asarray(xs, dtype=np.float64), np.shape(d)).ravel()
        out = _trilinear(self.offsets, np.ascontiguousarray(yy), np.ascontiguousarray(xx), dd,
                         float(self.step), float(self.d_start), float(self.d_step))
        return out.reshape(np.shape(d))

    def row_offset_map(self, disparity: np.ndarray) -> np.ndarray:
        """(H, W) float32 δy of every pixel of a left disparity map (NaN where it is NaN)."""
        d = np.asarray(disparity)
        out = np.full(d.shape, np.nan, dtype=np.float32)
        ys, xs = np.nonzero(np.isfinite(d))
        out[ys, xs] = self.row_offset(ys, xs, d[ys, xs])
        return out

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The table as plain arrays (for an ``.npz``; :meth:`from_arrays` reads them back)."""
        return {"epi_offsets": self.offsets, "epi_grid": np.array([self.step, self.d_start, self.d_step])}

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> EpipolarTable:
        grid = np.asarray(arrays["epi_grid"], dtype=np.float64)
        return cls(offsets=np.asarray(arrays["epi_offsets"], dtype=np.float32), step=int(grid[0]),
                   d_start=float(grid[1]), d_step=float(grid[2]))


@njit(cache=True, inline="always")
def _clamped(c: float, n: int) -> tuple[int, float]:  # pragma: no cover - numba
    """Cell and fraction of coordinate ``c`` on a grid of ``n`` samples, clamped to the grid (the edge value
    beyond it: scipy's ``map_coordinates(order=1, mode="nearest")``)."""
    c = min(max(c, 0.0), float(n - 1))
    i = min(int(np.floor(c)), max(n - 2, 0))
    return i, c - i


@njit(cache=True, parallel=True, nogil=True)
def _trilinear(grid: np.ndarray, ys: np.ndarray, xs: np.ndarray, d: np.ndarray, step: float, d_start: float,
               d_step: float) -> np.ndarray:  # pragma: no cover - numba
    """(N,) float64 trilinear lookup of ``grid[k, i, j]`` at k = (d − d_start) / d_step, i = y / step,
    j = x / step (clamped to the grid); NaN where ``d`` is not finite."""
    nk, ni, nj = grid.shape
    out = np.empty(d.size)
    for n in prange(d.size):
        if not np.isfinite(d[n]):
            out[n] = np.nan
            continue
        k, fk = _clamped((d[n] - d_start) / d_step, nk)
        i, fi = _clamped(ys[n] / step, ni)
        j, fj = _clamped(xs[n] / step, nj)
        k1, i1, j1 = min(k + 1, nk - 1), min(i + 1, ni - 1), min(j + 1, nj - 1)
        v = 0.0
        for a, wa in ((k, 1.0 - fk), (k1, fk)):
            for b, wb in ((i, 1.0 - fi), (i1, fi)):
                v += wa * wb * ((1.0 - fj) * float(grid[a, b, j]) + fj * float(grid[a, b, j1]))
        out[n] = v
    return out


def _right_rectified(pair: RectifiedPair, real_px: np.ndarray, iterations: int = 2) -> np.ndarray:
    """(N, 2) rectified-right pixels of real pixels through the pair's right remap table: the model's inverse
    (:meth:`RectifiedPair.real_to_rectified`), then Newton steps on the table itself (the table is what made
    the right image; it is interpolated between its solved points)."""
    rect = pair.real_to_rectified(real_px, "right")
    eps = 0.05
    for _ in range(iterations):
        q = pair.rectified_to_real(rect, "right")
        jx = (pair.rectified_to_real(rect + [eps, 0.0], "right") - q) / eps
        jy = (pair.rectified_to_real(rect + [0.0, eps], "right") - q) / eps
        r = q - real_px
        det = jx[:, 0] * jy[:, 1] - jy[:, 0] * jx[:, 1]
        with np.errstate(divide="ignore", invalid="ignore"):
            sx = (jy[:, 1] * r[:, 0] - jy[:, 0] * r[:, 1]) / det
            sy = (jx[:, 0] * r[:, 1] - jx[:, 1] * r[:, 0]) / det
        rect = rect - np.stack([sx, sy], axis=1)
    return rect


def _resample(d: np.ndarray, dy: np.ndarray, ok: np.ndarray, layers: np.ndarray) -> np.ndarray:
    """(n_layers, n) offsets at the disparities ``layers`` of each column's valid samples ``(d, dy)[ok]``
    (linear between samples, the end samples' values beyond them: ``np.interp`` per column, vectorised);
    NaN for a column without any."""
    order = np.argsort(np.where(ok, d, np.inf), axis=0)
    ds = np.take_along_axis(np.where(ok, d, np.inf), order, axis=0)
    ys = np.take_along_axis(dy, order, axis=0)
    cnt = ok.sum(axis=0)
    last = np.maximum(cnt - 1, 0)[None, :]
    above = (ds[None, :, :] <= layers[:, None, None]).sum(axis=1)  # valid samples at or below each layer
    i0 = np.clip(above - 1, 0, last)
    i1 = np.clip(above, 0, last)
    d0, d1 = np.take_along_axis(ds, i0, axis=0), np.take_along_axis(ds, i1, axis=0)
    y0, y1 = np.take_along_axis(ys, i0, axis=0), np.take_along_axis(ys, i1, axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        t = np.where(d1 > d0, (layers[:, None] - d0) / (d1 - d0), 0.0)
    out = y0 + np.clip(t, 0.0, 1.0) * (y1 - y0)
    return np.where(cnt[None, :] > 0, out, np.nan)


def epipolar_table(pair: RectifiedPair, *, step: int = 16, n_depths: int = 32, n_layers: int = 48
                   ) -> EpipolarTable:
    """Tabulate the row offset of matches of a rectified pair (module docstring).

    Parameters
    ----------
    pair : RectifiedPair
        With its rig (exact refraction) and remap tables.
    step : int
        Grid spacing of the left pixels, px.
    n_depths : int
        Depths sampled along each grid pixel's ray (uniform in inverse depth from just beyond the prism's
        back plane to 20 m).
    n_layers : int
        Regularly spaced disparities the offsets are resampled to (over the disparities the samples span,
        up to the image width).

    Returns
    -------
    EpipolarTable
    """
    rig = pair.rig
    w, h = pair.size
    gx = np.arange(0, w - 1 + step, step, dtype=np.float64)
    gy = np.arange(0, h - 1 + step, step, dtype=np.float64)
    xs, ys = np.meshgrid(gx, gy)
    px = np.stack([xs.ravel(), ys.ravel()], axis=1)
    n = px.shape[0]
    real_l = pair.rectified_to_real(px, "left")
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        rays = trace_pixels(rig, np.nan_to_num(real_l, nan=-1e6), face=int(pair.left_face), bounded=False)
        depths = 1.0 / np.linspace(1.0 / (rig.prism.back_distance * 1.02), 1.0 / _FAR_MM, n_depths)
        pts = rays.point_at_depth(depths[:, None]).reshape(-1, 3)  # (n_depths · n, 3)
        real_r, _ = project_exact(rig, pts, face=int(pair.right_face))
        rect_r = _right_rectified(pair, real_r)
    d = (np.tile(px[:, 0], n_depths) - rect_r[:, 0]).reshape(n_depths, n)
    dy = (rect_r[:, 1] - np.tile(px[:, 1], n_depths)).reshape(n_depths, n)
    ok = np.isfinite(d) & np.isfinite(dy) & np.isfinite(real_l[:, 0])[None, :] & (d > -w) & (d < 2 * w)
    if not ok.any():
        return EpipolarTable(offsets=np.zeros((1, gy.size, gx.size), np.float32), step=step, d_start=0.0,
                             d_step=1.0)
    lo, hi = float(np.min(d[ok])), min(float(np.max(d[ok])), float(w))
    layers = np.linspace(lo, hi, n_layers) if hi > lo else np.array([lo])
    grid = _resample(d, dy, ok, layers).reshape(layers.size, gy.size, gx.size)
    # grid pixels without a sample (outside the left view) take their nearest sampled neighbour's offsets,
    # so that the interpolation next to the view's edge is not pulled towards an arbitrary value
    missing = ~np.isfinite(grid[0])
    if missing.any():
        idx = distance_transform_edt(missing, return_distances=False, return_indices=True)
        grid = grid[:, idx[0], idx[1]]
    d_step = float(layers[1] - layers[0]) if layers.size > 1 else 1.0
    return EpipolarTable(offsets=grid.astype(np.float32), step=step, d_start=float(layers[0]), d_step=d_step)
