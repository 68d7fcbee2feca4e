"""Numba kernels of :mod:`prismstereo.matching.local.sgm` (imported lazily, so registering ``sgm`` loads no numba)."""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from prismstereo.matching.local.costs import popcount64

__all__ = ["census_codes", "census_kernel", "select_kernel", "sgm_kernel"]

@njit(cache=True, parallel=True)
def census_codes(padded: np.ndarray, ry: int, rx: int) -> np.ndarray:  # pragma: no cover - numba
    """Census codes of an edge-padded float32 image (``ry``, ``rx`` border), bit for bit those of
    ``costs.census_transform``: one bit per window pixel darker than the centre, row-major."""
    h, w = padded.shape[0] - 2 * ry, padded.shape[1] - 2 * rx
    out = np.empty((h, w), dtype=np.uint64)
    for y in prange(h):
        for x in range(w):
            c = padded[y + ry, x + rx]
            code = np.uint64(0)
            for dy in range(2 * ry + 1):
                for dx in range(2 * rx + 1):
                    if dy == ry and dx == rx:
                        continue
                    code = (code << np.uint64(1)) | np.uint64(padded[y + dy, x + dx] < c)
            out[y, x] = code
    return out


@njit(cache=True, parallel=True)
def census_kernel(cl: np.ndarray, cr: np.ndarray, gl: np.ndarray, gr: np.ndarray, min_disp: int, nd: int,
                   scale: int, grad_weight: float, grad_tau: float, invalid: int) -> np.ndarray:  # pragma: no cover
    """uint16 (H, W, D): ``scale·Hamming(cl, cr) + grad_weight·min(|gl - gr|, τ)`` per disparity."""
    h, w = cl.shape
    out = np.empty((h, w, nd), dtype=np.uint16)
    for y in prange(h):
        for x in range(w):
            a = cl[y, x]
            g = gl[y, x]
            for i in range(nd):
                xr = x - min_disp - i
                if xr < 0:
                    out[y, x, i] = invalid
                else:
                    c = scale * popcount64(a ^ cr[y, xr])
                    if grad_weight > 0.0:
                        c += int(grad_weight * min(abs(g - gr[y, xr]), grad_tau) + 0.5)
                    out[y, x, i] = c
    return out


@njit(cache=True, inline="always")
def _path_update(c: np.ndarray, prev: np.ndarray, pmin: int, p1: int, p2: int, dst: np.ndarray,
                 acc: np.ndarray) -> int:  # pragma: no cover - numba
    """One step of the path recursion for all disparities; adds the result to ``acc``; returns its min."""
    nd = c.shape[0]
    # int32 throughout: twice the SIMD lanes of numba's default int64
    m = np.int32(pmin)
    q1 = np.int32(p1)
    jump = np.int32(pmin + p2)
    if nd == 1:
        v = np.int32(c[0])
        dst[0] = v
        acc[0] += v
        return int(v)
    # the ends of the range apart, so that the loop over the inner disparities has no branches (SIMD)
    # the minimum is taken in the same pass (a vectorised min reduction; the same value as a second pass)
    v = min(min(prev[0], prev[1] + q1), jump) - m + np.int32(c[0])
    dst[0] = v
    acc[0] += v
    best = np.int32(v)
    for d in range(1, nd - 1):
        v = min(min(prev[d], prev[d - 1] + q1), min(prev[d + 1] + q1, jump)) - m + np.int32(c[d])
        dst[d] = v
        acc[d] += v
        best = min(best, np.int32(v))
    v = min(min(prev[nd - 1], prev[nd - 2] + q1), jump) - m + np.int32(c[nd - 1])
    dst[nd - 1] = v
    acc[nd - 1] += v
    best = min(best, np.int32(v))
    return int(best)


@njit(cache=True, inline="always")
def _path_start(c: np.ndarray, dst: np.ndarray, acc: np.ndarray) -> int:  # pragma: no cover - numba
    best = np.int32(c[0])
    for d in range(c.shape[0]):
        v = np.int32(c[d])
        dst[d] = v
        acc[d] += v
        best = min(best, v)
    return int(best)


@njit(cache=True, inline="always")
def _p2(gray: np.ndarray, y: int, x: int, y0: int, x0: int, p1: int, p2: int, gamma: float) -> int:  # pragma: no cover
    if gamma <= 0.0:
        return p2
    return max(p1, int(p2 / (1.0 + abs(gray[y, x] - gray[y0, x0]) / gamma)))


@njit(cache=True)
def _sgm_scan(cost: np.ndarray, gray: np.ndarray, p1: int, p2: int, gamma: float, forward: bool,
              out: np.ndarray) -> None:  # pragma: no cover - numba
    """Four of the eight paths in one raster scan (forward or backward); sums them into ``out``."""
    h, w, nd = cost.shape
    s = 1 if forward else -1
    prev = np.zeros((3, w, nd), dtype=np.int32)  # path costs of the previous row: diag-behind, vertical, diag-ahead
    cur = np.zeros((3, w, nd), dtype=np.int32)
    prev_min = np.zeros((3, w), dtype=np.int32)
    cur_min = np.zeros((3, w), dtype=np.int32)
    hor = np.zeros((2, nd), dtype=np.int32)
    acc = np.zeros(nd, dtype=np.int32)
    for yi in range(h):
        y = yi if forward else h - 1 - yi
        hmin = 0
        for xi in range(w):
            x = xi if forward else w - 1 - xi
            c = cost[y, x]
            acc[:] = 0
            # horizontal path (from x - s)
            hs, hd = hor[xi % 2], hor[(xi + 1) % 2]
            if xi == 0:
                hmin = _path_start(c, hd, acc)
            else:
                hmin = _path_update(c, hs, hmin, p1, _p2(gray, y, x, y, x - s, p1, p2, gamma), hd, acc)
            if yi == 0:
                for k in range(3):
                    cur_min[k, x] = _path_start(c, cur[k, x], acc)
            else:
                yp = y - s
                # diagonal from behind (x - s), vertical (x), diagonal from ahead (x + s)
                for k in range(3):
                    xp = x + (k - 1) * s
                    if xp < 0 or xp >= w:
                        cur_min[k, x] = _path_start(c, cur[k, x], acc)
                    else:
                        cur_min[k, x] = _path_update(c, prev[k, xp], prev_min[k, xp], p1,
                                                     _p2(gray, y, x, yp, xp, p1, p2, gamma), cur[k, x], acc)
            o = out[y, x]
            for d in range(nd):
                o[d] = acc[d]
        prev, cur = cur, prev
        prev_min, cur_min = cur_min, prev_min


@njit(cache=True, parallel=True)
def sgm_kernel(cost: np.ndarray, gray: np.ndarray, p1: int, p2: int,
               gamma: float) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - numba
    h, w, nd = cost.shape
    fwd = np.empty((h, w, nd), dtype=np.uint16)
    bwd = np.empty((h, w, nd), dtype=np.uint16)
    for k in prange(2):  # the two scans are independent: one thread each
        if k == 0:
            _sgm_scan(cost, gray, p1, p2, gamma, True, fwd)
        else:
            _sgm_scan(cost, gray, p1, p2, gamma, False, bwd)
    return fwd, bwd


@njit(cache=True, parallel=True)
def select_kernel(fwd: np.ndarray, bwd: np.ndarray, min_disp: int, uniqueness: int, tolerance: int,
                   subpixel: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - numba
    """WTA + uniqueness + parabola sub-pixel on ``fwd + bwd``; right view's WTA along the diagonals; L–R check.

    Returns (disparity float32 with NaN where rejected, the integer winner, the reject code: 0 kept,
    1 uniqueness, 2 left–right).
    """
    h, w, nd = fwd.shape
    disp = np.empty((h, w), dtype=np.float32)
    win = np.empty((h, w), dtype=np.int32)
    code = np.zeros((h, w), dtype=np.uint8)
    for y in prange(h):
        srow = np.empty(nd, dtype=np.int32)
        rbest = np.full(w, 1 << 30, dtype=np.int32)
        rarg = np.zeros(w, dtype=np.int32)
        for x in range(w):
            best = 1 << 30
            bi = 0
            for i in range(nd):
                v = int(fwd[y, x, i]) + int(bwd[y, x, i])
                srow[i] = v
                if v < best:
                    best = v
                    bi = i
                xr = x - min_disp - i
                if xr >= 0 and v < rbest[xr]:
                    rbest[xr] = v
                    rarg[xr] = i
            win[y, x] = bi
            if uniqueness > 0:
                for i in range(nd):
                    if (i < bi - 1 or i > bi + 1) and srow[i] * (100 - uniqueness) < best * 100:
                        code[y, x] = 1
                        break
            d = float(bi)
            if subpixel and 0 < bi < nd - 1:
                cm, cp = srow[bi - 1], srow[bi + 1]
                den = cm + cp - 2 * best
                if den > 0:
                    d += (cm - cp) / (2.0 * den)
            disp[y, x] = d + min_disp
        for x in range(w):
            xr = x - min_disp - win[y, x]
            if xr < 0 or abs(rarg[xr] - win[y, x]) > tolerance:
                if code[y, x] == 0:
                    code[y, x] = 2
            if code[y, x] != 0:
                disp[y, x] = np.nan
    return disp, win, code
