"""``coop``'s post-optimisation steps (boundary step, occlusion step, BPASW candidate planes, subpixel-preserving
median) carried over to the global multi-view method with multi-view evidence.

The two-view ``coop`` (:mod:`prismstereo.matching.coop`) follows its cooperative optimisation with steps that
read the ``bpasw`` matcher's aggregated cost of the one pair. Here each step reads the evidence of all views:

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

from prismstereo.checks import check_fields
from prismstereo.matching.coop.pipeline import occlusion_background_fill, segment_sweep_candidates
from prismstereo.matching.coop.steps import OcclusionParams, SweepParams
from prismstereo.matching.local.selection import (
    right_cost_volume,
    subpixel_refine,
    winner_take_all,
)
from prismstereo.matching.segments.planes import (
    SegmentIndex,
)
from prismstereo.multiview.baseline import PairCost, fuse_costs
from prismstereo.multiview.sharedbpasw import bpasw_pair_costs

__all__ = ["FusedBPASW", "PostParams", "fused_bpasw", "occlusion_sides", "sweep_candidates"]

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
I32 = npt.NDArray[np.int32]
B = npt.NDArray[np.bool_]


@dataclass(frozen=True, kw_only=True)
class PostParams:
    """The multi-view evidence of the steps after ``refit`` (the steps' own parameters are
    :class:`~prismstereo.matching.coop.steps.StepParams`, shared with ``coop``).

    Attributes
    ----------
    bpasw_min_ratio, bpasw_max_ratio : float
        Views whose ``|δ|`` lies in this range give BPASW pair costs to the fused cost (all views when none).
    bpasw_max_ratio_sides : float
        The upper bound instead when the data term selects sides (views on both sides of comparable weight):
        the side selection resolves the longer baselines' occlusions.
    consistency_tol : float
        A view's cross-checked BPASW disparity supports the fused winner within this (unit px).
    occ_both : bool
        With views on both sides of comparable weight (the data term's side selection, ``occlusion`` resolved
        to ``"sides"``), only pixels contradicted from both sides are changed by the occlusion step; otherwise
        each side's view changes the pixels it contradicts, one side after the other.
    occ_ratio : float
        Each side's occlusion step uses that side's view of ``|δ|`` closest to this.
    sweep_ratio : float
        The sweep step's slanted-window costs are read against the right view of ``|δ|`` closest to this.
    """

    bpasw_min_ratio: float = 0.5
    bpasw_max_ratio: float = 1.0
    bpasw_max_ratio_sides: float = 2.0
    consistency_tol: float = 1.0
    occ_both: bool = True
    occ_ratio: float = 1.0
    sweep_ratio: float = 1.0

    def __post_init__(self) -> None:
        check_fields(self, {"bpasw_min_ratio": (0.0, None), "bpasw_max_ratio": (0.0, None),
                            "bpasw_max_ratio_sides": (0.0, None), "consistency_tol": (0.0, None),
                            "occ_ratio": (0.0, None), "sweep_ratio": (0.0, None)})


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
                     index: SegmentIndex, assign: I32, plane_set: F64, *, max_disp: int, params: SweepParams,
                     ratio: float = 1.0) -> tuple[F64, npt.NDArray[np.int64]]:
    """``coop``'s sweep candidates (:func:`~prismstereo.matching.coop.pipeline.segment_sweep_candidates`) on the
    reference and its right view of ``|δ|`` closest to ``ratio``, converted to the unit baseline; returns the
    extended plane set and the (K, keep) candidate ids (-1 none; all -1 when there is no right view or the
    step is off)."""
    k = index.n_segments
    none = np.full((k, max(params.keep, 1)), -1, np.int64)
    right = [i for i, r in enumerate(ratios) if r > 0]
    if params.frac <= 0 or params.keep <= 0 or not right:
        return plane_set, none
    i = min(right, key=lambda j: abs(math.log(ratios[j] / ratio)))
    r = float(ratios[i])
    w = ref.shape[1]
    md = int(min(w - 1, math.ceil(r * max_disp)))
    out, ids = segment_sweep_candidates(np.ascontiguousarray(ref, np.uint8), np.ascontiguousarray(views[i], np.uint8),
                                 labels, index, assign, plane_set * r, min_disp=0, max_disp=md, params=params)
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


def occlusion_sides(final: F32, labels: I32, assign: I32, plane_set: F64, fb: FusedBPASW, *,
                    params: OcclusionParams, post: PostParams, sides_balanced: bool = False) -> F32:
    """The occlusion step against each side's view (see the module doc); (H, W) float32."""
    lab32 = np.ascontiguousarray(labels, dtype=np.int32)
    sides = []
    for side in (1, -1):
        cands = [pc for pc in fb.pairs if side * pc.ratio > 0]
        if cands:
            sides.append(min(cands, key=lambda c: abs(abs(c.ratio) - post.occ_ratio)))
    rad = params.rematch_radius
    if post.occ_both and sides_balanced and len(sides) == 2:
        # views on both sides: a wrongly fattened pixel is contradicted from both sides, a pixel that is
        # only half-occluded (or whose one-side view map is wrong) from one
        o1, m1 = _side_occlusion(final, lab32, assign, plane_set, sides[0], fb, tol=params.tol, radius=rad)
        o2, m2 = _side_occlusion(final, lab32, assign, plane_set, sides[1], fb, tol=params.tol, radius=rad)
        final = np.where(m1 & m2, np.minimum(o1, o2), final).astype(np.float32)
    else:
        for pc in sides:
            final, _m = _side_occlusion(final, lab32, assign, plane_set, pc, fb, tol=params.tol, radius=rad)
    return final
