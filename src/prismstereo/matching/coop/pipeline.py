"""``coop``: segment-based stereo with cooperative optimisation (thesis chapters 5-6), the flagship matcher.

Front end (kept in :class:`CoopResult`):

1. initial disparity map: adaptive-weight aggregated cost, WTA, parabola subpixel, left-right cross-check
   (§5.2, Eq. 6.7)                                             -> ``initial``, ``reliable``
2. mean-shift segmentation of the left image (§5.1)          -> ``labels``
3. robust plane per segment (Eqs. 6.1-6.10) and merging of similar neighbours (Eqs. 6.14-6.17); segments
   without a plane take their most similar neighbour's; a large segment whose plane the evidence (both
   cross-checked initial maps agree) does not support is split in quarters and refitted
                                                              -> ``plane_map`` (thesis Table 6.1)

then the steps of :mod:`prismstereo.matching.coop.steps`, shared with the global multi-view method
(optimise, refit, bpasw_planes, sweep, group_moves, fine, boundary, occlusion, curved, median, fallback), on the
two-view evidence (:class:`_PairEvidence`: the pair's data term, the ``bpasw`` matcher's cost volume of the pair
and its cross-checked map)                                        -> ``disparity`` (thesis Table 6.2)

Default parameters (the same for every scene): hs = 5, hr = 4, M = 20; guided filter r = 9, ε = 1e-4;
γ_segment = 0.9, t_outlier = 1, ε(6.10) = 0.99, δ = 0.8; κ = 0.5, μ = 1, ω_occ = 1, γ = 0.5;
data-term volumes for vertical slopes b = -1, -0.5, 0, 0.5, 1 (census window and 3x3 box sheared along the
plane, each plane reading its nearest); the steps' defaults are :class:`~prismstereo.matching.coop.steps.StepParams`.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, TypeVar

import cv2
import numpy as np
import numpy.typing as npt
from numba import njit

from prismstereo.errors import ConfigError, ImageError
from prismstereo.io.images import as_image
from prismstereo.matching.coop.coopcost import (
    CostParams,
    ShearedInputs,
    aggregated_costs,
    colour_term,
    keep_outside,
    raw_cost,
    raw_cost_from,
    shear_row_boxes,
    sheared_costs,
    sheared_inputs,
    sheared_row_boxes,
    sheared_row_costs_at,
)
from prismstereo.matching.coop.cooperative import (
    CoopMemo,
    CoopParams,
    build_segment_graph,
    cooperative_optimize,
)
from prismstereo.matching.coop.flatcost import contradicted_segments, flat_cost_segments, outvoted_segments, peak_ratio
from prismstereo.matching.coop.radiometry import RadiometryParams, compensate_right
from prismstereo.matching.coop.slanted import SlantedParams, segment_plane_costs, segment_sweep_costs, slanted_pair
from prismstereo.matching.coop.steps import (
    FallbackParams,
    OcclusionParams,
    PlaneLabels,
    StepParams,
    SweepParams,
    coerce_params,
    run_steps,
)
from prismstereo.matching.local import selection
from prismstereo.matching.local.matchers import BPASWMatcher
from prismstereo.matching.local.sgm import SGMMatcher
from prismstereo.matching.registry import MatchResult, register_matcher
from prismstereo.matching.segments.planes import (
    PlaneParams,
    fill_missing_planes,
    fit_planes_splitting,
    group_refit_planes,
    merge_planes,
    render_planes,
)
from prismstereo.matching.segments.segmentation import SegmentationParams, mean_shift_segment, segment_adjacency

log = logging.getLogger(__name__)

__all__ = ["CoopMatcher", "CoopResult", "DataTermParams", "PairMaps", "PairSetup", "coop_match", "initial_disparity",
           "occlusion_background_fill", "segment_sweep_candidates"]

F32 = npt.NDArray[np.float32]
R = TypeVar("R")


@dataclass(frozen=True)
class CoopResult:
    """Every stage of the ``coop`` pipeline.

    Attributes
    ----------
    labels : (H, W) int32           mean-shift segments (§5.1).
    initial : (H, W) float32        initial subpixel WTA map (§5.2), every pixel.
    reliable : (H, W) bool          pixels passing the cross-check (Eq. 6.7).
    plane_map : (H, W) float32      disparity of the fitted and merged planes (§6.1, Table 6.1).
    disparity : (H, W) float32      final map after cooperative optimisation (§6.2, Table 6.2).
    planes : (L, 3) float64         plane set ``(a, b, c)``, ``d = a x + b y + c``.
    assign_initial, assign : (K,) int32   plane index per segment before / after §6.2.
    info : dict                     energies before/after, sweeps, counts.
    timings : dict                  seconds per stage.
    stages : dict                   map after each step (name -> (H, W) float32; only with ``keep_stages``),
                                    plus the 0/1 masks ``evidence`` and ``split`` (non-planar segments).
    """

    labels: npt.NDArray[np.int32]
    initial: F32
    reliable: npt.NDArray[np.bool_]
    plane_map: F32
    disparity: F32
    planes: npt.NDArray[np.float64]
    assign_initial: npt.NDArray[np.int32]
    assign: npt.NDArray[np.int32]
    info: dict[str, float] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    stages: dict[str, F32] = field(default_factory=dict)


def _as_rgb8(image: npt.NDArray[np.generic], name: str) -> npt.NDArray[np.uint8]:
    """``image`` as (H, W, 3) uint8 RGB; implementation helper with no thesis equation of its own."""
    return as_image(image, name=name, channels=3)  # the one coercion rule (docs/conventions.md)


def initial_disparity(cost_left: F32, cost_right: F32, *, min_disp: int = 0,
                      tolerance: float = 0.0) -> tuple[F32, npt.NDArray[np.bool_]]:
    """WTA (Eq. 5.15) with parabola subpixel refinement and the left-right cross-check (Eq. 6.7).

    Parameters
    ----------
    cost_left, cost_right : (H, W, D) float32
        Aggregated costs of the left and right views (slice k = disparity ``min_disp + k``).
    min_disp : int, keyword-only
    tolerance : float, keyword-only
        Integer WTA disparities must agree within this (0: exactly; Eq. 6.7 reads ``< 1``).

    Returns
    -------
    disparity : (H, W) float32   subpixel left disparity at every pixel.
    reliable : (H, W) bool       cross-check passed (and the match lands inside the right image).
    """
    return _checked_subpixel(cost_left, cost_right.argmin(axis=2), min_disp=min_disp, tolerance=tolerance)


def _checked_subpixel(cost_left: F32, dr: npt.NDArray[np.int64], *, min_disp: int,
                      tolerance: float, dl: npt.NDArray[np.int64] | None = None
                      ) -> tuple[F32, npt.NDArray[np.bool_]]:
    """:func:`initial_disparity` from the right view's integer WTA slice index ``dr`` (H, W) (and the left
    view's, ``cost_left.argmin(axis=2)``, when already known).

    WTA (thesis Eq. 5.15) with parabola subpixel and the left-right cross-check of thesis Eq. 6.7.
    """
    h, w, nd = cost_left.shape
    if dl is None:
        dl = cost_left.argmin(axis=2)
    xr = np.arange(w)[None, :] - (dl + min_disp)
    inside = xr >= 0
    back = np.take_along_axis(dr, np.clip(xr, 0, w - 1), axis=1)
    reliable = inside & (np.abs(back - dl) <= tolerance)
    k = np.clip(dl, 1, max(nd - 2, 1))
    if nd >= 3:
        c0 = np.take_along_axis(cost_left, (k - 1)[..., None], 2)[..., 0]
        c1 = np.take_along_axis(cost_left, k[..., None], 2)[..., 0]
        c2 = np.take_along_axis(cost_left, (k + 1)[..., None], 2)[..., 0]
        den = c0 - 2.0 * c1 + c2
        off = np.where(den > 1e-6, (c0 - c2) / (2.0 * np.maximum(den, 1e-6)), 0.0)
        interior = (dl > 0) & (dl < nd - 1)
        sub = np.where(interior, dl + np.clip(off, -0.5, 0.5), dl)
    else:
        sub = dl.astype(np.float64)
    return (sub + min_disp).astype(np.float32), reliable


def box_filter_volume(vol: F32, r: int, *, vertical: bool = True) -> F32:
    """Box-sum each disparity slice of an (H, W, D) cost volume over a (2r+1)² window (or 1 × (2r+1)).

    Implementation helper (box aggregation of a cost volume) with no thesis equation of its own.

    Parameters
    ----------
    vol : (H, W, D) float32
    r : int
        Window radius; 0 returns ``vol`` itself.
    vertical : bool, keyword-only
        False: a horizontal (2r+1)-pixel window only.

    Returns
    -------
    (H, W, D) float32, the mean over the window (OpenCV ``boxFilter``, reflected borders).
    """
    if r <= 0:
        return vol
    k = 2 * r + 1
    out = np.empty_like(vol)
    for i in range(0, vol.shape[2], 512):
        out[:, :, i:i + 512] = cv2.boxFilter(vol[:, :, i:i + 512], -1, (k, k if vertical else 1),
                                             borderType=cv2.BORDER_REFLECT)
    return out


def bpasw_volume(left: npt.NDArray[np.uint8], right: npt.NDArray[np.uint8], *, max_disp: int,
                 min_disp: int = 0) -> F32:
    """The ``bpasw`` matcher's aggregated cost volume of the left view (thesis §5.2, Eqs. 5.6-5.14).

    S_AD plus half the census distance, aggregated with symmetric Weber-Fechner adaptive support weights
    (the ``bpasw`` matcher's defaults). Symmetric weights make the right view's volume the diagonal read of
    this one (:func:`prismstereo.matching.local.selection.right_cost_volume`).
    """
    return np.asarray(BPASWMatcher().cost_volume(left, right, max_disp=max_disp, min_disp=min_disp),
                      dtype=np.float32)


def bpasw_dense_map(vol: F32, image: npt.NDArray[np.uint8], *, min_disp: int = 0,
                    right_winner: npt.NDArray[np.int64] | None = None,
                    where: npt.NDArray[np.bool_] | None = None,
                    left_winner: npt.NDArray[np.int64] | None = None) -> F32:
    """The ``bpasw`` matcher's output from its cost volume: WTA, cross-check (1 px), background fill and
    colour-weighted median (radius 9), as :class:`prismstereo.matching.local.matchers.BPASWMatcher` with defaults.
    ``right_winner``: the volume's :func:`~prismstereo.matching.local.selection.right_winner`, when already
    known; ``where`` (H, W) bool: the pixels wanted (the final median runs there only; the others are left
    before it); ``left_winner``: ``vol.argmin(axis=2)`` of a finite volume, when already known. Returns
    (H, W) float32, dense.

    From the cost volume of thesis §5.2 (Eqs. 5.6-5.14): WTA (Eq. 5.15) and the cross-check (Eq. 6.7); the fill and
    the median are post-processing beyond the thesis.
    """
    if left_winner is None:
        disp = selection.winner_take_all(vol, min_disp=min_disp)
    else:
        disp = (left_winner + min_disp).astype(np.float32)
    ridx = selection.right_winner(vol, min_disp=min_disp) if right_winner is None else right_winner
    dright = np.where(ridx >= 0, (ridx + min_disp).astype(np.float32), np.float32(np.nan)).astype(np.float32)
    valid = selection.cross_check(disp, dright, tolerance=1.0)
    raw = np.where(valid, disp, np.float32(np.nan)).astype(np.float32)
    if valid.all():
        return raw
    radius = 9
    # the final median at ``where`` reads the filled holes within its window only: smooth just those
    near = None if where is None else cv2.dilate(where.astype(np.uint8), np.ones((2 * radius + 1,) * 2, np.uint8)) > 0
    dense = selection.fill_holes(raw, valid, image=image, median_radius=radius, median_where=near)
    if np.isfinite(dense).all():
        dense = selection.weighted_median_filter(dense, image, radius=radius, mask=where)
    return np.asarray(dense, np.float32)


def _bpasw_reliable(vol: F32, dr: npt.NDArray[np.int64], min_disp: int,
                    dl: npt.NDArray[np.int64] | None = None) -> tuple[npt.NDArray[np.bool_], F32]:
    # dr: the right view's winners (selection.right_winner; the BPASW volume is finite, so they are argmin's);
    # dl: the left view's (vol.argmin(axis=2)) when already known
    """The BPASW map's left-right cross-check (thesis Eq. 6.7): (H, W) reliable mask and subpixel disparity."""
    d, rel = _checked_subpixel(vol, dr, min_disp=min_disp, tolerance=0.0, dl=dl)
    return rel, d


@njit(cache=True)
def occlusion_background_fill(disp: F32, seg: npt.NDArray[np.int32], assign: npt.NDArray[np.int32],
                    planes: npt.NDArray[np.float64], dright: F32, rright: npt.NDArray[np.bool_],
                    tol: float, dleft: F32, rleft: npt.NDArray[np.bool_],
                    radius: int) -> tuple[F32, npt.NDArray[np.bool_]]:
    """Pixels whose match in the right view reliably sees a farther surface (``d_R < d - tol``) are taken as
    occluded and get the background plane: of the nearest consistent pixels left and right on the row, the
    plane (extrapolated to the pixel) with the smaller disparity.

    Post-processing beyond the thesis with no equation of its own (occluded pixels are those the visibility test finds,
    cf. thesis Eq. 6.22's ``N_occ``).
    """
    h, w = disp.shape
    occ = np.zeros((h, w), np.bool_)
    for y in range(h):
        for x in range(w):
            d = disp[y, x]
            xr = int(np.floor(x - d + 0.5))
            if xr < 0 or xr >= w:
                continue
            if rright[y, xr] and dright[y, xr] < d - tol:
                occ[y, x] = True
    out = disp.copy()
    for y in range(h):
        for x in range(w):
            if not occ[y, x]:
                continue
            if radius > 0 and rleft[y, x] and dleft[y, x] < disp[y, x] - tol:
                # visible after all, at the BPASW disparity: the nearby plane closest to it
                bd = 1e30
                bv = 0.0
                for yy in range(max(0, y - radius), min(h, y + radius + 1)):
                    for xx in range(max(0, x - radius), min(w, x + radius + 1)):
                        pl = planes[assign[seg[yy, xx]]]
                        v = pl[0] * x + pl[1] * y + pl[2]
                        if abs(v - dleft[y, x]) < bd:
                            bd = abs(v - dleft[y, x])
                            bv = v
                if bd <= tol:
                    out[y, x] = bv
                    continue
            best = 1e30
            for step in (-1, 1):
                xx = x + step
                while 0 <= xx < w and occ[y, xx]:
                    xx += step
                if 0 <= xx < w:
                    pl = planes[assign[seg[y, xx]]]
                    v = pl[0] * x + pl[1] * y + pl[2]
                    if v < best:
                        best = v
            if best < 1e29 and best < disp[y, x]:
                out[y, x] = best
    return out, occ


def segment_sweep_candidates(lft: npt.NDArray[np.uint8], rgt: npt.NDArray[np.uint8], labels: npt.NDArray[np.int32],
                      index: Any, assign: npt.NDArray[np.int32], plane_set: npt.NDArray[np.float64], *,
                      min_disp: int, max_disp: int, params: SweepParams,
                      ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """Candidate planes from a global sweep for the segments of highest mean slanted-window cost.

    The ``params.frac`` of segments (with at least ``params.min_px`` pixels) whose current plane has the highest
    mean slanted cost (:mod:`slanted`, sampled every ``params.step`` px, its window every ``params.dilation``
    px) get planes swept over the centre disparity (integer steps over the whole range) and the slopes ``b`` in
    ``params.slopes`` (``a`` = 0 and the current ``a``); the ``params.keep`` cheapest (at least 2 px apart in
    centre disparity or differing in slope) are returned as new planes and a (K, keep) index array into the
    extended plane set (-1 = none). The other fields of ``params`` are not read here.

    The segment sweep is an addition to the thesis with no equation of its own; its planes ``d = a x + b y + c`` are
    those of thesis Eq. 6.1 and become candidates of the cooperative minimisation (Eq. 6.19).
    """
    frac, slopes, keep, min_px = params.frac, params.slopes, params.keep, params.min_px
    window = SlantedParams(step=params.step, dilation=params.dilation)
    k = assign.shape[0]
    h, w = labels.shape
    pair = slanted_pair(lft, rgt)
    cur = segment_plane_costs(lft, rgt, labels, assign.astype(np.int64)[:, None], plane_set,
                              min_disp=min_disp, max_disp=max_disp, window=window, pair=pair)[:, 0]
    sizes = np.diff(index.starts)
    ok = np.isfinite(cur) & (sizes >= min_px)
    out_ids = np.full((k, keep), -1, np.int64)
    if not ok.any():
        return plane_set, out_ids
    thr = np.quantile(cur[ok], 1.0 - frac)
    sel = np.flatnonzero(ok & (cur >= thr))
    dcs = np.arange(int(min_disp), int(max_disp) + 1, dtype=np.float64)
    g = np.stack([np.repeat(np.asarray(slopes, np.float64), dcs.size), np.tile(dcs, len(slopes))], axis=1)
    ng = g.shape[0]
    active = np.zeros(k, np.bool_)
    active[sel] = True
    # segment centres: sums of integer coordinates are exact in any order, so these equal the per-segment means
    flat = index.order
    lens = np.diff(index.starts).astype(np.float64)
    nz = np.flatnonzero(lens > 0)
    centres = np.zeros((k, 2))
    for c, v in enumerate((flat % w, flat // w)):
        centres[nz, c] = np.add.reduceat(v.astype(np.float64), index.starts[nz]) / lens[nz]
    a_cur = plane_set[assign, 0]
    # a segment whose current a is 0 would sweep the same planes twice: cost them once, copy the costs
    avals = np.stack([np.zeros(k), np.where(a_cur == 0.0, np.nan, a_cur)], axis=1)
    avals[~active] = np.nan
    cost = segment_sweep_costs(lft, rgt, labels, active, avals, centres, slopes, min_disp=min_disp,
                               max_disp=max_disp, window=window, pair=pair)
    twin = np.isnan(avals[:, 1]) & active
    cost[twin, ng:] = cost[twin, :ng]
    avals[twin, 1] = 0.0
    rows = cost[sel]
    order = np.argsort(rows, axis=1)
    chosen: list[npt.NDArray[np.float64]] = []
    nxt = plane_set.shape[0]
    for i, s in enumerate(sel):
        c = rows[i]
        picked: list[int] = []
        for j in order[i]:
            if not np.isfinite(c[j]) or len(picked) >= keep:
                break
            jj = j % ng
            if any(abs(g[jj, 1] - g[q % ng, 1]) < 2 and g[jj, 0] == g[q % ng, 0] for q in picked):
                continue
            picked.append(int(j))
        cx, cy = centres[s]
        for t, j in enumerate(picked):
            a = avals[s, j // ng]
            b, dc = g[j % ng]
            chosen.append(np.array([a, b, dc - a * cx - b * cy]))
            out_ids[s, t] = nxt
            nxt += 1
    if not chosen:
        return plane_set, out_ids
    return np.concatenate([plane_set, np.asarray(chosen)]), out_ids


@dataclass(frozen=True, kw_only=True)
class DataTermParams:
    """The front end's data-term choices.

    Attributes
    ----------
    check_tolerance : float
        Tolerance of the left-right check of the integer WTA maps of the initial map (Eq. 6.7; 0 = they must
        agree exactly).
    radius : int
        Box radius of the pixel cost summed in the segment data term (Eq. 6.21); the segment itself is the
        aggregation window there, so only a light pre-smoothing is used (0 = raw pixel cost).
    cost : CostParams or None
        Pixel-cost parameters of the data term when they should differ from the initial map's.
    slopes : tuple of float
        Vertical disparity slopes ``b`` (px per row) of the data term's pixel-cost volumes
        (:func:`prismstereo.matching.coop.coopcost.sheared_costs`, an addition to Eq. 6.21): each plane's pixels
        read the volume of the slope nearest its ``b``, whose census window and smoothing box follow the slant.
        Square windows charge a steep floor more at its true plane than at an aliased fronto-parallel one.
        Empty = one unsheared volume.
    radiometry : RadiometryParams
        The right view's colours mapped to the left's before every cost of the pair when census matches show
        a radiometric difference (:func:`prismstereo.matching.coop.radiometry.compensate_right`); a mapping of
        its fields is accepted.
    """

    check_tolerance: float = 0.0
    radius: int = 1
    cost: CostParams | None = None
    slopes: tuple[float, ...] = (-1.0, -0.5, 0.0, 0.5, 1.0)
    radiometry: RadiometryParams = field(default_factory=RadiometryParams)

    def __post_init__(self) -> None:
        """Validate and coerce the fields; implementation helper with no thesis equation of its own."""
        object.__setattr__(self, "radiometry", coerce_params(RadiometryParams, self.radiometry, "data.radiometry"))
        if self.check_tolerance < 0 or self.radius < 0:
            raise ConfigError(f"expected data.check_tolerance and data.radius >= 0, got "
                              f"{self.check_tolerance!r}, {self.radius!r}")
        object.__setattr__(self, "slopes", tuple(float(b) for b in self.slopes))


@dataclass(frozen=True, kw_only=True)
class PairMaps:
    """The front end's maps of a pair, read by the steps (:class:`_PairEvidence`).

    Attributes
    ----------
    data : (H, W, D) or (S, H, W, D) float32   the data term's pixel cost (Eqs. 6.21-6.22).
    reliable : (H, W) bool      the initial map's cross-check (Eq. 6.7).
    initial : (H, W) float32    the initial map (§5.2).
    bvol : (H, W, D) float32    the ``bpasw`` matcher's cost volume of the pair.
    bdisp : (H, W) float32      its cross-checked subpixel map; ``brel`` (H, W) bool its cross-check.
    nonplanar : (H, W) bool     pixels of the segments that failed the plane support test.
    evidence : (H, W) bool      both cross-checked initial maps agree.
    bright, bleft : (H, W) int64 or None   the right and left view's winners of ``bvol`` (computed when None).
    sheared : ShearedInputs or None        the data term's pixel inputs, reused by the row-only volume.
    fallback_right : (H, W, 3) uint8 or None   the right view with a brightness offset removed, for the
        fallback's ``bpasw`` map only (:func:`_compensate_views`); None: the fallback reads ``bvol``.
    row_boxes : (S, H, W, D) float32 or None   the data term's pixel costs boxed along the row only, radius
        ``row_box_radius`` (:func:`~prismstereo.matching.coop.coopcost.sheared_row_boxes`, the sheared volumes'
        first pass), taken over by the sweep's row-only volume of that radius; None: it computes its own.
    """

    data: F32
    reliable: npt.NDArray[np.bool_]
    initial: F32
    bvol: F32
    bdisp: F32
    brel: npt.NDArray[np.bool_]
    nonplanar: npt.NDArray[np.bool_]
    evidence: npt.NDArray[np.bool_]
    bright: npt.NDArray[np.int64] | None = None
    bleft: npt.NDArray[np.int64] | None = None
    sheared: ShearedInputs | None = None
    fallback_right: npt.NDArray[np.uint8] | None = None
    row_boxes: F32 | None = None
    row_box_radius: int = -1


@dataclass(frozen=True, kw_only=True)
class PairSetup:
    """The parameters the steps read from the pair's evidence (:class:`_PairEvidence`): the optimiser's, the
    segmentation's (the fine step derives its own from it), the plane fit's, the pixel cost's and the data
    term's slopes (None = one unsheared volume)."""

    coop: CoopParams
    segmentation: SegmentationParams
    planes: PlaneParams
    cost: CostParams
    slopes: tuple[float, ...] | None


class _PairEvidence:
    """The two-view evidence of the steps (:class:`~prismstereo.matching.coop.steps.Evidence`): the pair's
    data term, the ``bpasw`` matcher's volume of the pair and its cross-checked map, the initial map."""

    def __init__(self, lft: npt.NDArray[np.uint8], rgt: npt.NDArray[np.uint8], *, min_disp: int, max_disp: int,
                 maps: PairMaps, params: PairSetup,
                 segments: dict[SegmentationParams, Future[npt.NDArray[np.int32]]] | None = None):
        """Implementation helper (the pair's evidence for the steps) with no thesis equation of its own."""
        self.image, self.right = lft, rgt
        self._sheared = maps.sheared  # the data term's census transforms etc., reused by the row-only volume
        self._segments = dict(segments or {})  # segmentations of the image computed ahead (the fine step's)
        bvol = maps.bvol
        # the right view's winners of the BPASW volume (read by the occlusion and fallback steps)
        self.bright = selection.right_winner(bvol, min_disp=min_disp) if maps.bright is None else maps.bright
        self.bleft = bvol.argmin(axis=2) if maps.bleft is None else maps.bleft  # the left view's (it is finite)
        self.min_disp, self.max_disp = int(min_disp), int(max_disp)
        self.data, self.reliable, self.initial = maps.data, maps.reliable, maps.initial
        self.check_data = maps.data
        self.bvol, self.bdisp, self.brel, self.nonplanar = bvol, maps.bdisp, maps.brel, maps.nonplanar
        self.coop, self.segmentation, self.plane_params = params.coop, params.segmentation, params.planes
        self.cost, self.slopes = params.cost, params.slopes
        self.evidence = maps.evidence
        self._fallback_right = maps.fallback_right
        self._row_boxes, self._row_box_radius = maps.row_boxes, maps.row_box_radius
        self.fallback_pixels = 0
        self.memo = CoopMemo()
        self._sgm: tuple[F32, npt.NDArray[np.bool_]] | None = None  # the fallback's ``sgm`` run, made once
        self._bpasw_dense: F32 | None = None  # the fallback's ``bpasw`` map at every pixel, when it was needed

    def optimise(self, s: PlaneLabels, assign: npt.NDArray[np.int32], planes: npt.NDArray[np.float64],
                 own: npt.NDArray[np.int64], *, neighbour_own_planes: bool = False
                 ) -> tuple[npt.NDArray[np.int32], npt.NDArray[np.float64], dict[str, float]]:
        # the cooperative optimisation (Eqs. 6.18-6.25) on the segments and the data term
        """The cooperative optimisation of thesis §6.2 (Eqs. 6.18-6.25) on the pair's data term."""
        prm = dataclasses.replace(self.coop, neighbour_own_planes=True) if neighbour_own_planes else self.coop
        return cooperative_optimize(assign, planes, s.index, s.graph, self.data, self.reliable, own=own,
                                    min_disp=self.min_disp, params=prm, slopes=self.slopes, memo=self.memo)

    def refit(self, s: PlaneLabels, assign: npt.NDArray[np.int32], planes: npt.NDArray[np.float64]
              ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]] | None:
        """One plane refitted per group of segments sharing a plane (thesis Eqs. 6.1-6.10 after the merging of §6.1.3).
        """
        return group_refit_planes(assign, planes, s.index, self.initial, self.reliable, params=self.plane_params)

    def bpasw_map(self) -> tuple[F32, npt.NDArray[np.bool_]]:
        """The BPASW map of thesis §5.2 and its cross-check mask (Eq. 6.7), each (H, W)."""
        return self.bdisp, self.brel

    def sweep(self, s: PlaneLabels, p: SweepParams) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
        """The segment sweep's candidate planes: an addition to the thesis with no equation of its own."""
        return segment_sweep_candidates(self.image, self.right, s.labels, s.index, s.assign, s.planes,
                                        min_disp=self.min_disp, max_disp=self.max_disp, params=p)

    def row_box(self, selected: npt.NDArray[np.bool_], p: SweepParams) -> None:
        """A row-only aggregated data term for the ``selected`` (H, W) pixels: an addition to thesis Eq. 6.21, no
        equation of its own."""
        kw = {"max_disp": self.max_disp, "min_disp": self.min_disp, "params": self.cost}
        # the row-boxed volume with the other pixels' data term becomes the optimiser's; moves are still checked
        # against the data term itself (``check_data``)
        if self.slopes is None:
            hb = box_filter_volume(raw_cost(self.image, self.right, **kw), p.row_box, vertical=False)  # type: ignore[arg-type]
            hb[~selected] = self.data[~selected]
        else:
            kept = self._row_boxes if p.row_box == self._row_box_radius else None
            self._row_boxes = None
            if kept is not None:
                hb = kept
                # the front end's row boxes (the same pixel costs, the same radius): the other pixels take the
                # data term, in place
                keep_outside(hb, self.data, selected)
            else:
                # the other pixels keep the data term: copied by the same kernel, not first copied whole and
                # overwritten
                hb = np.empty_like(self.data)
                sheared_row_costs_at(self.image, self.right, selected, hb, **kw,  # type: ignore[arg-type]
                                     slopes=self.slopes, radius=p.row_box, inputs=self._sheared, fill=self.data)
        self.check_data, self.data = self.data, hb

    def segments(self, params: SegmentationParams) -> npt.NDArray[np.int32]:
        """Mean-shift segmentation of the image (thesis §5.1, Eqs. 5.1-5.4)."""
        ahead = self._segments.pop(params, None)
        return mean_shift_segment(self.image, params=params) if ahead is None else ahead.result()

    def fine_evidence(self, tol: float) -> tuple[npt.NDArray[np.bool_], F32]:
        """Implementation helper (the steps' evidence: both initial maps agree) with no thesis equation of its own."""
        return _pair_agreement(self.reliable, self.initial, self.brel, self.bdisp, tol), self.initial

    def boundary_evidence(self, tol: float) -> tuple[F32, F32, npt.NDArray[np.bool_], npt.NDArray[np.bool_]]:
        """Implementation helper (the steps' evidence for the boundary step) with no thesis equation of its own."""
        return self.bvol, self.bdisp, self.brel, _pair_agreement(self.reliable, self.initial, self.brel,
                                                                 self.bdisp, tol)

    def occlusion(self, s: PlaneLabels, final: F32, p: OcclusionParams) -> F32:
        """The occlusion step's background fill (:func:`occlusion_background_fill`): post-processing beyond the thesis,
        no equation of its own."""
        md = self.min_disp
        dr_int = self.bright
        dl_int = self.bleft
        w = final.shape[1]
        xs = np.arange(w)[None, :] + dr_int + md
        rrel = (xs < w) & (np.take_along_axis(dl_int, np.clip(xs, 0, w - 1), axis=1) == dr_int)
        out, _occ = occlusion_background_fill(final.astype(np.float32), s.labels.astype(np.int32),
                                              s.assign.astype(np.int32), s.planes,
                                              (dr_int + md).astype(np.float32), rrel, float(p.tol), self.bdisp,
                                              self.brel, int(p.rematch_radius))
        return np.asarray(out, np.float32)

    def sparse_segments(self, s: PlaneLabels, final: F32, p: FallbackParams) -> npt.NDArray[np.bool_]:
        """(H, W) bool: the pixels of the segments whose evidence is thin, bare or against their map (the
        fallback's test, :meth:`fallback`). Post-processing beyond the thesis, no equation of its own."""
        lab = s.labels.ravel()
        sizes = np.bincount(lab, minlength=s.assign.size)
        covered = np.bincount(lab, weights=self.evidence.ravel(), minlength=s.assign.size)
        agree = self.evidence & (np.abs(final - self.initial) <= p.tol)
        agreeing = np.bincount(lab, weights=agree.ravel(), minlength=s.assign.size)
        thin = (sizes >= p.min_share * lab.size) & (covered < p.min_coverage * sizes)
        if p.coverage_reach > 0 and thin.any():
            # evidence scattered over a segment (the noisy capture of a dark, weakly textured wall) holds its plane
            # between the evidence pixels, not beyond them: a thin segment is extrapolated only where its pixels lie
            # farther than the reach from every evidence pixel its map agrees with
            k = 2 * p.coverage_reach + 1
            near = cv2.dilate(agree.astype(np.uint8), np.ones((k, k), np.uint8)) > 0
            reached = np.bincount(lab, weights=near.ravel(), minlength=s.assign.size)
            thin &= reached < p.min_coverage * sizes
        bare = (sizes >= p.bare_share * lab.size) & (covered < p.bare_coverage * sizes)
        against = ((sizes >= p.against_pixels) & (covered >= p.against_coverage * sizes)
                   & (agreeing < p.max_agreement * covered))
        return np.asarray((thin | bare | against)[s.labels], dtype=bool)

    def fallback(self, s: PlaneLabels, final: F32, p: FallbackParams) -> F32:
        # the segments that failed the plane support test are not planar; a segment the evidence covers only in
        # part has its plane extrapolated over the rest, one it barely covers has its plane from the neighbours
        # alone, and one whose map contradicts nearly all of its evidence was moved against it: the local map there
        """The fallback step (:func:`segment_support_choice`): post-processing beyond the thesis, no equation of its
        own."""
        sparse = self.sparse_segments(s, final, p)
        local = self.nonplanar | sparse
        if p.outvoted_tol > 0 and {"bpasw", "sgm"} <= set(p.candidates):
            # a plane both local matchers contradict, where they agree and both checks hold, is not supported
            sgm_map, sgm_valid = self._sgm_map()
            local |= outvoted_segments(s.labels, final, self._fallback_bpasw_map(None), self._bpasw_checked(),
                                       sgm_map, sgm_valid, tol=p.outvoted_tol, min_share=p.outvoted_share,
                                       min_size=p.outvoted_min_size)
        self.fallback_pixels = int(local.sum())
        if not local.any():
            return final
        maps: list[F32] = []
        support: list[npt.NDArray[np.bool_]] = []
        for name in p.candidates:
            if name == "plane":
                maps.append(final)
                support.append(self.evidence & (np.abs(final - self.initial) <= p.tol))
            elif name == "bpasw":
                maps.append(self._fallback_bpasw_map(local))
                support.append(self._bpasw_checked())
            else:
                sgm_map, sgm_valid = self._sgm_map()
                maps.append(sgm_map)
                support.append(sgm_valid)
        if len(maps) == 1:
            return np.where(local, maps[0], final)
        pick = segment_support_choice(s.labels, local, support, margin=p.margin)
        if p.flat_ratio > 0 and {"bpasw", "sgm"} <= set(p.candidates):
            # where BPASW's cost has no distinct minimum its map is a guess: sgm's, where its check holds
            ib, isg = p.candidates.index("bpasw"), p.candidates.index("sgm")
            flat = flat_cost_segments(s.labels, local, peak_ratio(self.bvol, self.bleft, local), support[isg],
                                      support[ib], max_ratio=p.flat_ratio, min_support=p.flat_min_support,
                                      support_margin=p.flat_support_margin)
            pick = np.where(flat, isg, pick)
        if p.contradicted_share > 0 and {"bpasw", "sgm"} <= set(p.candidates):
            # both checks holding on two different disparities: BPASW's colour cost is the one a radiometric
            # difference between the views moves (flatcost.py)
            ib, isg = p.candidates.index("bpasw"), p.candidates.index("sgm")
            both = contradicted_segments(s.labels, local, maps[ib], support[ib], maps[isg], support[isg],
                                         min_share=p.contradicted_share, min_size=p.contradicted_min_size)
            pick = np.where(both, isg, pick)
        out = final.copy()
        for i, m in enumerate(maps):
            sel = local & (pick == i)
            out[sel] = m[sel]
        return out

    def _fallback_bpasw_map(self, local: npt.NDArray[np.bool_] | None) -> F32:
        """The ``bpasw`` matcher's dense map (H, W) float32 at the ``local`` pixels (None: at every pixel, kept for
        the step's later reads), of the offset-compensated pair when there is one (:class:`PairMaps`
        ``fallback_right``): post-processing beyond the thesis, no equation of its own."""
        if self._bpasw_dense is not None:
            return self._bpasw_dense
        if self._fallback_right is None:
            out = bpasw_dense_map(self.bvol, self.image, min_disp=self.min_disp, right_winner=self.bright,
                                  where=local, left_winner=self.bleft)
        else:
            # a brightness offset between the views moves a colour cost's minimum on weak texture (radiometry.py)
            vol = bpasw_volume(self.image, self._fallback_right, max_disp=self.max_disp, min_disp=self.min_disp)
            out = bpasw_dense_map(vol, self.image, min_disp=self.min_disp, where=local)
        if local is None:
            self._bpasw_dense = out
        return out

    def _bpasw_checked(self) -> npt.NDArray[np.bool_]:
        # the BPASW matcher's own left-right check (1 px), the pixels its dense map keeps before filling
        """The BPASW matcher's left-right cross-check (thesis Eq. 6.7, 1 px) as an (H, W) mask."""
        md = self.min_disp
        dright = (self.bright + md).astype(np.float32)
        return np.asarray(selection.cross_check((self.bleft + md).astype(np.float32), dright, tolerance=1.0), bool)

    def _sgm_map(self) -> tuple[F32, npt.NDArray[np.bool_]]:
        # the ``sgm`` matcher (census cost, 8 paths) with its defaults: its dense map and its checked pixels
        """The ``sgm`` matcher's map and checked pixels: a fallback beyond the thesis with no equation of its own."""
        if self._sgm is None:
            res = SGMMatcher().compute(self.image, self.right, max_disp=self.max_disp, min_disp=self.min_disp)
            self._sgm = (np.asarray(res.disparity, np.float32), np.asarray(res.valid, bool))
        return self._sgm


def segment_support_choice(labels: npt.NDArray[np.int32], where: npt.NDArray[np.bool_],
                           support: list[npt.NDArray[np.bool_]], *, margin: float) -> npt.NDArray[np.int64]:
    """Per pixel, the index of the candidate map its segment takes in the fallback step.

    Post-processing beyond the thesis with no equation of its own.

    Parameters
    ----------
    labels : (H, W) int32  segments.
    where : (H, W) bool  the pixels being replaced.
    support : list of (H, W) bool  per candidate, the pixels where its own matcher's evidence holds (its
        left-right check passed).
    margin : float, keyword-only
        A segment keeps the first candidate unless another's supported share of the segment's ``where`` pixels
        exceeds the first's by more than ``margin``; then the best-supported one.

    Returns
    -------
    (H, W) int64 candidate index.
    """
    lab = labels[where]
    n = int(labels.max()) + 1
    cnt = np.maximum(np.bincount(lab, minlength=n), 1).astype(np.float64)
    share = np.stack([np.bincount(lab, weights=m[where].astype(np.float64), minlength=n) / cnt for m in support])
    best = share.argmax(axis=0)
    take = share[best, np.arange(n)] > share[0] + margin
    return np.asarray(np.where(take, best, 0)[labels], np.int64)


def _compensate_views(lft: npt.NDArray[np.uint8], rgt: npt.NDArray[np.uint8], *, max_disp: int,
                      radiometry: RadiometryParams, fallback: FallbackParams
                      ) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.uint8] | None, dict[str, float]]:
    """The right view every colour cost reads, the right view of the fallback's ``bpasw`` map, and the
    compensation's info (:func:`~prismstereo.matching.coop.radiometry.compensate_right`).

    An addition to thesis §5.2 with no equation of its own. A systematic brightness offset of at least
    ``fallback.radiometry_offset`` grey levels that the compensation's own rules leave in place is removed for
    the fallback's map only (None otherwise): removing it for the whole pipeline changes the maps of scenes
    whose offset did no harm (docs/EXPERIMENTS.md, issue 27, h-mb27).
    """
    offset = fallback.radiometry_offset
    want = fallback.enabled and offset > 0 and "bpasw" in fallback.candidates and radiometry.min_offset == 0
    params = dataclasses.replace(radiometry, min_offset=offset) if want else radiometry
    out, info = compensate_right(lft, rgt, max_disp=max_disp, params=params)
    if want and info.get("radiometry_offset_only", 0.0) == 1.0:
        # the pipeline reads the views as given: the census-only test is on their own colour difference
        census_only = float(info["radiometry_ad_before"] > radiometry.max_residual)
        info = {**info, "radiometry_applied": 0.0, "radiometry_census_only": census_only,
                "radiometry_fallback_offset": 1.0}
        log.info("coop: a brightness offset of %.1f levels between the views, removed for the fallback's map",
                 info["radiometry_offset_before"])
        return rgt, out, info
    return out, None, {**info, "radiometry_fallback_offset": 0.0}

def _shared_terms(left: npt.NDArray[np.uint8], right: npt.NDArray[np.uint8], *, max_disp: int, min_disp: int,
                  data: DataTermParams, cost: CostParams) -> list[Any]:
    """The data term's inputs and colour term, ``[ShearedInputs, (H, W, D) float64]``, when the initial map's pixel
    cost is the data term's (the same parameters, slope 0 among the slopes): evaluated once for both
    (:func:`~prismstereo.matching.coop.coopcost.raw_cost_from`); ``[]`` otherwise. The caller empties the list
    when the data volume is made, so the float64 term is not held beyond it.

    Implementation helper (shared evaluation of the pixel cost of thesis Eq. 5.6's variant) with no equation.
    """
    if not data.slopes or 0.0 not in data.slopes or (data.cost is not None and data.cost != cost):
        return []
    si = sheared_inputs(left, right, params=cost, slopes=data.slopes)
    return [si, colour_term(si, max_disp=max_disp, min_disp=min_disp)]


def _with_shared(fut: Future[list[Any]], fn: Callable[..., R], *args: Any, **kwargs: Any) -> R:
    """``fn(*args, **kwargs, shared=fut.result())``: a worker task that reads :func:`_shared_terms`' result.

    Implementation helper (task chaining) with no thesis equation of its own.
    """
    return fn(*args, **kwargs, shared=fut.result())


def _guided_initial(left: npt.NDArray[np.uint8], right: npt.NDArray[np.uint8], *, max_disp: int, min_disp: int,
                    params: CostParams, tolerance: float, shared: list[Any] | None = None
                    ) -> tuple[F32, npt.NDArray[np.bool_]]:
    """The cross-checked initial map of the guided-filter volumes (thesis §6.1): (H, W) float32 and bool.
    ``shared``: :func:`_shared_terms` of the pair (its pixel cost then comes from them, the same bits)."""
    if shared:
        raw = raw_cost_from(shared[0], shared[1], min_disp=min_disp)
    else:
        raw = raw_cost(left, right, max_disp=max_disp, min_disp=min_disp, params=params)
    agg_l, agg_r = aggregated_costs(left, right, max_disp=max_disp, min_disp=min_disp, params=params, raw=raw)
    return initial_disparity(agg_l, agg_r, min_disp=min_disp, tolerance=tolerance)


def _data_volume(left: npt.NDArray[np.uint8], right: npt.NDArray[np.uint8], *, max_disp: int, min_disp: int,
                 data: DataTermParams, cost: CostParams, shared: list[Any] | None = None,
                 row_boxes: bool = False) -> tuple[F32, ShearedInputs | None, F32 | None]:
    """The data term's pixel-cost volume (Eqs. 6.21-6.22): sheared per slope, or one box-filtered volume; the
    sheared volumes' inputs (None without slopes); with ``row_boxes`` (and slopes, ``data.radius`` > 0) their
    first pass, the pixel costs boxed along the row, (S, H, W, D) float32 (else None). ``shared``:
    :func:`_shared_terms` of the pair, emptied here."""
    if data.slopes:
        ad = None
        if shared:
            si, ad = shared
            shared.clear()
        else:
            si = sheared_inputs(left, right, params=data.cost or cost, slopes=data.slopes)
        if row_boxes and data.radius > 0:
            if ad is None:
                ad = colour_term(si, max_disp=max_disp, min_disp=min_disp)
            boxes = sheared_row_boxes(si, ad, min_disp=min_disp, radius=data.radius)
            del ad  # the float64 colour term is not held while the sheared volumes are made
            return shear_row_boxes(boxes, data.slopes, radius=data.radius), si, boxes
        return sheared_costs(left, right, max_disp=max_disp, min_disp=min_disp, params=data.cost or cost,
                             slopes=data.slopes, radius=data.radius, inputs=si, ad=ad), si, None
    raw = raw_cost(left, right, max_disp=max_disp, min_disp=min_disp, params=data.cost or cost)
    return box_filter_volume(raw, data.radius), None, None


def _pair_agreement(reliable: npt.NDArray[np.bool_], initial: F32, brel: npt.NDArray[np.bool_], bdisp: F32,
                    tol: float) -> npt.NDArray[np.bool_]:
    """Both cross-checked initial maps (differently aggregated) agree within ``tol``: the steps' evidence.

    Implementation helper (evidence mask, (H, W) bool) with no thesis equation of its own.
    """
    return reliable & brel & (np.abs(bdisp - initial) <= tol)


def coop_match(left: npt.NDArray[np.generic], right: npt.NDArray[np.generic], *, max_disp: int,
               min_disp: int = 0, segmentation: SegmentationParams | None = None,
               cost: CostParams | None = None, planes: PlaneParams | None = None,
               coop: CoopParams | None = None, data: DataTermParams | None = None,
               steps: StepParams | None = None, keep_stages: bool = False) -> CoopResult:
    """Run the whole segment-based cooperative pipeline (thesis §5.1, §5.2, §6.1, §6.2).

    The front end (initial maps, segmentation, planes with the support test) builds the plane labels; the
    steps of :mod:`prismstereo.matching.coop.steps` (shared with the global multi-view method) run on them.

    Parameters
    ----------
    left, right : (H, W, 3) uint8 RGB or (H, W) grey
        Rectified pair; disparity ``d = x_left - x_right`` in ``[min_disp, max_disp]``.
    max_disp, min_disp : int, keyword-only
    segmentation, cost, planes, coop : parameter dataclasses, keyword-only
        ``hs, hr, M``; cost/aggregation; ``γ_segment, t_outlier, ε, δ`` and the support test; ``κ, μ, ω_occ, γ``.
    data : DataTermParams, keyword-only
        Cross-check tolerance of the initial map and the data term's pixel-cost volumes.
    steps : StepParams, keyword-only
        One parameter set per step after the plane fit.
    keep_stages : bool, keyword-only
        Keep the map after each step in ``CoopResult.stages``.

    Returns
    -------
    CoopResult with every intermediate map.
    """
    lft = _as_rgb8(left, "left")
    rgt = _as_rgb8(right, "right")
    if lft.shape != rgt.shape:
        raise ImageError(f"expected left and right of the same shape, got {lft.shape} and {rgt.shape}")
    if int(max_disp) < int(min_disp):
        raise ImageError(f"expected max_disp >= min_disp, got {max_disp} < {min_disp}")
    sp = segmentation or SegmentationParams()
    cp = cost or CostParams()
    pp = planes or PlaneParams()
    op = coop or CoopParams()
    dp = data or DataTermParams()
    st = steps or StepParams()
    tm: dict[str, float] = {}
    tol = st.boundary.tol
    t = time.perf_counter()
    # every colour cost of the pair below reads the right view in the left view's radiometry
    rgt, fallback_right, radio = _compensate_views(lft, rgt, max_disp=int(max_disp), radiometry=dp.radiometry,
                                                   fallback=st.fallback)
    if radio["radiometry_census_only"]:
        # colours that no intensity mapping reconciles: the pixel costs keep their census term only
        cp = dataclasses.replace(cp, tau_color=0.0, tau_grad=0.0)
        if dp.cost is not None:
            dp = dataclasses.replace(dp, cost=dataclasses.replace(dp.cost, tau_color=0.0, tau_grad=0.0))
        log.warning("coop: the views' colours disagree beyond an intensity mapping (matched median AD %.1f); "
                    "matching on census alone", radio["radiometry_ad_after"])
    tm["radiometry"] = time.perf_counter() - t

    t = time.perf_counter()
    # Independent front-end stages run on two threads (their kernels release the GIL): the guided-filter
    # initial map and then the data term's sheared volumes on one, the segmentation (unless it needs the initial
    # map) and the BPASW volume on the other. Serial pieces (OpenCV box filters and mean shift, Python glue)
    # then overlap with parallel kernels instead of leaving a core idle; every result is the same.
    pool = ThreadPoolExecutor(max_workers=1)
    # the initial map's pixel cost and the data term's share their colour term (one worker, in this order)
    fut_shared = pool.submit(_shared_terms, lft, rgt, max_disp=max_disp, min_disp=min_disp, data=dp, cost=cp)
    fut_init = pool.submit(_with_shared, fut_shared, _guided_initial, lft, rgt, max_disp=max_disp,
                           min_disp=min_disp, params=cp, tolerance=dp.check_tolerance)
    # the sweep's row-only volume of the data term's radius is the sheared volumes' first pass: kept for it
    boxes = st.sweep.frac > 0 and st.sweep.row_box == dp.radius
    fut_data = pool.submit(_with_shared, fut_shared, _data_volume, lft, rgt, max_disp=max_disp, min_disp=min_disp,
                           data=dp, cost=cp, row_boxes=boxes)
    # the fine step's segmentations read the image only
    fine_seg = [dataclasses.replace(sp, hr=float(hr), min_region=int(m)) for hr, m in st.fine.levels]
    ahead = {f: pool.submit(mean_shift_segment, lft, params=f) for f in fine_seg}
    pool.shutdown(wait=False)  # the two tasks still run; their results are awaited below
    labels = None if sp.depth_tau > 0 else mean_shift_segment(lft, params=sp)
    bvol = bpasw_volume(lft, rgt, max_disp=max_disp, min_disp=min_disp)
    # cross-checked BPASW map (integer WTA must agree exactly), parabola subpixel
    bright = selection.right_winner(bvol, min_disp=min_disp)
    bleft = bvol.argmin(axis=2)  # computed once: the reliability test, the occlusion and fallback steps read it
    brel0, bdisp0 = _bpasw_reliable(bvol, bright, min_disp, bleft)
    initial, reliable = fut_init.result()
    tm["initial"] = time.perf_counter() - t

    t = time.perf_counter()
    if labels is None:
        labels = mean_shift_segment(lft, params=sp, disparity=initial)
    tm["segmentation"] = time.perf_counter() - t

    t = time.perf_counter()
    # the evidence of the safety tests: both cross-checked initial maps (differently aggregated) agree
    evidence = _pair_agreement(reliable, initial, brel0, bdisp0, tol)
    labels, index, fitted, ancestor = fit_planes_splitting(labels, lft, initial, reliable, evidence, params=pp,
                                                           min_region=sp.min_region)
    pairs, _length, contrast = segment_adjacency(labels, lft)
    cluster, cplanes = merge_planes(index, fitted, pairs, initial, reliable, params=pp)
    k = fitted.shape[0]
    fin = np.flatnonzero(np.isfinite(fitted[:, 0]))
    plane_set = np.concatenate([fitted[fin], cplanes]) if fin.size else np.array([[0.0, 0.0, float(min_disp)]])
    own = np.full((k, 2), -1, np.int64)
    own[fin, 0] = np.arange(fin.size)
    own[cluster >= 0, 1] = cluster[cluster >= 0] + fin.size
    split = np.flatnonzero(np.isfinite(ancestor[:, 0]))
    nonplanar = np.isfinite(ancestor[:, 0])[labels]  # pixels of segments that failed the plane support test
    if split.size:
        # pieces of a split segment are offered their unsplit plane: the data term decides between them
        uniq, inv = np.unique(ancestor[split], axis=0, return_inverse=True)
        own[split, 1] = plane_set.shape[0] + inv.ravel()
        plane_set = np.concatenate([plane_set, uniq])
    assign0 = fill_missing_planes(np.where(cluster >= 0, cluster + fin.size, -1).astype(np.int32), pairs,
                                  contrast)
    if (assign0 < 0).any():  # isolated segment without any plane in its component
        assign0 = assign0.copy()
        assign0[assign0 < 0] = 0
    plane_map = render_planes(index, plane_set, assign0)
    tm["planes"] = time.perf_counter() - t

    t = time.perf_counter()
    graph = build_segment_graph(labels, lft)
    dcost, sheared, row_boxes = fut_data.result()
    maps = PairMaps(data=dcost, reliable=reliable, initial=initial, bvol=bvol, bdisp=bdisp0, brel=brel0,
                    nonplanar=nonplanar, evidence=evidence, bright=bright, bleft=bleft, sheared=sheared,
                    fallback_right=fallback_right, row_boxes=row_boxes,
                    row_box_radius=dp.radius if row_boxes is not None else -1)
    ev = _PairEvidence(lft, rgt, min_disp=min_disp, max_disp=max_disp, maps=maps,
                       params=PairSetup(coop=op, segmentation=sp, planes=pp, cost=dp.cost or cp,
                                         slopes=dp.slopes or None), segments=ahead)
    state = PlaneLabels(labels=labels, index=index, graph=graph, assign=assign0, planes=plane_set, own=own,
                        parent=np.arange(k, dtype=np.int64), pairs=pairs,
                        info={"split_pieces": float(split.size)})
    stages: dict[str, F32] = {}
    if keep_stages:
        stages["initial"] = initial.copy()
        stages["bpasw"] = bdisp0.copy()
        stages["evidence"] = evidence.astype(np.float32)
        stages["plane_map"] = plane_map.copy()
        stages["split"] = nonplanar.astype(np.float32)
    marks = {"fine": "cooperative"}

    def snapshot(name: str, s: PlaneLabels) -> None:
        """Implementation helper (stage snapshots and timings) with no thesis equation of its own."""
        nonlocal t
        if keep_stages:
            stages[name] = (s.render() if s.disparity is None else s.disparity).copy()
        if name in marks:
            tm[marks[name]] = time.perf_counter() - t
            t = time.perf_counter()

    state = run_steps(state, ev, st, snapshot=snapshot)
    tm["boundary"] = time.perf_counter() - t
    assert state.disparity is not None
    info = {**state.info, **radio, "segments": float(state.assign.shape[0]), "planes_fitted": float(fin.size),
            "planes": float(len(state.planes)), "reliable_fraction": float(reliable.mean())}
    if st.fallback.enabled:
        info["split_evidence_pixels"] = float(nonplanar.sum())
        info["fallback_pixels"] = float(ev.fallback_pixels)
    log.info("coop: %d segments, %d planes, E %.0f -> %.0f", state.assign.shape[0], len(state.planes),
             info["energy_before"], info["energy_after"])
    return CoopResult(labels=state.labels, initial=initial, reliable=reliable, plane_map=plane_map,
                      disparity=state.disparity, planes=state.planes, assign_initial=assign0[state.parent],
                      assign=state.assign, info=info, timings=tm, stages=stages)


@register_matcher("coop")
class CoopMatcher:
    """Segment-based stereo with cooperative optimisation (thesis ch. 5-6) as a registry matcher.

    Parameters (keyword-only)
    -------------------------
    segmentation, cost, planes, coop, data, steps : parameter dataclasses, or mappings of their fields (the
        CLI's ``-p steps='{"sweep": {"frac": 0.3}}'``); validated here, before any image is read (defaults: the
        values used for all scenes).

    ``compute`` returns a :class:`MatchResult` whose ``extras`` hold the stage maps: ``labels``,
    ``initial``, ``reliable``, ``plane_map``, ``planes``, ``assign`` and ``info``.
    """

    def __init__(self, *, segmentation: SegmentationParams | dict[str, Any] | None = None,
                 cost: CostParams | dict[str, Any] | None = None, planes: PlaneParams | dict[str, Any] | None = None,
                 coop: CoopParams | dict[str, Any] | None = None, data: DataTermParams | dict[str, Any] | None = None,
                 steps: StepParams | dict[str, Any] | None = None):
        """Implementation helper (matcher configuration) with no thesis equation of its own."""
        self.segmentation = coerce_params(SegmentationParams, segmentation, "segmentation")
        self.cost = coerce_params(CostParams, cost, "cost")
        self.planes = coerce_params(PlaneParams, planes, "planes")
        self.coop = coerce_params(CoopParams, coop, "coop")
        self.data = coerce_params(DataTermParams, data, "data")
        self.steps = coerce_params(StepParams, steps, "steps")

    def compute(self, left: np.ndarray, right: np.ndarray, *, max_disp: int, min_disp: int = 0) -> MatchResult:
        """The ``coop`` matcher (thesis chapters 5-6, module docstring) as a :class:`MatchResult`."""
        res = coop_match(left, right, max_disp=max_disp, min_disp=min_disp, segmentation=self.segmentation,
                         cost=self.cost, planes=self.planes, coop=self.coop, data=self.data, steps=self.steps)
        raw = np.where(res.reliable, res.initial, np.nan).astype(np.float32)
        extras: dict[str, Any] = {"labels": res.labels, "initial": res.initial, "reliable": res.reliable,
                                  "plane_map": res.plane_map, "planes": res.planes, "assign": res.assign,
                                  "assign_initial": res.assign_initial, "info": res.info, "initial_raw": raw}
        return MatchResult(disparity=res.disparity, valid=np.isfinite(res.disparity), disparity_raw=None,
                           timings=dict(res.timings), extras=extras)
