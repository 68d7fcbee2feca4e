"""Local multi-baseline matching (thesis §7.1.1, Eqs. 7.3–7.8).

The reference is matched against every view with the two-view aggregated cost (BPASW by default, Eq. 7.2 /
7.9), each pair volume is resampled on the unit-baseline disparity grid by its signed baseline ratio
``δᵢ`` (Eq. 7.7), the views are summed (Eq. 7.8) and the winner is taken over the unit disparity
(Eq. 5.15), refined to subpixel by a parabola through the summed cost.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from prismstereo.checks import check_fields
from prismstereo.errors import ConfigError
from prismstereo.matching.local.selection import fill_holes, subpixel_refine, weighted_median_filter, winner_take_all
from prismstereo.matching.registry import MatchResult
from prismstereo.multiview.baseline import CostName, check_views, fuse_costs, pair_cost, resolve_occlusion
from prismstereo.multiview.sharedbpasw import bpasw_pair_costs

log = logging.getLogger(__name__)

__all__ = ["LocalMultiViewParams", "match_multibaseline"]


@dataclass(frozen=True, kw_only=True)
class LocalMultiViewParams:
    """Parameters of the local multi-baseline method.

    Attributes
    ----------
    cost : {"bpasw", "guided"}
        Pair cost (see :func:`~prismstereo.multiview.baseline.pair_cost`); the thesis uses BPASW.
    cost_params : dict
        Keyword parameters of that cost.
    subpixel : bool
        Parabola refinement of the unit disparity on the summed cost.
    fill : bool
        Invalidate pixels whose fused winner no pair's left–right-checked disparity supports (within
        ``support_tolerance``) and fill them (background scanline fill + weighted median), as the two-view
        BPASW matcher fills its cross-check failures; False keeps the plain WTA of Eq. 7.8 everywhere.
    support_tolerance : float
        Unit-baseline pixels.
    final_median : bool
        After filling, a colour-weighted median over the whole map (as the two-view BPASW matcher).
    weight_by_baseline : bool
        Weight each view by ``min(|δᵢ|, 1)`` in the sum (a short baseline resolves the unit disparity
        ``1/|δᵢ|`` times more coarsely).
    occlusion : {"auto", "sum", "sides"}
        ``"sum"``: Eq. 7.8 as written; ``"sides"``: with views on both sides, the lower of the left views'
        and the right views' fused cost per pixel and disparity (a point occluded on one side is seen from
        the other; Kang, Szeliski & Chai 2001); ``"auto"``: see
        :func:`~prismstereo.multiview.baseline.resolve_occlusion`.
    """

    cost: CostName = "bpasw"
    cost_params: dict[str, Any] = field(default_factory=dict)
    subpixel: bool = True
    fill: bool = True
    support_tolerance: float = 1.0
    occlusion: str = "auto"
    final_median: bool = True
    weight_by_baseline: bool = True

    def __post_init__(self) -> None:
        check_fields(self, {"support_tolerance": (0.0, None)})
        if self.cost not in ("bpasw", "guided"):
            raise ConfigError(f"LocalMultiViewParams.cost: expected 'bpasw' or 'guided', got {self.cost!r}")
        if self.occlusion not in ("auto", "sum", "sides"):
            raise ConfigError(f"LocalMultiViewParams.occlusion: expected 'auto', 'sum' or 'sides', got "
                              f"{self.occlusion!r}")


def match_multibaseline(reference: Any, views: Sequence[Any], *, ratios: Sequence[float], max_disp: int,
                        params: LocalMultiViewParams | None = None) -> MatchResult:
    """Disparity of the reference for the unit baseline from several collinear views (thesis Eq. 7.8).

    ``Sum_C(x, y, d) = Σᵢ C_i(x, y, δᵢ d)`` with ``C_i`` the aggregated cost of the reference against
    view ``i`` (Eq. 7.9) and ``δᵢ`` its signed baseline ratio (Eq. 7.6); ``D(x, y) = argmin_d Sum_C``.

    Parameters
    ----------
    reference : (H, W, 3) or (H, W) image, uint8 or float 0..255
    views : sequence of images, the reference's size, rectified with it (horizontal collinear baselines)
    ratios : sequence of float, keyword-only
        Signed baseline ratio of each view: ``+1`` = the standard right view, ``-2`` = twice as far on the
        left. Reference pixel ``x`` matches view pixel ``x - δ d``.
    max_disp : int, keyword-only
        Largest disparity of the UNIT baseline (ratio 1), ``0 <= max_disp < W``.
    params : LocalMultiViewParams, keyword-only

    Returns
    -------
    MatchResult
        ``disparity`` (H, W) float32 for the unit baseline; ``valid``: pixels whose winner at least one
        pair's checked disparity supports; ``extras``: ``"support"`` (H, W) int (number of such pairs),
        ``"pair_disparities"`` (V, H, W) float32 (each pair's own checked map, unit baseline).

    Raises
    ------
    ImageError, ConfigError, MatchingError
    """

    p = params or LocalMultiViewParams()
    ref, vs, rs, md = check_views(reference, views, ratios, max_disp=max_disp)
    timings: dict[str, float] = {}
    t = time.perf_counter()
    if p.cost == "bpasw":  # the reference's support weights computed once for all views (same volumes)

        pcs = bpasw_pair_costs(ref, vs, rs, max_disp=md, cost_params=p.cost_params)
    else:
        pcs = [pair_cost(ref, v, r, max_disp=md, cost=p.cost, cost_params=p.cost_params)
               for v, r in zip(vs, rs, strict=True)]
    timings["pair costs"] = time.perf_counter() - t
    t = time.perf_counter()
    def wfn(r: float) -> float:
        return min(abs(r), 1.0) if p.weight_by_baseline else 1.0

    occ = resolve_occlusion(p.occlusion, rs, weight_by_baseline=p.weight_by_baseline)
    if occ == "sides":
        lv = [pc for pc in pcs if pc.ratio < 0]
        rv = [pc for pc in pcs if pc.ratio > 0]
        fl, _ = fuse_costs(lv, max_disp=md, weights=[wfn(pc.ratio) for pc in lv])
        fr, _ = fuse_costs(rv, max_disp=md, weights=[wfn(pc.ratio) for pc in rv])
        fused = np.minimum(fl, fr)
    else:
        fused, _count = fuse_costs(pcs, max_disp=md, weights=[wfn(pc.ratio) for pc in pcs])
    timings["fusion"] = time.perf_counter() - t
    t = time.perf_counter()
    d0 = winner_take_all(fused)
    disp = subpixel_refine(fused, d0) if p.subpixel else d0
    pair_d = np.stack([np.where(pc.reliable, pc.disparity, np.float32(np.nan)) for pc in pcs])
    with np.errstate(invalid="ignore"):
        support = (np.abs(pair_d - disp[None]) <= p.support_tolerance).sum(axis=0)
    valid = support > 0
    timings["selection"] = time.perf_counter() - t
    extras: dict[str, Any] = {"support": support, "pair_disparities": pair_d}
    if p.fill and not valid.all():
        t = time.perf_counter()
        raw = np.where(valid, disp, np.float32(np.nan)).astype(np.float32)
        dense = fill_holes(raw, valid, image=ref)
        if p.final_median and np.isfinite(dense).all():
            dense = weighted_median_filter(dense, ref, radius=9)
        timings["fill"] = time.perf_counter() - t
        log.debug("multibaseline: %d views, %.1f %% supported", len(vs), 100.0 * valid.mean())
        return MatchResult(dense, valid, raw, timings, extras)
    log.debug("multibaseline: %d views, %.1f %% supported", len(vs), 100.0 * valid.mean())
    return MatchResult(disp.astype(np.float32), valid, None, timings, extras)
