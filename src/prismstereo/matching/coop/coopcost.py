"""Matching cost and edge-aware aggregation for the ``coop`` matcher's initial map and data term.

The thesis computes its initial map with adaptive support weights (BPASW, §5.2): a per-pixel weighted
mean of a truncated dissimilarity, weights from colour similarity and proximity. Here the same idea is
realised with the guided filter (He et al. 2013; Hosni et al. 2013, "fast cost-volume filtering"), an
edge-aware adaptive-weight aggregation whose cost is O(1) per pixel and disparity, over a robust
combination of truncated colour AD, truncated x-gradient difference and census Hamming distance
(Mei et al. 2011). Both views' volumes are produced (the right one for the cross-check, thesis Eq. 6.7).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np
import numpy.typing as npt
from numba import njit, prange

from prismstereo.checks import check_fields
from prismstereo.errors import ConfigError, MatchingError
from prismstereo.matching.local.costs import popcount64

__all__ = ["CostParams", "ShearedInputs", "aggregated_costs", "colour_term", "guided_filter_volume", "keep_outside",
           "raw_cost", "raw_cost_from", "shear_row_boxes", "sheared_costs", "sheared_inputs", "sheared_row_boxes",
           "sheared_row_costs_at"]

F32 = npt.NDArray[np.float32]


@dataclass(frozen=True)
class CostParams:
    """Parameters of the pixel cost and its aggregation.

    Attributes
    ----------
    tau_color : float
        Truncation of the mean absolute colour difference (0..255 scale); 0 switches the colour term off.
    tau_grad : float
        Truncation of the absolute x-gradient difference (0..255 scale per pixel); 0 switches it off (both 0:
        census alone, as ``coop`` does when the views' colours disagree beyond an intensity mapping).
    lambda_census : float
        Scale of the census term ``1 - exp(-hamming / lambda_census)``.
    lambda_ad : float
        Scale of the AD+gradient term ``1 - exp(-ad / lambda_ad)``.
    census_rx, census_ry : int
        Half sizes of the census window.
    radius : int
        Guided-filter window radius (the adaptive-support window of BPASW).
    eps : float
        Guided-filter regulariser on colours scaled to 0..1 (smaller = more edge-aware).
    """

    tau_color: float = 20.0
    tau_grad: float = 6.0
    lambda_census: float = 30.0
    lambda_ad: float = 10.0
    census_rx: int = 4
    census_ry: int = 3
    radius: int = 9
    eps: float = 1e-4

    def __post_init__(self) -> None:  # a census of (2 rx + 1)(2 ry + 1) - 1 <= 64 bits
        """Validate the fields; implementation helper with no thesis equation of its own."""
        check_fields(self, {"census_rx": (0, 7), "census_ry": (0, 7), "radius": (0, 100), "tau_color": (0, None),
                            "tau_grad": (0, None)}, positive=("lambda_census", "lambda_ad", "eps"))
        if (2 * self.census_rx + 1) * (2 * self.census_ry + 1) > 65:
            raise ConfigError(f"CostParams.census_rx, census_ry: expected a census window of at most 65 pixels, "
                              f"got {2 * self.census_rx + 1}x{2 * self.census_ry + 1}")


def census_bits(gray: F32, ry: int, rx: int) -> npt.NDArray[np.uint64]:
    """Census transform over a ``(2 ry + 1) x (2 rx + 1)`` window (bit set where the neighbour is darker).

    The census of Mei et al. 2011 (module docstring), an addition to the thesis with no thesis equation of its own.
    """
    return _census_sheared(gray, ry, rx, 0.0)


@njit(cache=True)
def _census_table(lam_c: float) -> npt.NDArray[np.float64]:
    """``1 - exp(-hd / λ_census)`` for every Hamming distance of a 64-bit census (the same float64 values as
    evaluating it per pixel).

    The census part of the pixel cost (Mei et al. 2011), an addition to the thesis with no thesis equation of its own.
    """
    t = np.empty(65, np.float64)
    for hd in range(65):
        t[hd] = 1.0 - np.exp(-hd / lam_c)
    return t


@njit(cache=True, inline="always")
def _ad_cost(left: F32, right: F32, gl: F32, gr: F32, y: int, x: int, xr: int, tau_c: float, tau_g: float,
             lam_ad: float) -> float:
    """``1 - exp(-(min(AD, τ_c) + min(|∇x|, τ_g)) / λ_ad)`` of left pixel (y, x) against right pixel (y, xr).

    A truncated, robust variant of the AD + gradient dissimilarity ``S_AD`` of thesis Eq. 5.6 (x-gradient only).
    """
    ad = 0.0
    for c in range(left.shape[2]):
        ad += abs(left[y, x, c] - right[y, xr, c])
    ad = min(ad / left.shape[2], tau_c)
    gd = min(abs(gl[y, x] - gr[y, xr]), tau_g)
    return 1.0 - np.exp(-(ad + gd) / lam_ad)


@njit(cache=True, parallel=True, nogil=True)
def _ad_term(left: F32, right: F32, gl: F32, gr: F32, min_disp: int, ndisp: int, tau_c: float, tau_g: float,
             lam_ad: float) -> npt.NDArray[np.float64]:
    """The colour + gradient part ``1 - exp(-(AD + ∇) / λ_ad)`` of :func:`_raw_cost` (NaN where x - d falls
    outside the right image): it does not depend on the census window, so sheared volumes share it.

    A truncated, robust variant of the AD + gradient dissimilarity ``S_AD`` of thesis Eq. 5.6 (x-gradient only).
    """
    h, w = left.shape[:2]
    out = np.full((h, w, ndisp), np.nan)
    for y in prange(h):
        for x in range(w):
            for k in range(ndisp):
                xr = x - (min_disp + k)
                if xr < 0 or xr >= w:
                    continue
                out[y, x, k] = _ad_cost(left, right, gl, gr, y, x, xr, tau_c, tau_g, lam_ad)
    return out


@njit(cache=True, inline="always")
def _reflect(p: int, n: int) -> int:
    """OpenCV's ``BORDER_REFLECT`` index (``fedcba|abcdef|fedcba``) of ``p`` in ``[0, n)``.

    Implementation helper (border index) with no thesis equation of its own.
    """
    if n == 1:
        return 0
    while p < 0 or p >= n:
        p = -p - 1 if p < 0 else 2 * n - 1 - p
    return p


@njit(cache=True, nogil=True)
def _census_raw_row(ad_row: npt.NDArray[np.float64], cl_row: npt.NDArray[np.uint64],
                    cr_row: npt.NDArray[np.uint64], need: npt.NDArray[np.bool_], min_disp: int,
                    tab: npt.NDArray[np.float64], raw: F32) -> None:
    """``raw[x, k]`` (W, D): the pixel cost ``ad + census`` (:func:`_raw_cost`'s) of one row at the columns of
    ``need``, 2 where the right pixel ``x - (min_disp + k)`` leaves the image.

    The pixel cost: a variant of thesis Eq. 5.6 plus a census term (an addition to the thesis).
    """
    w, ndisp = raw.shape
    for x in range(w):
        if not need[x]:
            continue
        c = cl_row[x]
        for k in range(ndisp):
            xr = x - (min_disp + k)
            if xr < 0 or xr >= w:
                raw[x, k] = 2.0
            else:
                raw[x, k] = ad_row[x, k] + tab[popcount64(c ^ cr_row[xr])]


@njit(cache=True, nogil=True)
def _row_needs(mask_row: npt.NDArray[np.bool_], r: int, need: npt.NDArray[np.bool_]) -> bool:
    """Flag in ``need`` (W,) the columns the (2r+1)-pixel row boxes of ``mask_row`` read (reflected borders);
    whether the row has any box at all.

    Implementation helper (the columns a row box reads) with no thesis equation of its own.
    """
    w = mask_row.size
    todo = False
    for x in range(w):
        if mask_row[x]:
            todo = True
            for o in range(-r, r + 1):
                need[_reflect(x + o, w)] = True
    return todo


@njit(cache=True, nogil=True)
def _row_box_mean(raw: F32, mask_row: npt.NDArray[np.bool_], r: int, inv: float, acc: npt.NDArray[np.float64],
             out_row: F32) -> None:
    """``out_row[x]`` (W, D): the (2r+1)-pixel mean of ``raw`` (W, D) around ``x`` at the columns of
    ``mask_row``, summed in float64 (``acc`` (D,) is scratch) in the window's order, as OpenCV's ``boxFilter``.

    Row-box aggregation of the pixel cost, an addition to the thesis with no thesis equation of its own.
    """
    w, ndisp = raw.shape
    for x in range(w):
        if not mask_row[x]:
            continue
        acc[:] = 0.0
        for o in range(-r, r + 1):
            xx = _reflect(x + o, w)
            for k in range(ndisp):
                acc[k] += raw[xx, k]
        for k in range(ndisp):
            out_row[x, k] = acc[k] * inv


@njit(cache=True, parallel=True, nogil=True)
def _census_row_box(ad: npt.NDArray[np.float64], cl: npt.NDArray[np.uint64], cr: npt.NDArray[np.uint64],
                    min_disp: int, lam_c: float, r: int, mask: npt.NDArray[np.bool_], out: F32) -> None:
    """``out[y, x]``: the (2r+1)-pixel row mean of the pixel costs ``ad + census`` (:func:`_raw_cost`'s) at
    the pixels of ``mask`` (reflected borders; untouched elsewhere).

    The row's pixel costs are float32, as :func:`_raw_cost` stores them, and their sum is exact in float64,
    so ``float32(sum * (1 / (2r+1)))`` is OpenCV's ``boxFilter`` of them bit for bit.

    Row-box aggregation of the pixel cost, an addition to the thesis with no thesis equation of its own.
    """
    h, w, ndisp = ad.shape
    tab = _census_table(lam_c)
    inv = 1.0 / (2 * r + 1)
    for y in prange(h):
        need = np.zeros(w, np.bool_)
        if not _row_needs(mask[y], r, need):
            continue
        raw = np.empty((w, ndisp), np.float32)
        _census_raw_row(ad[y], cl[y], cr[y], need, min_disp, tab, raw)
        _row_box_mean(raw, mask[y], r, inv, np.empty(ndisp), out[y])


class _RowBox(NamedTuple):
    """What :func:`_census_row_boxes_at` computes besides its arrays: disparities ``min_disp .. min_disp + ndisp
    - 1``, the pixel cost's ``τ_c``, ``τ_g``, ``λ_ad``, ``λ_census`` (:class:`CostParams`), the box radius ``r``."""

    min_disp: int
    ndisp: int
    tau_c: float
    tau_g: float
    lam_ad: float
    lam_c: float
    r: int


@njit(cache=True, parallel=True, nogil=True)
def _census_row_boxes_at(left: F32, right: F32, gl: F32, gr: F32, cl: npt.NDArray[np.uint64],
                         cr: npt.NDArray[np.uint64], box: _RowBox, mask: npt.NDArray[np.bool_], out: F32,
                         fill: F32) -> None:
    """:func:`_census_row_box` of every sheared right census ``cr`` (S, H, W) into ``out`` (S, H, W, D), with the
    colour + gradient term (:func:`_ad_term`'s float64 values) evaluated once, at the pixels the row boxes of
    ``mask`` read only, instead of read from a whole-image volume; ``out`` is ``fill`` elsewhere (when ``fill``
    has ``out``'s shape; untouched otherwise). Eqs. 6.21-6.22 with the box along the row only."""
    min_disp, ndisp, r = box.min_disp, box.ndisp, box.r
    tau_c, tau_g, lam_ad, lam_c = box.tau_c, box.tau_g, box.lam_ad, box.lam_c
    h, w = left.shape[:2]
    tab = _census_table(lam_c)
    inv = 1.0 / (2 * r + 1)
    copy = fill.shape == out.shape
    for y in prange(h):
        if copy:
            for x in range(w):
                if not mask[y, x]:
                    for i in range(cr.shape[0]):
                        out[i, y, x, :] = fill[i, y, x, :]
        need = np.zeros(w, np.bool_)
        if not _row_needs(mask[y], r, need):
            continue
        ad = np.empty((w, ndisp))
        for x in range(w):
            if not need[x]:
                continue
            for k in range(ndisp):
                xr = x - (min_disp + k)
                if 0 <= xr < w:
                    ad[x, k] = _ad_cost(left, right, gl, gr, y, x, xr, tau_c, tau_g, lam_ad)
        raw = np.empty((w, ndisp), np.float32)
        acc = np.empty(ndisp)
        for i in range(cr.shape[0]):
            _census_raw_row(ad, cl[y], cr[i, y], need, min_disp, tab, raw)
            _row_box_mean(raw, mask[y], r, inv, acc, out[i, y])


@njit(cache=True, parallel=True, nogil=True)
def _raw_cost(left: F32, right: F32, gl: F32, gr: F32, cl: npt.NDArray[np.uint64],
              cr: npt.NDArray[np.uint64], min_disp: int, ndisp: int, tau_c: float, tau_g: float,
              lam_ad: float, lam_c: float) -> F32:
    """Raw left-view cost C(y, x, k) for d = min_disp + k; pixels with x - d < 0 get the maximum 2.

    The pixel cost: a variant of the dissimilarity of thesis Eq. 5.6 plus a census term (an addition).
    """
    h, w = left.shape[:2]
    tab = _census_table(lam_c)
    out = np.full((h, w, ndisp), 2.0, dtype=np.float32)
    for y in prange(h):
        for x in range(w):
            for k in range(ndisp):
                xr = x - (min_disp + k)
                if xr < 0 or xr >= w:
                    continue
                out[y, x, k] = (_ad_cost(left, right, gl, gr, y, x, xr, tau_c, tau_g, lam_ad)
                                + tab[popcount64(cl[y, x] ^ cr[y, xr])])
    return out


@njit(cache=True, parallel=True, nogil=True)
def _raw_from_ad(ad: npt.NDArray[np.float64], cl: npt.NDArray[np.uint64], cr: npt.NDArray[np.uint64], min_disp: int,
                 lam_c: float) -> F32:
    """:func:`_raw_cost` from its colour + gradient part ``ad`` (:func:`_ad_term`'s float64 values): the same
    float64 sum ``ad + census`` rounded to float32, 2 where the right pixel leaves the image.

    The pixel cost: a variant of the dissimilarity of thesis Eq. 5.6 plus a census term (an addition).
    """
    h, w, ndisp = ad.shape
    tab = _census_table(lam_c)
    out = np.full((h, w, ndisp), 2.0, dtype=np.float32)
    for y in prange(h):
        for x in range(w):
            c = cl[y, x]
            for k in range(ndisp):
                xr = x - (min_disp + k)
                if xr < 0 or xr >= w:
                    continue
                out[y, x, k] = ad[y, x, k] + tab[popcount64(c ^ cr[y, xr])]
    return out


def _box(a: F32, r: int) -> F32:
    """Mean over a (2r+1)² window of each channel of an (H, W, C) or (H, W) float32 array.

    Implementation helper (box mean of the guided filter) with no thesis equation of its own.
    """
    k = 2 * r + 1
    if a.ndim == 3 and a.shape[2] > 512:
        return np.concatenate([_box(a[:, :, i:i + 512], r) for i in range(0, a.shape[2], 512)], axis=2)
    out = np.asarray(cv2.boxFilter(a, -1, (k, k), normalize=True, borderType=cv2.BORDER_REFLECT),
                     dtype=np.float32)
    if a.ndim == 3 and out.ndim == 2:
        out = out[:, :, None]
    return out


def guided_filter_volume(guide: npt.NDArray[np.generic], vol: F32, *, radius: int, eps: float,
                         right_of: int | None = None) -> F32:
    """Colour guided filter of every disparity slice of a cost volume (He et al. 2013).

    The guided filter is the edge-aware aggregation used in place of the adaptive support weights of thesis §5.2
    (Eqs. 5.7-5.14).

    Parameters
    ----------
    guide : (H, W, 3) uint8 or float
        Guidance image (RGB, 0..255).
    vol : (H, W, D) float32
        Cost volume.
    radius, eps : keyword-only
        Window radius and regulariser (colours scaled to 0..1).
    right_of : int, keyword-only, optional
        Filter the right view's volume of the left view's ``vol`` instead, read in place: slice k at right
        pixel x is ``vol`` at left pixel x + right_of + k, 2 outside the image.

    Returns
    -------
    (H, W, D) float32 filtered volume.
    """
    img = np.asarray(guide, dtype=np.float32) / 255.0
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    h, w, _ = img.shape
    r = radius
    mean_i = _box(img, r)  # H W 3
    ii = np.empty((h, w, 6), np.float32)
    idx = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]
    for n, (i, j) in enumerate(idx):
        ii[:, :, n] = img[:, :, i] * img[:, :, j]
    var = _box(ii, r)
    for n, (i, j) in enumerate(idx):
        var[:, :, n] -= mean_i[:, :, i] * mean_i[:, :, j]
    sig = np.empty((h, w, 3, 3), np.float64)
    for n, (i, j) in enumerate(idx):
        sig[:, :, i, j] = var[:, :, n]
        sig[:, :, j, i] = var[:, :, n]
    sig += eps * np.eye(3)
    inv = np.linalg.inv(sig).astype(np.float32)  # H W 3 3
    out = np.empty(vol.shape, np.float32)
    # the boxes of the cost, its colour products and the coefficients run fused in numba, a few disparity
    # slices per task (the slices are independent), with OpenCV's boxFilter arithmetic (float64 running sums
    # along the row, then down the column, BORDER_REFLECT): the result is cv2.boxFilter's bit for bit
    _gf_slices(np.ascontiguousarray(vol, dtype=np.float32), np.ascontiguousarray(img),
               np.ascontiguousarray(mean_i), np.ascontiguousarray(inv), int(r), 8, out,
               0 if right_of is None else int(right_of), right_of is not None)
    return out


@njit(cache=True, inline="always")
def _cost_at(vol: F32, yy: int, xx: int, kk: int, md: int, right: bool) -> np.float32:
    """``vol[yy, xx, kk]``, or with ``right`` the right view's cost ``vol[yy, xx + md + kk, kk]`` (2 outside).

    Implementation helper (volume read) with no thesis equation of its own.
    """
    if not right:
        return vol[yy, xx, kk]
    xl = xx + md + kk
    if 0 <= xl < vol.shape[1]:
        return vol[yy, xl, kk]
    return np.float32(2.0)


@njit(cache=True, nogil=True)
def _box_cost_row(vol: F32, img: F32, k0: int, ng: int, yy: int, r: int, fx: npt.NDArray[np.int64],
                  add: npt.NDArray[np.int64], sub: npt.NDArray[np.int64], row: npt.NDArray[np.float64],
                  md: int, right: bool) -> None:
    """``row[q, x, c]`` (4, W, ng): OpenCV's float64 row sum (its ``RowSum``: running for windows of 7 pixels
    and more) of row ``yy`` of slice ``k0 + c`` of the cost (q = 0) and of the cost times colour ``q - 1``
    (float32 products).

    Implementation helper (OpenCV's box filter reproduced) with no thesis equation of its own.
    """
    w = row.shape[1]
    k = 2 * r + 1
    if k <= 5:
        # OpenCV sums windows of 1, 3 and 5 pixels directly, left to right
        for x in range(w):
            for c in range(ng):
                s0 = 0.0
                s1 = 0.0
                s2 = 0.0
                s3 = 0.0
                for t in range(k):
                    xx = _reflect(x + t - r, w)
                    v = _cost_at(vol, yy, xx, k0 + c, md, right)
                    s0 += np.float64(v)
                    s1 += np.float64(v * img[yy, xx, 0])
                    s2 += np.float64(v * img[yy, xx, 1])
                    s3 += np.float64(v * img[yy, xx, 2])
                row[0, x, c] = s0
                row[1, x, c] = s1
                row[2, x, c] = s2
                row[3, x, c] = s3
        return
    # one slice at a time: the four running sums stay in registers
    for c in range(ng):
        kk = k0 + c
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        s3 = 0.0
        for t in range(k):
            xx = fx[t]
            v = _cost_at(vol, yy, xx, kk, md, right)
            s0 += np.float64(v)
            s1 += np.float64(v * img[yy, xx, 0])
            s2 += np.float64(v * img[yy, xx, 1])
            s3 += np.float64(v * img[yy, xx, 2])
        row[0, 0, c] = s0
        row[1, 0, c] = s1
        row[2, 0, c] = s2
        row[3, 0, c] = s3
        for x in range(w - 1):
            xa = add[x]
            xs = sub[x]
            va = _cost_at(vol, yy, xa, kk, md, right)
            vs = _cost_at(vol, yy, xs, kk, md, right)
            s0 += np.float64(va) - np.float64(vs)
            s1 += np.float64(va * img[yy, xa, 0]) - np.float64(vs * img[yy, xs, 0])
            s2 += np.float64(va * img[yy, xa, 1]) - np.float64(vs * img[yy, xs, 1])
            s3 += np.float64(va * img[yy, xa, 2]) - np.float64(vs * img[yy, xs, 2])
            row[0, x + 1, c] = s0
            row[1, x + 1, c] = s1
            row[2, x + 1, c] = s2
            row[3, x + 1, c] = s3


@njit(cache=True, nogil=True)
def _box_row(src: F32, yy: int, r: int, fx: npt.NDArray[np.int64], add: npt.NDArray[np.int64],
             sub: npt.NDArray[np.int64], row: npt.NDArray[np.float64]) -> None:
    """``row[q, x, c]``: OpenCV's float64 row sum (as :func:`_box_cost_row`) of row ``yy`` of ``src``
    (Q, H, W, ng).

    Implementation helper (OpenCV's box filter reproduced) with no thesis equation of its own.
    """
    w = row.shape[1]
    nq, _, _, ng = src.shape
    k = 2 * r + 1
    if k <= 5:
        # OpenCV sums windows of 1, 3 and 5 pixels directly, left to right
        for q in range(nq):
            for x in range(w):
                for c in range(ng):
                    s = 0.0
                    for t in range(k):
                        s += np.float64(src[q, yy, _reflect(x + t - r, w), c])
                    row[q, x, c] = s
        return
    for q in range(nq):
        for c in range(ng):
            s = 0.0
            for t in range(k):
                s += np.float64(src[q, yy, fx[t], c])
            row[q, 0, c] = s
            for x in range(w - 1):
                s += np.float64(src[q, yy, add[x], c]) - np.float64(src[q, yy, sub[x], c])
                row[q, x + 1, c] = s


@njit(cache=True, nogil=True)
def _box_column_step(acc: npt.NDArray[np.float64], nxt: npt.NDArray[np.float64], old: npt.NDArray[np.float64],
                     mean: F32, scale: float) -> None:
    """One output row of OpenCV's column pass (its ``ColumnSum``): ``mean = float32((acc + nxt) * scale)``,
    then ``acc = acc + nxt - old`` (all (Q, N); ``nxt`` the row sums entering the window, ``old`` leaving).

    Implementation helper (OpenCV's box filter reproduced) with no thesis equation of its own.
    """
    for q in range(acc.shape[0]):
        aq = acc[q]
        nq = nxt[q]
        oq = old[q]
        mq = mean[q]
        for i in range(aq.shape[0]):
            s = aq[i] + nq[i]
            mq[i] = np.float32(s * scale)
            aq[i] = s - oq[i]


@njit(cache=True, parallel=True, nogil=True)
def _gf_slices(vol: F32, img: F32, mean_i: F32, inv: F32, r: int, group: int, out: F32, md: int,
               right: bool) -> None:
    """The guided filter (He et al. 2013) of every slice of ``vol`` (H, W, D) (with ``right``: of its right
    view's volume, :func:`_cost_at`) into ``out``, ``group`` slices per task: a and b from the boxed cost and
    cost-colour products, then ``box(b) + Σ_c box(a_c) I_c``.

    Each box is OpenCV's ``boxFilter`` (normalised, BORDER_REFLECT) to the bit, streamed over the rows with a
    ring of 2r + 1 row sums; the float32 arithmetic of a, b and the output is the numpy formulation's.

    The guided filter is the edge-aware aggregation used in place of the adaptive support weights of thesis §5.2
    (Eqs. 5.7-5.14).
    """
    h, w, nd = vol.shape
    k = 2 * r + 1
    scale = 1.0 / (k * k)
    fx = np.empty(k, np.int64)
    for t in range(k):
        fx[t] = _reflect(t - r, w)
    add = np.empty(max(w - 1, 0), np.int64)
    sub = np.empty(max(w - 1, 0), np.int64)
    for x in range(w - 1):
        add[x] = _reflect(x + k - r, w)
        sub[x] = _reflect(x - r, w)
    # the coefficient rows a and b kept for the second box (its window and reflected borders): 2r + 1 rows,
    # the whole slice on an image of at most 2r + 1 rows; the second box trails the first by ``lag`` rows
    nkeep = k if h > k else h
    lag = r if h > k else h
    for task in prange((nd + group - 1) // group):
        k0 = task * group
        ng = min(group, nd - k0)
        ring = np.empty((k, 4, w, ng))
        acc = np.zeros((4, w * ng))
        mean = np.empty((4, w, ng), np.float32)
        meanf = mean.reshape(4, w * ng)
        ring2 = np.empty((k, 4, w, ng))
        acc2 = np.zeros((4, w * ng))
        mean2 = np.empty((4, w, ng), np.float32)
        meanf2 = mean2.reshape(4, w * ng)
        coef = np.empty((4, nkeep, w, ng), np.float32)  # row y in slot y % nkeep
        # the window's first 2r rows; row j of the padded image is row _reflect(j - r) of the slice
        for j in range(k - 1):
            _box_cost_row(vol, img, k0, ng, _reflect(j - r, h), r, fx, add, sub, ring[j], md, right)
            acc += ring[j].reshape(4, w * ng)
        for y1 in range(h + lag):
            if y1 < h:
                y = y1
                slot = y % nkeep
                nxt = ring[(y + k - 1) % k]
                _box_cost_row(vol, img, k0, ng, _reflect(y + k - 1 - r, h), r, fx, add, sub, nxt, md, right)
                _box_column_step(acc, nxt.reshape(4, w * ng), ring[y % k].reshape(4, w * ng), meanf, scale)
                for x in range(w):
                    m0 = mean_i[y, x, 0]
                    m1 = mean_i[y, x, 1]
                    m2 = mean_i[y, x, 2]
                    v00 = inv[y, x, 0, 0]
                    v01 = inv[y, x, 0, 1]
                    v02 = inv[y, x, 0, 2]
                    v10 = inv[y, x, 1, 0]
                    v11 = inv[y, x, 1, 1]
                    v12 = inv[y, x, 1, 2]
                    v20 = inv[y, x, 2, 0]
                    v21 = inv[y, x, 2, 1]
                    v22 = inv[y, x, 2, 2]
                    for c in range(ng):
                        mp = mean[0, x, c]
                        c0 = mean[1, x, c] - m0 * mp
                        c1 = mean[2, x, c] - m1 * mp
                        c2 = mean[3, x, c] - m2 * mp
                        a0 = v00 * c0 + v01 * c1 + v02 * c2
                        a1 = v10 * c0 + v11 * c1 + v12 * c2
                        a2 = v20 * c0 + v21 * c1 + v22 * c2
                        coef[0, slot, x, c] = a0
                        coef[1, slot, x, c] = a1
                        coef[2, slot, x, c] = a2
                        coef[3, slot, x, c] = mp - a0 * m0 - a1 * m1 - a2 * m2
            if y1 == lag - 1:  # the coefficient rows 0 .. lag - 1 are there: the second box's first 2r rows
                for j in range(k - 1):
                    _box_row(coef, _reflect(j - r, h) % nkeep, r, fx, add, sub, ring2[j])
                    acc2 += ring2[j].reshape(4, w * ng)
            y = y1 - lag
            if y < 0:
                continue
            # output row y: its window's last row, _reflect(y + r), is the coefficient row made last (or kept)
            nxt = ring2[(y + k - 1) % k]
            _box_row(coef, _reflect(y + k - 1 - r, h) % nkeep, r, fx, add, sub, nxt)
            _box_column_step(acc2, nxt.reshape(4, w * ng), ring2[y % k].reshape(4, w * ng), meanf2, scale)
            for x in range(w):
                g0 = img[y, x, 0]
                g1 = img[y, x, 1]
                g2 = img[y, x, 2]
                for c in range(ng):
                    q = mean2[3, x, c]
                    q = q + mean2[0, x, c] * g0
                    q = q + mean2[1, x, c] * g1
                    q = q + mean2[2, x, c] * g2
                    out[y, x, k0 + c] = q


class _CostInputs(NamedTuple):
    """A pair's pixel-cost inputs (:func:`_cost_inputs`): contiguous (H, W, 3) float32 RGB of both views (grey
    repeated), their (H, W) float32 grey images and x-gradients (Sobel / 4)."""

    left: F32
    right: F32
    gray_left: F32
    gray_right: F32
    grad_left: F32
    grad_right: F32


def _cost_inputs(left: npt.NDArray[np.generic], right: npt.NDArray[np.generic]) -> _CostInputs:
    """The :class:`_CostInputs` of a pair.

    Implementation helper (input preparation) with no thesis equation of its own.
    """
    lf = np.asarray(left, dtype=np.float32)
    rf = np.asarray(right, dtype=np.float32)
    if lf.ndim == 2:
        lf = np.repeat(lf[:, :, None], 3, axis=2)
        rf = np.repeat(rf[:, :, None], 3, axis=2)
    gray_l = np.asarray(cv2.cvtColor(lf, cv2.COLOR_RGB2GRAY), dtype=np.float32)
    gray_r = np.asarray(cv2.cvtColor(rf, cv2.COLOR_RGB2GRAY), dtype=np.float32)
    gxl = np.asarray(cv2.Sobel(gray_l, cv2.CV_32F, 1, 0, ksize=3) / 4.0, dtype=np.float32)
    gxr = np.asarray(cv2.Sobel(gray_r, cv2.CV_32F, 1, 0, ksize=3) / 4.0, dtype=np.float32)
    return _CostInputs(np.ascontiguousarray(lf), np.ascontiguousarray(rf), gray_l, gray_r, gxl, gxr)


def raw_cost(left: npt.NDArray[np.generic], right: npt.NDArray[np.generic], *, max_disp: int,
             min_disp: int = 0, params: CostParams | None = None) -> F32:
    """Pixel-wise left-view cost volume before aggregation, (H, W, D) float32 in [0, 2].

    ``(1 - exp(-(min(AD, τ_c) + min(|∇x|, τ_g)) / λ_ad)) + (1 - exp(-census / λ_census))``; slice k holds
    d = min_disp + k; pixels with x - d < 0 get the maximum 2.

    The pixel cost: a variant of the dissimilarity of thesis Eq. 5.6 plus a census term (an addition).
    """
    p = params or CostParams()
    ci = _cost_inputs(left, right)
    cl = census_bits(ci.gray_left, p.census_ry, p.census_rx)
    cr = census_bits(ci.gray_right, p.census_ry, p.census_rx)
    nd = max_disp - min_disp + 1
    return _raw_cost(ci.left, ci.right, ci.grad_left, ci.grad_right, cl, cr, int(min_disp), nd, p.tau_color,
                     p.tau_grad, p.lambda_ad, p.lambda_census)


def aggregated_costs(left: npt.NDArray[np.generic], right: npt.NDArray[np.generic], *, max_disp: int,
                     min_disp: int = 0, params: CostParams | None = None,
                     raw: F32 | None = None) -> tuple[F32, F32]:
    """Aggregated cost volumes of the left and the right view.

    The left volume is the ``c_data`` of the data term (thesis Eq. 6.21), the right one serves the cross-check
    (Eq. 6.7); the aggregation is the edge-aware aggregation used in place of the adaptive support weights of thesis
    §5.2 (Eqs. 5.7-5.14).

    Parameters
    ----------
    left, right : (H, W, 3) uint8 RGB (or (H, W) grey)
        Rectified pair, d = x_left - x_right.
    max_disp, min_disp : int, keyword-only
        Inclusive search range; slice k holds d = min_disp + k.
    params : CostParams

    Returns
    -------
    cost_left, cost_right : (H, W, D) float32
        Lower is better; ``cost_right[y, x, k]`` matches right pixel x with left pixel x + d.
    """
    p = params or CostParams()
    lf = np.asarray(left, dtype=np.float32)
    rf = np.asarray(right, dtype=np.float32)
    if lf.ndim == 2:
        lf = np.repeat(lf[:, :, None], 3, axis=2)
        rf = np.repeat(rf[:, :, None], 3, axis=2)
    if raw is None:
        raw = raw_cost(left, right, max_disp=max_disp, min_disp=min_disp, params=p)
    agg_l = guided_filter_volume(lf, raw, radius=p.radius, eps=p.eps)
    agg_r = guided_filter_volume(rf, raw, radius=p.radius, eps=p.eps, right_of=int(min_disp))
    return agg_l, agg_r


@njit(cache=True, parallel=True, nogil=True)
def _census_sheared(gray: F32, ry: int, rx: int, slope: float) -> npt.NDArray[np.uint64]:
    """Census of ``gray`` over a window whose row ``dy`` is shifted by ``-round(slope * dy)`` columns.

    The bit order is that of :func:`census_bits`, so a left census and a sheared right census compare the pixels
    that a surface ``d = a x + b y + c`` with ``b = slope`` maps onto each other.

    Sheared census for surfaces slanted in ``y`` (an addition to thesis Eq. 6.21) with no thesis equation of its own.
    """
    h, w = gray.shape
    out = np.zeros((h, w), dtype=np.uint64)
    for y in prange(h):
        for x in range(w):
            c = gray[y, x]
            bits = np.uint64(0)
            for dy in range(-ry, ry + 1):
                yy = min(max(y + dy, 0), h - 1)
                sh = int(np.floor(slope * dy + 0.5))
                for dx in range(-rx, rx + 1):
                    if dy == 0 and dx == 0:
                        continue
                    xx = min(max(x + dx - sh, 0), w - 1)
                    bits = (bits << np.uint64(1)) | np.uint64(1 if gray[yy, xx] < c else 0)
            out[y, x] = bits
    return out


@njit(cache=True, parallel=True, nogil=True)
def _shear_box_rows(hb: F32, slope: float, r: int, out: F32) -> None:
    """``out[y, x, k] = mean over |dy| <= r of hb[y + dy, x, k + slope * dy]`` (linear in k, rows clamped).

    Sheared aggregation for surfaces slanted in ``y`` (an addition to thesis Eq. 6.21) with no thesis equation of its
    own.
    """
    h, w, nd = hb.shape
    # the interpolation taps depend on (dy, k) only
    nr = 2 * r + 1
    k0s = np.empty((nr, nd), np.int64)
    k1s = np.empty((nr, nd), np.int64)
    fs = np.empty((nr, nd))
    gs = np.empty((nr, nd))
    for i in range(nr):
        for k in range(nd):
            kk = min(max(k + slope * (i - r), 0.0), nd - 1.0)
            k0s[i, k] = int(kk)
            k1s[i, k] = min(int(kk) + 1, nd - 1)
            fs[i, k] = kk - int(kk)
            gs[i, k] = 1.0 - fs[i, k]
    # per window row, the run of k whose taps are k + o, k + o + 1 with one weight pair (the same values as the
    # tables): read there as contiguous slices, the tables elsewhere (the clamped ends, a slope whose fraction
    # varies with k); the same products and sums in the same order
    ka = np.zeros(nr, np.int64)
    kb = np.zeros(nr, np.int64)
    offs = np.zeros(nr, np.int64)
    fu = np.zeros(nr)
    gu = np.zeros(nr)
    for i in range(nr):
        m = nd // 2
        o = k0s[i, m] - m
        if k1s[i, m] != m + o + 1:
            continue
        a = m
        while (a > 0 and k0s[i, a - 1] == a - 1 + o and k1s[i, a - 1] == a + o and fs[i, a - 1] == fs[i, m]
               and gs[i, a - 1] == gs[i, m]):
            a -= 1
        b = m + 1
        while (b < nd and k0s[i, b] == b + o and k1s[i, b] == b + o + 1 and fs[i, b] == fs[i, m]
               and gs[i, b] == gs[i, m]):
            b += 1
        ka[i], kb[i], offs[i], fu[i], gu[i] = a, b, o, fs[i, m], gs[i, m]
    for y in prange(h):
        s = np.empty(nd)
        for x in range(w):
            s[:] = 0.0
            # rows outside, disparities inside: the inner loop vectorises, each sum still runs over dy in order
            for i in range(nr):
                yy = min(max(y + i - r, 0), h - 1)
                row = hb[yy, x]
                a, b, o, f, g = ka[i], kb[i], offs[i], fu[i], gu[i]
                for k in range(a):
                    s[k] += gs[i, k] * row[k0s[i, k]] + fs[i, k] * row[k1s[i, k]]
                r0 = row[a + o:b + o]
                r1 = row[a + o + 1:b + o + 1]
                sv = s[a:b]
                for j in range(b - a):
                    sv[j] += g * r0[j] + f * r1[j]
                for k in range(b, nd):
                    s[k] += gs[i, k] * row[k0s[i, k]] + fs[i, k] * row[k1s[i, k]]
            for k in range(nd):
                out[y, x, k] = s[k] / nr


@dataclass(frozen=True)
class ShearedInputs:
    """The pixel inputs of a pair's sheared volumes (:func:`sheared_inputs`), made once for the front end's
    :func:`sheared_costs` and the sweep step's :func:`sheared_row_costs_at`.

    Attributes
    ----------
    left, right : (H, W, 3) float32        RGB of each view (grey repeated).
    grad_left, grad_right : (H, W) float32 x-gradients (Sobel / 4) of their grey images.
    census_left : (H, W) uint64             census of the left grey image.
    census_right : (S, H, W) uint64         census of the right grey image sheared by each slope.
    slopes : tuple of float                 the slopes of ``census_right``.
    params : CostParams                     the pixel-cost parameters they were made with.
    """

    left: F32
    right: F32
    grad_left: F32
    grad_right: F32
    census_left: npt.NDArray[np.uint64]
    census_right: npt.NDArray[np.uint64]
    slopes: tuple[float, ...]
    params: CostParams


def sheared_inputs(left: npt.NDArray[np.generic], right: npt.NDArray[np.generic], *,
                   params: CostParams | None = None, slopes: tuple[float, ...] = (0.0,)) -> ShearedInputs:
    """The :class:`ShearedInputs` of a rectified pair ((H, W, 3) uint8 RGB or (H, W) grey) for ``slopes``.

    Implementation helper (input preparation) with no thesis equation of its own.
    """
    p = params or CostParams()
    ci = _cost_inputs(left, right)
    cl = census_bits(ci.gray_left, p.census_ry, p.census_rx)
    cr = np.empty((len(slopes), *ci.gray_right.shape), np.uint64)
    for i, b in enumerate(slopes):
        cr[i] = _census_sheared(ci.gray_right, p.census_ry, p.census_rx, float(b))
    return ShearedInputs(ci.left, ci.right, ci.grad_left, ci.grad_right, cl, cr, tuple(float(b) for b in slopes), p)


def colour_term(inputs: ShearedInputs, *, max_disp: int, min_disp: int = 0) -> npt.NDArray[np.float64]:
    """The colour + gradient part of the pixel cost, ``1 - exp(-(min(AD, τ_c) + min(|∇x|, τ_g)) / λ_ad)``, of the
    pair of ``inputs``: (H, W, D) float64, NaN where ``x - d`` leaves the right image. It does not depend on the
    census window, so :func:`raw_cost_from` and :func:`sheared_costs` (``ad=``) share one evaluation.

    A truncated, robust variant of the AD + gradient dissimilarity ``S_AD`` of thesis Eq. 5.6 (x-gradient only).
    """
    p = inputs.params
    return _ad_term(inputs.left, inputs.right, inputs.grad_left, inputs.grad_right, int(min_disp),
                    int(max_disp) - int(min_disp) + 1, p.tau_color, p.tau_grad, p.lambda_ad)


def raw_cost_from(inputs: ShearedInputs, ad: npt.NDArray[np.float64], *, min_disp: int = 0) -> F32:
    """:func:`raw_cost` of the pair of ``inputs`` (with their ``params``) from its :func:`colour_term` ``ad``,
    bit for bit: (H, W, D) float32. ``inputs.slopes`` must hold 0 (its census is the unsheared one).

    The pixel cost: a variant of the dissimilarity of thesis Eq. 5.6 plus a census term (an addition).
    """
    if 0.0 not in inputs.slopes or ad.shape[:2] != inputs.census_left.shape:
        raise MatchingError("expected inputs with slope 0 among their slopes and a colour term of their pair")
    cr = inputs.census_right[inputs.slopes.index(0.0)]
    return _raw_from_ad(np.ascontiguousarray(ad, np.float64), inputs.census_left, cr, int(min_disp),
                        inputs.params.lambda_census)


def _check_inputs(inputs: ShearedInputs, shape: tuple[int, ...], p: CostParams, slopes: tuple[float, ...]) -> None:
    """Raise :class:`MatchingError` unless ``inputs`` fit this call; implementation helper with no thesis equation."""
    if inputs.left.shape[:2] != shape[:2] or inputs.params != p or inputs.slopes != tuple(float(b) for b in slopes):
        raise MatchingError("expected inputs made by sheared_inputs of this pair with the same params and slopes")


def sheared_costs(left: npt.NDArray[np.generic], right: npt.NDArray[np.generic], *, max_disp: int,
                  min_disp: int = 0, params: CostParams | None = None, slopes: tuple[float, ...] = (0.0,),
                  radius: int = 1, vertical: bool = True, inputs: ShearedInputs | None = None,
                  ad: npt.NDArray[np.float64] | None = None) -> F32:
    """Pixel cost volumes for surfaces slanted in ``y``: one per vertical disparity slope (an addition to Eq. 6.21).

    The census window of the right view and the ``(2 radius + 1)²`` smoothing box follow a surface of
    vertical slope ``b`` (``d = a x + b y + c``): row ``dy`` of the window is read ``b dy`` columns (census) or
    disparities (box) away. On a steep floor (``b`` near 1) the square windows of :func:`raw_cost` compare
    pixels of different surface points, so the true plane costs more than an aliased fronto-parallel one;
    the sheared volume removes that bias while keeping the full census. Slope 0 gives the boxed
    :func:`raw_cost` exactly.

    Parameters
    ----------
    left, right : (H, W, 3) uint8 RGB (or (H, W) grey)
    max_disp, min_disp : int, keyword-only
    params : CostParams, keyword-only
    slopes : tuple of float, keyword-only
        Vertical disparity slopes ``b`` (px per row), one volume each.
    radius : int, keyword-only
        Half size of the smoothing box (0: none).
    vertical : bool, keyword-only
        Box over rows as well (False: along the row only).
    inputs : ShearedInputs, keyword-only
        :func:`sheared_inputs` of the pair with ``params`` and ``slopes``, when already made.
    ad : (H, W, D) float64, keyword-only
        :func:`colour_term` of ``inputs`` over this range, when already made.

    Returns
    -------
    (S, H, W, D) float32, slice ``[s, :, :, k]`` = cost at disparity ``min_disp + k`` under slope ``slopes[s]``.
    """
    p = params or CostParams()
    si = sheared_inputs(left, right, params=p, slopes=slopes) if inputs is None else inputs
    _check_inputs(si, np.shape(left), p, slopes)
    cl = si.census_left
    nd = max_disp - min_disp + 1
    h, w = cl.shape
    out = np.empty((len(slopes), h, w, nd), np.float32)
    if ad is None:
        ad = colour_term(si, max_disp=max_disp, min_disp=min_disp)
    elif ad.shape != (h, w, nd):
        raise MatchingError(f"expected ad of shape {(h, w, nd)}, got {ad.shape}")
    every = np.ones((h, w), np.bool_)
    r = max(int(radius), 0)
    # the pixel costs boxed along the row, per slope; sheared over the rows from there
    hb = np.empty((h, w, nd), np.float32) if vertical and r > 0 else out[0]
    for i, b in enumerate(slopes):
        cr = si.census_right[i]
        if vertical and r > 0:
            _census_row_box(ad, cl, cr, int(min_disp), p.lambda_census, r, every, hb)
            _shear_box_rows(hb, float(b), r, out[i])
        else:
            _census_row_box(ad, cl, cr, int(min_disp), p.lambda_census, r, every, out[i])
    return out


def sheared_row_boxes(inputs: ShearedInputs, ad: npt.NDArray[np.float64], *, min_disp: int = 0,
                      radius: int = 1) -> F32:
    """The pixel costs of ``inputs`` boxed along the row (``2 radius + 1`` pixels), one volume per slope of
    ``inputs``: :func:`sheared_costs` ``(..., vertical=False)`` bit for bit, from the pair's :func:`colour_term`
    ``ad`` (H, W, D) float64. Returns (S, H, W, D) float32; :func:`shear_row_boxes` of it is :func:`sheared_costs`.

    Sheared costs for surfaces slanted in ``y`` (an addition to thesis Eq. 6.21) with no thesis equation of its own.
    """
    cl = inputs.census_left
    h, w = cl.shape
    if ad.shape[:2] != (h, w):
        raise MatchingError(f"expected ad of the pair's size {(h, w)}, got {ad.shape[:2]}")
    out = np.empty((len(inputs.slopes), h, w, ad.shape[2]), np.float32)
    every = np.ones((h, w), np.bool_)
    for i in range(len(inputs.slopes)):
        _census_row_box(ad, cl, inputs.census_right[i], int(min_disp), inputs.params.lambda_census,
                        max(int(radius), 0), every, out[i])
    return out


def shear_row_boxes(boxes: F32, slopes: tuple[float, ...], *, radius: int = 1) -> F32:
    """:func:`sheared_costs` (S, H, W, D) float32 from its row boxes ``boxes`` (:func:`sheared_row_boxes`, the
    same ``slopes`` and ``radius``): each slope's rows boxed along its slant, the same arithmetic.

    Sheared aggregation for surfaces slanted in ``y`` (an addition to thesis Eq. 6.21) with no thesis equation of its
    own.
    """
    r = max(int(radius), 0)
    if r == 0:
        return boxes.copy()
    out = np.empty_like(boxes)
    for i, b in enumerate(slopes):
        _shear_box_rows(boxes[i], float(b), r, out[i])
    return out


@njit(cache=True, parallel=True, nogil=True)
def _keep_outside(out: F32, fill: F32, mask: npt.NDArray[np.bool_]) -> None:
    """``out[:, y, x] = fill[:, y, x]`` (S, H, W, D) where ``mask[y, x]`` (H, W) is False.

    Implementation helper (a masked copy) with no thesis equation of its own.
    """
    ns, h, w = out.shape[:3]
    for y in prange(h):
        for x in range(w):
            if not mask[y, x]:
                for i in range(ns):
                    out[i, y, x, :] = fill[i, y, x, :]


def keep_outside(out: F32, fill: F32, mask: npt.NDArray[np.bool_]) -> None:
    """Copy ``fill`` into ``out`` (both (S, H, W, D) float32) at the pixels where ``mask`` (H, W) bool is False,
    in place, without a temporary of the copied part.

    Implementation helper (a masked copy) with no thesis equation of its own.
    """
    if out.shape != fill.shape or out.shape[1:3] != mask.shape:
        raise MatchingError(f"expected out and fill of one shape and a mask of their pixels, got {out.shape}, "
                            f"{fill.shape} and {mask.shape}")
    _keep_outside(out, fill, np.ascontiguousarray(mask, dtype=np.bool_))


def sheared_row_costs_at(left: npt.NDArray[np.generic], right: npt.NDArray[np.generic], selected: npt.NDArray[np.bool_],
                         out: F32, *, max_disp: int, min_disp: int = 0, params: CostParams | None = None,
                         slopes: tuple[float, ...] = (0.0,), radius: int = 1,
                         inputs: ShearedInputs | None = None, fill: F32 | None = None) -> None:
    """Write :func:`sheared_costs` ``(..., vertical=False)`` into ``out`` at the ``selected`` pixels only (and
    ``fill`` at the others, when given).

    Sheared costs for surfaces slanted in ``y`` (an addition to thesis Eq. 6.21) with no thesis equation of its own.

    Parameters
    ----------
    left, right : (H, W, 3) uint8 RGB (or (H, W) grey)
    selected : (H, W) bool
        The pixels to write.
    out : (S, H, W, D) float32
        Volume to update in place, one slice per slope; the other pixels are left as they are.
    max_disp, min_disp, params, slopes, radius, inputs : keyword-only
        As :func:`sheared_costs`.
    fill : (S, H, W, D) float32, keyword-only
        The volume whose values the other pixels of ``out`` get (None: they are left as they are).
    """
    p = params or CostParams()
    si = sheared_inputs(left, right, params=p, slopes=slopes) if inputs is None else inputs
    _check_inputs(si, np.shape(left), p, slopes)
    shape = si.census_left.shape
    nd = max_disp - min_disp + 1
    if out.shape != (len(slopes), *shape, nd):
        raise MatchingError(f"expected out of shape {(len(slopes), *shape, nd)}, got {out.shape}")
    if fill is not None and fill.shape != out.shape:
        raise MatchingError(f"expected fill of shape {out.shape}, got {fill.shape}")
    mask = np.ascontiguousarray(selected, dtype=np.bool_)
    box = _RowBox(int(min_disp), nd, p.tau_color, p.tau_grad, p.lambda_ad, p.lambda_census, max(int(radius), 0))
    _census_row_boxes_at(si.left, si.right, si.grad_left, si.grad_right, si.census_left, si.census_right, box,
                         mask, out, np.zeros((1, 1, 1, 1), np.float32) if fill is None else fill)
