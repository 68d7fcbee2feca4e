"""Numba passes of the sub-pixel left–right check (:mod:`prismstereo.depth.confidence`): one pass over the map
each, the same values as the numpy formulas they replace (index arrays of every finite pixel, fancy-indexed
reads and scatters, ``np.maximum.at``), row by row in parallel (a pixel writes only into its own row).

The arithmetic follows numpy's types exactly: ``x − d`` of an integer column and a float32 disparity is
float64 (numpy's and numba's promotion alike), its rounding ``rint`` (half to even) and ``floor``; the
interpolation weights of :func:`lr_gap` are float32, as numpy computes them from a float32 fraction.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

__all__ = ["lr_gap", "mirror", "read_by_check", "seen_from_right"]


@njit(cache=True, parallel=True)
def seen_from_right(d: np.ndarray) -> np.ndarray:  # pragma: no cover - numba
    """(H, W) float32: the finite values of the float32 (H, W) map ``d`` at their right pixels
    ``rint(x − d)``, the largest where several land on one pixel (a tie keeps the first in row order, as
    ``np.maximum.at``), NaN where none lands."""
    h, w = d.shape
    out = np.empty((h, w), dtype=np.float32)
    for y in prange(h):
        for x in range(w):
            out[y, x] = -np.inf
        for x in range(w):
            v = d[y, x]
            if not np.isfinite(v):
                continue
            xr = np.int64(np.rint(x - v))
            if 0 <= xr < w and v > out[y, xr]:
                out[y, xr] = v
        for x in range(w):
            if out[y, x] == -np.inf:
                out[y, x] = np.nan
    return out


@njit(cache=True, parallel=True)
def read_by_check(d: np.ndarray, where: np.ndarray) -> np.ndarray:  # pragma: no cover - numba
    """(H, W) bool: ``floor(x − d)`` and the next pixel of every finite ``d`` (float32 (H, W)) where ``where``
    ((H, W) bool) holds, inside the row."""
    h, w = d.shape
    out = np.zeros((h, w), dtype=np.bool_)
    for y in prange(h):
        for x in range(w):
            v = d[y, x]
            if not where[y, x] or not np.isfinite(v):
                continue
            x0 = np.int64(np.floor(x - v))
            if 0 <= x0 < w:
                out[y, x0] = True
            if 0 <= x0 + 1 < w:
                out[y, x0 + 1] = True
    return out


@njit(cache=True, parallel=True)
def lr_gap(d: np.ndarray, d_right: np.ndarray) -> np.ndarray:  # pragma: no cover - numba
    """(H, W) float32 ``|d(x) − d_right(x − d(x))|`` of two float32 (H, W) maps, ``d_right`` interpolated
    linearly between ``floor(x − d)`` and the next pixel (the finite one where the other is NaN), NaN where
    either is missing or the pair of pixels leaves the row."""
    h, w = d.shape
    out = np.empty((h, w), dtype=np.float32)
    one = np.float32(1.0)
    for y in prange(h):
        for x in range(w):
            out[y, x] = np.nan
            v = d[y, x]
            if not np.isfinite(v):
                continue
            xq = x - v
            x0 = np.int64(np.floor(xq))
            if x0 < 0 or x0 + 1 >= w:
                continue
            t = np.float32(xq - x0)
            a = d_right[y, x0]
            b = d_right[y, x0 + 1]
            if np.isfinite(a) and np.isfinite(b):
                dr = (one - t) * a + t * b
            elif np.isfinite(a):
                dr = a
            else:
                dr = b
            out[y, x] = np.abs(v - dr)
    return out


def mirror(a: np.ndarray) -> np.ndarray:
    """A C-contiguous copy of the (H, W) or (H, W, C) array ``a`` with its columns reversed (a right view becomes
    a left one): ``np.ascontiguousarray(a[:, ::-1])``, an (H, W, C) one in one parallel pass (numpy's copy of
    the reversed pixels is 2–3× slower there; of an (H, W) map it is the faster one)."""
    if a.ndim == 3:
        return _mirror3(a)
    return np.ascontiguousarray(a[:, ::-1])


@njit(cache=True, parallel=True)
def _mirror3(a: np.ndarray) -> np.ndarray:  # pragma: no cover - numba
    h, w, c = a.shape
    out = np.empty((h, w, c), dtype=a.dtype)
    for y in prange(h):
        for x in range(w):
            for k in range(c):
                out[y, w - 1 - x, k] = a[y, x, k]
    return out
