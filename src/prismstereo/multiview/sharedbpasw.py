"""BPASW pair costs of one reference against several views, the reference's support weights computed once.

The fused BPASW evidence of the global multi-view method (:func:`~prismstereo.multiview.poststeps.fused_bpasw`)
and the local method aggregate the reference against every view with the BPASW cost (thesis §5.2). The
symmetric aggregation (Eq. 5.14) weights each window pixel by the reference's colour/proximity weight times
the view's; computing a weight (a square root and a logarithm) costs far more than the disparity loop it
feeds (on Tsukuba about 0.37 s of the 0.85 s of one pair for each image's weights), and the reference's
weights are the same for every pair. Here they are computed once per row and read by all pairs, the views on
the left (matched on mirrored images, see :mod:`~prismstereo.multiview.baseline`) reading them mirrored. The
arithmetic per entry is that of :func:`prismstereo.matching.aggregation.aggregate_bpasw` in the same order,
so the volumes equal those of :func:`~prismstereo.multiview.baseline.pair_cost` (``cost="bpasw"``) up to
the last bit of some entries (the compiler vectorises the tail of the disparity loop differently for some
range lengths: 1 ulp, tested); on Tsukuba's four pairs they are equal bit for bit. Measured on Tsukuba's
four views (one thread): 4.24 s pair by pair, 2.94 s shared.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt
from numba import njit, prange

from prismstereo.errors import MatchingError
from prismstereo.matching.aggregation import _sim, to_lab, weber_fechner_weight, window_offsets
from prismstereo.multiview.baseline import PairCost, pair_cost

__all__ = ["bpasw_pair_costs"]

F32 = npt.NDArray[np.float32]
I64 = npt.NDArray[np.int64]


@njit(cache=True, parallel=True, fastmath=True)
def _bpasw_views_kernel(cost: F32, offs: I64, lab_ref: F32, lab_views: F32, mirrored: npt.NDArray[np.bool_],
                        dys: I64, dxs: I64, kmir: I64, prox: npt.NDArray[np.float64], kernel: int, s0: float,
                        s_min: float) -> F32:  # pragma: no cover - numba
    """Symmetric BPASW aggregation of the pairs' volumes ``cost[:, :, offs[p]:offs[p + 1]]`` (each in its pair's
    frame, mirrored for a view on the left), ``lab_views[p]`` the view in that frame, ``lab_ref`` the reference
    in the unmirrored frame; ``kmir[k]`` is the offset ``(dy, -dx)`` of offset ``k``."""
    h, w, _ = cost.shape
    nk = dys.shape[0]
    npair = offs.shape[0] - 1
    log_norm = 1.0 / np.log(s0 / s_min) if kernel == 0 else 1.0
    ndmax = 0
    for p in range(npair):
        ndmax = max(ndmax, offs[p + 1] - offs[p])
    out = np.empty_like(cost)
    for y in prange(h):
        # the reference's weights of this row, wl[k, x] (0 outside the image), shared by all pairs
        wl = np.zeros((nk, w), dtype=np.float32)
        for k in range(nk):
            qy = y + dys[k]
            if qy < 0 or qy >= h:
                continue
            for x in range(w):
                qx = x + dxs[k]
                if qx < 0 or qx >= w:
                    continue
                a = lab_ref[y, x, 0] - lab_ref[qy, qx, 0]
                b = lab_ref[y, x, 1] - lab_ref[qy, qx, 1]
                c = lab_ref[y, x, 2] - lab_ref[qy, qx, 2]
                wl[k, x] = np.float32(_sim(a * a + b * b + c * c, kernel, s0, s_min, log_norm) * prox[k])
        wr = np.zeros((nk, w), dtype=np.float32)
        num = np.empty(ndmax, dtype=np.float32)
        den = np.empty(ndmax, dtype=np.float32)
        for p in range(npair):
            o0 = offs[p]
            nd = offs[p + 1] - o0
            mir = mirrored[p]
            # the view's weights of this row, stored reversed (wr[k, w-1-xr]) as the two-view kernel does
            wr[:, :] = 0.0
            for k in range(nk):
                qy = y + dys[k]
                if qy < 0 or qy >= h:
                    continue
                for xr in range(w):
                    qx = xr + dxs[k]
                    if qx < 0 or qx >= w:
                        continue
                    a = lab_views[p, y, xr, 0] - lab_views[p, qy, qx, 0]
                    b = lab_views[p, y, xr, 1] - lab_views[p, qy, qx, 1]
                    c = lab_views[p, y, xr, 2] - lab_views[p, qy, qx, 2]
                    wr[k, w - 1 - xr] = _sim(a * a + b * b + c * c, kernel, s0, s_min, log_norm) * prox[k]
            for x in range(w):
                num[:nd] = 0.0
                den[:nd] = 0.0
                nvalid = min(nd, x + 1)
                base = w - 1 - x
                for k in range(nk):
                    qy = y + dys[k]
                    qx = x + dxs[k]
                    if qy < 0 or qy >= h or qx < 0 or qx >= w:
                        continue
                    # a mirrored pair's pixel x is the reference's w-1-x and its offset dx the reference's -dx
                    wlk = wl[kmir[k], w - 1 - x] if mir else wl[k, x]
                    if wlk == 0.0:
                        continue
                    wrk = wr[k, base:base + nvalid]
                    cq = cost[qy, qx, o0:o0 + nvalid]
                    for i in range(nvalid):
                        ww = wlk * wrk[i]
                        num[i] += ww * cq[i]
                        den[i] += ww
                for i in range(nd):
                    if i < nvalid and den[i] > 0.0:
                        out[y, x, o0 + i] = num[i] / den[i]
                    else:
                        out[y, x, o0 + i] = cost[y, x, o0 + i]
    return out


def bpasw_pair_costs(reference: np.ndarray, views: Sequence[np.ndarray], ratios: Sequence[float], *,
                     max_disp: int, cost_params: dict[str, Any] | None = None) -> list[PairCost]:
    """``[pair_cost(reference, v, r, max_disp=max_disp, cost="bpasw", cost_params=cost_params) ...]`` with the
    reference's support weights computed once for all views (the same values to 1 ulp; see the module doc).

    Parameters
    ----------
    reference : (H, W, 3) image, 0..255
    views : sequence of (H, W, 3) images
    ratios : sequence of float, the signed baseline ratio of each view
    max_disp : int, keyword-only, largest unit-baseline disparity
    cost_params : dict, optional, :class:`~prismstereo.matching.matchers.BPASWMatcher` fields

    Returns
    -------
    list of PairCost, one per view (``raw`` None)
    """
    from prismstereo.matching import costs
    from prismstereo.matching.matchers import BPASWMatcher
    from prismstereo.matching.selection import cross_check, right_disparity, subpixel_refine, winner_take_all

    params = dict(cost_params or {})
    m = BPASWMatcher(**params)
    if m.continuity or len(views) < 2:
        # nothing to share (one pair), or the two-pass continuity variant: the pair-by-pair path
        return [pair_cost(reference, v, r, max_disp=max_disp, cost="bpasw", cost_params=params)
                for v, r in zip(views, ratios, strict=True)]
    if m.radius < 0 or m.dilation < 1:
        raise MatchingError(f"expected radius >= 0 and dilation >= 1, got radius={m.radius}, "
                            f"dilation={m.dilation}")
    h, w = reference.shape[:2]
    vols: list[F32] = []
    labs: list[F32] = []
    for v, r in zip(views, ratios, strict=True):
        a = abs(float(r))
        max_s = int(min(w - 1, math.ceil(a * max_disp) + 1))  # as pair_cost
        lft, rgt = ((reference, v) if r > 0 else
                    (np.ascontiguousarray(reference[:, ::-1]), np.ascontiguousarray(v[:, ::-1])))
        # BPASWMatcher.cost_volume's pixel cost: S_AD (Eq. 5.6) plus the weighted census distance
        vol = costs.cost_s_ad(lft, rgt, max_disp=max_s, min_disp=0, omega=m.omega, tau_color=m.tau_color,
                              tau_gradient=m.tau_gradient)
        if m.census_weight > 0:
            vol += np.float32(m.census_weight) * costs.cost_census(lft, rgt, max_disp=max_s, min_disp=0)
        vols.append(np.asarray(vol, np.float32))
        labs.append(to_lab(rgt))
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
    offs = np.cumsum([0] + [vol.shape[2] for vol in vols]).astype(np.int64)
    agg = _bpasw_views_kernel(np.ascontiguousarray(np.concatenate(vols, axis=2)), offs, to_lab(reference),
                              np.ascontiguousarray(np.stack(labs)), np.array([r < 0 for r in ratios]),
                              dys, dxs, kmir, prox.astype(np.float64), kid, s0, s_min)
    del vols
    out = []
    for p, r in enumerate(ratios):
        vol = np.ascontiguousarray(agg[:, :, offs[p]:offs[p + 1]])
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
