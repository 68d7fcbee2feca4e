"""Disparity selection and post-processing: WTA, left–right check, subpixel, hole filling.

Disparity maps are float32 ``H×W`` in pixels (``d = x_left - x_right``), NaN = invalid.
"""

from __future__ import annotations

import cv2
import numpy as np
from numba import njit, prange

from prismstereo.errors import MatchingError
from prismstereo.matching.local._wmf import median_chunks, wmf_kernel
from prismstereo.matching.local.aggregation import to_lab

__all__ = [
    "cross_check",
    "fill_holes",
    "right_cost_volume",
    "right_disparity",
    "right_winner",
    "subpixel_refine",
    "weighted_median_filter",
    "winner_take_all",
]


def _check_volume(cost: np.ndarray) -> np.ndarray:
    vol = np.asarray(cost)
    if vol.ndim != 3 or vol.shape[2] < 1:
        raise MatchingError(f"expected a cost volume of shape (H, W, D), got shape {vol.shape}")
    return vol


def winner_take_all(cost: np.ndarray, *, min_disp: int = 0) -> np.ndarray:
    """Winner-take-all disparity ``D(x, y) = argmin_d C(x, y, d)`` (thesis Eq. 5.15).

    Parameters
    ----------
    cost : ndarray, (H, W, D)
        Slice ``i`` is disparity ``min_disp + i``. NaN entries are never selected.

    Returns
    -------
    ndarray, float32, (H, W)
        Integer-valued disparities; NaN where every entry of the pixel is NaN.
    """
    vol = _check_volume(cost)
    if np.isnan(vol).any():
        filled = np.where(np.isnan(vol), np.inf, vol)
        idx = np.argmin(filled, axis=2)
        disp = (idx + min_disp).astype(np.float32)
        disp[np.all(np.isnan(vol), axis=2)] = np.nan
        return disp
    return (np.argmin(vol, axis=2) + min_disp).astype(np.float32)


def _diagonal_volume(cost: np.ndarray, min_disp: int, fill: float) -> np.ndarray:
    h, w, nd = cost.shape
    out = np.full((h, w, nd), np.float32(fill), dtype=np.float32)
    for i in range(nd):  # loop over disparities, not pixels
        d = min_disp + i
        if d >= w:
            break
        out[:, : w - d, i] = cost[:, d:, i]
    return out


def right_cost_volume(cost: np.ndarray, *, min_disp: int = 0) -> np.ndarray:
    """The right view's cost volume read along the diagonals of the left one: ``C_R(x, d) = C_L(x + d, d)``.

    Exact for pixel-wise costs and for symmetric aggregation (box windows, BPASW with both-image weights);
    entries with ``x + d >= W`` get the volume's maximum (never preferred).
    """
    vol = np.ascontiguousarray(_check_volume(cost), dtype=np.float32)
    fill = float(np.nanmax(vol)) if vol.size else 0.0
    return _diagonal_volume(vol, int(min_disp), fill)


@njit(cache=True, parallel=True, nogil=True)
def _right_argmin(vol: np.ndarray, min_disp: int, fill: float) -> np.ndarray:  # pragma: no cover - numba
    """argmin over k of ``C_L(y, x + min_disp + k, k)`` (``fill`` past the right edge), NaN read as +inf, the
    first of equal minima (``np.argmin``'s); -1 where every entry is NaN."""
    h, w, nd = vol.shape
    out = np.empty((h, w), np.int64)
    for y in prange(h):
        for x in range(w):
            best = np.inf
            arg = 0
            seen = False
            for k in range(nd):
                xl = x + min_disp + k
                v = vol[y, xl, k] if xl < w else fill
                if np.isnan(v):
                    continue
                seen = True
                if v < best:
                    best = v
                    arg = k
            out[y, x] = arg if seen else -1
    return out


def right_winner(cost: np.ndarray, *, min_disp: int = 0) -> np.ndarray:
    """Integer WTA slice index of the RIGHT view from the LEFT cost volume, without building the right volume.

    The argmin over ``k`` of :func:`right_cost_volume` (NaN entries never selected, the first of equal minima),
    int64 ``(H, W)``; -1 where every entry is NaN.
    """
    vol = np.ascontiguousarray(_check_volume(cost), dtype=np.float32)
    fill = float(np.nanmax(vol)) if vol.size and not np.isnan(vol).all() else np.nan
    return _right_argmin(vol, int(min_disp), fill)


def right_disparity(cost: np.ndarray, *, min_disp: int = 0) -> np.ndarray:
    """WTA disparity of the RIGHT view from the LEFT cost volume (see :func:`right_cost_volume`).

    Returns float32 ``(H, W)``: for right pixel ``x`` the match is left pixel ``x + d``; NaN where every
    entry is NaN.
    """
    idx = right_winner(cost, min_disp=min_disp)
    return np.where(idx >= 0, (idx + min_disp).astype(np.float32), np.float32(np.nan)).astype(np.float32)


def _cross_check(dl: np.ndarray, dr: np.ndarray, tol: float) -> np.ndarray:
    h, w = dl.shape
    finite = np.isfinite(dl)
    xs = np.arange(w)[None, :]
    xr = np.floor(xs - np.where(finite, dl, 0.0) + 0.5).astype(np.int64)
    inside = finite & (xr >= 0) & (xr < w)
    rows = np.broadcast_to(np.arange(h)[:, None], (h, w))
    e = dr[rows, np.clip(xr, 0, w - 1)]
    with np.errstate(invalid="ignore"):
        return inside & np.isfinite(e) & (np.abs(dl - e) <= tol)


def cross_check(disp_left: np.ndarray, disp_right: np.ndarray, *, tolerance: float = 1.0) -> np.ndarray:
    """Left–right consistency check (thesis Eq. 6.7).

    A left pixel ``x`` with disparity ``d_L`` is valid when ``|d_L(x) - d_R(x - round(d_L))| <= tolerance``.

    Parameters
    ----------
    disp_left, disp_right : ndarray, (H, W)
        Disparities of the left and of the right view (both positive, ``d = x_left - x_right``).
    tolerance : float
        Pixels.

    Returns
    -------
    ndarray, bool, (H, W)
    """
    dl = np.asarray(disp_left, dtype=np.float32)
    dr = np.asarray(disp_right, dtype=np.float32)
    if dl.shape != dr.shape or dl.ndim != 2:
        raise MatchingError(f"expected two disparity maps of the same (H, W) shape, got {dl.shape} "
                            f"and {dr.shape}")
    return _cross_check(np.ascontiguousarray(dl), np.ascontiguousarray(dr), float(tolerance))


def subpixel_refine(cost: np.ndarray, disp: np.ndarray, *, min_disp: int = 0) -> np.ndarray:
    """Parabola fit through the cost at ``d-1, d, d+1`` around each integer disparity.

    The offset ``(c₋ - c₊) / (2 (c₋ - 2c₀ + c₊))`` is clipped to ±0.5; pixels at the ends of the range,
    with a non-convex fit, a non-finite neighbour cost or NaN disparity are left unchanged.

    Returns
    -------
    ndarray, float32, (H, W)
    """
    vol = _check_volume(cost)
    d = np.asarray(disp, dtype=np.float32)
    out = d.copy()
    nd = vol.shape[2]
    finite = np.isfinite(d)
    idx = np.zeros(d.shape, dtype=np.int64)
    idx[finite] = np.rint(d[finite]).astype(np.int64) - min_disp
    inner = finite & (idx >= 1) & (idx <= nd - 2)
    if not inner.any():
        return out
    ys, xs = np.nonzero(inner)
    i = idx[ys, xs]
    c0 = vol[ys, xs, i].astype(np.float64)
    cm = vol[ys, xs, i - 1].astype(np.float64)
    cp = vol[ys, xs, i + 1].astype(np.float64)
    denom = cm - 2.0 * c0 + cp
    good = np.isfinite(denom) & (denom > 1e-12)  # a banded volume's +inf outside the band: left unchanged
    offset = np.zeros_like(c0)
    offset[good] = np.clip((cm[good] - cp[good]) / (2.0 * denom[good]), -0.5, 0.5)
    out[ys, xs] = (d[ys, xs] + offset).astype(np.float32)
    return out


def _scanline_fill(disp: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Each invalid pixel: min of the nearest valid values to its left and right on the row."""
    h, w = disp.shape
    xs = np.broadcast_to(np.arange(w)[None, :], (h, w))
    rows = np.broadcast_to(np.arange(h)[:, None], (h, w))
    li = np.maximum.accumulate(np.where(valid, xs, -1), axis=1)
    ri = np.minimum.accumulate(np.where(valid, xs, w)[:, ::-1], axis=1)[:, ::-1]
    lv = np.where(li >= 0, disp[rows, np.clip(li, 0, w - 1)], np.nan)
    rv = np.where(ri < w, disp[rows, np.clip(ri, 0, w - 1)], np.nan)
    fill = np.fmin(lv, rv).astype(np.float32)
    return np.where(valid, disp, fill).astype(np.float32)


def weighted_median_filter(disp: np.ndarray, image: np.ndarray, *, mask: np.ndarray | None = None,
                           radius: int = 9, gamma_color: float = 10.0,
                           gamma_distance: float = 9.0) -> np.ndarray:
    """Bilateral weighted median of a disparity map (integer bins), guided by ``image``.

    Weights ``exp(-ΔE_Lab/γ_c - ‖Δp‖/γ_d)``; only pixels where ``mask`` is True are changed (all if None); NaN
    neighbours give no weight (a masked pixel with none keeps its value).

    Returns float32 ``(H, W)``.
    """

    d = np.ascontiguousarray(disp, dtype=np.float32)
    m = np.ones(d.shape, dtype=bool) if mask is None else np.ascontiguousarray(mask, dtype=bool)
    if not np.isfinite(d).any():
        return d.copy()
    dmin = float(np.floor(np.nanmin(d)))
    nbins = int(np.ceil(np.nanmax(d))) - int(dmin) + 2
    lab3 = np.ascontiguousarray(to_lab(image).transpose(2, 0, 1))
    return wmf_kernel(d, np.isfinite(d), m, lab3, int(radius), float(gamma_color), float(gamma_distance), dmin, nbins,
                      median_chunks(d.shape[0]))


def fill_holes(disp: np.ndarray, valid: np.ndarray | None = None, *, image: np.ndarray | None = None,
               median_radius: int = 9, median_where: np.ndarray | None = None) -> np.ndarray:
    """Dense disparity from a sparse one: background scanline fill, then a weighted median.

    Each invalid pixel takes the *lower* (background, as occlusions belong to the farther surface) of
    the nearest valid disparities to its left and right on the scanline; when ``image`` is given the
    filled pixels are then smoothed by :func:`weighted_median_filter` guided by it (numba); without
    ``image`` they get a plain 5×5 median instead (OpenCV, no compilation to load).

    Parameters
    ----------
    disp : ndarray, (H, W)
    valid : ndarray, bool, (H, W), optional
        Defaults to ``isfinite(disp)``.
    image : ndarray, (H, W, 3) or (H, W), optional
        Guidance image of the same view.
    median_where : ndarray, bool, (H, W), optional
        Only the holes here are smoothed (default: every hole); the others keep the scanline fill.

    Returns
    -------
    ndarray, float32, (H, W)
        Finite wherever the row holds at least one valid pixel (NaN only for rows with none).
    """
    d = np.ascontiguousarray(disp, dtype=np.float32)
    v = np.isfinite(d) if valid is None else (np.asarray(valid, dtype=bool) & np.isfinite(d))
    if d.shape != v.shape or d.ndim != 2:
        raise MatchingError(f"expected disp and valid of the same (H, W) shape, got {d.shape} and {v.shape}")
    filled = _scanline_fill(d, np.ascontiguousarray(v))
    holes = ~v
    if median_radius > 0 and holes.any() and np.isfinite(filled).all():
        smooth = holes if median_where is None else holes & np.asarray(median_where, dtype=bool)
        if image is not None:
            filled = weighted_median_filter(filled, image, mask=smooth, radius=median_radius)
        else:
            med = cv2.medianBlur(filled, 5)
            filled = np.where(smooth, med, filled).astype(np.float32)
    return filled
