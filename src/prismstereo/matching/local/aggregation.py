"""Cost aggregation: box windows and the thesis's BPASW adaptive support weights (thesis §5.2).

BPASW (biologically and psychophysically inspired adaptive support weights) weights every pixel ``q`` of
the support window of ``p`` by three Gestalt laws — proximity (thesis Eq. 5.7), colour similarity
(Eq. 5.8) and depth continuity (Eq. 5.9) — each mapped to a weight through the Weber–Fechner law
(Eq. 5.5, Eqs. 5.10–5.12), multiplies them (Eq. 5.13), computes the weights in *both* images and
aggregates the S_AD cost with their product (Eq. 5.14).

The Weber–Fechner reading
-------------------------
The thesis writes ``w = -k ln(S)`` (``S0 = 1``). Read literally it is negative for ``S > 1`` (a neighbour
more than one grey level away would *subtract* support), infinite at ``S = 0`` (the centre pixel, or two
equal colours) and its ``k`` cancels in Eq. 5.14 only if every weight has the same sign. We use the
law as psychophysics states it, with an explicit perception threshold ``S0`` and a just-noticeable floor
``S_min``::

    w(S) = ln(S0 / clip(S, S_min, S0)) / ln(S0 / S_min)        (0 <= w <= 1)

* ``S <= S_min`` (identical colours, the centre pixel, its 4-neighbours): full weight 1 — differences
  below one just-noticeable step are not perceived (removes the singularity at 0);
* ``S_min < S < S0``: the logarithmic Weber–Fechner fall-off, monotone decreasing;
* ``S >= S0``: weight 0 — stimuli at or beyond the threshold give no support (removes the negative
  branch). ``k`` is the normalisation ``1 / ln(S0 / S_min)`` and, as the thesis notes, cancels in Eq. 5.14.

For proximity ``S`` is the Euclidean pixel distance (Eq. 5.7) with ``S_min = 1`` and ``S0`` just beyond
the window corner; for similarity it is the CIE-Lab colour distance (Eq. 5.8 on colour, as Yoon–Kweon)
with ``S_min = 1`` (about one JND) and ``S0 = similarity_s0``; for continuity (optional second pass) the
neighbour's current disparity differing from the candidate by more than one pixel is the stimulus ζ,
giving the factor ``continuity_weight`` (Eq. 5.12 with the same clipping: equal disparities get 1).
``kernel="exp"`` swaps in Yoon–Kweon's ``exp(-S / γ)`` for comparison.

Speed: a full (2r+1)² window costs O(H·W·D·r²). ``dilation`` samples the window on a grid of that step
(the honest speed-up used by default: a 33×33 window read on a 17×17 grid). The right-image weights are
computed once per row and reused for all disparities.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import cv2
import numba
import numpy as np
from numba import njit, prange

from prismstereo.errors import MatchingError

__all__ = ["SegmentBand", "aggregate_box", "aggregate_bpasw", "to_lab", "weber_fechner_weight", "window_offsets"]


@dataclass(frozen=True, eq=False)
class SegmentBand:
    """The slices a banded aggregation computes: per row and per ``segment`` columns, one inclusive range.

    Attributes
    ----------
    bounds : ndarray, int64, (H, ceil(W / segment), 2)
        ``bounds[y, s] = (lo, hi)``: slices ``lo..hi`` of the cost volume are computed for the pixels of row ``y``,
        columns ``[s·segment, (s + 1)·segment)``; ``lo > hi``: none.
    segment : int
        Columns per segment.
    """

    bounds: np.ndarray
    segment: int

    def __post_init__(self) -> None:
        b = np.asarray(self.bounds)
        if b.ndim != 3 or b.shape[2] != 2 or self.segment < 1:
            raise MatchingError(f"expected bounds of shape (H, segments, 2) and segment >= 1, got shape {b.shape} "
                                f"and segment {self.segment}")

    def check(self, height: int, width: int) -> np.ndarray:
        """The bounds as contiguous int64 for an ``height × width`` volume (MatchingError when they do not fit)."""
        b = np.ascontiguousarray(self.bounds, dtype=np.int64)
        if b.shape[0] != height or b.shape[1] != -(-width // self.segment):
            raise MatchingError(f"expected band bounds for {height} rows and {-(-width // self.segment)} segments "
                                f"of {self.segment} columns, got shape {b.shape}")
        return b

    def mask(self, height: int, width: int) -> np.ndarray:
        """Pixels whose band holds at least one slice, bool ``(H, W)``."""
        b = self.check(height, width)
        busy = b[:, :, 0] <= b[:, :, 1]
        return np.repeat(busy, self.segment, axis=1)[:, :width]

    def dilated(self, *, rows: int, cols: int, height: int, width: int) -> SegmentBand:
        """The band that holds, per row segment, every slice of the segments within ``rows`` rows and ``cols``
        columns of it (the min…max of their bounds): the entries an aggregation window of that reach reads.

        Parameters
        ----------
        rows, cols : int
            Reach of the window in rows and columns (pixels, ≥ 0).
        height, width : int
            Size of the volume.
        """
        b = self.check(height, width)
        busy = b[:, :, 0] <= b[:, :, 1]
        big = np.float32(2**24)
        ks = -(-cols // self.segment)
        kernel = np.ones((2 * rows + 1, 2 * ks + 1), np.uint8)
        # (the default border of erode / dilate is neutral: the maximum / minimum value)
        lo = cv2.erode(np.where(busy, b[:, :, 0], big).astype(np.float32), kernel)
        hi = cv2.dilate(np.where(busy, b[:, :, 1], -big).astype(np.float32), kernel)
        out = np.stack([lo, hi], axis=2).astype(np.int64)
        out[lo > hi] = (1, 0)
        return SegmentBand(bounds=out, segment=self.segment)

    def pixels(self, height: int, width: int) -> int:
        """Pixel·slices inside the band."""
        b = self.check(height, width)
        n = np.maximum(b[:, :, 1] - b[:, :, 0] + 1, 0)
        widths = np.full(b.shape[1], self.segment, np.int64)
        widths[-1] = width - self.segment * (b.shape[1] - 1)
        return int((n * widths[None, :]).sum())


def aggregate_box(cost: np.ndarray, *, radius: int) -> np.ndarray:
    """Mean of each disparity slice over a ``(2·radius+1)²`` box window (running sums).

    Parameters
    ----------
    cost : ndarray, float32, (H, W, D)
    radius : int
        Window half-size in pixels (0 returns a copy).

    Returns
    -------
    ndarray, float32, (H, W, D)
    """
    if radius < 0:
        raise MatchingError(f"expected radius >= 0, got {radius}")
    vol = np.ascontiguousarray(cost, dtype=np.float32)
    out = np.empty_like(vol)
    k = (2 * radius + 1, 2 * radius + 1)
    for i in range(vol.shape[2]):  # loop over disparities, not pixels
        out[:, :, i] = cv2.blur(np.ascontiguousarray(vol[:, :, i]), k, borderType=cv2.BORDER_REFLECT_101)
    return out


def weber_fechner_weight(s: np.ndarray | float, *, s0: float, s_min: float = 1.0) -> np.ndarray:
    """Clipped Weber–Fechner weight ``ln(S0 / clip(S, S_min, S0)) / ln(S0 / S_min)`` (thesis Eq. 5.5).

    Monotone non-increasing in ``S``, 1 for ``S <= S_min``, 0 for ``S >= S0``. See the module docstring.
    """
    if not s0 > s_min > 0:
        raise MatchingError(f"expected s0 > s_min > 0, got s0={s0}, s_min={s_min}")
    s_arr = np.clip(np.asarray(s, dtype=np.float64), s_min, s0)
    return np.log(s0 / s_arr) / np.log(s0 / s_min)


def to_lab(image: np.ndarray) -> np.ndarray:
    """CIE-Lab (L in 0..100) of an RGB image (0..255), float32 ``H×W×3``; gray images give L only."""
    img = np.asarray(image, dtype=np.float32)
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    lab = cv2.cvtColor(np.clip(img, 0, 255) / np.float32(255.0), cv2.COLOR_RGB2Lab)
    return np.ascontiguousarray(lab, dtype=np.float32)


def window_offsets(radius: int, dilation: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Offsets ``(dy, dx)`` of a square window sampled every ``dilation`` pixels, and their distances."""
    steps = np.arange(-(radius // dilation), radius // dilation + 1) * dilation
    gy, gx = np.meshgrid(steps, steps, indexing="ij")
    dy, dx = gy.ravel().astype(np.int64), gx.ravel().astype(np.int64)
    return dy, dx, np.sqrt(dy.astype(np.float64) ** 2 + dx**2)


@njit(cache=True, inline="always")
def _sim(d2: float, kernel: int, s0: float, s_min: float, log_norm: float) -> float:  # pragma: no cover
    s = np.sqrt(d2)
    if kernel == 0:  # clipped Weber–Fechner
        if s <= s_min:
            return 1.0
        if s >= s0:
            return 0.0
        return np.log(s0 / s) * log_norm
    return np.exp(-s / s0)  # Yoon–Kweon exp kernel, s0 = gamma


@njit(cache=True, inline="always")
def pair_weight(lab: np.ndarray, y: int, x: int, qy: int, qx: int, kernel: int, s0: float, s_min: float,
                 log_norm: float) -> float:  # pragma: no cover - numba
    """Colour similarity (:func:`_sim`) of Lab pixels ``(y, x)`` and ``(qy, qx)``."""
    a = lab[y, x, 0] - lab[qy, qx, 0]
    b = lab[y, x, 1] - lab[qy, qx, 1]
    c = lab[y, x, 2] - lab[qy, qx, 2]
    return _sim(a * a + b * b + c * c, kernel, s0, s_min, log_norm)


@njit(cache=True, inline="always")
def _log_ge1(x: float) -> float:  # pragma: no cover - numba
    """``ln(x)`` for ``1 <= x < 2**64`` in branch-free float64 arithmetic, so that a loop calling it vectorises
    (the libm call does not): the exponent is taken out by comparisons, then fdlibm's ``log`` kernel
    (``ln(1 + f) = 2 atanh(f / (2 + f))``, error below 1 ulp). Other ``x > 0`` give finite values only."""
    m = x
    k = 0.0
    c = m >= 4294967296.0
    m = m * 2.3283064365386963e-10 if c else m
    k += 32.0 if c else 0.0
    c = m >= 65536.0
    m = m * 1.52587890625e-05 if c else m
    k += 16.0 if c else 0.0
    c = m >= 256.0
    m = m * 0.00390625 if c else m
    k += 8.0 if c else 0.0
    c = m >= 16.0
    m = m * 0.0625 if c else m
    k += 4.0 if c else 0.0
    c = m >= 4.0
    m = m * 0.25 if c else m
    k += 2.0 if c else 0.0
    c = m >= 2.0
    m = m * 0.5 if c else m
    k += 1.0 if c else 0.0
    c = m > 1.4142135623730951
    m = m * 0.5 if c else m
    k += 1.0 if c else 0.0
    f = m - 1.0
    s = f / (2.0 + f)
    z = s * s
    w = z * z
    t1 = w * (3.999999999940941908e-01 + w * (2.222219843214978396e-01 + w * 1.531383769920937332e-01))
    t2 = z * (6.666666666666735130e-01 + w * (2.857142874366239149e-01 + w * (1.818357216161805012e-01
                                                                          + w * 1.479819860511658591e-01)))
    hfsq = 0.5 * f * f
    return k * 6.93147180369123816490e-01 - ((hfsq - (s * (t2 + t1 + hfsq) + k * 1.90821492927058770002e-10)) - f)


@njit(cache=True, nogil=True, error_model="numpy")
def _weber_row(out: np.ndarray, lab3: np.ndarray, y: int, qy: int, dx: int, lo: int, hi: int, prox_k: float,
               s0: float, s_min: float, log_norm: float) -> None:  # pragma: no cover - numba
    """``out[x] = float32(w((y, x), (qy, x + dx)) * prox_k)`` for ``lo <= x < hi``: :func:`pair_weight`'s clipped
    Weber–Fechner weight on planar Lab ``lab3`` (3, H, W), the same float32 colour distance; compiled without
    fastmath, so that the products keep their order (the weights equal :func:`pair_weight`'s bit for bit at the
    default constants; checked over every float32 distance in (S_min, S0))."""
    x0 = s0 / s_min
    # slices aligned on x: unit-stride loads and stores (an index x + dx that might be negative makes numba
    # wrap it, and the vectorised loop then gathers and scatters)
    p0, p1, p2 = lab3[0, y, lo:hi], lab3[1, y, lo:hi], lab3[2, y, lo:hi]
    q0, q1, q2 = lab3[0, qy, lo + dx:hi + dx], lab3[1, qy, lo + dx:hi + dx], lab3[2, qy, lo + dx:hi + dx]
    o = out[lo:hi]
    for j in range(hi - lo):
        a = p0[j] - q0[j]
        b = p1[j] - q1[j]
        c = p2[j] - q2[j]
        s = np.sqrt(a * a + b * b + c * c)
        v = _log_ge1(min(s0 / s, x0) if s > s_min else x0) * log_norm
        v = 1.0 if s <= s_min else (0.0 if s >= s0 else v)
        o[j] = np.float32(v * prox_k)


# compiled once and called (not inlined into each of the kernels' four call sites: a first run compiles it once);
# fastmath as in the kernels that call it, so that its products round as they did inlined there
@njit(cache=True, fastmath=True, nogil=True)
def _weight_row(tab: np.ndarray, slot: int, lab: np.ndarray, lab3: np.ndarray, y: int, dys: np.ndarray,
                dxs: np.ndarray, prox: np.ndarray, mirror: np.ndarray, nrows: int, kernel: int, s0: float,
                s_min: float, log_norm: float, reverse: bool, forward_only: bool,
                buf: np.ndarray) -> None:  # pragma: no cover - numba
    """Row ``y``'s support weights ``w(p, p + o_k) prox_k`` (float32; 0 outside the image) into ``tab[slot]``.

    Weights are symmetric, ``w(p, q) = w(q, p)``: an offset whose mirror ``-o_k`` points forwards (``mirror[k]
    >= 0``) is read from the row it points to, computed before (``nrows`` rows kept, ``slot = y % nrows``),
    instead of evaluated again; the colour distance is a sum of squares, so the value is the same bit for bit.
    ``reverse``: column ``x`` is stored at ``w - 1 - x``; ``forward_only``: the mirrored offsets are skipped.
    ``buf``: scratch of length ``w``."""
    h, w = lab.shape[0], lab.shape[1]
    nk = dys.shape[0]
    for kk in range(2 * nk):  # the offsets computed first: the mirrored ones on the row itself read them
        k = kk % nk
        mk = mirror[k]
        if (mk >= 0) != (kk >= nk) or (mk >= 0 and forward_only):
            continue
        qy = y + dys[k]
        dx = dxs[k]
        lo = max(0, -dx)
        hi = min(w, w - dx)
        if qy < 0 or qy >= h:
            hi = lo
        row = tab[slot, k]
        if mk >= 0:  # a contiguous shifted copy in the stored order
            src = tab[qy % nrows, mk]
            sh = -dx if reverse else dx
            a0, a1 = (w - hi, w - lo) if reverse else (lo, hi)
            # element loops, not slice assignments: those compile a shape check whose error message alone
            # takes seconds to compile
            for x in range(a0, a1):
                row[x] = src[x + sh]
            row[:a0] = 0.0
            row[a1:] = 0.0
            continue
        if kernel == 0:
            buf[:] = 0.0
            _weber_row(buf, lab3, y, qy, dx, lo, hi, prox[k], s0, s_min, log_norm)
        else:
            for x in range(w):
                v = np.float32(0.0)
                if lo <= x < hi:
                    v = np.float32(pair_weight(lab, y, x, qy, x + dx, kernel, s0, s_min, log_norm) * prox[k])
                buf[x] = v
        if reverse:
            for x in range(w):
                row[w - 1 - x] = buf[x]
        else:
            for x in range(w):
                row[x] = buf[x]


@njit(cache=True, parallel=True, nogil=True)
def _disparity_major(cost: np.ndarray, pad: int) -> np.ndarray:  # pragma: no cover - numba
    """(H, W, D) -> (H, D, W + 2 pad) copy, columns shifted by ``pad``, zero in the margins."""
    h, w, nd = cost.shape
    out = np.empty((h, nd, w + 2 * pad), dtype=cost.dtype)
    for y in prange(h):
        out[y, :, :pad] = 0.0
        out[y, :, w + pad:] = 0.0
        for x in range(w):
            for i in range(nd):
                out[y, i, x + pad] = cost[y, x, i]
    return out


@njit(cache=True, inline="always")
def _kept_rows(dys: np.ndarray, mirror: np.ndarray) -> int:  # pragma: no cover - numba
    """Rows of weights a row reads back (its mirrored offsets point at most this many rows up), plus itself."""
    back = 0
    for k in range(dys.shape[0]):
        if mirror[k] >= 0:
            back = max(back, -dys[k])
    return back + 1


# fused multiply-adds as with fastmath=True, but no reassociation: the fused loop adds four terms to a sum per
# step, which must stay in the order of k
@njit(cache=True, fastmath={"contract", "nnan", "ninf", "nsz", "arcp", "afn"}, nogil=True)
def _accumulate_runs(num: np.ndarray, den: np.ndarray, wl: np.ndarray, wr: np.ndarray, ct: np.ndarray, y: int,
                     dys: np.ndarray, dxs: np.ndarray, min_disp: int, pad: int, run_lo: np.ndarray,
                     run_hi: np.ndarray, nruns: np.ndarray) -> None:  # pragma: no cover - numba
    """Row ``y``'s sums of Eq. 5.14 with symmetric weights, disparity-major: ``num[i, x] = Σ_k wl[k, x]
    wr[k, x - d] c(q, d)`` and ``den[i, x] = Σ_k wl[k, x] wr[k, x - d]`` (``d = min_disp + i``, ``q = (y, x) +
    o_k``; ``ct`` the cost volume as (H, D, W + 2 pad), columns shifted by ``pad >= max |dx|``, zero outside);
    only the terms with ``q`` and ``x - d`` inside the images, and only on slice ``i``'s runs of columns
    ``[run_lo[i, r], run_hi[i, r])``, ``r < nruns[i]`` (the others are left as they are).

    The inner loop runs along the row (hundreds of pixels, contiguous in every array) instead of over the
    disparities of one pixel, and each sum still adds its terms in the order of ``k``; a zero weight adds
    ``0·c = 0``, so the sums equal those that skip it, and a sum does not depend on the runs it lies in. Up to
    four consecutive offsets on one window row (the same ``q`` row) are added in one pass over the run, so that
    ``num`` and ``den`` are read and written once per four terms: the pass runs over every ``x`` with ``x - d``
    inside the image, and a term whose ``q`` lies outside adds ``0·0`` (its left weight is 0 there, the padded
    cost too), which leaves the sum unchanged bit for bit (it starts at +0, so it is never -0)."""
    h = ct.shape[0]
    nd = ct.shape[1]
    w = ct.shape[2] - 2 * pad
    nk = dys.shape[0]
    k = 0
    while k < nk:
        qy = y + dys[k]
        n = 1
        while n < 4 and k + n < nk and dys[k + n] == dys[k]:
            n += 1
        if qy < 0 or qy >= h:
            k += n
            continue
        for i in range(nd):
            if nruns[i] == 0:
                continue
            d = min_disp + i
            cr = ct[qy, i]
            if n == 4:
                for r in range(nruns[i]):
                    lo = max(max(0, d), run_lo[i, r])
                    hi = min(min(w, w + d), run_hi[i, r])
                    if hi <= lo:
                        continue
                    ns = num[i, lo:hi]
                    ds = den[i, lo:hi]
                    o = lo + pad
                    a0, b0, c0 = wl[k, lo:hi], wr[k, lo - d:hi - d], cr[o + dxs[k]:o + dxs[k] + hi - lo]
                    a1, b1, c1 = (wl[k + 1, lo:hi], wr[k + 1, lo - d:hi - d],
                                  cr[o + dxs[k + 1]:o + dxs[k + 1] + hi - lo])
                    a2, b2, c2 = (wl[k + 2, lo:hi], wr[k + 2, lo - d:hi - d],
                                  cr[o + dxs[k + 2]:o + dxs[k + 2] + hi - lo])
                    a3, b3, c3 = (wl[k + 3, lo:hi], wr[k + 3, lo - d:hi - d],
                                  cr[o + dxs[k + 3]:o + dxs[k + 3] + hi - lo])
                    for j in range(hi - lo):
                        nn = ns[j]
                        dd = ds[j]
                        ww = a0[j] * b0[j]
                        nn += ww * c0[j]
                        dd += ww
                        ww = a1[j] * b1[j]
                        nn += ww * c1[j]
                        dd += ww
                        ww = a2[j] * b2[j]
                        nn += ww * c2[j]
                        dd += ww
                        ww = a3[j] * b3[j]
                        nn += ww * c3[j]
                        dd += ww
                        ns[j] = nn
                        ds[j] = dd
                continue
            for kk in range(k, k + n):
                dx = dxs[kk]
                for r in range(nruns[i]):
                    lo = max(max(max(0, -dx), d), run_lo[i, r])
                    hi = min(min(min(w, w - dx), w + d), run_hi[i, r])
                    if hi <= lo:
                        continue
                    wls = wl[kk, lo:hi]
                    wrs = wr[kk, lo - d:hi - d]
                    cs = cr[lo + dx + pad:hi + dx + pad]
                    ns = num[i, lo:hi]
                    ds = den[i, lo:hi]
                    for j in range(hi - lo):
                        ww = wls[j] * wrs[j]
                        ns[j] += ww * cs[j]
                        ds[j] += ww
        k += n


@njit(cache=True, nogil=True)
def _row_runs(band: np.ndarray, y: int, seg: int, w: int, run_lo: np.ndarray, run_hi: np.ndarray,
              nruns: np.ndarray) -> int:  # pragma: no cover - numba
    """Row ``y``'s runs of consecutive segments whose band holds slice ``i``, per slice (into the three arrays);
    returns how many slices have at least one."""
    nseg = band.shape[1]
    nd = nruns.shape[0]
    busy = 0
    for i in range(nd):
        nr = 0
        open_ = False
        for s in range(nseg):
            inside = band[y, s, 0] <= i <= band[y, s, 1]
            if inside and not open_:
                run_lo[i, nr] = s * seg
                open_ = True
            elif not inside and open_:
                run_hi[i, nr] = s * seg
                nr += 1
                open_ = False
        if open_:
            run_hi[i, nr] = w
            nr += 1
        nruns[i] = nr
        if nr > 0:
            busy += 1
    return busy


@njit(cache=True, parallel=True, fastmath=True, nogil=True)
def _bpasw_symmetric_kernel(cost: np.ndarray, lab_l: np.ndarray, lab_r: np.ndarray, lab3_l: np.ndarray,
                            lab3_r: np.ndarray, dys: np.ndarray, dxs: np.ndarray, prox: np.ndarray, min_disp: int,
                            kernel: int, s0: float, s_min: float, mirror: np.ndarray, nbands: int,
                            ct: np.ndarray, pad: int, band: np.ndarray, seg: int, y_a: int,
                            y_b: int) -> np.ndarray:  # pragma: no cover - numba
    """Eq. 5.14 with symmetric weights and no continuity prior (the ``bpasw`` matcher's aggregation), inside a
    band of slices per row segment (``band[y, s] = (lo, hi)``, inclusive slice indices, columns ``[s·seg, (s +
    1)·seg)``; ``lo > hi``: none) on the rows ``[y_a, y_b)``; every other entry is +inf. The sums run along
    the rows of the disparity-major volume ``ct`` (:func:`_accumulate_runs`), so an entry does not depend on
    the band: a band over every slice is the whole volume's aggregation. The path of :func:`_bpasw_kernel` for
    this case, compiled on its own: a first run compiles only what it calls."""
    h, w, nd = cost.shape
    nk = dys.shape[0]
    nseg = band.shape[1]
    log_norm = 1.0 / np.log(s0 / s_min) if kernel == 0 else 1.0
    out = np.full((h, w, nd), np.inf, dtype=np.float32)
    # rows run in bands, each in order, so that a row's weights towards the rows above are read from the
    # weights those rows computed towards it (mirror); a band first computes the rows above it it reads
    nrows = _kept_rows(dys, mirror)
    back = nrows - 1
    rows = max(0, y_b - y_a)
    band_rows = (rows + nbands - 1) // nbands
    for bi in prange(nbands):
        y0 = y_a + bi * band_rows
        y1 = min(y_b, y0 + band_rows)
        if y1 <= y0:
            continue
        # weights of the rows kept, left and right image (the symmetric sums read the right weights forwards)
        tl = np.zeros((nrows, nk, w), dtype=np.float32)
        tr = np.zeros((nrows, nk, w), dtype=np.float32)
        wbuf = np.empty(w, dtype=np.float32)
        # (``y < y0``: the rows above the band need only their forward offsets; a run-time flag, so that
        # _weight_row is compiled for one signature)
        for y in range(max(0, y0 - back), y0):  # only their weights the band's rows read
            _weight_row(tl, y % nrows, lab_l, lab3_l, y, dys, dxs, prox, mirror, nrows, kernel, s0, s_min,
                        log_norm, False, y < y0, wbuf)
            _weight_row(tr, y % nrows, lab_r, lab3_r, y, dys, dxs, prox, mirror, nrows, kernel, s0, s_min,
                        log_norm, False, y < y0, wbuf)
        num = np.empty(nd, dtype=np.float32)
        den = np.empty(nd, dtype=np.float32)
        numr = np.empty((nd, w), dtype=np.float32)
        denr = np.empty((nd, w), dtype=np.float32)
        run_lo = np.empty((nd, nseg + 1), dtype=np.int64)
        run_hi = np.empty((nd, nseg + 1), dtype=np.int64)
        nruns = np.empty(nd, dtype=np.int64)
        for y in range(y0, y1):
            slot = y % nrows
            _weight_row(tl, slot, lab_l, lab3_l, y, dys, dxs, prox, mirror, nrows, kernel, s0, s_min, log_norm,
                        False, y < y0, wbuf)
            _weight_row(tr, slot, lab_r, lab3_r, y, dys, dxs, prox, mirror, nrows, kernel, s0, s_min,
                        log_norm, False, y < y0, wbuf)
            if _row_runs(band, y, seg, w, run_lo, run_hi, nruns) == 0:
                continue
            numr[:] = 0.0
            denr[:] = 0.0
            _accumulate_runs(numr, denr, tl[slot], tr[slot], ct, y, dys, dxs, min_disp, pad, run_lo, run_hi, nruns)
            for x in range(w):
                s = x // seg
                blo = max(band[y, s, 0], 0)
                bhi = min(band[y, s, 1], nd - 1)
                if blo > bhi:
                    continue
                # the whole pixel's quotients in one loop over the slices (vectorised: its division rounds as
                # the whole volume's does), then +inf outside the band
                nvalid = min(nd, x - min_disp + 1)
                for i in range(nd):
                    num[i] = numr[i, x]
                    den[i] = denr[i, x]
                for i in range(nd):
                    if i < nvalid and den[i] > 0.0:
                        out[y, x, i] = num[i] / den[i]
                    else:
                        out[y, x, i] = cost[y, x, i]
                out[y, x, :blo] = np.inf
                out[y, x, bhi + 1:] = np.inf
    return out


@njit(cache=True, parallel=True, fastmath=True, nogil=True)
def _bpasw_kernel(cost: np.ndarray, lab_l: np.ndarray, lab_r: np.ndarray, lab3_l: np.ndarray,
                  lab3_r: np.ndarray, dys: np.ndarray,
                  dxs: np.ndarray, prox: np.ndarray, min_disp: int, kernel: int, s0: float,
                  s_min: float, prior: np.ndarray, use_prior: bool, cont_w: float,
                  symmetric: bool, mirror: np.ndarray, nbands: int) -> np.ndarray:  # pragma: no cover - numba
    """Eq. 5.14 with a continuity prior (Eqs. 5.9, 5.12) or left weights only, pixel by pixel (the symmetric
    case without a prior is :func:`_bpasw_symmetric_kernel`)."""
    h, w, nd = cost.shape
    nk = dys.shape[0]
    log_norm = 1.0 / np.log(s0 / s_min) if kernel == 0 else 1.0
    out = np.empty((h, w, nd), dtype=np.float32)
    # rows run in bands as in _bpasw_symmetric_kernel
    nrows = _kept_rows(dys, mirror)
    back = nrows - 1
    band = (h + nbands - 1) // nbands
    for bi in prange(nbands):
        y0 = bi * band
        y1 = min(h, y0 + band)
        # weights of the rows kept, left and right image; the right one column-reversed, so that the inner loop
        # over disparities reads it forwards (SIMD)
        tl = np.zeros((nrows, nk, w), dtype=np.float32)
        tr = np.zeros((nrows if symmetric else 1, nk, w), dtype=np.float32)
        wbuf = np.empty(w, dtype=np.float32)
        for y in range(max(0, y0 - back), y0):  # only their weights the band's rows read
            _weight_row(tl, y % nrows, lab_l, lab3_l, y, dys, dxs, prox, mirror, nrows, kernel, s0, s_min,
                        log_norm, False, True, wbuf)
            if symmetric:
                _weight_row(tr, y % nrows, lab_r, lab3_r, y, dys, dxs, prox, mirror, nrows, kernel, s0, s_min,
                            log_norm, True, True, wbuf)
        num = np.empty(nd, dtype=np.float32)
        den = np.empty(nd, dtype=np.float32)
        for y in range(y0, y1):
            slot = y % nrows
            _weight_row(tl, slot, lab_l, lab3_l, y, dys, dxs, prox, mirror, nrows, kernel, s0, s_min, log_norm,
                        False, False, wbuf)
            if symmetric:
                _weight_row(tr, slot, lab_r, lab3_r, y, dys, dxs, prox, mirror, nrows, kernel, s0, s_min,
                            log_norm, True, False, wbuf)
            for x in range(w):
                num[:] = 0.0
                den[:] = 0.0
                # candidates i with x - d >= 0: d = min_disp + i <= x
                nvalid = min(nd, x - min_disp + 1)
                base = w - 1 - x + min_disp  # right-weight column of candidate i is base + i
                for k in range(nk):
                    qy = y + dys[k]
                    qx = x + dxs[k]
                    if qy < 0 or qy >= h or qx < 0 or qx >= w:
                        continue
                    wl = tl[slot, k, x]
                    if wl == 0.0:
                        continue
                    if use_prior:
                        pq = prior[qy, qx]
                        for i in range(nvalid):
                            ww = wl
                            if symmetric:
                                ww = ww * tr[slot, k, base + i]
                            if pq >= 0 and abs(pq - i) > 1:
                                ww = ww * np.float32(cont_w)
                            num[i] += ww * cost[qy, qx, i]
                            den[i] += ww
                    elif symmetric:
                        wrk = tr[slot, k, base:base + nvalid]
                        cq = cost[qy, qx, :nvalid]
                        for i in range(nvalid):
                            ww = wl * wrk[i]
                            num[i] += ww * cq[i]
                            den[i] += ww
                    else:
                        for i in range(nvalid):
                            num[i] += wl * cost[qy, qx, i]
                            den[i] += wl
                for i in range(nd):
                    if i < nvalid and den[i] > 0.0:
                        out[y, x, i] = num[i] / den[i]
                    else:
                        out[y, x, i] = cost[y, x, i]
    return out


def _mirrors(dys: np.ndarray, dxs: np.ndarray) -> np.ndarray:
    """For each window offset pointing backwards (up, or left on the row), the index of its opposite; -1 for
    the others (and for an offset without an opposite in the window)."""
    where = {(int(a), int(b)): k for k, (a, b) in enumerate(zip(dys, dxs, strict=True))}
    out = np.full(len(dys), -1, np.int64)
    for k, (a, b) in enumerate(zip(dys, dxs, strict=True)):
        if a < 0 or (a == 0 and b < 0):
            out[k] = where.get((-int(a), -int(b)), -1)
    return out


def aggregate_bpasw(cost: np.ndarray, left: np.ndarray, right: np.ndarray | None = None, *,
                    radius: int = 16, dilation: int = 2, min_disp: int = 0,
                    kernel: Literal["weber", "exp"] = "weber", similarity_s0: float = 28.0,
                    similarity_s_min: float = 1.0, proximity_s0: float | None = None,
                    gamma_color: float = 7.0, gamma_proximity: float = 17.5,
                    prior: np.ndarray | None = None, continuity_weight: float = 0.2,
                    band: SegmentBand | None = None) -> np.ndarray:
    """BPASW aggregation of a cost volume with symmetric adaptive support weights (thesis Eqs. 5.7–5.14).

    ``C(p, d) = Σ_q w_l(p, q) w_r(p̄, q̄) c(q, d) / Σ_q w_l(p, q) w_r(p̄, q̄)`` with ``p̄ = p - (d, 0)``,
    ``q̄ = q - (d, 0)`` and ``w = w_dist · w_dissim [· w_cont]`` (Eq. 5.13), each factor a clipped
    Weber–Fechner weight (module docstring).

    Parameters
    ----------
    cost : ndarray, float32, (H, W, D)
        Per-pixel cost, e.g. :func:`~prismstereo.matching.local.costs.cost_s_ad` (Eq. 5.6).
    left, right : ndarray, (H, W, 3) RGB or (H, W) gray, 0..255
        The images the weights come from. ``right=None`` gives left-only (asymmetric) weights.
    radius : int
        Window half-size in pixels.
    dilation : int
        Sample the window every ``dilation`` pixels (1 = full window; 2 = 4× faster).
    min_disp : int
        Disparity of slice 0 of ``cost``.
    kernel : {"weber", "exp"}
        Clipped Weber–Fechner weights (default) or Yoon–Kweon ``exp(-S/γ)`` weights.
    similarity_s0, similarity_s_min : float
        Threshold ``S0`` and floor ``S_min`` of the colour weight, CIE-Lab ΔE units.
    proximity_s0 : float, optional
        Threshold of the distance weight in pixels; default just beyond the window corner
        (``√2·radius + 1``).
    gamma_color, gamma_proximity : float
        Yoon–Kweon constants for ``kernel="exp"``.
    prior : ndarray, int, (H, W), optional
        A current disparity estimate (slice index, ``-1`` unknown) enabling the continuity law
        (Eqs. 5.9, 5.12): neighbours whose prior differs from the candidate by more than 1 px are
        weighted by ``continuity_weight``.
    band : SegmentBand, optional
        Compute only these slices (symmetric weights, no ``prior``); the others are +inf. The entries computed
        equal those of the whole volume's aggregation.

    Returns
    -------
    ndarray, float32, (H, W, D)
        Aggregated cost; entries with ``x - d < 0`` keep the input's out-of-range value.
    """
    if radius < 0 or dilation < 1:
        raise MatchingError(f"expected radius >= 0 and dilation >= 1, got radius={radius}, "
                            f"dilation={dilation}")
    if kernel not in ("weber", "exp"):
        raise MatchingError(f"expected kernel 'weber' or 'exp', got {kernel!r}")
    vol = np.ascontiguousarray(cost, dtype=np.float32)
    lab_l = to_lab(left)
    symmetric = right is not None
    lab_r = to_lab(right) if right is not None else lab_l
    if lab_l.shape[:2] != vol.shape[:2] or lab_r.shape != lab_l.shape:
        raise MatchingError(f"expected images of the cost volume's size {vol.shape[:2]}, got "
                            f"{lab_l.shape[:2]} and {lab_r.shape[:2]}")
    dys, dxs, dist = window_offsets(radius, dilation)
    kid = 0 if kernel == "weber" else 1
    if kernel == "weber":
        p_s0 = proximity_s0 if proximity_s0 is not None else np.sqrt(2.0) * radius + 1.0
        prox = weber_fechner_weight(dist, s0=max(p_s0, 1.0 + 1e-6), s_min=1.0)
        s0, s_min = float(similarity_s0), float(similarity_s_min)
        if not s0 > s_min > 0:
            raise MatchingError(f"expected similarity_s0 > similarity_s_min > 0, got {s0}, {s_min}")
    else:
        prox = np.exp(-dist / gamma_proximity)
        s0, s_min = float(gamma_color), 1.0
    use_prior = prior is not None
    pr = (np.ascontiguousarray(prior, dtype=np.int64) if prior is not None
          else np.zeros((1, 1), dtype=np.int64))
    # bands of rows in parallel, a multiple of the threads; each band first computes the rows above it reads
    nt = numba.get_num_threads()
    nbands = nt * max(1, min(4, vol.shape[0] // (nt * (4 * radius + 4))))
    # planar Lab for the weights' vectorised rows
    lab3_l = np.ascontiguousarray(lab_l.transpose(2, 0, 1))
    lab3_r = np.ascontiguousarray(lab_r.transpose(2, 0, 1)) if symmetric else lab3_l
    if band is not None and (not symmetric or use_prior):
        raise MatchingError("expected a band only with both images' weights and no continuity prior")
    if symmetric and not use_prior:
        h, w, nd = vol.shape
        if band is None:  # every slice of every row: one segment per row
            bounds, seg, y_a, y_b = np.tile(np.array([0, nd - 1], np.int64), (h, 1, 1)), max(w, 1), 0, h
        else:
            bounds, seg = band.check(h, w), int(band.segment)
            busy = np.flatnonzero((bounds[:, :, 0] <= bounds[:, :, 1]).any(axis=1))
            if busy.size == 0:
                return np.full(vol.shape, np.inf, dtype=np.float32)
            y_a, y_b = int(busy[0]), int(busy[-1]) + 1
            nbands = nt * max(1, min(4, (y_b - y_a) // (nt * (4 * radius + 4))))
        pad = int(np.abs(dxs).max())
        return _bpasw_symmetric_kernel(vol, lab_l, lab_r, lab3_l, lab3_r, dys, dxs, prox.astype(np.float64),
                                       int(min_disp), kid, s0, s_min, _mirrors(dys, dxs), nbands,
                                       _disparity_major(vol, pad), pad, bounds, seg, y_a, y_b)
    return _bpasw_kernel(vol, lab_l, lab_r, lab3_l, lab3_r, dys, dxs, prox.astype(np.float64), int(min_disp), kid,
                         s0, s_min, pr, use_prior, float(continuity_weight), symmetric, _mirrors(dys, dxs), nbands)
