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

:func:`segment_plane_costs` gives the mean cost of candidate planes over each segment, and
:func:`segment_sweep_costs` the same for a sweep's planes (every integer centre disparity x a few slopes), read
contiguously along the disparity (``coop``'s sweep candidates). The per-pixel and per-segment plane
refinements built on it were measured worse than ``coop`` without them and were removed (docs/EXPERIMENTS.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np
import numpy.typing as npt
from numba import njit, prange

from prismstereo.checks import check_fields
from prismstereo.matching.coop.coopcost import census_bits
from prismstereo.matching.local.costs import popcount64

__all__ = ["SlantedPair", "SlantedParams", "add_unique", "plane_cost", "segment_plane_costs", "segment_sweep_costs",
           "slanted_inputs", "slanted_pair"]

F32 = npt.NDArray[np.float32]


@dataclass(frozen=True, kw_only=True)
class SlantedParams:
    """The slanted-window cost's parameters (module docstring).

    Attributes
    ----------
    step : int          the segment costs sample every ``step``-th pixel of a segment (a diagonal grid).
    radius : int        half size of the support window ``W(p)``.
    dilation : int      the window is read every ``dilation`` pixels.
    gamma : float       colour scale ``γ`` of the support weight ``w(p, q)``.
    alpha : float       share ``α`` of the gradient term in ``ρ``.
    tau_col, tau_grad : float   truncations ``τ_col``, ``τ_grad`` of the colour and gradient terms.
    census : float      weight of the 7×9 census distance added to ``ρ`` (0 = none); a :class:`SlantedPair` given
        to a cost function brings its own.
    """

    step: int = 2
    radius: int = 15
    dilation: int = 2
    gamma: float = 20.0
    alpha: float = 0.5
    tau_col: float = 30.0
    tau_grad: float = 6.0
    census: float = 0.5

    def __post_init__(self) -> None:
        """Validate the fields; implementation helper with no thesis equation of its own."""
        check_fields(self, {"step": (1, None), "radius": (0, None), "dilation": (1, None), "alpha": (0.0, 1.0),
                            "tau_col": (0.0, None), "tau_grad": (0.0, None), "census": (0.0, None)},
                     positive=("gamma",))


class _Window(NamedTuple):
    """A :class:`SlantedParams` as the kernels read it (``lam_cen``: the census weight of the pair's inputs)."""

    radius: int
    dil: int
    gamma: float
    alpha: float
    tau_col: float
    tau_grad: float
    lam_cen: float


def _kernel_window(window: SlantedParams, census: float) -> _Window:
    """The :class:`_Window` of ``window`` and ``census``; implementation helper with no thesis equation."""
    return _Window(int(window.radius), int(window.dilation), float(window.gamma), float(window.alpha),
                   float(window.tau_col), float(window.tau_grad), float(census))


class _SweepPlanes(NamedTuple):
    """The planes of a sweep (:func:`_sweep_costs`): ``d = a x + b y + (d0 + i) - a cx - b cy`` with ``a`` in
    ``avals[s, :na[s]]`` (K, 2) float64, ``b`` in ``slopes`` (B,) float64, ``(cx, cy)`` = ``cx[s]``, ``cy[s]``
    (K,) float64 and ``i`` < ``nd``."""

    avals: npt.NDArray[np.float64]
    na: npt.NDArray[np.int64]
    cx: npt.NDArray[np.float64]
    cy: npt.NDArray[np.float64]
    slopes: npt.NDArray[np.float64]
    d0: float
    nd: int


def slanted_inputs(image: npt.NDArray[np.uint8]) -> F32:
    """(H, W, 4) float32: RGB (0..255) and the x-gradient of the grey image (central difference / 2).

    An addition to the thesis (module docstring, after PatchMatch Stereo) with no thesis equation of its own; the colour
    and gradient channels are those of the dissimilarity of thesis Eq. 5.6 (x-gradient only).
    """
    img = np.asarray(image, dtype=np.float32)
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    img = img[:, :, :3]
    gray = img.mean(axis=2)
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=1, borderType=cv2.BORDER_REPLICATE) * np.float32(0.5)
    return np.ascontiguousarray(np.concatenate([img, gx[:, :, None]], axis=2), dtype=np.float32)


@dataclass(frozen=True)
class SlantedPair:
    """The per-pixel inputs of the slanted-window cost of one pair (:func:`slanted_pair`), made once for the
    several cost calls on it.

    Attributes
    ----------
    left, right : (H, W, 4) float32   :func:`slanted_inputs` of each image.
    census_left, census_right : (H, W) uint64   7×9 census bits of the grey images ((1, 1) when ``census`` is 0).
    census : float                    weight of the census distance in the cost.
    """

    left: F32
    right: F32
    census_left: npt.NDArray[np.uint64]
    census_right: npt.NDArray[np.uint64]
    census: float


def slanted_pair(left: npt.NDArray[np.uint8], right: npt.NDArray[np.uint8], *, census: float = 0.5) -> SlantedPair:
    """The :class:`SlantedPair` of a rectified pair ((H, W, 3) uint8 or (H, W) grey).

    Implementation helper (input preparation) with no thesis equation of its own.
    """
    cl, cr = _census_pair(left, right, census)
    return SlantedPair(slanted_inputs(left), slanted_inputs(right), cl, cr, float(census))


def _census_pair(left: npt.NDArray[np.uint8], right: npt.NDArray[np.uint8],
                 weight: float) -> tuple[npt.NDArray[np.uint64], npt.NDArray[np.uint64]]:
    """7×9 census transforms of the grey images (a dummy pair when the census weight is 0).

    An addition to the thesis (module docstring, after PatchMatch Stereo) with no thesis equation of its own (the
    thesis's data term, §5.2.2, has no census).
    """
    if weight <= 0:
        z = np.zeros((1, 1), np.uint64)
        return z, z

    def grey(im: npt.NDArray[np.uint8]) -> F32:
        """Mean of the RGB channels as (H, W) float32; implementation helper with no thesis equation."""
        f = np.asarray(im, np.float32)
        return np.ascontiguousarray(f.mean(axis=2) if f.ndim == 3 else f, dtype=np.float32)

    return census_bits(grey(left), 3, 4), census_bits(grey(right), 3, 4)


@njit(cache=True, fastmath=True, inline="always")
def _sample(fr: F32, y: int, xf: float, ch: int) -> float:  # pragma: no cover - numba
    """Channel ``ch`` of row ``y`` of ``fr`` at column ``xf``, linearly interpolated (the match ``q'`` of the module
    docstring's ``ρ``), clamped to the border columns.

    Implementation helper (linear interpolation) with no thesis equation of its own.
    """
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
    """The support window ``W(p)`` of pixel ``(y, x)`` (every ``dil`` px within ``radius``, inside the image) into
    ``wy, wx`` and its weights ``w(p, q) = exp(-‖I_p − I_q‖₁ / γ)`` into ``ww`` (module docstring; PatchMatch
    Stereo's, an addition to the thesis); returns the number of samples.

    An addition to the thesis (module docstring, after PatchMatch Stereo) with no thesis equation of its own.
    """
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
    """Append ``label`` to ``cand[:nc]`` unless it is already there; returns the new count.

    Implementation helper (candidate list) with no thesis equation of its own.
    """
    for t in range(nc):
        if cand[t] == label:
            return nc
    cand[nc] = label
    return nc + 1


@njit(cache=True, fastmath=True)
def _cost(fl: F32, fr: F32, cl: npt.NDArray[np.uint64], cr: npt.NDArray[np.uint64], n: int,
          wy: npt.NDArray[np.int64], wx: npt.NDArray[np.int64], ww: F32, a: float, b: float, c: float,
          win: _Window) -> float:  # pragma: no cover - numba
    """``C(p; plane)`` of the module docstring over the ``n`` window samples ``(wy, wx)`` of weights ``ww``.

    An addition to the thesis (module docstring, after PatchMatch Stereo) with no thesis equation of its own; the plane
    is that of thesis Eq. 6.1.
    """
    lam_cen, alpha, tau_col, tau_grad = win.lam_cen, win.alpha, win.tau_col, win.tau_grad
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
            rho += lam_cen * popcount64(cl[qy, qx] ^ cr[qy, xi])
        num += ww[k] * rho
        den += ww[k]
    return num / den if den > 0 else 0.0


@njit(cache=True, parallel=True, fastmath=True, nogil=True)
def _plane_cost_map(fl: F32, fr: F32, cl: npt.NDArray[np.uint64], cr: npt.NDArray[np.uint64],
                    plane: npt.NDArray[np.float64], win: _Window) -> F32:  # pragma: no cover - numba
    """:func:`_cost` of one plane at every pixel.

    An addition to the thesis (module docstring, after PatchMatch Stereo) with no thesis equation of its own.
    """
    radius, dil, gamma = win.radius, win.dil, win.gamma
    h, w = fl.shape[0], fl.shape[1]
    out = np.empty((h, w), np.float32)
    m = (2 * radius // dil + 1) ** 2
    for y in prange(h):
        wy = np.empty(m, np.int64)
        wx = np.empty(m, np.int64)
        ww = np.empty(m, np.float32)
        for x in range(w):
            n = _window(fl, y, x, radius, dil, gamma, wy, wx, ww)
            out[y, x] = _cost(fl, fr, cl, cr, n, wy, wx, ww, plane[0], plane[1], plane[2], win)
    return out


def plane_cost(left: npt.NDArray[np.uint8], right: npt.NDArray[np.uint8], plane: tuple[float, float, float], *,
               window: SlantedParams | None = None) -> F32:
    """Slanted-window cost of one plane ``d = a x + b y + c`` at every pixel (module docstring), (H, W) float32.

    A fronto-parallel window is the special case ``a = b = 0`` with ``c`` the pixel's disparity. ``window``:
    the cost's parameters (its ``step`` is not read here).

    An addition to the thesis (module docstring, after PatchMatch Stereo) with no thesis equation of its own; the plane
    is that of thesis Eq. 6.1.
    """
    win = window or SlantedParams()
    cl, cr = _census_pair(left, right, win.census)
    return _plane_cost_map(slanted_inputs(left), slanted_inputs(right), cl, cr, np.asarray(plane, np.float64),
                           _kernel_window(win, win.census))


@njit(cache=True)
def _sample_pixels(seg: npt.NDArray[np.int32], cand: npt.NDArray[np.int64], step: int,
                   ) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64],
                              npt.NDArray[np.float64]]:  # pragma: no cover - numba
    """The ``step``-grid pixels of the segments with candidates, grouped by segment in row-major order
    (``pix[nper[s]:nper[s + 1]]``), and the sampled pixel count of every segment.

    Implementation helper (pixel sampling) with no thesis equation of its own.
    """
    k = cand.shape[0]
    has = np.zeros(k, np.bool_)
    for s in range(k):
        for j in range(cand.shape[1]):
            if cand[s, j] >= 0:
                has[s] = True
                break
    return _sample_grid(seg, has, step)


@njit(cache=True)
def _sample_grid(seg: npt.NDArray[np.int32], has: npt.NDArray[np.bool_], step: int,
                 ) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64],
                            npt.NDArray[np.float64]]:  # pragma: no cover - numba
    """:func:`_sample_pixels` of the segments where ``has`` (K,) is set.

    Implementation helper (pixel sampling) with no thesis equation of its own.
    """
    h, w = seg.shape
    k = has.shape[0]
    cnt = np.zeros(k)
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
def _segment_sums(val: npt.NDArray[np.float64], pix: npt.NDArray[np.int64], nper: npt.NDArray[np.int64],
                  w: int) -> npt.NDArray[np.float64]:  # pragma: no cover - numba
    """(K, M) sums over each segment's sampled pixels ``pix[nper[s]:nper[s + 1]]`` of their rows of ``val``,
    taken row by row of the image in row-major order, so the totals do not depend on the number of threads.

    An addition to the thesis (module docstring, after PatchMatch Stereo) with no thesis equation of its own.
    """
    k = nper.size - 1
    m = val.shape[1]
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
    return acc


@njit(cache=True, parallel=True, fastmath=True, nogil=True)
def _segment_costs(fl: F32, fr: F32, cl: npt.NDArray[np.uint64], cr: npt.NDArray[np.uint64],
                   seg: npt.NDArray[np.int32], cand: npt.NDArray[np.int64], planes: npt.NDArray[np.float64],
                   step: int, dmin: float, dmax: float, win: _Window,
                   ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:  # pragma: no cover - numba
    """Sums of the slanted cost of each segment's candidate planes over its pixels on a ``step`` grid.

    Every sampled pixel is one parallel task (balanced however the segments' sizes differ); the sums are then
    taken row by row in row-major order, so the totals do not depend on the number of threads.

    An addition to the thesis (module docstring, after PatchMatch Stereo) with no thesis equation of its own; a segment
    sum like the data term of thesis Eq. 6.21, with the slanted cost in place of ``c_data``.
    """
    lam_cen, radius, dil, gamma = win.lam_cen, win.radius, win.dil, win.gamma
    alpha, tau_col, tau_grad = win.alpha, win.tau_col, win.tau_grad
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
                    rho += lam_cen * popcount64(clq ^ cr[qy, xi])
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
    return _segment_sums(val, pix, nper, w), cnt


def segment_plane_costs(left: npt.NDArray[np.uint8], right: npt.NDArray[np.uint8], labels: npt.NDArray[np.int32],
                        candidates: npt.NDArray[np.int64], planes: npt.NDArray[np.float64], *, min_disp: float,
                        max_disp: float, window: SlantedParams | None = None,
                        pair: SlantedPair | None = None) -> npt.NDArray[np.float64]:
    """Mean slanted-window cost of each segment's candidate planes over its pixels (a ``window.step`` grid).

    ``candidates`` (K, M) holds plane indices per segment (-1 = none). ``window``: the cost's parameters
    (default :class:`SlantedParams`). ``pair``: the pair's :func:`slanted_pair` when already made (then the
    census weight is its own). Returns (K, M); ``inf`` for missing candidates and for segments without a
    sampled pixel.

    An addition to the thesis (module docstring, after PatchMatch Stereo) with no thesis equation of its own; a segment
    mean like the data term of thesis Eq. 6.21, with the slanted cost in place of ``c_data``.
    """
    win = window or SlantedParams()
    sp = slanted_pair(left, right, census=win.census) if pair is None else pair
    cand = np.ascontiguousarray(candidates, np.int64)
    acc, cnt = _segment_costs(sp.left, sp.right, sp.census_left, sp.census_right,
                              np.ascontiguousarray(labels, np.int32), cand,
                              np.ascontiguousarray(planes, np.float64), int(win.step), float(min_disp),
                              float(max_disp), _kernel_window(win, sp.census))
    out = np.where(cnt[:, None] > 0, acc / np.maximum(cnt[:, None], 1.0), np.inf)
    out[cand < 0] = np.inf
    return out


@njit(cache=True, fastmath=True, inline="always")
def _rho_at(l0: float, l1: float, l2: float, l3: float, rv: F32, qy: int, x: int, crq: np.uint64,
            clq: np.uint64, win: _Window) -> float:  # pragma: no cover - numba
    """``ρ`` of the module docstring between left values ``l0..l3`` (census ``clq``) and mirrored right column
    ``x`` of row ``qy`` (census ``crq``).

    An addition to the thesis (module docstring, after PatchMatch Stereo) with no thesis equation of its own; cf. the
    dissimilarity ``S_AD`` of thesis Eq. 5.6.
    """
    lam_cen, alpha, tau_col, tau_grad = win.lam_cen, win.alpha, win.tau_col, win.tau_grad
    col = abs(l0 - rv[qy, 0, x]) + abs(l1 - rv[qy, 1, x]) + abs(l2 - rv[qy, 2, x])
    rho = (1.0 - alpha) * min(col, tau_col) + alpha * min(abs(l3 - rv[qy, 3, x]), tau_grad)
    if lam_cen > 0.0:
        rho += lam_cen * popcount64(clq ^ crq)
    return rho


@njit(cache=True, parallel=True, fastmath=True, nogil=True)
def _sweep_costs(fl: F32, rv: F32, cl: npt.NDArray[np.uint64], crv: npt.NDArray[np.uint64],
                 seg: npt.NDArray[np.int32], active: npt.NDArray[np.bool_], sweep: _SweepPlanes, step: int,
                 dmin: float, dmax: float, win: _Window,
                 ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:  # pragma: no cover - numba
    """:func:`_segment_costs` of the sweep's planes ``d = a x + b y + (d0 + i) - a cx - b cy`` (``a`` in
    ``avals[s, :na[s]]``, ``b`` in ``slopes``, ``i`` < ``nd``: :class:`_SweepPlanes`), column
    ``(ia * nb + ib) * nd + i``.

    Along ``i`` a window sample's match moves left by exactly one pixel at a constant subpixel fraction, so the
    right image, mirrored and channel-planar (``rv[y, ch, W - 1 - x]``, ``crv[y, W - 1 - x]`` its census), is
    read contiguously forwards, and the samples whose match leaves the image (clamped to its border column)
    share one cost.

    An addition to the thesis (module docstring, after PatchMatch Stereo) with no thesis equation of its own (the
    segment sweep of ``coop``'s sweep step).
    """
    avals, na, cx, cy, slopes, d0, nd = sweep.avals, sweep.na, sweep.cx, sweep.cy, sweep.slopes, sweep.d0, sweep.nd
    lam_cen, radius, dil, gamma = win.lam_cen, win.radius, win.dil, win.gamma
    alpha, tau_col, tau_grad = win.alpha, win.tau_col, win.tau_grad
    h, w = seg.shape
    nb = slopes.shape[0]
    ng = nb * nd
    m = 2 * ng
    nper, pix, cnt = _sample_grid(seg, active, step)
    npx = pix.size
    val = np.zeros((npx, m))
    mw = (2 * radius // dil + 1) ** 2
    wr = rv.shape[2]
    a1 = np.float32(1.0 - alpha)
    a2 = np.float32(alpha)
    tc = np.float32(tau_col)
    tg = np.float32(tau_grad)
    lc = np.float32(lam_cen)
    for t in prange(npx):
        y = pix[t] // w
        x = pix[t] % w
        s = seg[y, x]
        wy = np.empty(mw, np.int64)
        wx = np.empty(mw, np.int64)
        ww = np.empty(mw, np.float32)
        n = _window(fl, y, x, radius, dil, gamma, wy, wx, ww)
        num = np.zeros(m, np.float32)
        nas = na[s]
        # each block's plane at i = 0: d = a x + b y + c0
        ca = np.empty(nas * nb)
        cb = np.empty(nas * nb)
        c0 = np.empty(nas * nb)
        for ia in range(nas):
            for ib in range(nb):
                ca[ia * nb + ib] = avals[s, ia]
                cb[ia * nb + ib] = slopes[ib]
                c0[ia * nb + ib] = d0 - avals[s, ia] * cx[s] - slopes[ib] * cy[s]
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
            # the match beyond the left / right border reads the border column (the clamp of _segment_costs)
            rho_l = wq * _rho_at(l0, l1, l2, l3, rv, qy, wr - 1, crv[qy, wr - 1] if lam_cen > 0.0 else np.uint64(0),
                                 clq, win)
            rho_r = wq * _rho_at(l0, l1, l2, l3, rv, qy, 0, crv[qy, 0] if lam_cen > 0.0 else np.uint64(0), clq, win)
            for blk in range(nas * nb):
                xr0 = qx - (ca[blk] * qx + cb[blk] * qy + c0[blk])
                base = blk * nd
                fx = np.floor(xr0)
                # interior i (0 <= xr0 - i < wr - 1): il excluded; left of the image: i >= il
                il = min(max(int(fx) + 1, 0), nd)
                ir = min(max(int(np.floor(xr0 - (wr - 1.0))) + 1, 0), il)
                for i in range(ir):
                    num[base + i] += rho_r
                for i in range(il, nd):
                    num[base + i] += rho_l
                if il <= ir:
                    continue
                # interior u = i - ir: right pixels x0 = x00 - i and x0 + 1 are, in the mirrored rows,
                # rv[.., sx + u + 1] and rv[.., sx + u]
                x00 = int(fx)
                f = np.float32(xr0 - fx)
                g = np.float32(1.0) - f
                nin = il - ir
                sx = wr - 2 - x00 + ir
                q0 = rv[qy, 0, sx:sx + nin + 1]
                q1 = rv[qy, 1, sx:sx + nin + 1]
                q2 = rv[qy, 2, sx:sx + nin + 1]
                q3 = rv[qy, 3, sx:sx + nin + 1]
                nv = num[base + ir:base + il]
                # ``nv`` a view of the task's own row, which the compiler knows aliases no input: vectorised
                if lam_cen > 0.0:
                    sc = sx + (0 if f >= 0.5 else 1)
                    cc = crv[qy, sc:sc + nin]
                    for u in range(nin):
                        col = (abs(l0 - (g * q0[u + 1] + f * q0[u])) + abs(l1 - (g * q1[u + 1] + f * q1[u]))
                               + abs(l2 - (g * q2[u + 1] + f * q2[u])))
                        gr = abs(l3 - (g * q3[u + 1] + f * q3[u]))
                        nv[u] += wq * (a1 * min(col, tc) + a2 * min(gr, tg)
                                       + lc * np.float32(popcount64(clq ^ cc[u])))
                else:
                    for u in range(nin):
                        col = (abs(l0 - (g * q0[u + 1] + f * q0[u])) + abs(l1 - (g * q1[u + 1] + f * q1[u]))
                               + abs(l2 - (g * q2[u + 1] + f * q2[u])))
                        gr = abs(l3 - (g * q3[u + 1] + f * q3[u]))
                        nv[u] += wq * (a1 * min(col, tc) + a2 * min(gr, tg))
        for blk in range(nas * nb):
            dp = ca[blk] * x + cb[blk] * y + c0[blk]
            base = blk * nd
            for i in range(nd):
                d = dp + i
                pen = 1e3 if (d < dmin - 0.5 or d > dmax + 0.5) else 0.0
                val[t, base + i] = (num[base + i] / den if den > 0 else 0.0) + pen
    return _segment_sums(val, pix, nper, w), cnt


def segment_sweep_costs(left: npt.NDArray[np.uint8], right: npt.NDArray[np.uint8], labels: npt.NDArray[np.int32],
                        active: npt.NDArray[np.bool_], avals: npt.NDArray[np.float64], centres: npt.NDArray[np.float64],
                        slopes: tuple[float, ...], *, min_disp: int, max_disp: int, window: SlantedParams | None = None,
                        pair: SlantedPair | None = None) -> npt.NDArray[np.float64]:
    """:func:`segment_plane_costs` of a sweep's planes: for each ``active`` segment, the planes through its centre
    ``centres[s] = (cx, cy)`` at every integer centre disparity ``min_disp..max_disp`` with each slope ``a`` of
    ``avals[s]`` (K, 2; NaN = none) and ``b`` of ``slopes``.

    Returns (K, 2 x len(slopes) x D) float64, column ``(ia * len(slopes) + ib) * D + (dc - min_disp)`` for the
    plane ``a = avals[s, ia]``, ``b = slopes[ib]``, ``c = dc - a cx - b cy``; ``inf`` for missing ``a`` and for
    segments without a sampled pixel. ``window`` and ``pair`` as in :func:`segment_plane_costs`.

    An addition to the thesis (module docstring, after PatchMatch Stereo) with no thesis equation of its own (the
    segment sweep of ``coop``'s sweep step).
    """
    win = window or SlantedParams()
    sp = slanted_pair(left, right, census=win.census) if pair is None else pair
    # the right rows mirrored: a sweep's matches move left as its disparity grows, so they run forwards there
    rv = np.ascontiguousarray(sp.right.transpose(0, 2, 1)[:, :, ::-1])
    crv = np.ascontiguousarray(sp.census_right[:, ::-1])
    av = np.ascontiguousarray(np.nan_to_num(avals, nan=0.0), np.float64)
    na = np.where(np.isnan(avals[:, 1]), 1, 2).astype(np.int64)
    nd = int(max_disp) - int(min_disp) + 1
    sl = np.asarray(slopes, np.float64)
    sweep = _SweepPlanes(av, na, np.ascontiguousarray(centres[:, 0], np.float64),
                         np.ascontiguousarray(centres[:, 1], np.float64), sl, float(min_disp), nd)
    acc, cnt = _sweep_costs(sp.left, rv, sp.census_left, crv, np.ascontiguousarray(labels, np.int32),
                            np.ascontiguousarray(active, np.bool_), sweep, int(win.step), float(min_disp),
                            float(max_disp), _kernel_window(win, sp.census))
    out = np.where(cnt[:, None] > 0, acc / np.maximum(cnt[:, None], 1.0), np.inf)
    out[~np.asarray(active, bool)] = np.inf
    out[na == 1, sl.size * nd:] = np.inf
    return out
