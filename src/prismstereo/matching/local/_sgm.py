"""Numba kernels of :mod:`prismstereo.matching.local.sgm` (imported lazily, so registering ``sgm`` loads no numba)."""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from prismstereo.matching.local.costs import popcount64

__all__ = ["census_codes", "census_kernel", "check_row", "edge_p2", "path_step", "select_kernel", "sgm_kernel",
           "sgm_select_kernel"]

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
    count update. Used at the image's borders (:func:`_four_updates` inside)."""
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


@njit(cache=True)
def path_step(p: np.ndarray, k: int, x: int, d: int, q1: int, jump: int) -> int:  # pragma: no cover - numba
    """min(L(d), L(d±1) + P1, min L + P2) of path ``k`` at ``x`` for an inner disparity ``d``, in the work
    type: each sum wrapped back to it (no sum overflows it, :func:`_pad_layout`), so that the minima are taken
    on its lanes (numba widens a sum of two int16 to int64: 4× fewer lanes).

    A plain ``njit`` function that LLVM inlines, NOT numba's ``inline="always"``: inlined at numba's IR level
    (array arguments inside the loop), it left a call in :func:`_four_updates`'s loop when LLVM's vectoriser
    ran ("call instruction cannot be vectorized"), so that loop ran one disparity at a time."""
    t = p.dtype.type
    return min(min(p[k, x, d], t(p[k, x, d - 1] + q1)), min(t(p[k, x, d + 1] + q1), jump))


@njit(cache=True)
def _end(p: np.ndarray, k: int, x: int, d: int, e: int, q1: int, jump: int) -> int:  # pragma: no cover - numba
    """The same at an end ``d`` of the range, whose one neighbour is ``e``."""
    t = p.dtype.type
    return min(min(p[k, x, d], t(p[k, x, e] + q1)), jump)


@njit(cache=True, inline="always")
def _four_updates(c: np.ndarray, hor: np.ndarray, hs: int, hmin: int, prev: np.ndarray, pmin: np.ndarray,
                  cur: np.ndarray, cmin: np.ndarray, x: int, s: int, p1: int, j: tuple[int, int, int, int],
                  acc: np.ndarray) -> int:  # pragma: no cover - numba
    """The four path updates of an inner pixel (every predecessor inside the image) in ONE pass over the
    disparities: the horizontal path from ``hor[hs]`` into ``hor[1 - hs]``, the diagonal from behind, the
    vertical and the diagonal from ahead from ``prev[k, x + (k - 1)·s]`` into ``cur[k, x]``; ``acc`` = their sum
    (the same values as four :func:`_path_update` calls: integer sums wrap alike in any order). ``j``: the
    jumps ``min + P2'`` of the four paths. Sets ``cmin[k, x]``; returns the horizontal path's min."""
    nd = c.shape[0]
    t = acc.dtype.type
    q1 = t(p1)
    xa, xc = x - s, x + s
    mh, ma, mb, mc = t(hmin), t(pmin[0, xa]), t(pmin[1, x]), t(pmin[2, xc])
    jh, ja, jb, jc = t(j[0]), t(j[1]), t(j[2]), t(j[3])
    h0 = 1 - hs
    vh = t(_end(hor, hs, 0, 0, 1, q1, jh) - mh + c[0])
    va = t(_end(prev, 0, xa, 0, 1, q1, ja) - ma + c[0])
    vb = t(_end(prev, 1, x, 0, 1, q1, jb) - mb + c[0])
    vc = t(_end(prev, 2, xc, 0, 1, q1, jc) - mc + c[0])
    hor[h0, 0, 0] = vh
    cur[0, x, 0] = va
    cur[1, x, 0] = vb
    cur[2, x, 0] = vc
    acc[0] = t(vh + va + vb + vc)
    bh, ba, bb, bc = vh, va, vb, vc
    for d in range(1, nd - 1):
        cd = c[d]
        vh = t(path_step(hor, hs, 0, d, q1, jh) - mh + cd)
        va = t(path_step(prev, 0, xa, d, q1, ja) - ma + cd)
        vb = t(path_step(prev, 1, x, d, q1, jb) - mb + cd)
        vc = t(path_step(prev, 2, xc, d, q1, jc) - mc + cd)
        hor[h0, 0, d] = vh
        cur[0, x, d] = va
        cur[1, x, d] = vb
        cur[2, x, d] = vc
        acc[d] = t(vh + va + vb + vc)
        bh, ba, bb, bc = min(bh, vh), min(ba, va), min(bb, vb), min(bc, vc)
    e = nd - 1
    vh = t(_end(hor, hs, 0, e, e - 1, q1, jh) - mh + c[e])
    va = t(_end(prev, 0, xa, e, e - 1, q1, ja) - ma + c[e])
    vb = t(_end(prev, 1, x, e, e - 1, q1, jb) - mb + c[e])
    vc = t(_end(prev, 2, xc, e, e - 1, q1, jc) - mc + c[e])
    hor[h0, 0, e] = vh
    cur[0, x, e] = va
    cur[1, x, e] = vb
    cur[2, x, e] = vc
    acc[e] = t(vh + va + vb + vc)
    cmin[0, x] = int(min(ba, va))
    cmin[1, x] = int(min(bb, vb))
    cmin[2, x] = int(min(bc, vc))
    return int(min(bh, vh))


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
def edge_p2(gray: np.ndarray, y: int, x: int, y0: int, x0: int, p1: int, p2: int,
            gamma: float) -> int:  # pragma: no cover - numba
    """The edge-adaptive penalty ``P2' = max(P1, P2 / (1 + |I(y, x) - I(y0, x0)| / γ))`` of a path step from
    (y0, x0) to (y, x); ``gamma`` 0: ``P2``."""
    if gamma <= 0.0:
        return p2
    return max(p1, int(p2 / (1.0 + abs(gray[y, x] - gray[y0, x0]) / gamma)))


@njit(cache=True, inline="always")
def _select_pixel(srow: np.ndarray, best: int | np.int32, y: int, x: int, min_disp: int, uniqueness: int,
                  subpixel: bool, leftward: bool, rbest: np.ndarray, rarg: np.ndarray, disp: np.ndarray,
                  win: np.ndarray, code: np.ndarray) -> None:  # pragma: no cover - numba
    """WTA of the aggregated costs ``srow`` (minimum ``best``) of pixel (y, x), its uniqueness test and parabola
    sub-pixel into ``disp``, ``win``, ``code``; the right view's WTA along the diagonal (right pixel
    ``x - min_disp - i``) into the row's ``rbest``, ``rarg``: the smallest x wins a tie, also when the row's
    pixels come ``leftward`` (from the right end)."""
    nd = srow.shape[0]
    # the first winner: the smallest index holding the minimum, as a branch-free min reduction (SIMD) rather
    # than a scan that stops at it
    bi = nd
    for i in range(nd):
        bi = min(bi, i if srow[i] == best else nd)
    for i in range(min(nd, x - min_disp + 1)):
        xr = x - min_disp - i
        v = srow[i]
        take = (v < rbest[xr]) | (leftward & (v == rbest[xr]))
        rbest[xr] = min(v, rbest[xr])
        rarg[xr] = i if take else rarg[xr]
    win[y, x] = bi
    if uniqueness > 0:
        # some cost not adjacent to the winner within the margin: the smallest of them is (the factor
        # 100 - uniqueness is positive), a min reduction on the int32 lanes
        big = np.int32(1 << 30)
        far = big
        for i in range(nd):
            far = min(far, srow[i] if (i < bi - 1) | (i > bi + 1) else big)
        if np.int64(far) * (100 - uniqueness) < np.int64(best) * 100:
            code[y, x] = 1
    d = float(bi)
    if subpixel and 0 < bi < nd - 1:
        cm, cp = srow[bi - 1], srow[bi + 1]
        den = cm + cp - 2 * best
        if den > 0:
            d += (cm - cp) / (2.0 * den)
    disp[y, x] = d + min_disp


@njit(cache=True, inline="always")
def check_row(y: int, min_disp: int, tolerance: int, rarg: np.ndarray, disp: np.ndarray, win: np.ndarray,
              code: np.ndarray) -> None:  # pragma: no cover - numba
    """The left–right check of row ``y`` against the right view's winners ``rarg``; NaN where rejected."""
    for x in range(disp.shape[1]):
        xr = x - min_disp - win[y, x]
        if xr < 0 or abs(rarg[xr] - win[y, x]) > tolerance:
            if code[y, x] == 0:
                code[y, x] = 2
        if code[y, x] != 0:
            disp[y, x] = np.nan


@njit(cache=True)
def _sgm_scan(cost: np.ndarray, gray: np.ndarray, p1: int, p2: int, gamma: float, forward: bool, yi0: int,
              yi1: int, state: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
              out: np.ndarray, select: tuple[int, int, int, bool], maps: tuple[np.ndarray, np.ndarray, np.ndarray],
              combine: bool) -> None:  # pragma: no cover - numba
    """Rows ``yi0 .. yi1 - 1`` (in scan order) of four of the eight paths in one raster scan (forward or
    backward).

    ``state`` = (path costs of the last two rows ``(2, 3, W, Dp)``, their minima ``(2, 3, W)``, the horizontal
    path ``(2, 1, Dp)``, the pixel's padded cost ``(Dp,)``, the four paths' sum ``(Dp,)``), carried from one call
    to the next, so that a scan can run in parts. ``combine`` False: the four paths' sum goes to ``out[y, x]``;
    True: ``out[y, x]`` holds the other scan's sum, and the pixel is selected on the total (``select`` =
    (min_disp, uniqueness, tolerance, subpixel), into ``maps`` = (disparity, winner, reject code)).

    The path costs are held with the state's length and dtype (:func:`sgm_kernel`): the disparities beyond
    the volume's are padding whose cost is too large to be anyone's minimum, so every path update runs whole
    SIMD vectors (the volume's 75 disparities would leave a scalar tail of 11 per path); the pixel's cost
    buffer holds that padding beyond the volume's disparities."""
    h, w, nd0 = cost.shape
    rows, mins, hor, c, acc = state
    min_disp, uniqueness, tolerance, subpixel = select
    disp, win, code = maps
    s = 1 if forward else -1
    srow = np.empty(nd0, dtype=np.int32)
    rbest = np.empty(w, dtype=np.int32)
    rarg = np.zeros(w, dtype=np.int32)
    for yi in range(yi0, yi1):
        y = yi if forward else h - 1 - yi
        cur, prev = rows[yi % 2], rows[1 - yi % 2]
        cur_min, prev_min = mins[yi % 2], mins[1 - yi % 2]
        yp = y - s
        if combine:
            rbest[:] = 1 << 30
        hmin = 0
        for xi in range(w):
            x = xi if forward else w - 1 - xi
            for d in range(nd0):
                c[d] = cost[y, x, d]
            hs = xi % 2
            if xi > 0 and yi > 0 and 0 < x < w - 1:
                jumps = (hmin + edge_p2(gray, y, x, y, x - s, p1, p2, gamma),
                         prev_min[0, x - s] + edge_p2(gray, y, x, yp, x - s, p1, p2, gamma),
                         prev_min[1, x] + edge_p2(gray, y, x, yp, x, p1, p2, gamma),
                         prev_min[2, x + s] + edge_p2(gray, y, x, yp, x + s, p1, p2, gamma))
                hmin = _four_updates(c, hor, hs, hmin, prev, prev_min, cur, cur_min, x, s, p1, jumps, acc)
            else:
                acc[:] = 0
                # horizontal path (from x - s)
                if xi == 0:
                    hmin = _path_start(c, hor, 1 - hs, 0, acc)
                else:
                    hmin = _path_update(c, hor, hs, 0, hmin, p1, edge_p2(gray, y, x, y, x - s, p1, p2, gamma), hor,
                                        1 - hs, 0, acc)
                # diagonal from behind (x - s), vertical (x), diagonal from ahead (x + s)
                for k in range(3):
                    xp = x + (k - 1) * s
                    if yi == 0 or xp < 0 or xp >= w:
                        cur_min[k, x] = _path_start(c, cur, k, x, acc)
                    else:
                        cur_min[k, x] = _path_update(c, prev, k, xp, prev_min[k, xp], p1,
                                                     edge_p2(gray, y, x, yp, xp, p1, p2, gamma), cur, k, x, acc)
            if combine:
                # the two scans' uint16 sums added as int32, as sgm_select adds fwd and bwd
                best = np.int32(1 << 30)
                for d in range(nd0):
                    v = np.int32(np.uint16(acc[d])) + np.int32(out[y, x, d])
                    srow[d] = v
                    best = min(best, v)
                _select_pixel(srow, best, y, x, min_disp, uniqueness, subpixel, not forward, rbest, rarg, disp,
                              win, code)
            else:
                for d in range(nd0):
                    out[y, x, d] = acc[d]
        if combine:
            check_row(y, min_disp, tolerance, rarg, disp, win, code)


@njit(cache=True, inline="always")
def _pad_layout(cost: np.ndarray, cost_max: int, p2: int) -> tuple[int, int, bool]:  # pragma: no cover - numba
    """(padding cost, padded length, int16 work) of a volume whose largest cost is ``cost_max`` (the caller's
    one pass over it, not a second, serial one here): a path cost is at most max cost + P2 (``top``);
    padding disparities cost ``2·top + 1``, so that a padded neighbour plus P1 never beats the jump
    ``min + P2``; the inner loop of a path update runs whole vectors of 16; int16 work while four padded path
    costs fit it, else int32 (the same values)."""
    nd = cost.shape[2]
    top = cost_max + p2
    pad = 2 * top + 1
    ndp = max(nd, 3)
    while (ndp - 2) % 16 != 0:
        ndp += 1
    return pad, ndp, 4 * (pad + p2) <= 32767


@njit(cache=True, inline="always")
def _state(w: int, ndp: int, pad: int, like: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                                                  np.ndarray]:  # pragma: no cover - numba
    """A scan's zeroed state (:func:`_sgm_scan`) in the work dtype of ``like``."""
    t = like.dtype
    return (np.zeros((2, 3, w, ndp), dtype=t), np.zeros((2, 3, w), dtype=np.int32), np.zeros((2, 1, ndp), dtype=t),
            np.full(ndp, pad, dtype=t), np.zeros(ndp, dtype=t))


@njit(cache=True, parallel=True)
def sgm_kernel(cost: np.ndarray, gray: np.ndarray, p1: int, p2: int, gamma: float,
               cost_max: int) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - numba
    """The two raster scans of :func:`_sgm_scan`, one thread each: (forward, backward) uint16 path sums;
    ``cost_max``: the volume's largest cost (0 if empty)."""
    h, w, nd = cost.shape
    pad, ndp, small = _pad_layout(cost, cost_max, p2)
    fwd = np.empty((h, w, nd), dtype=np.uint16)
    bwd = np.empty((h, w, nd), dtype=np.uint16)
    maps = (np.empty((0, 0), np.float32), np.empty((0, 0), np.int32), np.empty((0, 0), np.uint8))
    for k in prange(2):  # the two scans are independent: one thread each
        out = fwd if k == 0 else bwd
        if small:
            _sgm_scan(cost, gray, p1, p2, gamma, k == 0, 0, h, _state(w, ndp, pad, np.zeros(0, np.int16)), out,
                      (0, 0, 0, False), maps, False)
        else:
            _sgm_scan(cost, gray, p1, p2, gamma, k == 0, 0, h, _state(w, ndp, pad, np.zeros(0, np.int32)), out,
                      (0, 0, 0, False), maps, False)
    return fwd, bwd


@njit(cache=True)
def _two_halves(cost: np.ndarray, gray: np.ndarray, p1: int, p2: int, gamma: float, forward: bool, phase: int,
                states: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray], half: np.ndarray,
                select: tuple[int, int, int, bool],
                maps: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:  # pragma: no cover - numba
    """One scan's part of :func:`sgm_select_kernel`: phase 0 its first half of the rows into ``half``, phase 1
    the rest, selected on the sum with the other scan's first half."""
    h = cost.shape[0]
    first = h // 2 if forward else h - h // 2  # rows of the scan's first half: the forward one starts at the top
    if phase == 0:
        _sgm_scan(cost, gray, p1, p2, gamma, forward, 0, first, states, half, select, maps, False)
    else:
        _sgm_scan(cost, gray, p1, p2, gamma, forward, first, h, states, half, select, maps, True)


@njit(cache=True, parallel=True)
def _halves(cost: np.ndarray, gray: np.ndarray, p1: int, p2: int, gamma: float, half: np.ndarray,
            select: tuple[int, int, int, bool], maps: tuple[np.ndarray, np.ndarray, np.ndarray],
            fwd_state: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
            bwd_state: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]) -> None:  # pragma: no cover
    for phase in range(2):  # the second phase reads what the other thread wrote in the first
        for k in prange(2):
            _two_halves(cost, gray, p1, p2, gamma, k == 0, phase, fwd_state if k == 0 else bwd_state, half, select,
                        maps)


@njit(cache=True)
def sgm_select_kernel(cost: np.ndarray, gray: np.ndarray, p1: int, p2: int, gamma: float, cost_max: int,
                      min_disp: int, uniqueness: int, tolerance: int,
                      subpixel: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - numba
    """:func:`select_kernel` of :func:`sgm_kernel`'s two sums, the same maps, without holding both sums
    (``cost_max`` as there).

    Each scan (one thread each) first runs its half of the rows (the forward one the top half, the backward
    one the bottom half) and keeps their sums in one uint16 volume; then each runs on into the other's half,
    adds the stored sums to its own pixel by pixel and selects the pixel, a row's left–right check at the
    row's end. So both threads select, and the aggregated volume is never written whole."""
    h, w, nd = cost.shape
    pad, ndp, small = _pad_layout(cost, cost_max, p2)
    half = np.empty((h, w, nd), dtype=np.uint16)
    maps = (np.empty((h, w), dtype=np.float32), np.empty((h, w), dtype=np.int32), np.zeros((h, w), dtype=np.uint8))
    select = (min_disp, uniqueness, tolerance, subpixel)
    if small:
        like = np.zeros(0, np.int16)
        _halves(cost, gray, p1, p2, gamma, half, select, maps, _state(w, ndp, pad, like), _state(w, ndp, pad, like))
    else:
        wide = np.zeros(0, np.int32)
        _halves(cost, gray, p1, p2, gamma, half, select, maps, _state(w, ndp, pad, wide), _state(w, ndp, pad, wide))
    return maps


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
            # the sum and its minimum in one pass without branches (SIMD)
            best = np.int32(1 << 30)
            for i in range(nd):
                v = np.int32(np.int32(fwd[y, x, i]) + np.int32(bwd[y, x, i]))
                srow[i] = v
                best = min(best, v)
            _select_pixel(srow, best, y, x, min_disp, uniqueness, subpixel, False, rbest, rarg, disp, win, code)
        check_row(y, min_disp, tolerance, rarg, disp, win, code)
    return disp, win, code
