"""Global multi-view matching (thesis §7.1.2, Eqs. 7.9–7.18).

The steps are the two-view ``coop`` pipeline of thesis chapter 6, with every data-dependent step extended
to all views, and they reuse the ``coop`` building blocks of :mod:`prismstereo.matching`:

1. **Initial maps** (Eq. 7.9): the reference against each view ``i`` (pair cost of
   :func:`~prismstereo.multiview.baseline.pair_cost`), WTA + left–right check + subpixel, converted to the
   unit baseline (``d = s / |δᵢ|``) — the disparity sets ``d^(1) … d^(n)``.
2. **Segmentation** of the reference (:func:`~prismstereo.matching.segments.segmentation.mean_shift_segment`), kept
   from crossing the depth edges of the views' fused initial map (``segmentation.depth_tau``).
3. **One plane per segment fitted jointly to all views** (Eqs. 7.10–7.14): the reliable pixels of every
   disparity set are stacked into one least-squares system ``A [a b c]ᵀ = B`` (Eq. 7.11) solved with the
   pseudo-inverse (Eqs. 7.12–7.13), with the outlier rules of §6.1.2 (cross-check, the reliable-region
   rule Eq. 6.8 over all views' pixels, the distance rule Eq. 6.9 with the Eq. 6.10 iteration) — the
   robust solver :func:`prismstereo.matching.segments.planes.fit_one_plane` run on the stacked observations. By default
   (``fit_source="both"``) one more disparity set joins the stack: the winner of the views' aggregated
   costs fused on the unit grid (the local method's map), reliable where a pair agrees with it — a
   deviation from the literal Eq. 7.11 (``fit_source="pairs"``: the pairs' maps alone).
4. **Merging** of similar neighbouring planes (§6.1.3, :func:`~prismstereo.matching.segments.planes.merge_planes`)
   on the per-pixel mean of the views' reliable disparities (the normal equations of Eq. 7.14 only see
   that mean, weighted by the number of views).
5. **Cooperative optimisation** (Eqs. 7.15–7.18 with 6.18–6.25,
   :func:`~prismstereo.matching.coop.cooperative.cooperative_optimize`) of ``E = Σᵢ E_data^(i) + E_occ + E_smooth``:
   the data term is the views' costs summed on the unit-baseline grid
   (:func:`~prismstereo.multiview.baseline.fuse_costs`, each view's cost at ``δᵢ d``), truncated per view
   and weighted per view by that view's reliability before summing, so ``Σᵢ c_data(x, y, d^(i, j))`` of
   Eq. 7.16 is what the optimiser reads. Occlusion (Eq. 7.17) is charged by the optimiser where the plane
   leaves the search range; a view that cannot see a match (out of its image) does not vote.

6. **The steps shared with ``coop``** (:mod:`prismstereo.matching.coop.steps`, the parameters
   :data:`MULTIVIEW_STEPS`) on the multi-view evidence (:class:`_ViewsEvidence`): group refit (jointly over
   the disparity sets), candidate planes fitted to the fused BPASW map (:mod:`prismstereo.multiview.poststeps`:
   the BPASW pair costs of the views with ``|δ|`` in ``[0.5, 1]``, ``[0.5, 2]`` when the sides are balanced,
   fused on the unit grid, reliable where a view's cross-checked BPASW map agrees within 1 px), sweep
   candidates against the right view nearest the unit baseline with the views' row-boxed pixel costs on
   their pixels, group moves, finer segments at three levels (a move kept where the trusted fused
   disparities side with it), the boundary step on the fused BPASW cost, the occlusion step against each
   side's view (only pixels contradicted from both sides when the sides are balanced), a subpixel-preserving
   median. Measurements: docs/EXPERIMENTS.md.

Deviation, stated: the per-view truncation and reliability weighting are applied to each view's volume
before the sum (``cooperative_optimize`` takes one data volume); the optimiser then sees a volume that is
already truncated and weighted, and is called with ``data_trunc`` above its range and
``unreliable_weight = 1``.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import numpy.typing as npt
from numba import njit

from prismstereo.checks import check_fields
from prismstereo.errors import ConfigError
from prismstereo.matching.coop.cooperative import (
    CoopMemo,
    CoopParams,
    build_segment_graph,
    cooperative_optimize,
)
from prismstereo.matching.coop.steps import (
    BoundaryParams,
    BpaswPlanesParams,
    CurvedParams,
    FallbackParams,
    FineParams,
    MedianParams,
    OcclusionParams,
    PlaneLabels,
    StepParams,
    SweepParams,
    coerce_params,
    run_steps,
)
from prismstereo.matching.registry import MatchResult
from prismstereo.matching.segments.planes import (
    PlaneParams,
    SegmentIndex,
    build_segment_index,
    fill_missing_planes,
    fit_one_plane,
    group_refit_planes,
    merge_planes,
    render_planes,
)
from prismstereo.matching.segments.segmentation import SegmentationParams, mean_shift_segment, segment_adjacency
from prismstereo.multiview.baseline import (
    CostName,
    PairCost,
    check_views,
    pair_cost,
    resample_to_unit,
    resolve_occlusion,
)
from prismstereo.multiview.poststeps import (
    FusedBPASW,
    PostParams,
    fused_bpasw,
    occlusion_sides,
    sweep_candidates,
)

log = logging.getLogger(__name__)


__all__ = ["MULTIVIEW_STEPS", "GlobalMultiViewParams", "data_volume", "fit_planes_joint", "match_multiview_global"]

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
I32 = npt.NDArray[np.int32]


#: the global method's step parameters: where they differ from ``coop``'s, measured on Tsukuba (five views)
#: and Cones (nine views) (docs/EXPERIMENTS.md)
MULTIVIEW_STEPS = StepParams(
    bpasw_planes=BpaswPlanesParams(rounds=2),
    sweep=SweepParams(frac=0.35, min_px=40, step=2),
    fine=FineParams(levels=((3.0, 10), (1.5, 3), (1.0, 1)), check=1),
    boundary=BoundaryParams(agree=2),
    median=MedianParams(radius=3),
    fallback=FallbackParams(enabled=False),
    curved=CurvedParams(enabled=False),
)


@dataclass(frozen=True, kw_only=True)
class GlobalMultiViewParams:
    """Parameters of the global multi-view method.

    Attributes
    ----------
    cost : {"guided", "bpasw"}
        Pair cost (see :func:`~prismstereo.multiview.baseline.pair_cost`); ``"guided"`` is the ``coop``
        matcher's cost, on whose scale ``coop`` defaults (``CoopParams``) are set.
    cost_params : dict
        Keyword parameters of that cost.
    segmentation, planes, coop : the ``coop`` building blocks' parameter sets. Two defaults differ from
        ``coop``'s: the segmentation keeps neighbours apart whose fused initial disparities differ by
        ``depth_tau`` = 2.5 px (:func:`~prismstereo.matching.segments.segmentation.mean_shift_segment` with the map of
        the views' fused aggregated costs, which is far more reliable than one pair's), and the smoothness
        weight γ is 0.6 (the data term carries ``data_agg`` on top of the pixel cost).
    occlusion : {"auto", "sides", "sum"}
        How the views' data costs combine (:func:`data_volume`); ``"sum"`` is the thesis's plain sum;
        ``"auto"`` chooses (:func:`~prismstereo.multiview.baseline.resolve_occlusion`). With
        ``"sides"`` and views on both sides the optimiser's right-view visibility test is switched off
        (the side selection already keeps occluded views from voting).
    scale_smoothness : bool
        Divide the smoothness weight γ (Eq. 6.24) by ``√n_eff``, ``n_eff = (Σ wᵢ)² / Σ wᵢ²`` the effective
        number of views of the data term: the data term is a mean over views whose noise falls as
        ``1/√n_eff``, so the two-view balance of data and smoothness (``coop``'s γ, tuned for one view)
        is kept at equal noise. ``n_eff = 1`` for one view, so one view reproduces ``coop``. Off by default
        (with ``coop``'s γ = 0.5).
    weight_by_baseline : bool
        Weight each view's data cost by ``min(|δᵢ|, 1)`` (see :func:`data_volume`).
    fit_min_ratio : float
        Views with ``|δᵢ|`` below this give no disparity set to the plane fit (their unit-baseline
        disparities are ``1/|δᵢ|`` times coarser); all views are used when none qualifies.
    fit_source : {"pairs", "fused", "both"}
        Disparity sets of the joint plane fit: every pair's checked map (Eq. 7.11, the thesis), the map of
        the fused aggregated costs (the local method's winner, reliable where a pair agrees), or both.
    steps : StepParams
        The steps after the plane fit, shared with ``coop`` (:mod:`prismstereo.matching.coop.steps`), with
        the multi-view defaults :data:`MULTIVIEW_STEPS`; the group refit fits jointly over the disparity sets.
    data_radius : int
        Box radius of the pixel cost summed in the data term (as ``coop``).
    unreliable_weight : float
        Weight of a view's data cost at pixels where that view's pair failed the left–right check
        (thesis: only reliable pixels ``N_r`` count; the ``coop`` default keeps a fraction).
    post : PostParams or None
        The multi-view evidence of the steps after ``refit`` (:mod:`prismstereo.multiview.poststeps`: the
        fused BPASW cost and map, the per-side occlusion views); None = those steps off.
    fit_bpasw : bool
        Also stack the fused BPASW map (reliable where multi-view consistent) into the joint plane fit.
    data_bpasw : float
        Add this times the fused BPASW cost's residual above its per-pixel minimum to the data term (as
        ``coop``'s ``data_term="both"``). Off by default: the result turns on the exact factor (a large
        segment flips).
    data_agg : float
        Add this times the views' fused AGGREGATED (guided) cost's residual above its per-pixel minimum to the
        data term (not on the sweep step's row-boxed pixels: the aggregated cost's square support favours
        fronto-parallel planes, which is what the row box avoids there). Why: a fine segment of 3–30
        pixels along a depth edge sums too few pixel costs for Eq. 7.16 to tell its two neighbours' planes
        apart; the edge-aware aggregated cost brings the colour-weighted support of the initial maps. Its
        residual is ≈ 0–1 against the pixel cost's truncation at ``coop.data_trunc``.
    """

    cost: CostName = "guided"
    cost_params: dict[str, Any] = field(default_factory=dict)
    segmentation: SegmentationParams = field(default_factory=lambda: SegmentationParams(depth_tau=2.5))
    planes: PlaneParams = field(default_factory=PlaneParams)
    coop: CoopParams = field(default_factory=lambda: CoopParams(gamma=0.6))
    unreliable_weight: float = 1.0
    data_radius: int = 1
    occlusion: str = "auto"
    scale_smoothness: bool = False
    weight_by_baseline: bool = True
    fit_min_ratio: float = 0.5
    fit_source: str = "both"
    steps: StepParams = field(default_factory=lambda: MULTIVIEW_STEPS)
    post: PostParams | None = field(default_factory=PostParams)
    fit_bpasw: bool = False
    data_bpasw: float = 0.0
    data_agg: float = 2.0

    def __post_init__(self) -> None:
        # a mapping (the CLI's -p JSON) changes the multi-view defaults' fields; validated here, before any image
        object.__setattr__(self, "steps", coerce_params(StepParams, self.steps, "steps", MULTIVIEW_STEPS))
        check_fields(self, {"unreliable_weight": (0.0, None), "data_radius": (0, 50), "fit_min_ratio": (0.0, None),
                            "data_bpasw": (0.0, None), "data_agg": (0.0, None)})


@njit(cache=True)
def _fit_all_joint(order: npt.NDArray[np.int64], starts: npt.NDArray[np.int64], w: int, disp: F64,
                   reliable: npt.NDArray[np.bool_], gamma: float, t_out: float, eps: float, max_iter: int,
                   min_pix: int, trials: int, max_slope: float) -> tuple[F64, I32]:  # pragma: no cover
    """Stacked (Eq. 7.11) robust plane fit per segment; ``disp``/``reliable`` are (V, H·W)."""
    nv = disp.shape[0]
    k = starts.size - 1
    planes = np.full((k, 3), np.nan)
    ninl = np.zeros(k, np.int32)
    for j in range(k):
        s0 = starts[j]
        s1 = starts[j + 1]
        nseg = (s1 - s0) * nv
        nrel = 0
        for v in range(nv):
            for t in range(s0, s1):
                if reliable[v, order[t]]:
                    nrel += 1
        # Eq. 6.8 over all views' pixels: too many unreliable -> no plane
        if nrel < min_pix or (nseg - nrel) > gamma * nseg:
            continue
        xs = np.empty(nrel)
        ys = np.empty(nrel)
        ds = np.empty(nrel)
        q = 0
        for v in range(nv):
            for t in range(s0, s1):
                p = order[t]
                if reliable[v, p]:
                    xs[q] = p % w
                    ys[q] = p // w
                    ds[q] = disp[v, p]
                    q += 1
        a, b, c, n_in = fit_one_plane(xs, ys, ds, t_out, eps, max_iter, min_pix, trials, max_slope, j + 1)
        if n_in >= min_pix:
            planes[j, 0] = a
            planes[j, 1] = b
            planes[j, 2] = c
            ninl[j] = n_in
    return planes, ninl


def fit_planes_joint(index: SegmentIndex, disparities: npt.NDArray[np.floating],
                     reliable: npt.NDArray[np.bool_], *, params: PlaneParams | None = None) -> tuple[F64, I32]:
    """One disparity plane per segment fitted to ALL views' disparity sets at once (thesis Eqs. 7.10–7.14).

    The reliable pixels of the ``n`` unit-baseline disparity sets ``d^(1, j) … d^(n, j)`` of segment ``j``
    are stacked into ``A [a, b, c]ᵀ = B`` (Eq. 7.11) and solved by the SVD pseudo-inverse
    (Eqs. 7.12–7.13) inside the outlier iteration of §6.1.2 (Eqs. 6.8–6.10), seeded robustly.

    Parameters
    ----------
    index : SegmentIndex
    disparities : (V, H, W) float
        Each view's disparity converted to the unit baseline; NaN where unknown.
    reliable : (V, H, W) bool
        Each view's left–right check (Eq. 6.7).
    params : PlaneParams, keyword-only

    Returns
    -------
    planes : (K, 3) float64, ``(a, b, c)`` with ``d = a x + b y + c``; NaN rows for segments without one.
    inliers : (K,) int32, stacked observations within ``t_outlier`` of the plane.
    """
    p = params or PlaneParams()
    d = np.asarray(disparities, dtype=np.float64)
    v = d.shape[0]
    rel = np.asarray(reliable, dtype=np.bool_).reshape(v, -1) & np.isfinite(d.reshape(v, -1))
    dd = np.nan_to_num(d.reshape(v, -1), nan=0.0)
    return _fit_all_joint(index.order, index.starts, index.shape[1], np.ascontiguousarray(dd),
                          np.ascontiguousarray(rel), p.gamma_segment, p.t_outlier, p.epsilon, p.max_iter,
                          p.min_pixels, p.ransac_trials, p.max_slope)


def _side_mean(pcs: Sequence[PairCost], *, max_disp: int, trunc: float, wu: float,
               raw: bool, by_baseline: bool = False) -> tuple[F32, F32]:
    """Σ of truncated, reliability-weighted costs of ``pcs`` on the unit grid, and Σ of the weights."""
    acc: F32 | None = None
    den: F32 | None = None
    for pc in pcs:
        c, seen = resample_to_unit(pc, max_disp=max_disp, raw=raw)
        if raw:
            np.minimum(c, np.float32(trunc), out=c)
        wb = np.float32(min(abs(pc.ratio), 1.0) if by_baseline else 1.0)
        wgt = np.where(pc.reliable, wb, wb * np.float32(wu))[:, :, None] * seen
        if acc is None or den is None:
            acc, den = c * wgt, wgt.astype(np.float32)
        else:
            acc += c * wgt
            den += wgt
    assert acc is not None and den is not None
    return acc, den


def _mean(acc: F32, den: F32) -> F32:
    return np.where(den > 0, acc / np.maximum(den, np.float32(1e-6)), np.float32(np.inf)).astype(np.float32)


def data_volume(pcs: Sequence[PairCost], *, max_disp: int, trunc: float, wu: float = 1.0,
                occlusion: str = "sides", weight_by_baseline: bool = True) -> F32:
    """Multi-view data term on the unit-baseline grid (thesis Eq. 7.16), per pixel and disparity.

    Each view's pixel cost at ``δᵢ d`` is truncated at ``trunc`` (Eq. 6.21) and weighted by 1 where that
    view's pair passed the left–right check, ``wu`` elsewhere; views that cannot see the match do not vote.

    ``weight_by_baseline``: a view's weight is ``min(|δᵢ|, 1)`` — on the unit grid a view at ratio δ
    resolves disparity |δ| times more coarsely, so short baselines (Cones' ±0.25) vote less.

    ``occlusion="sum"``: the mean over all views (Eq. 7.16's sum over ``i`` divided by ``n``).
    ``occlusion="sides"``: for every pixel and disparity, the views on the left of the reference or those on
    its right, whichever side's mean AGGREGATED cost is lower (where both sides see the match), supply the
    data cost: a point occluded on one side is still seen from the other (Kang, Szeliski & Chai,
    CVPR 2001), so occlusion no longer charges the true disparity. Deciding the side on the aggregated cost
    keeps the choice from following pixel noise. With views on one side only both options coincide.

    Returns
    -------
    (H, W, max_disp + 1) float32, on the scale of one view's cost; ``trunc`` where no view sees.
    """
    if occlusion not in ("sum", "sides"):
        raise ConfigError(f"expected occlusion 'sum' or 'sides', got {occlusion!r}")
    left = [pc for pc in pcs if pc.ratio < 0]
    right = [pc for pc in pcs if pc.ratio > 0]
    if occlusion == "sum" or not left or not right:
        out = _mean(*_side_mean(pcs, max_disp=max_disp, trunc=trunc, wu=wu, raw=True, by_baseline=weight_by_baseline))
    else:
        agg_l = _mean(*_side_mean(left, max_disp=max_disp, trunc=trunc, wu=wu, raw=False,
                                      by_baseline=weight_by_baseline))
        agg_r = _mean(*_side_mean(right, max_disp=max_disp, trunc=trunc, wu=wu, raw=False,
                                      by_baseline=weight_by_baseline))
        raw_l = _mean(*_side_mean(left, max_disp=max_disp, trunc=trunc, wu=wu, raw=True,
                                      by_baseline=weight_by_baseline))
        raw_r = _mean(*_side_mean(right, max_disp=max_disp, trunc=trunc, wu=wu, raw=True,
                                      by_baseline=weight_by_baseline))
        out = np.where(agg_l <= agg_r, raw_l, raw_r)
    out = np.where(np.isfinite(out), out, np.float32(trunc))
    return np.ascontiguousarray(out, dtype=np.float32)


def _fused_aggregated(pcs: Sequence[PairCost], *, max_disp: int, wu: float, occlusion: str,
                      weight_by_baseline: bool) -> F32:
    """The views' AGGREGATED costs fused on the unit grid (the local method's volume), with the same side
    selection and weights as the data term; matches no view sees get the largest cost plus one."""
    left = [pc for pc in pcs if pc.ratio < 0]
    right = [pc for pc in pcs if pc.ratio > 0]

    def side(group: Sequence[PairCost]) -> F32:
        return _mean(*_side_mean(group, max_disp=max_disp, trunc=np.inf, wu=wu, raw=False,
                                 by_baseline=weight_by_baseline))

    vol = np.minimum(side(left), side(right)) if occlusion == "sides" and left and right else side(pcs)
    top = np.float32(np.nanmax(np.where(np.isfinite(vol), vol, 0.0)) + 1.0)
    return np.ascontiguousarray(np.where(np.isfinite(vol), vol, top), dtype=np.float32)


def _fused_initial(vol: F32, pcs: Sequence[PairCost]) -> tuple[F32, npt.NDArray[np.bool_]]:
    """WTA + parabola on the fused aggregated costs ``vol`` (:func:`_fused_aggregated`); reliable where a
    pair's checked map agrees (±1)."""
    nd = vol.shape[2]
    k = vol.argmin(axis=2)
    kc = np.clip(k, 1, max(nd - 2, 1))
    if nd >= 3:
        c0 = np.take_along_axis(vol, (kc - 1)[..., None], 2)[..., 0]
        c1 = np.take_along_axis(vol, kc[..., None], 2)[..., 0]
        c2 = np.take_along_axis(vol, (kc + 1)[..., None], 2)[..., 0]
        den = c0 - 2.0 * c1 + c2
        off = np.where(den > 1e-6, (c0 - c2) / (2.0 * np.maximum(den, 1e-6)), 0.0)
        d = np.where((k > 0) & (k < nd - 1), k + np.clip(off, -0.5, 0.5), k).astype(np.float32)
    else:
        d = k.astype(np.float32)
    agree = np.zeros(d.shape, bool)
    for pc in pcs:
        agree |= pc.reliable & (np.abs(pc.disparity - d) <= 1.0)
    return d, agree


def match_multiview_global(reference: Any, views: Sequence[Any], *, ratios: Sequence[float], max_disp: int,
                           params: GlobalMultiViewParams | None = None) -> MatchResult:
    """Global multi-view disparity of the reference for the unit baseline (thesis §7.1.2).

    Parameters
    ----------
    reference : (H, W, 3) or (H, W) image, 0..255
    views : sequence of images of the reference's size (rectified, collinear horizontal baselines)
    ratios : sequence of float, keyword-only
        Signed baseline ratio of each view (+ = right of the reference; ``+1`` = the unit baseline).
    max_disp : int, keyword-only
        Largest disparity of the unit baseline.
    params : GlobalMultiViewParams, keyword-only

    Returns
    -------
    MatchResult
        ``disparity`` (H, W) float32 (dense, one plane per segment); ``valid``: pixels that at least one
        view's pair found reliable; ``disparity_raw``: the plane map before optimisation;
        ``extras``: ``labels`` (H, W), ``planes`` (L, 3), ``assign`` (K,), ``energy_before/after``,
        ``pair_disparities`` (V, H, W).
    """
    p = params or GlobalMultiViewParams()
    ref, vs, rs, md = check_views(reference, views, ratios, max_disp=max_disp)
    timings: dict[str, float] = {}
    t = time.perf_counter()
    post = p.post
    # the sweep step's row-boxed data term boxes the same pixel costs along the row: keep that volume from
    # this one pass over each pair instead of a second pair pass (it was 20 % of the five-view time)
    sw = p.steps.sweep
    row_radius = sw.row_box if post is not None and sw.frac > 0 and sw.row_box >= 0 else None
    pcs = [pair_cost(ref, v, r, max_disp=md, cost=p.cost, cost_params=p.cost_params, keep_raw=True,
                     data_radius=p.data_radius, row_radius=row_radius)
           for v, r in zip(vs, rs, strict=True)]
    timings["pair costs"] = time.perf_counter() - t
    t = time.perf_counter()
    occ = resolve_occlusion(p.occlusion, rs, weight_by_baseline=p.weight_by_baseline)
    data = data_volume(pcs, max_disp=md, trunc=p.coop.data_trunc, wu=p.unreliable_weight,
                       occlusion=occ, weight_by_baseline=p.weight_by_baseline)
    # later steps read the aggregated costs, disparities and checks only: free the square-boxed volumes
    pcs = [replace(pc, raw=None) for pc in pcs]
    timings["fusion"] = time.perf_counter() - t
    fb = None
    bpasw_term: F32 | None = None
    if p.post is not None:
        t = time.perf_counter()
        fb = fused_bpasw(ref, vs, rs, max_disp=md, occlusion=occ, weight_by_baseline=p.weight_by_baseline,
                         params=p.post)
        timings["bpasw"] = time.perf_counter() - t
        if p.data_bpasw > 0:
            bpasw_term = (fb.cost - fb.cost.min(axis=2, keepdims=True)) * np.float32(p.data_bpasw)
            data = np.ascontiguousarray(data + bpasw_term, np.float32)
    t = time.perf_counter()
    fused0: tuple[F32, npt.NDArray[np.bool_]] | None = None
    if p.fit_source in ("fused", "both") or p.segmentation.depth_tau > 0 or p.data_agg > 0 or p.post is not None:
        agg = _fused_aggregated(pcs, max_disp=md, wu=p.unreliable_weight, occlusion=occ,
                                weight_by_baseline=p.weight_by_baseline)
        fused0 = _fused_initial(agg, pcs)
        if p.data_agg > 0:
            data = np.ascontiguousarray(data + (agg - agg.min(axis=2, keepdims=True)) * np.float32(p.data_agg),
                                        np.float32)
        del agg
    timings["fusion"] += time.perf_counter() - t
    t = time.perf_counter()
    # the fused map is the depth cue of a depth-aware segmentation (unused when depth_tau is 0)
    labels = mean_shift_segment(ref, params=p.segmentation, disparity=None if fused0 is None else fused0[0])
    index = build_segment_index(labels)
    pairs, _length, contrast = segment_adjacency(labels, ref)
    timings["segmentation"] = time.perf_counter() - t
    t = time.perf_counter()
    disps = np.stack([pc.disparity for pc in pcs])
    rels = np.stack([pc.reliable for pc in pcs]) & np.isfinite(disps)
    fit_views = np.array([abs(pc.ratio) >= p.fit_min_ratio for pc in pcs])
    if not fit_views.any():
        fit_views[:] = True
    disps, rels = disps[fit_views], rels[fit_views]
    if p.fit_source in ("fused", "both"):
        assert fused0 is not None
        fd, frel = fused0
        if p.fit_source == "fused":
            disps, rels = fd[None], frel[None]
        else:
            disps, rels = np.concatenate([disps, fd[None]]), np.concatenate([rels, frel[None]])
    elif p.fit_source != "pairs":
        raise ConfigError(f"expected fit_source 'pairs', 'fused' or 'both', got {p.fit_source!r}")
    if p.fit_bpasw and fb is not None:
        disps, rels = np.concatenate([disps, fb.disparity[None]]), np.concatenate([rels, fb.reliable[None]])
    planes, _inl = fit_planes_joint(index, disps, rels, params=p.planes)
    with np.errstate(invalid="ignore"):
        n_rel = rels.sum(axis=0)
        mean_d = np.where(n_rel > 0, np.nansum(np.where(rels, disps, 0.0), axis=0) / np.maximum(n_rel, 1),
                          np.nan).astype(np.float32)
    any_rel = n_rel > 0
    cluster, cplanes = merge_planes(index, planes, pairs, mean_d, any_rel, params=p.planes)
    k = index.n_segments
    fin = np.flatnonzero(np.isfinite(planes[:, 0]))
    plane_set = (np.concatenate([planes[fin], cplanes]) if fin.size
                 else np.array([[0.0, 0.0, float(np.nanmedian(mean_d)) if any_rel.any() else 0.0]]))
    own = np.full((k, 2), -1, np.int64)
    own[fin, 0] = np.arange(fin.size)
    own[cluster >= 0, 1] = cluster[cluster >= 0] + fin.size
    assign = fill_missing_planes(np.where(cluster >= 0, cluster + fin.size, -1).astype(np.int32), pairs,
                                 contrast)
    assign = np.where(assign < 0, 0, assign).astype(np.int32)
    timings["planes"] = time.perf_counter() - t
    t = time.perf_counter()
    graph = build_segment_graph(labels, ref)
    gamma = p.coop.gamma
    if p.scale_smoothness:
        wv = np.array([min(abs(r), 1.0) if p.weight_by_baseline else 1.0 for r in rs])
        n_eff = float(wv.sum() ** 2 / np.square(wv).sum())  # Kish effective number of views
        gamma = p.coop.gamma / math.sqrt(n_eff)
    cp = replace(p.coop, data_trunc=float(np.float32(data.max())) + 1.0, unreliable_weight=1.0, gamma=gamma)
    if occ == "sides" and hasattr(cp, "visibility"):
        # views on both sides: the side selection of the data term already lets the unoccluded side vote;
        # the optimiser's right-view visibility test would charge occlusion the left views do not see
        cp = replace(cp, visibility=False)
    initial = render_planes(index, plane_set, assign)
    steps = p.steps
    if p.post is None or fb is None:
        steps = steps.without("bpasw_planes", "sweep", "group_moves", "fine", "boundary", "occlusion", "median",
                              "fallback", "curved")
    ev = _ViewsEvidence(ref, vs, rs, pcs, data=data, coop=cp, segmentation=p.segmentation, planes=p.planes,
                        max_disp=md, fb=fb, fused0=fused0, disps=disps, rels=rels, bpasw_term=bpasw_term,
                        row_radius=row_radius, params=p, occlusion=occ)
    state = PlaneLabels(labels=labels, index=index, graph=graph, assign=assign, planes=plane_set, own=own,
                        parent=np.arange(k, dtype=np.int64), pairs=pairs)

    def snapshot(name: str, s: PlaneLabels) -> None:
        nonlocal t
        if name == "refit":
            timings["optimisation"] = time.perf_counter() - t
            t = time.perf_counter()

    state = run_steps(state, ev, steps, snapshot=snapshot)
    if p.post is not None and fb is not None:
        timings["post"] = time.perf_counter() - t
    assert state.disparity is not None
    info = state.info
    extras: dict[str, Any] = {"labels": state.labels, "planes": state.planes, "assign": state.assign,
                              "pair_disparities": disps, **info}
    log.debug("global multiview: %d views, %d segments, %d planes, E %.1f -> %.1f", len(vs), state.assign.size,
              state.planes.shape[0], info["energy_before"], info["energy_after"])
    return MatchResult(state.disparity, any_rel, initial, timings, extras)


class _ViewsEvidence:
    """The multi-view evidence of the steps (:class:`~prismstereo.matching.coop.steps.Evidence`): the views'
    data term on the unit grid, the fused BPASW cost and map (:mod:`prismstereo.multiview.poststeps`), the
    map of the views' fused aggregated costs and the pairs' checked maps."""

    min_disp = 0
    slopes: tuple[float, ...] | None = None

    def __init__(self, ref: npt.NDArray[np.uint8], views: Sequence[Any], ratios: Sequence[float],
                 pcs: list[PairCost], *, data: F32, coop: CoopParams, segmentation: SegmentationParams,
                 planes: PlaneParams, max_disp: int, fb: FusedBPASW | None,
                 fused0: tuple[F32, npt.NDArray[np.bool_]] | None, disps: npt.NDArray[np.floating],
                 rels: npt.NDArray[np.bool_], bpasw_term: F32 | None, row_radius: int | None,
                 params: GlobalMultiViewParams, occlusion: str):
        self.image, self.views, self.ratios, self.pcs = ref, views, ratios, pcs
        self.data, self.coop, self.segmentation, self.plane_params = data, coop, segmentation, planes
        self.check_data = data
        self.max_disp, self.fb, self.fused0, self.disps, self.rels = max_disp, fb, fused0, disps, rels
        self.bpasw_term, self.row_radius, self.p, self.occ = bpasw_term, row_radius, params, occlusion
        self.reliable = np.ones(ref.shape[:2], bool)
        self.memo = CoopMemo()

    def optimise(self, s: PlaneLabels, assign: I32, planes: F64, own: npt.NDArray[np.int64], *,
                 neighbour_own_planes: bool = False) -> tuple[I32, F64, dict[str, float]]:
        prm = replace(self.coop, neighbour_own_planes=True) if neighbour_own_planes else self.coop
        out = cooperative_optimize(assign, planes, s.index, s.graph, self.data, self.reliable, own=own,
                                   min_disp=0, params=prm, memo=self.memo)
        # (assign, info), or (assign, extended planes, info) when the optimiser refines planes continuously
        if len(out) == 3:
            return out[0], out[1], out[2]
        return out[0], planes, out[1]  # type: ignore[unreachable]

    def refit(self, s: PlaneLabels, assign: I32, planes: F64) -> tuple[F64, npt.NDArray[np.int64]] | None:
        # as coop, jointly over the disparity sets
        return group_refit_planes(assign, planes, s.index,
                                  fit=lambda g: fit_planes_joint(g, self.disps, self.rels, params=self.plane_params)[0])

    def bpasw_map(self) -> tuple[F32, npt.NDArray[np.bool_]] | None:
        return None if self.fb is None else (self.fb.disparity, self.fb.reliable)

    def sweep(self, s: PlaneLabels, p: SweepParams) -> tuple[F64, npt.NDArray[np.int64]]:
        ratio = self.p.post.sweep_ratio if self.p.post is not None else 1.0
        return sweep_candidates(self.image, self.views, self.ratios, s.labels, s.index, s.assign, s.planes,
                                max_disp=self.max_disp, params=p, ratio=ratio)

    def row_box(self, selected: npt.NDArray[np.bool_], p: SweepParams) -> None:
        if self.row_radius is None:
            return
        # the same pair costs with the row-boxed pixel cost as their raw volume
        hb = data_volume([replace(pc, raw=pc.raw_row) for pc in self.pcs], max_disp=self.max_disp,
                         trunc=self.p.coop.data_trunc, wu=self.p.unreliable_weight, occlusion=self.occ,
                         weight_by_baseline=self.p.weight_by_baseline)
        self.pcs = [replace(pc, raw_row=None) for pc in self.pcs]
        if self.bpasw_term is not None:
            hb = hb + self.bpasw_term
        data = self.data.copy()
        data[selected] = hb[selected]
        self.check_data, self.data = self.data, np.ascontiguousarray(data, np.float32)

    def segments(self, params: SegmentationParams) -> npt.NDArray[np.int32]:
        return mean_shift_segment(self.image, params=params)

    def fine_evidence(self, tol: float) -> tuple[npt.NDArray[np.bool_], F32] | None:
        if self.fused0 is None or self.fb is None:
            return None
        fd0, frel0 = self.fused0
        return frel0 & self.fb.reliable & (np.abs(self.fb.disparity - fd0) <= tol), fd0

    def boundary_evidence(self, tol: float) -> tuple[F32, F32, npt.NDArray[np.bool_], npt.NDArray[np.bool_]] | None:
        if self.fb is None:
            return None
        gagree = np.zeros(self.image.shape[:2], bool)
        for pc in self.pcs:
            gagree |= pc.reliable & (np.abs(pc.disparity - self.fb.disparity) <= tol)
        return self.fb.cost, self.fb.disparity, self.fb.reliable, self.fb.reliable & gagree

    def occlusion(self, s: PlaneLabels, final: F32, p: OcclusionParams) -> F32:
        if self.fb is None or self.p.post is None:
            return final
        return occlusion_sides(final, s.labels, s.assign, s.planes, self.fb, params=p, post=self.p.post,
                               sides_balanced=self.occ == "sides")

    def fallback(self, s: PlaneLabels, final: F32, p: FallbackParams) -> F32:
        # the front end has no plane support test here (it measured worse on Tsukuba's five views): nothing to
        # fall back from
        return final
