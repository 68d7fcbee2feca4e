"""BPASW pair costs of one reference against several views, each image's support weights computed once.

The fused BPASW evidence of the global multi-view method (:func:`~prismstereo.multiview.poststeps.fused_bpasw`)
and the local method aggregate the reference against every view with the BPASW cost (thesis §5.2). The
symmetric aggregation (Eq. 5.14) weights each window pixel by the reference's colour/proximity weight times
the view's; computing a weight (a square root and a logarithm) costs far more than the disparity loop it
feeds (on Tsukuba about 0.37 s of the 0.85 s of one pair for each image's weights). Here

* the reference's weights are computed once for all pairs (the views on the left, matched on mirrored images,
  see :mod:`~prismstereo.multiview.baseline`, read them mirrored), and
* each image's weights are computed for half of the window's offsets only: the weight of a pixel and its
  neighbour at offset ``(dy, dx)`` is the neighbour's weight at ``(-dy, -dx)`` (the colour difference only
  changes sign, the distance not at all), so the other half is read from the table at the neighbour.

The arithmetic per entry is that of :func:`prismstereo.matching.local.aggregation.aggregate_bpasw` in the same order,
so the volumes equal those of :func:`~prismstereo.multiview.baseline.pair_cost` (``cost="bpasw"``) up to
the last bit of some entries (the compiler vectorises the tail of the disparity loop differently for some
range lengths: 1 ulp, tested); on Tsukuba's four pairs they are equal bit for bit. Sharing the reference's
weights and the half tables roughly halves the time of the pair-by-pair costs (docs/EXPERIMENTS.md).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt
from numba import njit, prange

from prismstereo.errors import MatchingError
from prismstereo.matching.local.aggregation import pair_weight, to_lab, weber_fechner_weight, window_offsets
from prismstereo.matching.local.matchers import BPASWMatcher
from prismstereo.matching.local.selection import cross_check, right_disparity, subpixel_refine, winner_take_all
from prismstereo.multiview.baseline import PairCost, pair_cost

__all__ = ["bpasw_pair_costs"]

F32 = npt.NDArray[np.float32]
I64 = npt.NDArray[np.int64]


@njit(cache=True, parallel=True, fastmath=True)
def _half_weights(lab: F32, dys: I64, dxs: I64, half: I64, prox: npt.NDArray[np.float64], kernel: int, s0: float,
                  s_min: float) -> F32:  # pragma: no cover - numba
    """Support weights ``T[y, j, x]`` of pixel ``(y, x)`` and its neighbour at offset ``half[j]``, for the half of
    the window's offsets that lie after the centre (0 outside the image): the weight of a pixel and its
    neighbour is symmetric (the colour difference only changes sign, the distance not at all), so the other
    half is ``T`` read at the neighbour."""
    h, w, _ = lab.shape
    nh = half.shape[0]
    log_norm = 1.0 / np.log(s0 / s_min) if kernel == 0 else 1.0
    out = np.zeros((h, nh, w), dtype=np.float32)
    for y in prange(h):
        for j in range(nh):
            k = half[j]
            qy = y + dys[k]
            if qy < 0 or qy >= h:
                continue
            for x in range(w):
                qx = x + dxs[k]
                if qx < 0 or qx >= w:
                    continue
                out[y, j, x] = np.float32(pair_weight(lab, y, x, qy, qx, kernel, s0, s_min, log_norm) * prox[k])
    return out


@njit(cache=True, inline="always")
def _weight_row(tab: F32, y: int, k: int, dys: I64, dxs: I64, hidx: I64, kneg: I64, row: F32) -> None:
    """``row[x]``: the weight of ``(y, x)`` and its neighbour at offset ``k`` from the half table."""
    h = tab.shape[0]
    w = tab.shape[2]
    j = hidx[k]
    if j >= 0:
        row[:] = tab[y, j]
        return
    row[:] = 0.0
    qy = y + dys[k]
    if qy < 0 or qy >= h:
        return
    jn = hidx[kneg[k]]
    for x in range(w):
        qx = x + dxs[k]
        if 0 <= qx < w:
            row[x] = tab[qy, jn, qx]


@njit(cache=True, parallel=True, fastmath=True)
def _bpasw_pair_kernel(cost: F32, tab_ref: F32, tab_view: F32, mirrored: bool, dys: I64, dxs: I64, hidx: I64,
                       kneg: I64, kmir: I64) -> F32:  # pragma: no cover - numba
    """Symmetric BPASW aggregation (as :func:`prismstereo.matching.local.aggregation._bpasw_kernel`) of one pair's
    volume ``cost`` (in the pair's frame, mirrored for a view on the left) from the half weight tables of the
    reference (unmirrored frame) and of the view (the pair's frame)."""
    h, w, nd = cost.shape
    nk = dys.shape[0]
    out = np.empty_like(cost)
    for y in prange(h):
        buf = np.empty(w, dtype=np.float32)
        wl = np.empty((nk, w), dtype=np.float32)
        wr = np.empty((nk, w), dtype=np.float32)
        for k in range(nk):
            if mirrored:  # the pair's pixel x is the reference's w-1-x and its offset dx the reference's -dx
                _weight_row(tab_ref, y, kmir[k], dys, dxs, hidx, kneg, buf)
                for x in range(w):
                    wl[k, x] = buf[w - 1 - x]
            else:
                _weight_row(tab_ref, y, k, dys, dxs, hidx, kneg, wl[k])
            # the view's weights stored reversed, wr[k, w-1-xr], as the two-view kernel does
            _weight_row(tab_view, y, k, dys, dxs, hidx, kneg, buf)
            for x in range(w):
                wr[k, w - 1 - x] = buf[x]
        num = np.empty(nd, dtype=np.float32)
        den = np.empty(nd, dtype=np.float32)
        for x in range(w):
            num[:] = 0.0
            den[:] = 0.0
            nvalid = min(nd, x + 1)
            base = w - 1 - x
            for k in range(nk):
                qy = y + dys[k]
                qx = x + dxs[k]
                if qy < 0 or qy >= h or qx < 0 or qx >= w:
                    continue
                wlk = wl[k, x]
                if wlk == 0.0:
                    continue
                wrk = wr[k, base:base + nvalid]
                cq = cost[qy, qx, :nvalid]
                for i in range(nvalid):
                    ww = wlk * wrk[i]
                    num[i] += ww * cq[i]
                    den[i] += ww
            for i in range(nd):
                if i < nvalid and den[i] > 0.0:
                    out[y, x, i] = num[i] / den[i]
                else:
                    out[y, x, i] = cost[y, x, i]
    return out


def bpasw_pair_costs(reference: np.ndarray, views: Sequence[np.ndarray], ratios: Sequence[float], *,
                     max_disp: int, cost_params: dict[str, Any] | None = None) -> list[PairCost]:
    """``[pair_cost(reference, v, r, max_disp=max_disp, cost="bpasw", cost_params=cost_params) ...]`` with the
    reference's support weights computed once for all views and every image's weights for half the window
    (the same values to 1 ulp; see the module doc).

    Parameters
    ----------
    reference : (H, W, 3) image, 0..255
    views : sequence of (H, W, 3) images
    ratios : sequence of float, the signed baseline ratio of each view
    max_disp : int, keyword-only, largest unit-baseline disparity
    cost_params : dict, optional, :class:`~prismstereo.matching.local.matchers.BPASWMatcher` fields

    Returns
    -------
    list of PairCost, one per view (``raw`` None)
    """

    params = dict(cost_params or {})
    m = BPASWMatcher(**params)
    if m.continuity or len(views) < 2:
        # nothing to share (one pair), or the two-pass continuity variant: the pair-by-pair path
        return [pair_cost(reference, v, r, max_disp=max_disp, cost="bpasw", cost_params=params)
                for v, r in zip(views, ratios, strict=True)]
    if m.radius < 0 or m.dilation < 1:
        raise MatchingError(f"expected radius >= 0 and dilation >= 1, got radius={m.radius}, "
                            f"dilation={m.dilation}")
    w = reference.shape[1]
    # aggregate_bpasw's window and weight constants
    dys, dxs, dist = window_offsets(m.radius, m.dilation)
    if m.kernel == "weber":
        prox = weber_fechner_weight(dist, s0=max(math.sqrt(2.0) * m.radius + 1.0, 1.0 + 1e-6), s_min=1.0)
        kid, s0, s_min = 0, float(m.similarity_s0), 1.0
        if not s0 > s_min > 0:
            raise MatchingError(f"expected similarity_s0 > similarity_s_min > 0, got {s0}, {s_min}")
    else:
        prox = np.exp(-dist / m.gamma_proximity)
        kid, s0, s_min = 1, float(m.gamma_color), 1.0
    pos = {(int(dy), int(dx)): k for k, (dy, dx) in enumerate(zip(dys, dxs, strict=True))}
    kmir = np.array([pos[(int(dy), -int(dx))] for dy, dx in zip(dys, dxs, strict=True)], np.int64)
    kneg = np.array([pos[(-int(dy), -int(dx))] for dy, dx in zip(dys, dxs, strict=True)], np.int64)
    half = np.flatnonzero((dys > 0) | ((dys == 0) & (dxs >= 0))).astype(np.int64)
    hidx = np.full(dys.size, -1, np.int64)
    hidx[half] = np.arange(half.size)
    prox = prox.astype(np.float64)
    tab_ref = _half_weights(to_lab(reference), dys, dxs, half, prox, kid, s0, s_min)
    out = []
    for v, r in zip(views, ratios, strict=True):
        a = abs(float(r))
        max_s = int(min(w - 1, math.ceil(a * max_disp) + 1))  # as pair_cost
        lft, rgt = ((reference, v) if r > 0 else
                    (np.ascontiguousarray(reference[:, ::-1]), np.ascontiguousarray(v[:, ::-1])))
        raw = m.pixel_cost(lft, rgt, max_disp=max_s, min_disp=0)
        tab_view = _half_weights(to_lab(rgt), dys, dxs, half, prox, kid, s0, s_min)
        vol = _bpasw_pair_kernel(np.ascontiguousarray(raw, dtype=np.float32), tab_ref, tab_view, bool(r < 0), dys,
                                 dxs, hidx, kneg, kmir)
        del raw, tab_view
        d0 = winner_take_all(vol)
        ok = cross_check(d0, right_disparity(vol), tolerance=0.0)
        d = np.asarray(subpixel_refine(vol, d0), np.float32)
        ok = np.asarray(ok, bool)
        if r < 0:  # back from the mirrored frame
            vol, d, ok = (np.ascontiguousarray(vol[:, ::-1]), np.ascontiguousarray(d[:, ::-1]),
                          np.ascontiguousarray(ok[:, ::-1]))
        disp = (d / np.float32(abs(float(r)))).astype(np.float32)
        out.append(PairCost(float(r), vol, disp, ok, None, 1))
    return out
