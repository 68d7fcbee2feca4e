"""Numba kernel of the bilateral weighted median (imported lazily, so box matchers need no numba)."""

from __future__ import annotations

import numba
import numpy as np
from numba import njit, prange

#: colour-distance lookup resolution (entries per ΔE unit) and range (ΔE)
_LUT_STEP = 4.0
_LUT_MAX = 256.0


@njit(cache=True, fastmath=True, nogil=True)
def _median_pixel(out: np.ndarray, finite: np.ndarray, bins: np.ndarray, lab: np.ndarray,
                  y: int, x: int, radius: int, spatial: np.ndarray, lut: np.ndarray, hist: np.ndarray,
                  kbuf: np.ndarray, dmin: float) -> None:  # pragma: no cover - numba
    """``out[y, x]``: the weighted median of pixel ``(y, x)`` alone (a sparse row's path); ``hist`` scratch of
    ``nbins`` entries, any values; ``kbuf`` of ``2 radius + 1``."""
    h, w = finite.shape
    nbins = hist.shape[0]
    nlut = lut.shape[0]
    # only the bins this window touches are reset and scanned: the same sums (the bins below hold 0)
    blo, bhi = nbins, -1
    total = np.float32(0.0)
    l0, l1, l2 = lab[0, y, x], lab[1, y, x], lab[2, y, x]
    x0, x1 = max(0, x - radius), min(w, x + radius + 1)
    for yy in range(max(0, y - radius), min(h, y + radius + 1)):
        q0, q1, q2 = lab[0, yy, x0:x1], lab[1, yy, x0:x1], lab[2, yy, x0:x1]
        # the window row's colour distances first: a loop that vectorises (as in _median_row)
        for j in range(x1 - x0):
            a = l0 - q0[j]
            b = l1 - q1[j]
            c = l2 - q2[j]
            kbuf[j] = int(np.sqrt(a * a + b * b + c * c) * _LUT_STEP + 0.5)
        for xx in range(x0, x1):
            k = kbuf[xx - x0]
            if k >= nlut or not finite[yy, xx]:
                continue
            wt = lut[k] * spatial[yy - y + radius, xx - x + radius]
            bi = bins[yy, xx]
            if bhi < 0:
                hist[bi] = 0.0
                blo = bi
                bhi = bi
            elif bi < blo:
                for k2 in range(bi, blo):
                    hist[k2] = 0.0
                blo = bi
            elif bi > bhi:
                for k2 in range(bhi + 1, bi + 1):
                    hist[k2] = 0.0
                bhi = bi
            hist[bi] += wt
            total += wt
    if total <= 0.0:
        return
    acc = np.float32(0.0)
    for bi in range(blo, bhi + 1):
        acc += hist[bi]
        if acc >= 0.5 * total:
            out[y, x] = dmin + bi
            return


@njit(cache=True, fastmath=True, nogil=True)
def _median_row(out: np.ndarray, finite: np.ndarray, bins: np.ndarray, mask: np.ndarray, lab: np.ndarray,
                y: int, radius: int, spatial: np.ndarray, lut: np.ndarray, hist: np.ndarray, kbuf: np.ndarray,
                total: np.ndarray, blo: np.ndarray, bhi: np.ndarray, dmin: float) -> None:  # pragma: no cover
    """``out[y, x]`` for the masked pixels of row ``y`` at once: per window offset, the colour distances of the whole
    row in one vectorised loop, then their weights added to each pixel's histogram
    ``hist[:, x]`` (``(nbins, W)`` scratch, zero on entry and left zero; bin-major, so that the neighbours of a
    smooth map add to nearby entries).

    Each pixel's histogram and total add the same terms in the same order as :func:`_median_pixel` (the window
    row-major)."""
    h, w = out.shape
    nlut = lut.shape[0]
    total[:] = 0.0
    blo[:] = hist.shape[0]
    bhi[:] = -1
    for yy in range(max(0, y - radius), min(h, y + radius + 1)):
        for dx in range(-radius, radius + 1):
            lo = max(0, -dx)
            hi = min(w, w - dx)
            if hi <= lo:
                continue
            sp = spatial[yy - y + radius, dx + radius]
            p0, p1, p2 = lab[0, y, lo:hi], lab[1, y, lo:hi], lab[2, y, lo:hi]
            q0, q1, q2 = lab[0, yy, lo + dx:hi + dx], lab[1, yy, lo + dx:hi + dx], lab[2, yy, lo + dx:hi + dx]
            fq = finite[yy, lo + dx:hi + dx]
            bq = bins[yy, lo + dx:hi + dx]
            ks = kbuf[lo:hi]
            # the colour distances alone: this loop vectorises (a table lookup in it would not)
            for j in range(hi - lo):
                a = p0[j] - q0[j]
                b = p1[j] - q1[j]
                c = p2[j] - q2[j]
                ks[j] = int(np.sqrt(a * a + b * b + c * c) * _LUT_STEP + 0.5)
            for j in range(hi - lo):
                k = ks[j]
                if k >= nlut or not fq[j]:
                    continue
                x = lo + j
                bi = bq[j]
                wt = lut[k] * sp
                hist[bi, x] += wt
                total[x] += wt
                blo[x] = min(blo[x], bi)
                bhi[x] = max(bhi[x], bi)
    for x in range(w):
        if mask[y, x] and total[x] > 0.0:
            acc = np.float32(0.0)
            for bi in range(blo[x], bhi[x] + 1):
                acc += hist[bi, x]
                if acc >= 0.5 * total[x]:
                    out[y, x] = dmin + bi
                    break
        for bi in range(blo[x], bhi[x] + 1):
            hist[bi, x] = 0.0


@njit(cache=True, parallel=True, fastmath=True, nogil=True)
def wmf_kernel(disp: np.ndarray, finite: np.ndarray, mask: np.ndarray, lab: np.ndarray, radius: int,
               gamma_c: float, gamma_d: float, dmin: float, nbins: int,
               nchunks: int) -> np.ndarray:  # pragma: no cover - numba
    """Weighted median over integer bins, weights exp(-ΔE/γc - ‖Δp‖/γd) from lookup tables; ``lab`` planar
    (3, H, W); the disparities not ``finite`` (given: under fastmath ``isfinite`` is folded to True) give no
    weight. Rows run in ``nchunks`` chunks in parallel; a row with many
    masked pixels runs whole (:func:`_median_row`), a sparse one pixel by pixel (:func:`_median_pixel`): the
    same values."""
    h, w = disp.shape
    out = disp.copy()
    side = 2 * radius + 1
    spatial = np.empty((side, side), dtype=np.float32)
    for i in range(side):
        for j in range(side):
            spatial[i, j] = np.exp(-np.sqrt(float((i - radius) ** 2 + (j - radius) ** 2)) / gamma_d)
    nlut = int(_LUT_MAX * _LUT_STEP) + 1
    lut = np.empty(nlut, dtype=np.float32)
    for i in range(nlut):
        lut[i] = np.exp(-(i / _LUT_STEP) / gamma_c)
    bins = np.empty((h, w), dtype=np.int64)
    for y in prange(h):
        for x in range(w):
            bi = int(np.floor(disp[y, x] - dmin + 0.5)) if finite[y, x] else 0
            bins[y, x] = min(max(bi, 0), nbins - 1)
    rows = (h + nchunks - 1) // nchunks
    for ci in prange(nchunks):
        hist1 = np.zeros(nbins, dtype=np.float32)
        hist = np.zeros((nbins, 0), dtype=np.float32)
        kbuf = np.empty(max(w, side), dtype=np.int64)
        total = np.empty(w, dtype=np.float32)
        blo = np.empty(w, dtype=np.int64)
        bhi = np.empty(w, dtype=np.int64)
        for y in range(ci * rows, min(h, (ci + 1) * rows)):
            n = 0
            for x in range(w):
                n += mask[y, x]
            if n == 0:
                continue
            # the whole row costs about as much as half of its pixels one by one (measured on Middlebury v2)
            if 2 * n >= w:
                if hist.shape[1] == 0:
                    hist = np.zeros((nbins, w), dtype=np.float32)
                _median_row(out, finite, bins, mask, lab, y, radius, spatial, lut, hist, kbuf, total, blo, bhi,
                            dmin)
            else:
                for x in range(w):
                    if mask[y, x]:
                        _median_pixel(out, finite, bins, lab, y, x, radius, spatial, lut, hist1, kbuf, dmin)
    return out


def median_chunks(height: int) -> int:
    """Row chunks for :func:`wmf_kernel`: a few per thread (rows differ in cost), each holding its scratch."""
    return max(1, min(height, 4 * numba.get_num_threads()))
