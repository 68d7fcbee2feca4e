"""Slanted-support-window adaptive-weight cost of a disparity plane, per pixel and per segment.

An addition to the thesis's ``coop`` pipeline, after PatchMatch Stereo (Bleyer, Rhemann & Rother, BMVC 2011):
the cost of plane ``(a, b, c)`` (``d = a x + b y + c``) at pixel ``p`` is

    C(p; plane) = Σ_{q∈W(p)} w(p, q) ρ(q, x_q − d_plane(q)) / Σ_q w(p, q)

with the plane's disparity evaluated at EVERY window pixel ``q`` (so the support window follows a slanted
surface instead of assuming it fronto-parallel, which penalises slanted planes when a fronto-parallel
aggregated cost such as BPASW is interpolated at their disparity), ``w(p, q) = exp(-‖I_p − I_q‖₁ / γ)``
(RGB L1; the proximity factor of PatchMatch Stereo is dropped as there), and
``ρ = (1 − α) min(‖I_q − I'_{q'}‖₁, τ_col) + α min(|∇I_q − ∇I'_{q'}|, τ_grad)`` with linear interpolation
in the right image at the subpixel match ``q'``. The window is sampled every ``dilation`` pixels.

:func:`segment_plane_costs` gives the mean cost of candidate planes over each segment (``coop``'s sweep
candidates). The per-pixel and per-segment plane refinements built on it were measured worse than ``coop``
without them and were removed (docs/EXPERIMENTS.md).
"""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt
from numba import njit, prange

from prismstereo.matching.coop.coopcost import census_bits

__all__ = ["add_unique", "plane_cost", "segment_plane_costs", "slanted_inputs"]

F32 = npt.NDArray[np.float32]


def slanted_inputs(image: npt.NDArray[np.uint8]) -> F32:
    """(H, W, 4) float32: RGB (0..255) and the x-gradient of the grey image (central difference / 2)."""
    img = np.asarray(image, dtype=np.float32)
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    img = img[:, :, :3]
    gray = img.mean(axis=2)
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=1, borderType=cv2.BORDER_REPLICATE) * np.float32(0.5)
    return np.ascontiguousarray(np.concatenate([img, gx[:, :, None]], axis=2), dtype=np.float32)


def _census_pair(left: npt.NDArray[np.uint8], right: npt.NDArray[np.uint8],
                 weight: float) -> tuple[npt.NDArray[np.uint64], npt.NDArray[np.uint64]]:
    """7×9 census transforms of the grey images (a dummy pair when the census weight is 0)."""
    if weight <= 0:
        z = np.zeros((1, 1), np.uint64)
        return z, z

    def grey(im: npt.NDArray[np.uint8]) -> F32:
        f = np.asarray(im, np.float32)
        return np.ascontiguousarray(f.mean(axis=2) if f.ndim == 3 else f, dtype=np.float32)

    return census_bits(grey(left), 3, 4), census_bits(grey(right), 3, 4)


@njit(cache=True, fastmath=True, inline="always")
def _sample(fr: F32, y: int, xf: float, ch: int) -> float:  # pragma: no cover - numba
    w = fr.shape[1]
    if xf <= 0.0:
        return fr[y, 0, ch]
    if xf >= w - 1.0:
        return fr[y, w - 1, ch]
    x0 = int(xf)
    f = xf - x0
    return (1.0 - f) * fr[y, x0, ch] + f * fr[y, x0 + 1, ch]


@njit(cache=True, fastmath=True)
def _window(fl: F32, y: int, x: int, radius: int, dil: int, gamma: float, wy: npt.NDArray[np.int64],
            wx: npt.NDArray[np.int64], ww: F32) -> int:  # pragma: no cover - numba
    h, w = fl.shape[0], fl.shape[1]
    n = 0
    for dy in range(-radius, radius + 1, dil):
        qy = y + dy
        if qy < 0 or qy >= h:
            continue
        for dx in range(-radius, radius + 1, dil):
            qx = x + dx
            if qx < 0 or qx >= w:
                continue
            s = (abs(fl[y, x, 0] - fl[qy, qx, 0]) + abs(fl[y, x, 1] - fl[qy, qx, 1])
                 + abs(fl[y, x, 2] - fl[qy, qx, 2]))
            wy[n] = qy
            wx[n] = qx
            ww[n] = np.exp(-s / gamma)
            n += 1
    return n


@njit(cache=True, inline="always")
def add_unique(cand: npt.NDArray[np.int64], nc: int, label: int) -> int:  # pragma: no cover - numba
    """Append ``label`` to ``cand[:nc]`` unless it is already there; returns the new count."""
    for t in range(nc):
        if cand[t] == label:
            return nc
    cand[nc] = label
    return nc + 1


@njit(cache=True, inline="always")
def _popcount(v: np.uint64) -> int:  # pragma: no cover - numba
    v = v - ((v >> np.uint64(1)) & np.uint64(0x5555555555555555))
    v = (v & np.uint64(0x3333333333333333)) + ((v >> np.uint64(2)) & np.uint64(0x3333333333333333))
    v = (v + (v >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return int((v * np.uint64(0x0101010101010101)) >> np.uint64(56))


@njit(cache=True, fastmath=True)
def _cost(fl: F32, fr: F32, cl: npt.NDArray[np.uint64], cr: npt.NDArray[np.uint64], lam_cen: float, n: int,
          wy: npt.NDArray[np.int64], wx: npt.NDArray[np.int64], ww: F32,
          a: float, b: float, c: float, alpha: float, tau_col: float, tau_grad: float) -> float:  # pragma: no cover
    num = 0.0
    den = 0.0
    for k in range(n):
        qy = wy[k]
        qx = wx[k]
        xr = qx - (a * qx + b * qy + c)
        col = (abs(fl[qy, qx, 0] - _sample(fr, qy, xr, 0)) + abs(fl[qy, qx, 1] - _sample(fr, qy, xr, 1))
               + abs(fl[qy, qx, 2] - _sample(fr, qy, xr, 2)))
        gr = abs(fl[qy, qx, 3] - _sample(fr, qy, xr, 3))
        rho = (1.0 - alpha) * min(col, tau_col) + alpha * min(gr, tau_grad)
        if lam_cen > 0.0:
            xi = int(np.floor(xr + 0.5))
            xi = min(max(xi, 0), fr.shape[1] - 1)
            rho += lam_cen * _popcount(cl[qy, qx] ^ cr[qy, xi])
        num += ww[k] * rho
        den += ww[k]
    return num / den if den > 0 else 0.0


@njit(cache=True, parallel=True, fastmath=True, nogil=True)
def _plane_cost_map(fl: F32, fr: F32, cl: npt.NDArray[np.uint64], cr: npt.NDArray[np.uint64],
                    lam_cen: float, plane: npt.NDArray[np.float64], radius: int, dil: int, gamma: float,
                    alpha: float, tau_col: float, tau_grad: float) -> F32:  # pragma: no cover - numba
    h, w = fl.shape[0], fl.shape[1]
    out = np.empty((h, w), np.float32)
    m = (2 * radius // dil + 1) ** 2
    for y in prange(h):
        wy = np.empty(m, np.int64)
        wx = np.empty(m, np.int64)
        ww = np.empty(m, np.float32)
        for x in range(w):
            n = _window(fl, y, x, radius, dil, gamma, wy, wx, ww)
            out[y, x] = _cost(fl, fr, cl, cr, lam_cen, n, wy, wx, ww, plane[0], plane[1], plane[2], alpha,
                              tau_col, tau_grad)
    return out


def plane_cost(left: npt.NDArray[np.uint8], right: npt.NDArray[np.uint8], plane: tuple[float, float, float], *,
               radius: int = 15, dilation: int = 2, gamma: float = 20.0, alpha: float = 0.5,
               tau_col: float = 30.0, tau_grad: float = 6.0, census: float = 0.5) -> F32:
    """Slanted-window cost of one plane ``d = a x + b y + c`` at every pixel (module docstring), (H, W) float32.

    A fronto-parallel window is the special case ``a = b = 0`` with ``c`` the pixel's disparity.
    """
    cl, cr = _census_pair(left, right, census)
    return _plane_cost_map(slanted_inputs(left), slanted_inputs(right), cl, cr, float(census),
                           np.asarray(plane, np.float64),
                           int(radius), int(dilation), float(gamma), float(alpha), float(tau_col), float(tau_grad))


@njit(cache=True)
def _sample_pixels(seg: npt.NDArray[np.int32], cand: npt.NDArray[np.int64], step: int,
                   ) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64],
                              npt.NDArray[np.float64]]:  # pragma: no cover - numba
    """The ``step``-grid pixels of the segments with candidates, grouped by segment in row-major order
    (``pix[nper[s]:nper[s + 1]]``), and the sampled pixel count of every segment."""
    h, w = seg.shape
    k = cand.shape[0]
    cnt = np.zeros(k)
    has = np.zeros(k, np.bool_)
    for s in range(k):
        for j in range(cand.shape[1]):
            if cand[s, j] >= 0:
                has[s] = True
                break
    nper = np.zeros(k + 1, np.int64)
    for y in range(0, h, step):
        for x in range((y // step) % step, w, step):
            s = seg[y, x]
            cnt[s] += 1.0
            if has[s]:
                nper[s + 1] += 1
    for s in range(k):
        nper[s + 1] += nper[s]
    pix = np.empty(nper[k], np.int64)
    fill = nper[:k].copy()
    for y in range(0, h, step):
        for x in range((y // step) % step, w, step):
            s = seg[y, x]
            if has[s]:
                pix[fill[s]] = y * w + x
                fill[s] += 1
    return nper, pix, cnt


@njit(cache=True, parallel=True, fastmath=True, nogil=True)
def _segment_costs(fl: F32, fr: F32, cl: npt.NDArray[np.uint64], cr: npt.NDArray[np.uint64], lam_cen: float,
                   seg: npt.NDArray[np.int32], cand: npt.NDArray[np.int64], planes: npt.NDArray[np.float64],
                   step: int, radius: int, dil: int, gamma: float, alpha: float, tau_col: float, tau_grad: float,
                   dmin: float, dmax: float,
                   ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:  # pragma: no cover - numba
    """Sums of the slanted cost of each segment's candidate planes over its pixels on a ``step`` grid.

    Every sampled pixel is one parallel task (balanced however the segments' sizes differ); the sums are then
    taken row by row in row-major order, so the totals do not depend on the number of threads."""
    h, w = seg.shape
    k, m = cand.shape
    nper, pix, cnt = _sample_pixels(seg, cand, step)
    npx = pix.size
    val = np.empty((npx, m))
    mw = (2 * radius // dil + 1) ** 2
    wr = fr.shape[1]
    for t in prange(npx):
        y = pix[t] // w
        x = pix[t] % w
        s = seg[y, x]
        wy = np.empty(mw, np.int64)
        wx = np.empty(mw, np.int64)
        ww = np.empty(mw, np.float32)
        n = _window(fl, y, x, radius, dil, gamma, wy, wx, ww)
        # the segment's candidate planes, contiguous: the inner loop runs over candidates (vectorised), the
        # window samples outside, so each candidate still sums its samples in window order
        pa = np.empty(m)
        pb = np.empty(m)
        pc = np.empty(m)
        num = np.zeros(m)
        nc = 0
        for j in range(m):
            c = cand[s, j]
            if c >= 0:
                pa[nc] = planes[c, 0]
                pb[nc] = planes[c, 1]
                pc[nc] = planes[c, 2]
                nc += 1
        den = 0.0
        for q in range(n):
            qy = wy[q]
            qx = wx[q]
            l0 = fl[qy, qx, 0]
            l1 = fl[qy, qx, 1]
            l2 = fl[qy, qx, 2]
            l3 = fl[qy, qx, 3]
            clq = cl[qy, qx] if lam_cen > 0.0 else np.uint64(0)
            wq = ww[q]
            den += wq
            for j in range(nc):
                xr = qx - (pa[j] * qx + pb[j] * qy + pc[j])
                xc = min(max(xr, 0.0), wr - 1.0)
                x0 = min(int(xc), wr - 2)
                f = xc - x0
                g = 1.0 - f
                col = (abs(l0 - (g * fr[qy, x0, 0] + f * fr[qy, x0 + 1, 0]))
                       + abs(l1 - (g * fr[qy, x0, 1] + f * fr[qy, x0 + 1, 1]))
                       + abs(l2 - (g * fr[qy, x0, 2] + f * fr[qy, x0 + 1, 2])))
                gr = abs(l3 - (g * fr[qy, x0, 3] + f * fr[qy, x0 + 1, 3]))
                rho = (1.0 - alpha) * min(col, tau_col) + alpha * min(gr, tau_grad)
                if lam_cen > 0.0:
                    xi = min(max(int(np.floor(xr + 0.5)), 0), wr - 1)
                    rho += lam_cen * _popcount(clq ^ cr[qy, xi])
                num[j] += wq * rho
        nc = 0
        for j in range(m):
            c = cand[s, j]
            if c < 0:
                val[t, j] = 0.0
                continue
            d = pa[nc] * x + pb[nc] * y + pc[nc]
            pen = 0.0
            if d < dmin - 0.5 or d > dmax + 0.5:
                pen = 1e3
            val[t, j] = (num[nc] / den if den > 0 else 0.0) + pen
            nc += 1
    acc = np.zeros((k, m))
    for s in prange(k):
        row = np.zeros(m)
        prev_y = -1
        for t in range(nper[s], nper[s + 1]):
            y = pix[t] // w
            if y != prev_y and prev_y >= 0:
                for j in range(m):
                    acc[s, j] += row[j]
                    row[j] = 0.0
            prev_y = y
            for j in range(m):
                row[j] += val[t, j]
        if prev_y >= 0:
            for j in range(m):
                acc[s, j] += row[j]
    return acc, cnt


def segment_plane_costs(left: npt.NDArray[np.uint8], right: npt.NDArray[np.uint8], labels: npt.NDArray[np.int32],
                        candidates: npt.NDArray[np.int64], planes: npt.NDArray[np.float64], *, min_disp: float,
                        max_disp: float, step: int = 2, radius: int = 15, dilation: int = 2, gamma: float = 20.0,
                        alpha: float = 0.5, tau_col: float = 30.0, tau_grad: float = 6.0,
                        census: float = 0.5) -> npt.NDArray[np.float64]:
    """Mean slanted-window cost of each segment's candidate planes over its pixels (a ``step`` grid).

    ``candidates`` (K, M) holds plane indices per segment (-1 = none). Returns (K, M); ``inf`` for missing
    candidates and for segments without a sampled pixel.
    """
    fl = slanted_inputs(left)
    fr = slanted_inputs(right)
    cl, cr = _census_pair(left, right, census)
    cand = np.ascontiguousarray(candidates, np.int64)
    acc, cnt = _segment_costs(fl, fr, cl, cr, float(census), np.ascontiguousarray(labels, np.int32), cand,
                              np.ascontiguousarray(planes, np.float64), int(step), int(radius), int(dilation),
                              float(gamma), float(alpha), float(tau_col), float(tau_grad), float(min_disp),
                              float(max_disp))
    out = np.where(cnt[:, None] > 0, acc / np.maximum(cnt[:, None], 1.0), np.inf)
    out[cand < 0] = np.inf
    return out
