"""``coop``'s post-optimisation steps (boundary step, occlusion step, BPASW candidate planes, subpixel-preserving
median) carried over to the global multi-view method with multi-view evidence.

The two-view ``coop`` (:mod:`prismstereo.matching.coop`) follows its cooperative optimisation with steps that
read issue 3's BPASW aggregated cost of the one pair. Here each step reads the evidence of all views:

* **Fused BPASW cost** (:func:`fused_bpasw`): the BPASW aggregated cost of the reference against each view
  whose ``|δ|`` lies in ``[bpasw_min_ratio, bpasw_max_ratio]``, resampled to the unit baseline and summed
  with baseline weights, the lower of the left and right sides' sums where the data term uses side selection
  (the local method's volume, :func:`~prismstereo.multiview.local.match_multibaseline`). Its WTA map is
  *reliable* where at least one view's cross-checked BPASW map agrees with it (multi-view consistency; the
  two-view ``coop`` uses the pair's own cross-check).
* **Candidate planes**: planes fitted to that reliable map per segment, their merged clusters, and planes
  refitted over groups of segments sharing a plane are offered to the optimiser, which resumes after each.
* **Boundary step**: coop's ``boundary_pixel_planes`` on the fused BPASW cost (a nearby segment's plane wins where it
  is cheaper by a margin and agrees with the reliable fused map; moves to a larger disparity also need a
  guided pair's checked map to agree).
* **Occlusion step**: coop's ``occlusion_background_fill`` run once per side, with that side's view of ``|δ|`` closest
  to 1 (the left side on mirrored images): a pixel whose match in a view reliably sees a farther surface
  cannot be at that disparity (it would occlude that surface), whichever side the view is on.
* **Median**: colour-weighted median that only overrides disparities it moves by more than 1 px.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from prismstereo.matching.coop import (
    boundary_pixel_planes,
    bpasw_candidate_rounds,
    occlusion_background_fill,
    segment_sweep_candidates,
)
from prismstereo.matching.local.selection import (
    right_cost_volume,
    subpixel_refine,
    weighted_median_filter,
    winner_take_all,
)
from prismstereo.matching.segments.planes import (
    SegmentIndex,
    render_planes,
)
from prismstereo.multiview.baseline import PairCost, fuse_costs
from prismstereo.multiview.sharedbpasw import bpasw_pair_costs

__all__ = ["FusedBPASW", "PostParams", "fused_bpasw", "boundary_and_occlusion", "bpasw_candidate_rounds",
           "sweep_candidates"]

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
I32 = npt.NDArray[np.int32]
B = npt.NDArray[np.bool_]


@dataclass(frozen=True, kw_only=True)
class PostParams:
    """Post-step parameters (``coop``'s defaults where the step is the same).

    Attributes
    ----------
    bpasw_min_ratio, bpasw_max_ratio : float
        Views whose ``|δ|`` lies in this range give BPASW pair costs to the fused cost (all views when none).
    bpasw_max_ratio_sides : float
        The upper bound instead when the data term selects sides (views on both sides of comparable weight):
        the side selection resolves the longer baselines' occlusions. Measured: Tsukuba five views
        1.67 -> 1.58 nonocc with ±2 included; Cones (plain sum) 1.81 -> 2.03 with its +1.25, +1.5 included.
    consistency_tol : float
        A view's cross-checked BPASW disparity supports the fused winner within this (unit px).
    bpasw_planes : int
        Candidate-plane rounds on the fused BPASW map (1: per-segment fits, 2: + merged clusters,
        3: + group refit), as ``coop``'s ``bpasw_planes``.
    pixel_radius, pixel_margin, pixel_tol, pixel_agree, pixel_bplanes : boundary step, as ``coop``.
    occlusion_fill, occ_tol, occ_rematch : occlusion step, as ``coop`` (per side).
    occ_both : bool
        Each side's occlusion step uses that side's view of ``|δ|`` closest to ``occ_ratio`` (Tsukuba five
        views: 1 -> 1.58 nonocc, 2 -> 1.59).
        With views on both sides of comparable weight (the data term's side selection, ``occlusion`` resolved
        to ``"sides"``), only pixels contradicted from both sides are changed; otherwise each side's view
        changes the pixels it contradicts, one side after the other.
    post_median : int
        Radius of the final subpixel-preserving weighted median (0 = off; 3 since the finer segment levels
        follow edges closely: Tsukuba five views 1.01 -> 0.98 nonocc against 4, Cones nine views 1.81 -> 1.80).
    sweep_frac, sweep_slopes, sweep_keep, sweep_min_px, sweep_step, sweep_dil, sweep_hbox : sweep step
        As ``coop`` (:func:`prismstereo.matching.coop.segment_sweep_candidates`, after the BPASW rounds): the
        ``sweep_frac`` of the segments with the highest slanted-window cost against the right view of ``|δ|``
        closest to ``sweep_ratio`` get the ``sweep_keep`` cheapest planes of a global sweep (whole range x ``b`` in
        ``sweep_slopes``) as candidates, and with ``sweep_hbox >= 0`` the data term on their pixels is the
        views' pixel costs boxed along the row only (radius ``sweep_hbox``); ``sweep_frac`` 0 = off.
        Measured (bad > 1 px, nonocc/all/disc): Tsukuba five views 1.58/1.97/6.69 -> 1.37/1.73/6.53
        (``coop``'s 50 % and step 4: 1.57/1.92/6.55; 75 %: 3.13/3.44/7.10; 20 %: 1.52/1.88/6.64; the row box
        changes nothing there), Cones nine views 1.75/3.41/5.11 -> 1.74/3.39/5.08 (step 4: 1.75/3.42/5.11).
        ``sweep_ratio`` 2 (Tsukuba's +2 view) measured worse: 3.06/3.41/6.61 at 50 %.
    group_moves : bool
        After the sweep, sweep candidates and the planes across segment boundaries may move whole regions at
        once (:func:`~prismstereo.matching.coop.cooperative.expand_planes`, as ``coop``); Tsukuba five views
        unchanged (1.24/1.60/5.87), Cones nine views 1.72/3.34/5.05 -> 1.70/3.30/4.97.
    fine_hr, fine_min, fine_check : finer segments, as ``coop``
        (:func:`~prismstereo.matching.coop.refine_fine_segments`, after the sweep step): the reference is
        segmented again with range radius ``fine_hr`` and minimum size ``fine_min`` inside the segments; fine
        segments touching another plane resume the cooperative optimisation on the multi-view data term, a
        move kept only when at least ``fine_check`` more of the fine segment's evidence pixels lie within
        1 px of the new plane than of the old; ``fine_hr`` 0 = off. Measured (bad > 1 px, nonocc/all/disc):
        Tsukuba five views 1.37/1.73/6.53 -> 1.24/1.60/5.87, Cones nine views 1.74/3.39/5.08 -> 1.72/3.34/5.05.
        The evidence is ``coop``'s rule on the unit grid: the map of the views' fused guided costs where a
        pair's checked map agrees with it and the fused BPASW map is reliable and within ``pixel_tol`` of it
        (the boundary step's evidence instead, the reliable fused BPASW map where a guided pair's checked map
        agrees, measured 1.25/1.61/5.85 and 1.73/3.33/5.05: not kept).
    fine_extra : tuple of (hr, min_region)
        Further, finer levels of the same step, each run on the previous level's segments (which they
        subdivide) with the same evidence check: the colour edge of a depth edge is often one or two pixels
        from the first level's boundary, and a segment cut at ``hr`` 1.5 / 1 can follow it. Measured (nonocc,
        the other defaults unchanged): Tsukuba five views 1.08 -> 0.98, Cones nine views 1.80 -> 1.80; added
        alone to the previous defaults, Tsukuba 1.24 -> 1.16 and Cones unchanged (1.70); ``()`` = off.
    """

    bpasw_min_ratio: float = 0.5
    bpasw_max_ratio: float = 1.0
    bpasw_max_ratio_sides: float = 2.0
    consistency_tol: float = 1.0
    bpasw_planes: int = 2
    pixel_radius: int = 5
    pixel_margin: float = 5.0
    pixel_tol: float = 1.0
    pixel_agree: int = 2
    group_moves: bool = True
    pixel_bplanes: int = 2
    occlusion_fill: bool = True
    occ_tol: float = 1.0
    occ_rematch: bool = True
    occ_both: bool = True
    occ_ratio: float = 1.0
    post_median: int = 3
    sweep_frac: float = 0.35
    sweep_slopes: tuple[float, ...] = (-1.0, -0.5, 0.0, 0.5, 1.0)
    sweep_keep: int = 2
    sweep_min_px: int = 40
    sweep_step: int = 2
    sweep_dil: int = 3
    sweep_hbox: int = 1
    sweep_ratio: float = 1.0
    fine_hr: float = 3.0
    fine_min: int = 10
    fine_check: int = 1
    fine_extra: tuple[tuple[float, int], ...] = ((1.5, 3), (1.0, 1))


@dataclass(frozen=True)
class FusedBPASW:
    """The fused BPASW evidence: ``cost`` (H, W, D+1) on the unit grid, its WTA+subpixel map ``disparity``,
    ``reliable`` (multi-view consistent), and the per-view BPASW pair costs ``pairs``."""

    cost: F32
    disparity: F32
    reliable: B
    pairs: list[PairCost]


def fused_bpasw(ref: np.ndarray, views: Sequence[np.ndarray], ratios: Sequence[float], *, max_disp: int,
                occlusion: str, weight_by_baseline: bool, params: PostParams) -> FusedBPASW:
    """BPASW pair costs of the selected views fused on the unit grid (the local method's volume)."""
    hi = params.bpasw_max_ratio_sides if occlusion == "sides" else params.bpasw_max_ratio
    sel = [i for i, r in enumerate(ratios) if params.bpasw_min_ratio <= abs(r) <= hi]
    if not sel:
        sel = list(range(len(ratios)))
    pcs = bpasw_pair_costs(ref, [views[i] for i in sel], [ratios[i] for i in sel], max_disp=max_disp)

    def wfn(r: float) -> float:
        return min(abs(r), 1.0) if weight_by_baseline else 1.0

    lv = [pc for pc in pcs if pc.ratio < 0]
    rv = [pc for pc in pcs if pc.ratio > 0]
    if occlusion == "sides" and lv and rv:
        fl, _ = fuse_costs(lv, max_disp=max_disp, weights=[wfn(pc.ratio) for pc in lv])
        fr, _ = fuse_costs(rv, max_disp=max_disp, weights=[wfn(pc.ratio) for pc in rv])
        fused = np.minimum(fl, fr)
    else:
        fused, _ = fuse_costs(pcs, max_disp=max_disp, weights=[wfn(pc.ratio) for pc in pcs])
    fused = np.ascontiguousarray(fused, dtype=np.float32)
    d0 = winner_take_all(fused)
    disp = np.asarray(subpixel_refine(fused, d0), np.float32)
    rel = np.zeros(disp.shape, bool)
    for pc in pcs:
        rel |= pc.reliable & (np.abs(pc.disparity - disp) <= params.consistency_tol)
    return FusedBPASW(fused, disp, rel, pcs)


def sweep_candidates(ref: np.ndarray, views: Sequence[np.ndarray], ratios: Sequence[float], labels: I32,
                     index: SegmentIndex, assign: I32, plane_set: F64, *, max_disp: int,
                     params: PostParams) -> tuple[F64, npt.NDArray[np.int64]]:
    """``coop``'s sweep candidates (:func:`~prismstereo.matching.coop.segment_sweep_candidates`) on the reference and
    its right view of ``|δ|`` closest to 1, converted to the unit baseline; returns the extended plane set and
    the (K, keep) candidate ids (-1 none; all -1 when there is no right view or the step is off)."""
    k = index.n_segments
    none = np.full((k, max(params.sweep_keep, 1)), -1, np.int64)
    right = [i for i, r in enumerate(ratios) if r > 0]
    if params.sweep_frac <= 0 or params.sweep_keep <= 0 or not right:
        return plane_set, none
    i = min(right, key=lambda j: abs(math.log(ratios[j] / params.sweep_ratio)))
    r = float(ratios[i])
    w = ref.shape[1]
    md = int(min(w - 1, math.ceil(r * max_disp)))
    out, ids = segment_sweep_candidates(np.ascontiguousarray(ref, np.uint8), np.ascontiguousarray(views[i], np.uint8),
                                 labels, index, assign, plane_set * r, min_disp=0, max_disp=md,
                                 frac=params.sweep_frac, slopes=tuple(params.sweep_slopes),
                                 keep=params.sweep_keep, min_px=params.sweep_min_px, step=params.sweep_step,
                                 dilation=params.sweep_dil)
    base = plane_set.shape[0]
    return np.concatenate([plane_set, out[base:] / r]), ids


def _side_occlusion(final: F32, labels: I32, assign: I32, plane_set: F64, pc: PairCost, fb: FusedBPASW,
                    *, tol: float, radius: int) -> tuple[F32, B]:
    """coop's occlusion step against one view (scaled to its pair disparities; mirrored for a left view)."""
    a = abs(pc.ratio)
    w = final.shape[1]
    vol = pc.cost
    disp, lab, bd, br = final, labels, fb.disparity, fb.reliable
    pl = plane_set * a
    if pc.ratio < 0:  # mirrored frame: the left view becomes a right view
        vol = vol[:, ::-1]
        disp, lab, bd, br = disp[:, ::-1], lab[:, ::-1], bd[:, ::-1], br[:, ::-1]
        pl = np.stack([-pl[:, 0], pl[:, 1], pl[:, 2] + pl[:, 0] * (w - 1)], axis=1)
    vol = np.ascontiguousarray(vol, dtype=np.float32)
    rvol = right_cost_volume(vol)
    dr_int = rvol.argmin(axis=2)
    dl_int = vol.argmin(axis=2)
    xs = np.arange(w)[None, :] + dr_int
    rrel = (xs < w) & (np.take_along_axis(dl_int, np.clip(xs, 0, w - 1), axis=1) == dr_int)
    out, occ = occlusion_background_fill(np.ascontiguousarray(disp * np.float32(a), dtype=np.float32),
                                np.ascontiguousarray(lab, dtype=np.int32), assign.astype(np.int32),
                                np.ascontiguousarray(pl, dtype=np.float64), dr_int.astype(np.float32),
                                np.ascontiguousarray(rrel), float(tol * a),
                                np.ascontiguousarray(bd * np.float32(a), dtype=np.float32),
                                np.ascontiguousarray(br), int(radius))
    out = out / np.float32(a)
    if pc.ratio < 0:
        out, occ = out[:, ::-1], occ[:, ::-1]
    return np.ascontiguousarray(out, dtype=np.float32), np.ascontiguousarray(occ)


def boundary_and_occlusion(ref: np.ndarray, labels: I32, index: SegmentIndex, assign: I32, plane_set: F64,
                           own: npt.NDArray[np.int64], bfit_ids: npt.NDArray[np.int64] | None, fb: FusedBPASW,
                           guided: Sequence[PairCost], *, max_disp: int, params: PostParams,
                           sides_balanced: bool = False) -> F32:
    """Boundary step, per-side occlusion step and the subpixel-preserving median (see the module doc)."""
    p = params
    lab32 = np.ascontiguousarray(labels, dtype=np.int32)
    if p.pixel_radius > 0:
        extra = []
        if p.pixel_bplanes and bfit_ids is not None:
            extra.append(bfit_ids)
        if p.pixel_bplanes > 1:
            extra.append(own[:, 0])
        k = own.shape[0]
        bown = np.ascontiguousarray(np.stack(extra, axis=1) if extra else np.full((k, 1), -1), dtype=np.int32)
        gagree = np.zeros(labels.shape, bool)
        for pc in guided:
            gagree |= pc.reliable & (np.abs(pc.disparity - fb.disparity) <= p.pixel_tol)
        bagree = fb.reliable & gagree
        brel = bagree if p.pixel_agree == 1 else fb.reliable
        final = boundary_pixel_planes(lab32, assign.astype(np.int32), plane_set, fb.cost, 0, int(p.pixel_radius),
                              float(p.pixel_margin), np.ascontiguousarray(brel), fb.disparity,
                              float(p.pixel_tol), np.ascontiguousarray(bagree if p.pixel_agree else brel),
                              bown)
    else:
        final = render_planes(index, plane_set, assign).astype(np.float32)
    if p.occlusion_fill:
        sides = []
        for side in (1, -1):
            cands = [pc for pc in fb.pairs if side * pc.ratio > 0]
            if cands:
                sides.append(min(cands, key=lambda c: abs(abs(c.ratio) - p.occ_ratio)))
        rad = p.pixel_radius if p.occ_rematch else 0
        if p.occ_both and sides_balanced and len(sides) == 2:
            # views on both sides: a wrongly fattened pixel is contradicted from both sides, a pixel that is
            # only half-occluded (or whose one-side view map is wrong) from one
            o1, m1 = _side_occlusion(final, lab32, assign, plane_set, sides[0], fb, tol=p.occ_tol, radius=rad)
            o2, m2 = _side_occlusion(final, lab32, assign, plane_set, sides[1], fb, tol=p.occ_tol, radius=rad)
            final = np.where(m1 & m2, np.minimum(o1, o2), final).astype(np.float32)
        else:
            for pc in sides:
                final, _m = _side_occlusion(final, lab32, assign, plane_set, pc, fb, tol=p.occ_tol, radius=rad)
    if p.post_median > 0:
        wm = weighted_median_filter(final, ref, radius=p.post_median)
        final = np.where(np.abs(wm - final) <= 1.0, final, wm)
    return np.clip(final, 0, max_disp).astype(np.float32)
