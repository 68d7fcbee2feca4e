"""Numba kernels of semi-global matching within a per-pixel disparity band (:mod:`prismstereo.matching.local.sgm`,
``SGMMatcher.compute_banded``), after Rothermel et al.'s tSGM (2012): each pixel searches only its own index range
``[lo, hi]`` of the volume, and a path's recursion reads the predecessor's costs only inside the predecessor's
range (outside it they count as unreachable: a change of disparity there costs ``P2``).

With every band the whole range, the maps are those of :func:`~prismstereo.matching.local._sgm.sgm_kernel` and
:func:`~prismstereo.matching.local._sgm.select_kernel` (tested). The volumes are ragged: pixel (y, x)'s costs
and path sums are the ``hi - lo + 1`` entries from ``off[y, x]`` of one flat array (``off``: the running sum of
the band widths in raster order), so time and memory follow pixels × band, not pixels × range. The work is
int32. The kernels release the GIL (``nogil``): a stream's reader and writer threads run meanwhile.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from prismstereo.matching.local._sgm import check_row, edge_p2, path_step
from prismstereo.matching.local.costs import popcount64

__all__ = ["census_band_kernel", "select_band_kernel", "sgm_band_kernel"]

@njit(cache=True, parallel=True, nogil=True)
def census_band_kernel(cl: np.ndarray, cr: np.ndarray, gl: np.ndarray, gr: np.ndarray, min_disp: int,
                       blo: np.ndarray, bhi: np.ndarray, off: np.ndarray, total: int, scale: int, grad_weight: float,
                       grad_tau: float, invalid: int) -> np.ndarray:  # pragma: no cover - numba
    """uint16 (total,) ragged volume: :func:`~prismstereo.matching.local._sgm.census_kernel`'s costs at the
    indices ``blo[y, x] .. bhi[y, x]`` of each pixel, from ``off[y, x]``."""
    h, w = cl.shape
    out = np.empty(total, dtype=np.uint16)
    for y in prange(h):
        for x in range(w):
            a = cl[y, x]
            g = gl[y, x]
            base = off[y, x] - blo[y, x]
            for i in range(blo[y, x], bhi[y, x] + 1):
                xr = x - min_disp - i
                if xr < 0:
                    out[base + i] = invalid
                else:
                    c = scale * popcount64(a ^ cr[y, xr])
                    if grad_weight > 0.0:
                        c += int(grad_weight * min(abs(g - gr[y, xr]), grad_tau) + 0.5)
                    out[base + i] = c
    return out


@njit(cache=True, inline="always")
def _band_start(cost: np.ndarray, base: int, lo: int, hi: int, dst: np.ndarray, dk: int, dx: int,
                acc: np.ndarray) -> int:  # pragma: no cover - numba
    """A path's first pixel: its costs (``cost[base + d]``) into ``dst[dk, dx, 1 + d]``, added to ``acc``;
    returns their min."""
    t = acc.dtype.type
    best = 1 << 30
    for d in range(lo, hi + 1):
        v = t(cost[base + d])
        dst[dk, dx, d + 1] = v
        acc[d] = t(acc[d] + v)
        best = min(best, int(v))
    return best


@njit(cache=True, inline="always")
def _fence(src: np.ndarray, sk: int, sx: int, lo: int, hi: int, qlo: int, qhi: int,
           pad: int) -> None:  # pragma: no cover - numba
    """Set the predecessor's path costs ``src[sk, sx, 1 + d]`` that a pixel of band ``lo .. hi`` reads
    (``d = lo - 1 .. hi + 1``) outside the predecessor's own band ``qlo .. qhi`` to ``pad`` (unreachable), so
    that the recursion over the band reads no mask. Each stored path row is read by one pixel only (the next
    pixel along its path), so writing into it is safe."""
    t = src.dtype.type
    for d in range(lo - 1, min(hi + 1, qlo - 1) + 1):
        src[sk, sx, d + 1] = t(pad)
    for d in range(max(lo - 1, qhi + 1), hi + 2):
        src[sk, sx, d + 1] = t(pad)


@njit(cache=True, inline="always")
def _band_update(cost: np.ndarray, base: int, lo: int, hi: int, src: np.ndarray, sk: int, sx: int, qlo: int,
                 qhi: int, qmin: int, p1: int, p2: int, pad: int, dst: np.ndarray, dk: int, dx: int,
                 acc: np.ndarray) -> int:  # pragma: no cover - numba
    """One step of the path recursion over the pixel's band ``lo .. hi`` (costs ``cost[base + d]``) from the
    predecessor's path costs ``src[sk, sx, 1 + d]`` (its band ``qlo .. qhi``, min ``qmin``) into
    ``dst[dk, dx, 1 + d]``; adds them to ``acc``; returns their min. Used at the image's borders."""
    _fence(src, sk, sx, lo, hi, qlo, qhi, pad)
    t = acc.dtype.type
    q1 = t(p1)
    m = t(qmin)
    jump = t(qmin + p2)
    best = 1 << 30
    for d in range(lo, hi + 1):
        v = t(path_step(src, sk, sx, d + 1, q1, jump) - m + t(cost[base + d]))
        dst[dk, dx, d + 1] = v
        acc[d] = t(acc[d] + v)
        best = min(best, int(v))
    return best


@njit(cache=True)
def _ustep(p: np.ndarray, k: int, x: int, i: np.uint64, q1: int, jump: int) -> int:  # pragma: no cover - numba
    """:func:`~prismstereo.matching.local._sgm.path_step` at the unsigned index ``i``: numba checks a signed index
    for a negative (wrap-around) value, an unsigned one not, so that LLVM vectorises a loop over a band whose
    start is known only at run time."""
    t = p.dtype.type
    one = np.uint64(1)
    return min(min(p[k, x, i], t(p[k, x, i - one] + q1)), min(t(p[k, x, i + one] + q1), jump))


@njit(cache=True, inline="always")
def _four_band(cost: np.ndarray, base: int, lo: int, hi: int, hor: np.ndarray, hs: int, hmin: int,
               prev: np.ndarray, pmin: np.ndarray, cur: np.ndarray, cmin: np.ndarray, x: int, s: int, p1: int,
               j: tuple[int, int, int, int], pad: int, c: np.ndarray, acc: np.ndarray) -> int:  # pragma: no cover
    """The four path updates of an inner pixel in one pass over its band (the fences set), as
    :func:`~prismstereo.matching.local._sgm._four_updates`: the pixel's costs ``c[d]`` and the sum into ``acc[d]``
    (work-type buffers: one element type in the loop, which LLVM then vectorises). Sets ``cmin[k, x]``;
    returns the horizontal path's min."""
    t = hor.dtype.type
    q1 = t(p1)
    xa, xc = x - s, x + s
    mh, ma, mb, mc = t(hmin), t(pmin[0, xa]), t(pmin[1, x]), t(pmin[2, xc])
    jh, ja, jb, jc = t(j[0]), t(j[1]), t(j[2]), t(j[3])
    h0 = 1 - hs
    bh, ba, bb, bc = t(pad), t(pad), t(pad), t(pad)  # above every path cost
    one = np.uint64(1)
    for d in range(np.uint64(lo), np.uint64(hi + 1)):
        i = d + one
        cd = c[d]
        vh = t(_ustep(hor, hs, 0, i, q1, jh) - mh + cd)
        va = t(_ustep(prev, 0, xa, i, q1, ja) - ma + cd)
        vb = t(_ustep(prev, 1, x, i, q1, jb) - mb + cd)
        vc = t(_ustep(prev, 2, xc, i, q1, jc) - mc + cd)
        hor[h0, 0, i] = vh
        cur[0, x, i] = va
        cur[1, x, i] = vb
        cur[2, x, i] = vc
        acc[d] = t(vh + va + vb + vc)
        bh, ba, bb, bc = min(bh, vh), min(ba, va), min(bb, vb), min(bc, vc)
    cmin[0, x] = int(ba)
    cmin[1, x] = int(bb)
    cmin[2, x] = int(bc)
    return int(bh)


@njit(cache=True, nogil=True)
def _band_scan(cost: np.ndarray, gray: np.ndarray, blo: np.ndarray, bhi: np.ndarray, off: np.ndarray, nd: int,
               p1: int, p2: int, gamma: float, pad: int, forward: bool, out: np.ndarray,
               like: np.ndarray) -> None:  # pragma: no cover - numba
    """Four of the eight paths in one raster scan (forward: left, up-left, up, up-right; backward: the
    opposite four) over the ragged volume ``cost`` of ``nd`` disparities, their sum per pixel and band index
    into ``out`` (uint16, laid out as ``cost``); path costs in ``like``'s dtype (int16 where they fit)."""
    h, w = blo.shape
    t = like.dtype
    rows = np.zeros((2, 3, w, nd + 2), dtype=t)
    mins = np.zeros((2, 3, w), dtype=np.int32)
    hor = np.zeros((2, 1, nd + 2), dtype=t)
    acc = np.zeros(nd, dtype=t)
    c = np.zeros(nd, dtype=t)
    s = 1 if forward else -1
    for yi in range(h):
        y = yi if forward else h - 1 - yi
        cur, prev = rows[yi % 2], rows[1 - yi % 2]
        cur_min, prev_min = mins[yi % 2], mins[1 - yi % 2]
        yp = y - s
        hmin = 0
        for xi in range(w):
            x = xi if forward else w - 1 - xi
            lo, hi = int(blo[y, x]), int(bhi[y, x])
            base = int(off[y, x]) - lo
            hs = xi % 2
            if xi > 0 and yi > 0 and 0 < x < w - 1:
                xa, xc = x - s, x + s
                _fence(hor, hs, 0, lo, hi, int(blo[y, xa]), int(bhi[y, xa]), pad)
                _fence(prev, 0, xa, lo, hi, int(blo[yp, xa]), int(bhi[yp, xa]), pad)
                _fence(prev, 1, x, lo, hi, int(blo[yp, x]), int(bhi[yp, x]), pad)
                _fence(prev, 2, xc, lo, hi, int(blo[yp, xc]), int(bhi[yp, xc]), pad)
                jumps = (hmin + edge_p2(gray, y, x, y, xa, p1, p2, gamma),
                         prev_min[0, xa] + edge_p2(gray, y, x, yp, xa, p1, p2, gamma),
                         prev_min[1, x] + edge_p2(gray, y, x, yp, x, p1, p2, gamma),
                         prev_min[2, xc] + edge_p2(gray, y, x, yp, xc, p1, p2, gamma))
                ub = np.uint64(base)
                for d in range(np.uint64(lo), np.uint64(hi + 1)):
                    c[d] = cost[ub + d]
                hmin = _four_band(cost, base, lo, hi, hor, hs, hmin, prev, prev_min, cur, cur_min, x, s, p1, jumps,
                                  pad, c, acc)
                for d in range(np.uint64(lo), np.uint64(hi + 1)):
                    out[ub + d] = acc[d]
                continue
            for d in range(lo, hi + 1):
                acc[d] = 0
            if xi == 0:
                hmin = _band_start(cost, base, lo, hi, hor, 1 - hs, 0, acc)
            else:
                xq = x - s
                hmin = _band_update(cost, base, lo, hi, hor, hs, 0, int(blo[y, xq]), int(bhi[y, xq]), hmin, p1,
                                    edge_p2(gray, y, x, y, xq, p1, p2, gamma), pad, hor, 1 - hs, 0, acc)
            for k in range(3):
                xq = x + (k - 1) * s
                if yi == 0 or xq < 0 or xq >= w:
                    cur_min[k, x] = _band_start(cost, base, lo, hi, cur, k, x, acc)
                else:
                    cur_min[k, x] = _band_update(cost, base, lo, hi, prev, k, xq, int(blo[yp, xq]),
                                                 int(bhi[yp, xq]), prev_min[k, xq], p1,
                                                 edge_p2(gray, y, x, yp, xq, p1, p2, gamma), pad, cur, k, x, acc)
            for d in range(lo, hi + 1):
                out[base + d] = np.uint16(acc[d])


@njit(cache=True, parallel=True, nogil=True)
def sgm_band_kernel(cost: np.ndarray, gray: np.ndarray, blo: np.ndarray, bhi: np.ndarray, off: np.ndarray, nd: int,
                    p1: int, p2: int, gamma: float, cost_max: int) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover
    """The two raster scans of :func:`_band_scan`, one thread each: (forward, backward) uint16 path sums, ragged
    as ``cost``; ``cost_max``: the largest cost the volume can hold. Path costs are int16 where four of them
    and the unreachable value fit (:func:`~prismstereo.matching.local._sgm._pad_layout`'s rule), else int32."""
    top = cost_max + p2
    pad = 2 * top + 1  # a neighbour at pad plus P1 never beats the jump min + P2
    small = 4 * (pad + p2) <= 32767
    fwd = np.empty(cost.size, dtype=np.uint16)
    bwd = np.empty(cost.size, dtype=np.uint16)
    for k in prange(2):  # the two scans are independent: one thread each
        out = fwd if k == 0 else bwd
        if small:
            _band_scan(cost, gray, blo, bhi, off, nd, p1, p2, gamma, pad, k == 0, out, np.zeros(0, np.int16))
        else:
            _band_scan(cost, gray, blo, bhi, off, nd, p1, p2, gamma, pad, k == 0, out, np.zeros(0, np.int32))
    return fwd, bwd


@njit(cache=True, parallel=True, nogil=True)
def select_band_kernel(fwd: np.ndarray, bwd: np.ndarray, blo: np.ndarray, bhi: np.ndarray, off: np.ndarray, nd: int,
                       min_disp: int, uniqueness: int, tolerance: int,
                       subpixel: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - numba
    """:func:`~prismstereo.matching.local._sgm.select_kernel` over each pixel's band: WTA, uniqueness (against
    the band's costs), parabola sub-pixel (inside the band), the right view's WTA along the diagonals of the
    bands, left–right check. Returns (disparity float32, NaN where rejected; winner index; reject code)."""
    h, w = blo.shape
    disp = np.empty((h, w), dtype=np.float32)
    win = np.empty((h, w), dtype=np.int32)
    code = np.zeros((h, w), dtype=np.uint8)
    big = np.int32(1 << 30)
    for y in prange(h):
        srow = np.empty(nd, dtype=np.int32)
        rbest = np.full(w, 1 << 30, dtype=np.int32)
        rarg = np.zeros(w, dtype=np.int32)
        for x in range(w):
            lo, hi = int(blo[y, x]), int(bhi[y, x])
            # unsigned indices: no wrap-around test, so that the loops over the band vectorise (_ustep)
            ulo, uhi, ub = np.uint64(lo), np.uint64(hi + 1), np.uint64(int(off[y, x]) - lo)
            best = big
            for u in range(ulo, uhi):
                v = np.int32(np.int32(fwd[ub + u]) + np.int32(bwd[ub + u]))
                srow[u] = v
                best = min(best, v)
            bi = np.int64(hi + 1)
            for u in range(ulo, uhi):
                bi = min(bi, np.int64(u) if srow[u] == best else np.int64(hi + 1))
            for i in range(lo, min(hi, x - min_disp) + 1):
                xr = x - min_disp - i
                v = srow[i]
                take = v < rbest[xr]
                rbest[xr] = min(v, rbest[xr])
                rarg[xr] = i if take else rarg[xr]
            win[y, x] = bi
            if uniqueness > 0:
                far = big
                for u in range(ulo, uhi):
                    iu = np.int64(u)
                    far = min(far, srow[u] if (iu < bi - 1) | (iu > bi + 1) else big)
                if np.int64(far) * (100 - uniqueness) < np.int64(best) * 100:
                    code[y, x] = 1
            d = float(bi)
            if subpixel and lo < bi < hi:
                cm, cp = srow[bi - 1], srow[bi + 1]
                den = cm + cp - 2 * best
                if den > 0:
                    d += (cm - cp) / (2.0 * den)
            disp[y, x] = d + min_disp
        check_row(y, min_disp, tolerance, rarg, disp, win, code)
    return disp, win, code
