"""Numba kernel of the bilateral weighted median (imported lazily, so box matchers need no numba)."""

from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(cache=True, parallel=True)
def wmf_kernel(disp: np.ndarray, mask: np.ndarray, lab: np.ndarray, radius: int, gamma_c: float,
         gamma_d: float, dmin: float, nbins: int) -> np.ndarray:  # pragma: no cover - numba
    h, w = disp.shape
    out = disp.copy()
    for y in prange(h):
        hist = np.zeros(nbins, dtype=np.float64)
        for x in range(w):
            if not mask[y, x]:
                continue
            hist[:] = 0.0
            total = 0.0
            for yy in range(max(0, y - radius), min(h, y + radius + 1)):
                for xx in range(max(0, x - radius), min(w, x + radius + 1)):
                    v = disp[yy, xx]
                    if not np.isfinite(v):
                        continue
                    a = lab[y, x, 0] - lab[yy, xx, 0]
                    b = lab[y, x, 1] - lab[yy, xx, 1]
                    c = lab[y, x, 2] - lab[yy, xx, 2]
                    dc = np.sqrt(a * a + b * b + c * c)
                    ds = np.sqrt(float((y - yy) ** 2 + (x - xx) ** 2))
                    wt = np.exp(-dc / gamma_c - ds / gamma_d)
                    bi = int(np.floor(v - dmin + 0.5))
                    bi = min(max(bi, 0), nbins - 1)
                    hist[bi] += wt
                    total += wt
            if total <= 0.0:
                continue
            acc = 0.0
            for bi in range(nbins):
                acc += hist[bi]
                if acc >= 0.5 * total:
                    out[y, x] = dmin + bi
                    break
    return out
