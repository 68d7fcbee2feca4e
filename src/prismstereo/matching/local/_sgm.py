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
def _path_update(c: np.ndarray, prev: np.ndarray, pk: int, px: int, pmin: int, p1: int, p2: int, dst: np.ndarray,
                 dk: int, dx: int, acc: np.ndarray) -> int:  # pragma: no cover - numba
    """One step of the path recursion for all disparities, from ``prev[pk, px]`` into ``dst[dk, dx]``; adds
    the result to ``acc``; returns its min. Indices rather than row views: a view per call costs a reference
    count update, and this runs four times per pixel."""
    nd = c.shape[0]
    t = acc.dtype.type  # the work type (int16: twice the SIMD lanes of int32)
    m = t(pmin)
    q1 = t(p1)
    jump = t(pmin + p2)
    # the ends of the range apart, so that the loop over the inner disparities has no branches (SIMD);
    # the minimum is taken in the same pass (a vectorised min reduction)
    v = t(min(min(prev[pk, px, 0], prev[pk, px, 1] + q1), jump) - m + c[0])
    dst[dk, dx, 0] = v
    acc[0] += v
    best = v
    for d in range(1, nd - 1):
        v = t(min(min(prev[pk, px, d], prev[pk, px, d - 1] + q1), min(prev[pk, px, d + 1] + q1, jump)) - m + c[d])
        dst[dk, dx, d] = v
        acc[d] += v
        best = min(best, v)
    v = t(min(min(prev[pk, px, nd - 1], prev[pk, px, nd - 2] + q1), jump) - m + c[nd - 1])
    dst[dk, dx, nd - 1] = v
    acc[nd - 1] += v
    best = min(best, v)
    return int(best)


@njit(cache=True, inline="always")
def _path_start(c: np.ndarray, dst: np.ndarray, dk: int, dx: int, acc: np.ndarray) -> int:  # pragma: no cover
    best = c[0]
    for d in range(c.shape[0]):
        v = c[d]
        dst[dk, dx, d] = v
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
              out: np.ndarray, work: np.ndarray, pad: int) -> None:  # pragma: no cover - numba
    """Four of the eight paths in one raster scan (forward or backward); sums them into ``out``.

    The path costs are held with ``work``'s length and dtype (:func:`sgm_kernel`): the disparities beyond
    the volume's are padding whose cost ``pad`` is too large to be anyone's minimum, so every path update
    runs whole SIMD vectors (the volume's 75 disparities would leave a scalar tail of 11 per path)."""
    h, w, nd0 = cost.shape
    nd = work.shape[0]
    s = 1 if forward else -1
    c = np.full(nd, pad, dtype=work.dtype)  # the pixel's cost, padded
    prev = np.zeros((3, w, nd), dtype=work.dtype)  # path costs of the previous row: diag-behind, vertical, diag-ahead
    cur = np.zeros((3, w, nd), dtype=work.dtype)
    prev_min = np.zeros((3, w), dtype=np.int32)
    cur_min = np.zeros((3, w), dtype=np.int32)
    hor = np.zeros((2, 1, nd), dtype=work.dtype)
    acc = np.zeros(nd, dtype=work.dtype)
    for yi in range(h):
        y = yi if forward else h - 1 - yi
        hmin = 0
        for xi in range(w):
            x = xi if forward else w - 1 - xi
            for d in range(nd0):
                c[d] = cost[y, x, d]
            acc[:] = 0
            # horizontal path (from x - s)
            hs = xi % 2
            if xi == 0:
                hmin = _path_start(c, hor, 1 - hs, 0, acc)
            else:
                hmin = _path_update(c, hor, hs, 0, hmin, p1, _p2(gray, y, x, y, x - s, p1, p2, gamma), hor, 1 - hs,
                                    0, acc)
            if yi == 0:
                for k in range(3):
                    cur_min[k, x] = _path_start(c, cur, k, x, acc)
            else:
                yp = y - s
                # diagonal from behind (x - s), vertical (x), diagonal from ahead (x + s)
                for k in range(3):
                    xp = x + (k - 1) * s
                    if xp < 0 or xp >= w:
                        cur_min[k, x] = _path_start(c, cur, k, x, acc)
                    else:
                        cur_min[k, x] = _path_update(c, prev, k, xp, prev_min[k, xp], p1,
                                                     _p2(gray, y, x, yp, xp, p1, p2, gamma), cur, k, x, acc)
            for d in range(nd0):
                out[y, x, d] = acc[d]
        prev, cur = cur, prev
        prev_min, cur_min = cur_min, prev_min


@njit(cache=True, parallel=True)
def sgm_kernel(cost: np.ndarray, gray: np.ndarray, p1: int, p2: int,
               gamma: float) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - numba
    """The two raster scans of :func:`_sgm_scan`, one thread each: (forward, backward) uint16 path sums.

    A path cost is at most max cost + P2 (``top``); padding disparities cost ``2·top + 1``, so that a padded
    neighbour plus P1 never beats the jump ``min + P2``; int16 work while four padded path costs fit it,
    else int32 (the same values)."""
    h, w, nd = cost.shape
    top = int(cost.max()) + p2 if cost.size else p2
    pad = 2 * top + 1
    ndp = max(nd, 3)
    while (ndp - 2) % 16 != 0:  # the inner loop of a path update in whole vectors of 16
        ndp += 1
    fwd = np.empty((h, w, nd), dtype=np.uint16)
    bwd = np.empty((h, w, nd), dtype=np.uint16)
    small = 4 * (pad + p2) <= 32767
    for k in prange(2):  # the two scans are independent: one thread each
        if small:
            _sgm_scan(cost, gray, p1, p2, gamma, k == 0, fwd if k == 0 else bwd, np.zeros(ndp, np.int16), pad)
        else:
            _sgm_scan(cost, gray, p1, p2, gamma, k == 0, fwd if k == 0 else bwd, np.zeros(ndp, np.int32), pad)
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
            # the sum, its minimum and the first disparity that reaches it, in passes without branches (SIMD)
            best = np.int32(1 << 30)
            for i in range(nd):
                v = np.int32(np.int32(fwd[y, x, i]) + np.int32(bwd[y, x, i]))
                srow[i] = v
                best = min(best, v)
            bi = 0
            while srow[bi] != best:
                bi += 1
            # the right view's WTA along the diagonal (right pixel x - min_disp - i): the first x wins a tie
            for i in range(min(nd, x - min_disp + 1)):
                xr = x - min_disp - i
                v = srow[i]
                take = v < rbest[xr]
                rbest[xr] = min(v, rbest[xr])
                rarg[xr] = i if take else rarg[xr]
            win[y, x] = bi
            if uniqueness > 0:
                lim = np.int64(best) * 100
                fail = 0
                for i in range(nd):
                    fail |= int(((i < bi - 1) | (i > bi + 1)) & (np.int64(srow[i]) * (100 - uniqueness) < lim))
                if fail:
                    code[y, x] = 1
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
