"""Numba kernel of the bilateral weighted median (imported lazily, so box matchers need no numba)."""

from __future__ import annotations

import numpy as np
from numba import njit, prange

#: colour-distance lookup resolution (entries per ΔE unit) and range (ΔE)
_LUT_STEP = 4.0
_LUT_MAX = 256.0


@njit(cache=True, parallel=True, fastmath=True)
def wmf_kernel(disp: np.ndarray, mask: np.ndarray, lab: np.ndarray, radius: int, gamma_c: float,
               gamma_d: float, dmin: float, nbins: int) -> np.ndarray:  # pragma: no cover - numba
    """Weighted median over integer bins, weights exp(-ΔE/γc - ‖Δp‖/γd) from lookup tables."""
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
    for y in prange(h):
        hist = np.zeros(nbins, dtype=np.float32)
        for x in range(w):
            if not mask[y, x]:
                continue
            # only the bins this window touches are reset and scanned: the same sums (the bins below hold 0)
            blo, bhi = nbins, -1
            total = np.float32(0.0)
            l0, l1, l2 = lab[y, x, 0], lab[y, x, 1], lab[y, x, 2]
            for yy in range(max(0, y - radius), min(h, y + radius + 1)):
                for xx in range(max(0, x - radius), min(w, x + radius + 1)):
                    v = disp[yy, xx]
                    if not np.isfinite(v):
                        continue
                    a = l0 - lab[yy, xx, 0]
                    b = l1 - lab[yy, xx, 1]
                    c = l2 - lab[yy, xx, 2]
                    k = int(np.sqrt(a * a + b * b + c * c) * _LUT_STEP + 0.5)
                    if k >= nlut:
                        continue
                    wt = lut[k] * spatial[yy - y + radius, xx - x + radius]
                    bi = int(np.floor(v - dmin + 0.5))
                    bi = min(max(bi, 0), nbins - 1)
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
                continue
            acc = np.float32(0.0)
            for bi in range(blo, bhi + 1):
                acc += hist[bi]
                if acc >= 0.5 * total:
                    out[y, x] = dmin + bi
                    break
    return out
