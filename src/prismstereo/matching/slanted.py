"""Slanted-support-window adaptive-weight cost of a disparity plane, and a per-pixel plane refinement.

An addition to the thesis's ``coop`` pipeline, after PatchMatch Stereo (Bleyer, Rhemann & Rother, BMVC 2011):
the cost of plane ``(a, b, c)`` (``d = a x + b y + c``) at pixel ``p`` is

    C(p; plane) = Σ_{q∈W(p)} w(p, q) ρ(q, x_q − d_plane(q)) / Σ_q w(p, q)

with the plane's disparity evaluated at EVERY window pixel ``q`` (so the support window follows a slanted
surface instead of assuming it fronto-parallel, which penalises slanted planes when a fronto-parallel
aggregated cost such as BPASW is interpolated at their disparity), ``w(p, q) = exp(-‖I_p − I_q‖₁ / γ)``
(RGB L1; the proximity factor of PatchMatch Stereo is dropped as there), and
``ρ = (1 − α) min(‖I_q − I'_{q'}‖₁, τ_col) + α min(|∇I_q − ∇I'_{q'}|, τ_grad)`` with linear interpolation
in the right image at the subpixel match ``q'``. The window is sampled every ``dilation`` pixels.

:func:`refine_plane_labels` lets each pixel choose, among the planes of the segments around it and of its
neighbours' current choices (PatchMatch-style spatial propagation, red-black order), the plane of lowest
slanted cost.
"""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt
from numba import njit, prange

__all__ = ["plane_cost", "refine_plane_labels", "slanted_inputs"]

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
    from prismstereo.matching.coopcost import _census

    def grey(im: npt.NDArray[np.uint8]) -> F32:
        f = np.asarray(im, np.float32)
        return np.ascontiguousarray(f.mean(axis=2) if f.ndim == 3 else f, dtype=np.float32)

    return _census(grey(left), 3, 4), _census(grey(right), 3, 4)


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


@njit(cache=True, parallel=True, fastmath=True)
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


@njit(cache=True, parallel=True, fastmath=True)
def _refine(fl: F32, fr: F32, cl: npt.NDArray[np.uint64], cr: npt.NDArray[np.uint64], lam_cen: float,
            seg: npt.NDArray[np.int32], assign: npt.NDArray[np.int32],
            planes: npt.NDArray[np.float64], lab: npt.NDArray[np.int32], cur: F32, active: npt.NDArray[np.bool_],
            seg_radius: int, prop: int, parity: int, margin: float, radius: int, dil: int, gamma: float,
            alpha: float, tau_col: float, tau_grad: float, dmin: float, dmax: float, dref: F32, tol: float,
            ) -> tuple[npt.NDArray[np.int32], F32]:  # pragma: no cover - numba
    """One pass: pixels (of the given checkerboard parity, or all when parity < 0) pick the cheapest plane among
    their own, the segments' planes within ``seg_radius`` (first pass) and the labels of the pixels ``prop``
    px away (propagation). ``cur`` holds each pixel's current cost (recomputed when < 0)."""
    h, w = seg.shape
    out = lab.copy()
    oc = cur.copy()
    m = (2 * radius // dil + 1) ** 2
    nmax = (2 * seg_radius + 1) ** 2 + 9
    for y in prange(h):
        wy = np.empty(m, np.int64)
        wx = np.empty(m, np.int64)
        ww = np.empty(m, np.float32)
        cand = np.empty(nmax, np.int64)
        for x in range(w):
            if not active[y, x]:
                continue
            if parity >= 0 and (x + y) % 2 != parity:
                continue
            own = lab[y, x]
            nc = 0
            if seg_radius > 0:
                for yy in range(max(0, y - seg_radius), min(h, y + seg_radius + 1), 2):
                    for xx in range(max(0, x - seg_radius), min(w, x + seg_radius + 1), 2):
                        c = assign[seg[yy, xx]]
                        if c != own:
                            nc = add_unique(cand, nc, c)
            if prop > 0:
                for dy, dx in ((-prop, 0), (prop, 0), (0, -prop), (0, prop)):
                    yy = y + dy
                    xx = x + dx
                    if yy < 0 or yy >= h or xx < 0 or xx >= w:
                        continue
                    c = lab[yy, xx]
                    if c != own:
                        nc = add_unique(cand, nc, c)
            if nc == 0:
                continue
            n = _window(fl, y, x, radius, dil, gamma, wy, wx, ww)
            best = cur[y, x]
            if best < 0:
                pl = planes[own]
                best = _cost(fl, fr, cl, cr, lam_cen, n, wy, wx, ww, pl[0], pl[1], pl[2], alpha, tau_col, tau_grad)
                oc[y, x] = best
            bl = own
            for t in range(nc):
                pl = planes[cand[t]]
                d = pl[0] * x + pl[1] * y + pl[2]
                if d < dmin - 0.5 or d > dmax + 0.5:
                    continue
                if tol > 0 and abs(d - dref[y, x]) > tol:
                    continue
                c2 = _cost(fl, fr, cl, cr, lam_cen, n, wy, wx, ww, pl[0], pl[1], pl[2], alpha, tau_col,
                           tau_grad) + margin
                if c2 < best:
                    best = c2
                    bl = cand[t]
            if bl != own:
                out[y, x] = bl
                oc[y, x] = best - margin
    return out, oc


def refine_plane_labels(left: npt.NDArray[np.uint8], right: npt.NDArray[np.uint8], labels: npt.NDArray[np.int32],
                        assign: npt.NDArray[np.int32], planes: npt.NDArray[np.float64], *, min_disp: float,
                        max_disp: float, seg_radius: int = 6, iterations: int = 2, margin: float = 0.0,
                        active: npt.NDArray[np.bool_] | None = None, radius: int = 15, dilation: int = 2,
                        gamma: float = 20.0, alpha: float = 0.5, tau_col: float = 30.0,
                        tau_grad: float = 6.0, census: float = 0.5, dref: npt.NDArray[np.float32] | None = None,
                        tol: float = 0.0) -> npt.NDArray[np.int32]:
    """Per-pixel plane labels minimising the slanted-window cost (PatchMatch Stereo's cost, Bleyer et al. 2011).

    Starts from each pixel's segment plane ``assign[labels]``; a first pass offers the planes of the segments
    within ``seg_radius`` px, then ``iterations`` red-black propagation passes offer the labels of the 4
    neighbours at distance 1 (and 4 px, for faster spread). Another plane must be cheaper by more than
    ``margin``, and (with ``dref``) lie within ``tol`` of ``dref`` at the pixel. Only ``active`` pixels (all if
    None) change. Returns the (H, W) int32 plane index map.
    """
    fl = slanted_inputs(left)
    fr = slanted_inputs(right)
    cl, cr = _census_pair(left, right, census)
    seg = np.ascontiguousarray(labels, np.int32)
    asg = np.ascontiguousarray(assign, np.int32)
    pl = np.ascontiguousarray(planes, np.float64)
    lab = asg[seg]
    act = np.ones(seg.shape, bool) if active is None else np.ascontiguousarray(active, bool)
    cur = np.full(seg.shape, -1.0, np.float32)
    args = (int(radius), int(dilation), float(gamma), float(alpha), float(tau_col), float(tau_grad),
            float(min_disp), float(max_disp),
            np.ascontiguousarray(dref if dref is not None else np.zeros((1, 1)), np.float32),
            float(tol) if dref is not None else 0.0)
    lab, cur = _refine(fl, fr, cl, cr, float(census), seg, asg, pl, lab, cur, act, int(seg_radius), 0, -1,
                       float(margin), *args)
    for _ in range(iterations):
        for step in (1, 4):
            for parity in (0, 1):
                lab, cur = _refine(fl, fr, cl, cr, float(census), seg, asg, pl, lab, cur, act, 0, step, parity,
                                   float(margin), *args)
    return lab


@njit(cache=True, parallel=True, fastmath=True)
def _segment_costs(fl: F32, fr: F32, cl: npt.NDArray[np.uint64], cr: npt.NDArray[np.uint64], lam_cen: float,
                   seg: npt.NDArray[np.int32], cand: npt.NDArray[np.int64], planes: npt.NDArray[np.float64],
                   step: int, radius: int, dil: int, gamma: float, alpha: float, tau_col: float, tau_grad: float,
                   dmin: float, dmax: float,
                   ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:  # pragma: no cover - numba
    """Per row: sums of the slanted cost of each segment's candidate planes over its pixels on a ``step`` grid."""
    h, w = seg.shape
    k, m = cand.shape
    ys = np.arange(0, h, step)
    acc = np.zeros((ys.size, k, m))
    cnt = np.zeros((ys.size, k))
    mw = (2 * radius // dil + 1) ** 2
    for r in prange(ys.size):
        y = ys[r]
        wy = np.empty(mw, np.int64)
        wx = np.empty(mw, np.int64)
        ww = np.empty(mw, np.float32)
        for x in range((y // step) % step, w, step):
            s = seg[y, x]
            n = _window(fl, y, x, radius, dil, gamma, wy, wx, ww)
            cnt[r, s] += 1.0
            for j in range(m):
                c = cand[s, j]
                if c < 0:
                    continue
                pl = planes[c]
                d = pl[0] * x + pl[1] * y + pl[2]
                pen = 0.0
                if d < dmin - 0.5 or d > dmax + 0.5:
                    pen = 1e3
                acc[r, s, j] += _cost(fl, fr, cl, cr, lam_cen, n, wy, wx, ww, pl[0], pl[1], pl[2], alpha, tau_col,
                                      tau_grad) + pen
    return acc.sum(axis=0), cnt.sum(axis=0)


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


@njit(cache=True, fastmath=True)
def _seg_eval(fl: F32, fr: F32, cl: npt.NDArray[np.uint64], cr: npt.NDArray[np.uint64], lam_cen: float,
              nn: npt.NDArray[np.int64], wy: npt.NDArray[np.int64], wx: npt.NDArray[np.int64], ww: F32,
              px: npt.NDArray[np.float64], py: npt.NDArray[np.float64], cx: float, cy: float, a: float, b: float,
              dc: float, prm: tuple[float, float, float, float, float]) -> float:  # pragma: no cover - numba
    """Mean slanted cost over a segment's sampled pixels of the plane ``d = a (x-cx) + b (y-cy) + dc``."""
    alpha, tau_col, tau_grad, dmin, dmax = prm
    ns = px.shape[0]
    tot = 0.0
    c = dc - a * cx - b * cy
    for i in range(ns):
        d = a * (px[i] - cx) + b * (py[i] - cy) + dc
        pen = 0.0
        if d < dmin - 0.5 or d > dmax + 0.5:
            pen = 1e3
        tot += _cost(fl, fr, cl, cr, lam_cen, nn[i], wy[i], wx[i], ww[i], a, b, c, alpha, tau_col, tau_grad) + pen
    return tot / ns


@njit(cache=True, parallel=True, fastmath=True)
def _refine_segment_planes(fl: F32, fr: F32, cl: npt.NDArray[np.uint64], cr: npt.NDArray[np.uint64],
                           lam_cen: float, order: npt.NDArray[np.int64], starts: npt.NDArray[np.int64],
                           init: npt.NDArray[np.float64], max_px: int, min_px: int, levels: int, step_d: float,
                           step_s: float, n_grid: int, grid_s: float, radius: int, dil: int, gamma: float,
                           alpha: float, tau_col: float,
                           tau_grad: float, dmin: float, dmax: float,
                           ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    # pragma: no cover - numba
    w = fl.shape[1]
    k = init.shape[0]
    out = init.copy()
    c0 = np.full(k, np.inf)
    c1 = np.full(k, np.inf)
    mw = (2 * radius // dil + 1) ** 2
    for s in prange(k):
        n_all = starts[s + 1] - starts[s]
        if n_all < min_px or not np.isfinite(init[s, 0]):
            continue
        stride = max(1, (n_all + max_px - 1) // max_px)
        ns = (n_all + stride - 1) // stride
        wy = np.empty((ns, mw), np.int64)
        wx = np.empty((ns, mw), np.int64)
        ww = np.empty((ns, mw), np.float32)
        nn = np.empty(ns, np.int64)
        px = np.empty(ns)
        py = np.empty(ns)
        for i in range(ns):
            j = min(i * stride + (i * 7919) % stride, n_all - 1)  # scattered, not one column per row
            p = order[starts[s] + j]
            y = p // w
            x = p % w
            px[i] = x
            py[i] = y
            nn[i] = _window(fl, y, x, radius, dil, gamma, wy[i], wx[i], ww[i])
        cx = px.mean()
        cy = py.mean()
        prm = (alpha, tau_col, tau_grad, dmin, dmax)
        a = init[s, 0]
        b = init[s, 1]
        dc = a * cx + b * cy + init[s, 2]

        best = _seg_eval(fl, fr, cl, cr, lam_cen, nn, wy, wx, ww, px, py, cx, cy, a, b, dc, prm)
        c0[s] = best
        for axis in range(2):  # coarse slope grid, x then y (escapes the fronto-parallel basin)
            a0 = a
            b0 = b
            d0 = dc
            for t in range(2 * n_grid):
                g = grid_s * (t // 2 + 1) * (1.0 if t % 2 == 0 else -1.0)
                na = a0 + g if axis == 0 else a0
                nb = b0 + g if axis == 1 else b0
                for o in range(-1, 2):  # jointly with the centre disparity (narrow basins)
                    nd = d0 + o * step_d
                    c = _seg_eval(fl, fr, cl, cr, lam_cen, nn, wy, wx, ww, px, py, cx, cy, na, nb, nd, prm)
                    if c < best:
                        best = c
                        a, b, dc = na, nb, nd
        sd = step_d
        ss = step_s
        for _lv in range(levels):
            improved = True
            it = 0
            while improved and it < 3:
                improved = False
                it += 1
                for t in range(6):
                    na, nb, nd = a, b, dc
                    if t == 0:
                        nd = dc + sd
                    elif t == 1:
                        nd = dc - sd
                    elif t == 2:
                        na = a + ss
                    elif t == 3:
                        na = a - ss
                    elif t == 4:
                        nb = b + ss
                    else:
                        nb = b - ss
                    c = _seg_eval(fl, fr, cl, cr, lam_cen, nn, wy, wx, ww, px, py, cx, cy, na, nb, nd, prm)
                    if c < best:
                        best = c
                        a, b, dc = na, nb, nd
                        improved = True
            sd *= 0.5
            ss *= 0.5
        out[s, 0] = a
        out[s, 1] = b
        out[s, 2] = dc - a * cx - b * cy
        c1[s] = best
    return out, c0, c1


def refine_segment_planes(left: npt.NDArray[np.uint8], right: npt.NDArray[np.uint8], order: npt.NDArray[np.int64],
                          starts: npt.NDArray[np.int64], init: npt.NDArray[np.float64], *, min_disp: float,
                          max_disp: float, max_px: int = 32, min_px: int = 20, levels: int = 4, step_d: float = 1.0,
                          step_s: float = 0.1, n_grid: int = 10, grid_s: float = 0.1, radius: int = 15,
                          dilation: int = 3, gamma: float = 20.0,
                          alpha: float = 0.5, tau_col: float = 30.0, tau_grad: float = 6.0, census: float = 0.5,
                          ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Segment-plane refinement (PatchMatch Stereo's plane refinement, Bleyer et al. 2011, per segment): a pattern
    search over ``(a, b, d_centre)`` (steps ``step_d`` px and ``step_s`` px/px, halved ``levels`` times) minimising
    the segment's mean slanted-window cost over up to ``max_px`` of its pixels. Returns the refined planes and
    the mean costs before and after (``inf`` where skipped: fewer than ``min_px`` pixels or no plane)."""
    fl = slanted_inputs(left)
    fr = slanted_inputs(right)
    cl, cr = _census_pair(left, right, census)
    return _refine_segment_planes(fl, fr, cl, cr, float(census), np.ascontiguousarray(order, np.int64),
                                  np.ascontiguousarray(starts, np.int64), np.ascontiguousarray(init, np.float64),
                                  int(max_px), int(min_px), int(levels), float(step_d), float(step_s), int(n_grid),
                                  float(grid_s), int(radius),
                                  int(dilation), float(gamma), float(alpha), float(tau_col), float(tau_grad),
                                  float(min_disp), float(max_disp))
