"""``coop``: segment-based stereo with cooperative optimisation (thesis chapters 5-6), the flagship matcher.

Stages (each callable on its own, and all kept in :class:`CoopResult`):

1. mean-shift segmentation of the left image (§5.1)          -> ``labels``
2. initial disparity map: adaptive-weight aggregated cost, WTA, parabola subpixel, left-right
   cross-check (§5.2, Eq. 6.7)                                -> ``initial``, ``reliable``
3. robust plane per segment (Eqs. 6.1-6.10) and merging of similar neighbours (Eqs. 6.14-6.17); segments
   without a plane take their most similar neighbour's; a large segment whose plane the evidence (both
   cross-checked initial maps agree) does not support is split in quarters and refitted (issue 14: mean
   shift's huge segments on curved or repetitive surfaces)  -> ``plane_map`` (thesis Table 6.1)
4. cooperative optimisation of the plane labels (Eqs. 6.18-6.25), then one round in which segments that
   share a plane are refitted together and the optimisation resumes, then one in which planes fitted to
   issue 3's cross-checked BPASW map (and their merged clusters) are offered and it resumes again; then
   the half of the segments with the highest slanted-window cost get planes from a global sweep (whole
   disparity range x a few vertical slopes) as candidates, with a row-only boxed pixel cost on their pixels,
   and those candidates and the planes across segment boundaries may move whole regions at once (group moves);
   last, finer segments (a second mean shift with a smaller range radius, inside the segments) along plane
   boundaries may take a neighbour's plane where the cross-checked initial maps support it
5. boundary step (an addition to the thesis): pixels near segment boundaries may take a nearby segment's
   plane (current, or fitted to either initial map) where issue 3's BPASW aggregated cost (symmetric
   adaptive weights, §5.2) clearly prefers it and both cross-checked initial maps agree with it (fixes
   fattened boundaries); pixels whose right-view match reliably sees a farther surface take the background
   plane (occlusion); then a colour-weighted median that only overrides disparities it moves by more than
   1 px; segments that failed the plane support test of stage 3 (not one plane) take the ``bpasw``
   matcher's map                                              -> ``disparity`` (thesis Table 6.2)

Default parameters (the same for every scene): hs = 5, hr = 4, M = 20; guided filter r = 9, ε = 1e-4;
γ_segment = 0.9, t_outlier = 1, ε(6.10) = 0.99, δ = 0.8; κ = 0.5, μ = 1, ω_occ = 1, γ = 0.5;
BPASW as issue 3's ``bpasw`` matcher; boundary step radius 5 px, margin 5 (BPASW cost units), tolerance
1 px; weighted median radius 4; finer segments hr = 3, M = 10; data-term volumes for vertical slopes
b = -1, -0.5, 0, 0.5, 1 (census window and 3x3 box sheared along the plane, each plane reading its nearest).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt
from numba import njit

from prismstereo.errors import ImageError
from prismstereo.matching.coop.coopcost import CostParams, aggregated_costs, raw_cost, sheared_costs
from prismstereo.matching.coop.cooperative import (
    CoopParams,
    build_segment_graph,
    cooperative_optimize,
    expand_planes,
    neighbour_plane_candidates,
)
from prismstereo.matching.coop.slanted import add_unique
from prismstereo.matching.local.selection import right_cost_volume, weighted_median_filter
from prismstereo.matching.registry import MatchResult, register_matcher
from prismstereo.matching.segments.planes import (
    PlaneParams,
    SegmentIndex,
    build_segment_index,
    fill_missing_planes,
    fit_planes,
    fit_planes_splitting,
    group_refit_planes,
    merge_planes,
    render_planes,
)
from prismstereo.matching.segments.segmentation import SegmentationParams, mean_shift_segment, segment_adjacency

log = logging.getLogger(__name__)

__all__ = ["CoopMatcher", "CoopResult", "FineSegments", "boundary_pixel_planes",
           "bpasw_candidate_rounds", "coop_match", "initial_disparity",
           "occlusion_background_fill", "refine_fine_segments",
           "segment_sweep_candidates"]

F32 = npt.NDArray[np.float32]


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
    img = np.asarray(image)
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    if img.ndim != 3 or img.shape[2] not in (3, 4):
        raise ImageError(f"expected {name} as an H×W or H×W×3 image, got shape {img.shape}")
    img = img[:, :, :3]
    if img.dtype != np.uint8:
        f = img.astype(np.float32)
        if f.size and float(np.nanmax(f)) <= 1.0 + 1e-6:
            f = f * 255.0
        img = np.clip(np.rint(np.nan_to_num(f)), 0, 255).astype(np.uint8)
    return np.ascontiguousarray(img)


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
    h, w, nd = cost_left.shape
    dl = cost_left.argmin(axis=2)
    dr = cost_right.argmin(axis=2)
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


def _box3(vol: F32, r: int, *, vertical: bool = True) -> F32:
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
    """Issue 3's BPASW aggregated cost volume of the left view (thesis §5.2, Eqs. 5.6-5.14).

    S_AD plus half the census distance, aggregated with symmetric Weber-Fechner adaptive support weights
    (the ``bpasw`` matcher's defaults). Symmetric weights make the right view's volume the diagonal read of
    this one (:func:`prismstereo.matching.local.selection.right_cost_volume`).
    """
    from prismstereo.matching.local.matchers import BPASWMatcher

    return np.asarray(BPASWMatcher().cost_volume(left, right, max_disp=max_disp, min_disp=min_disp),
                      dtype=np.float32)


@njit(cache=True)
def boundary_pixel_planes(seg: npt.NDArray[np.int32], assign: npt.NDArray[np.int32], planes: npt.NDArray[np.float64],
                  cost: F32, min_disp: int, radius: int, margin: float,
                  active: npt.NDArray[np.bool_], dref: F32, tol: float,
                  active_up: npt.NDArray[np.bool_], assign2: npt.NDArray[np.int32]) -> F32:  # assign2: (K, M)
    """Per pixel, the disparity of the plane with the lowest aggregated cost among the planes of the segments
    within ``radius`` (its own first; another wins only when cheaper by more than ``margin``)."""
    h, w = seg.shape
    nd = cost.shape[2]
    out = np.empty((h, w), np.float32)
    nm = assign2.shape[1] + 1
    cand = np.empty(nm * (2 * radius + 1) ** 2, np.int64)
    for y in range(h):
        for x in range(w):
            own = assign[seg[y, x]]
            nc = 0
            if not active[y, x]:
                pl = planes[own]
                out[y, x] = pl[0] * x + pl[1] * y + pl[2]
                continue
            for yy in range(max(0, y - radius), min(h, y + radius + 1)):
                for xx in range(max(0, x - radius), min(w, x + radius + 1)):
                    for m in range(nm):
                        lab = assign[seg[yy, xx]] if m == 0 else assign2[seg[yy, xx], m - 1]
                        if lab != own and lab >= 0:
                            nc = add_unique(cand, nc, lab)
            pl = planes[own]
            best_d = pl[0] * x + pl[1] * y + pl[2]
            own_d = best_d
            if nc == 0:
                out[y, x] = best_d
                continue
            best = 1e30
            for t in range(-1, nc):
                pl = planes[own] if t < 0 else planes[cand[t]]
                d = pl[0] * x + pl[1] * y + pl[2]
                k = d - min_disp
                if k < 0.0 or k > nd - 1.0 or x - d < 0.0:
                    if t < 0:
                        break  # own plane without evidence here: keep it
                    continue
                if tol > 0 and t >= 0 and abs(d - dref[y, x]) > tol:
                    continue
                if t >= 0 and d > own_d and not active_up[y, x]:
                    continue
                k0 = int(k)
                k1 = min(k0 + 1, nd - 1)
                f = k - k0
                c = (1.0 - f) * cost[y, x, k0] + f * cost[y, x, k1]
                if t >= 0:
                    c += margin
                if c < best:
                    best = c
                    best_d = d
            out[y, x] = best_d
    return out


def bpasw_dense_map(vol: F32, image: npt.NDArray[np.uint8], *, min_disp: int = 0) -> F32:
    """Issue 3's ``bpasw`` matcher output from its cost volume: WTA, cross-check (1 px), background fill and
    colour-weighted median (radius 9), as :class:`prismstereo.matching.local.matchers.BPASWMatcher` with defaults.
    Returns (H, W) float32, dense."""
    from prismstereo.matching.local import selection

    disp = selection.winner_take_all(vol, min_disp=min_disp)
    valid = selection.cross_check(disp, selection.right_disparity(vol, min_disp=min_disp), tolerance=1.0)
    raw = np.where(valid, disp, np.float32(np.nan)).astype(np.float32)
    if valid.all():
        return raw
    dense = selection.fill_holes(raw, valid, image=image)
    if np.isfinite(dense).all():
        dense = selection.weighted_median_filter(dense, image, radius=9)
    return np.asarray(dense, np.float32)


def _bpasw_reliable(vol: F32, min_disp: int) -> tuple[npt.NDArray[np.bool_], F32]:
    d, rel = initial_disparity(vol, right_cost_volume(vol, min_disp=min_disp), min_disp=min_disp)
    return rel, d


Optimise = Callable[[npt.NDArray[np.int32], npt.NDArray[np.float64], npt.NDArray[np.int64]],
                    tuple[npt.NDArray[np.int32], npt.NDArray[np.float64], dict[str, float]]]


def bpasw_candidate_rounds(assign: npt.NDArray[np.int32], plane_set: npt.NDArray[np.float64],
                           own: npt.NDArray[np.int64], index: SegmentIndex, pairs: npt.NDArray[np.int32],
                           disparity: F32, reliable: npt.NDArray[np.bool_], optimise: Optimise, *,
                           planes: PlaneParams, rounds: int
                           ) -> tuple[npt.NDArray[np.int32], npt.NDArray[np.float64], dict[str, float] | None,
                                      npt.NDArray[np.int64] | None]:
    """``coop``'s ``bpasw_planes`` rounds: planes fitted per segment to the cross-checked BPASW map
    ``disparity`` (reliable where ``reliable``) offered as each segment's first candidate (1), with their
    merged-cluster planes as second (2), then one plane refitted per group of segments sharing a plane (3);
    ``optimise(assign, planes, own)`` resumes the cooperative optimisation after each. Returns assign,
    planes, the last optimisation's info (None when none ran) and each segment's own BPASW-fit plane id
    (-1 none)."""
    info: dict[str, float] | None = None
    bfit_ids: npt.NDArray[np.int64] | None = None
    if rounds <= 0:
        return assign, plane_set, info, bfit_ids
    bfit, _ = fit_planes(index, disparity, reliable, params=planes)
    okb = np.flatnonzero(np.isfinite(bfit[:, 0]))
    if okb.size:
        own3 = own.copy()
        own3[:, 0] = -1
        own3[okb, 0] = plane_set.shape[0] + np.arange(okb.size)
        bfit_ids = own3[:, 0].copy()
        plane_set = np.concatenate([plane_set, bfit[okb]])
        if rounds > 1:
            bcl, bcp = merge_planes(index, bfit, pairs, disparity, reliable, params=planes)
            own3[:, 1] = np.where(bcl >= 0, bcl + plane_set.shape[0], -1)
            plane_set = np.concatenate([plane_set, bcp])
        assign, plane_set, info = optimise(assign, plane_set, own3)
    if rounds > 2:
        refit = group_refit_planes(assign, plane_set, index, disparity, reliable, params=planes)
        if refit is not None:
            plane_set, group_ids = refit
            own4 = own.copy()
            own4[:, 1] = group_ids
            assign, plane_set, info = optimise(assign, plane_set, own4)
    return assign, plane_set, info, bfit_ids


@njit(cache=True)
def occlusion_background_fill(disp: F32, seg: npt.NDArray[np.int32], assign: npt.NDArray[np.int32],
                    planes: npt.NDArray[np.float64], dright: F32, rright: npt.NDArray[np.bool_],
                    tol: float, dleft: F32, rleft: npt.NDArray[np.bool_],
                    radius: int) -> tuple[F32, npt.NDArray[np.bool_]]:
    """Pixels whose match in the right view reliably sees a farther surface (``d_R < d - tol``) are taken as
    occluded and get the background plane: of the nearest consistent pixels left and right on the row, the
    plane (extrapolated to the pixel) with the smaller disparity."""
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
                      min_disp: int, max_disp: int, frac: float, slopes: tuple[float, ...], keep: int,
                      min_px: int, step: int, dilation: int = 2,
                      ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """Candidate planes from a global sweep for the segments of highest mean slanted-window cost.

    The ``frac`` of segments (with at least ``min_px`` pixels) whose current plane has the highest mean slanted
    cost (:mod:`slanted`) get planes swept over the centre disparity (integer steps over the whole range) and
    the slopes ``b`` in ``slopes`` (``a`` = 0 and the current ``a``); the ``keep`` cheapest (at least 2 px
    apart in centre disparity or differing in slope) are returned as new planes and a (K, keep) index array
    into the extended plane set (-1 = none)."""
    from prismstereo.matching.coop.slanted import segment_plane_costs

    k = assign.shape[0]
    h, w = labels.shape
    cur = segment_plane_costs(lft, rgt, labels, assign.astype(np.int64)[:, None], plane_set,
                              min_disp=min_disp, max_disp=max_disp, step=step, dilation=dilation)[:, 0]
    sizes = np.diff(index.starts)
    ok = np.isfinite(cur) & (sizes >= min_px)
    out_ids = np.full((k, keep), -1, np.int64)
    if not ok.any():
        return plane_set, out_ids
    thr = np.quantile(cur[ok], 1.0 - frac)
    sel = np.flatnonzero(ok & (cur >= thr))
    flat = index.order
    xs_all = (flat % w).astype(np.float64)
    ys_all = (flat // w).astype(np.float64)
    dcs = np.arange(int(min_disp), int(max_disp) + 1, dtype=np.float64)
    grid = []
    for b in slopes:
        for dc in dcs:
            grid.append((b, dc))
    g = np.asarray(grid)
    ng = g.shape[0]
    m = 2 * ng
    planes_new = np.empty((sel.size * m, 3), np.float64)
    cand = np.full((k, m), -1, np.int64)
    base = plane_set.shape[0]
    for i, s in enumerate(sel):
        sl = slice(index.starts[s], index.starts[s + 1])
        cx = float(xs_all[sl].mean())
        cy = float(ys_all[sl].mean())
        a_cur = float(plane_set[assign[s], 0])
        for j, a in enumerate((0.0, a_cur)):
            blk = planes_new[i * m + j * ng:i * m + (j + 1) * ng]
            blk[:, 0] = a
            blk[:, 1] = g[:, 0]
            blk[:, 2] = g[:, 1] - a * cx - g[:, 0] * cy
        cand[s] = base + i * m + np.arange(m)
    allp = np.concatenate([plane_set, planes_new])
    cost = segment_plane_costs(lft, rgt, labels, cand, allp, min_disp=min_disp, max_disp=max_disp, step=step,
                               dilation=dilation)
    chosen: list[npt.NDArray[np.float64]] = []
    nxt = base
    for i, s in enumerate(sel):
        c = cost[s]
        if not np.isfinite(c).any():
            continue
        picked: list[int] = []
        for j in np.argsort(c):
            if not np.isfinite(c[j]) or len(picked) >= keep:
                break
            jj = j % ng
            if any(abs(g[jj, 1] - g[q % ng, 1]) < 2 and g[jj, 0] == g[q % ng, 0] for q in picked):
                continue
            picked.append(int(j))
        for t, j in enumerate(picked):
            chosen.append(planes_new[i * m + j])
            out_ids[s, t] = nxt
            nxt += 1
    if not chosen:
        return plane_set, out_ids
    return np.concatenate([plane_set, np.asarray(chosen)]), out_ids


@dataclass(frozen=True)
class FineSegments:
    """Result of :func:`refine_fine_segments`.

    Attributes
    ----------
    labels : (H, W) int32       fine segments (each inside one segment of the coarse labels).
    parent : (K_f,) int64       coarse segment of each fine segment.
    index : SegmentIndex        pixels of the fine segments.
    assign : (K_f,) int32       plane per fine segment, into ``planes``.
    planes : (L, 3) float64
    info : dict                 energies, sweeps, ``fine_segments``, ``fine_moves``.
    """

    labels: npt.NDArray[np.int32]
    parent: npt.NDArray[np.int64]
    index: Any
    assign: npt.NDArray[np.int32]
    planes: npt.NDArray[np.float64]
    info: dict[str, float]


def refine_fine_segments(image: npt.NDArray[np.uint8], labels: npt.NDArray[np.int32],
                         assign: npt.NDArray[np.int32], planes: npt.NDArray[np.float64], cost: F32,
                         reliable: npt.NDArray[np.bool_], evidence: npt.NDArray[np.bool_], reference: F32, *,
                         segmentation: SegmentationParams, coop: CoopParams, min_disp: int = 0,
                         beta_scale: float = 1.0, check: int = 1,
                         slopes: tuple[float, ...] | None = None) -> FineSegments:
    """Finer segments along plane boundaries resume the cooperative optimisation (an addition to §6.2).

    The image is segmented again with ``segmentation`` (a smaller range radius) and intersected with
    ``labels``; each fine segment starts from its segment's plane, and those touching a fine segment on
    another plane may take a neighbour's plane by the cooperative scheme (Eq. 6.19) on ``cost``. A move is
    kept only when at least ``check`` more of the fine segment's ``evidence`` pixels lie within 1 px of
    ``reference`` under the new plane than under the old (0 = keep every move).

    Parameters
    ----------
    image : (H, W, 3) uint8 reference image.
    labels : (H, W) int32 segments; assign : (K,) plane per segment; planes : (L, 3).
    cost : (H, W, D) or (S, H, W, D) float32 data-term pixel cost (as :func:`cooperative_optimize`, with
        ``slopes``).
    reliable : (H, W) bool cross-check mask of the data term.
    evidence : (H, W) bool pixels whose ``reference`` disparity is trusted.
    reference : (H, W) float32 disparity map the moves are checked against.
    """
    fine = mean_shift_segment(image, params=segmentation)
    comb = labels.astype(np.int64) * (int(fine.max()) + 1) + fine
    _, inv = np.unique(comb, return_inverse=True)
    flab = inv.reshape(labels.shape).astype(np.int32)
    parent = np.zeros(int(flab.max()) + 1, np.int64)
    parent[flab.ravel()] = labels.ravel()
    findex = build_segment_index(flab)
    fgraph = build_segment_graph(flab, image, beta_scale=beta_scale)
    fa = np.asarray(assign, np.int32)[parent]
    fown = np.full((parent.size, 2), -1, np.int64)
    fown[:, 0] = fa
    # interiors keep their segment's plane: only fine segments touching another plane may move
    diff = fa[fgraph.pairs[:, 0]] != fa[fgraph.pairs[:, 1]]
    active = np.zeros(parent.size, bool)
    active[fgraph.pairs[diff, 0]] = True
    active[fgraph.pairs[diff, 1]] = True
    new, planes_out, info = cooperative_optimize(fa, planes, findex, fgraph, cost, reliable, own=fown,
                                                 min_disp=min_disp, active=active, slopes=slopes,
                                                 params=dataclasses.replace(coop, neighbour_own_planes=False))
    moved = np.flatnonzero(new != fa)
    if check and moved.size:
        # the data term of a 10-pixel segment is noisy: the trusted initial disparities must side with the move
        h, w = labels.shape
        yy, xx = np.mgrid[0:h, 0:w]
        fl = flab.ravel()
        ev = np.asarray(evidence, bool).ravel()
        ref = np.asarray(reference, np.float64).ravel()

        def support(lab: npt.NDArray[np.int32]) -> npt.NDArray[np.float64]:
            pl = planes_out[lab][fl]
            d = pl[:, 0] * xx.ravel() + pl[:, 1] * yy.ravel() + pl[:, 2]
            return np.bincount(fl, weights=(ev & (np.abs(d - ref) <= 1.0)).astype(np.float64),
                               minlength=parent.size).astype(np.float64)

        sn, so = support(new), support(fa)
        undo = moved[sn[moved] < so[moved] + check]
        new = new.copy()
        new[undo] = fa[undo]
    info = {**info, "fine_segments": float(parent.size), "fine_moves": float((new != fa).sum())}
    return FineSegments(flab, parent, findex, new.astype(np.int32), planes_out, info)


def coop_match(left: npt.NDArray[np.generic], right: npt.NDArray[np.generic], *, max_disp: int,
               min_disp: int = 0, segmentation: SegmentationParams | None = None,
               cost: CostParams | None = None, planes: PlaneParams | None = None,
               coop: CoopParams | None = None, data_radius: int = 1, refit_rounds: int = 1,
               data_cost: CostParams | None = None, check_tolerance: float = 0.0,
               beta_scale: float = 1.0, initial_cost: str = "guided", data_term: str = "raw",
               data_scale: float = 0.1, pixel_radius: int = 5, pixel_margin: float = 5.0,
               pixel_tol: float = 1.0, pixel_agree: int = 0, post_median: int = 4,
               occlusion_fill: bool = True, occ_tol: float = 1.0,
               bpasw_planes: int = 3, occ_rematch: bool = True,
               pixel_bplanes: int = 2, sweep_frac: float = 0.5,
               sweep_slopes: tuple[float, ...] = (-1.0, -0.5, 0.0, 0.5, 1.0), sweep_keep: int = 2,
               sweep_min_px: int = 20, sweep_step: int = 4, sweep_hbox: int = 1,
               sweep_nbr: bool = False, sweep_dil: int = 3, fine_hr: float = 3.0,
               fine_min: int = 10, fine_check: int = 1,
               data_slopes: tuple[float, ...] = (-1.0, -0.5, 0.0, 0.5, 1.0),
               group_moves: bool = True, split_evidence: bool = True,
               keep_stages: bool = False) -> CoopResult:
    """Run the whole segment-based cooperative pipeline (thesis §5.1, §5.2, §6.1, §6.2).

    Parameters
    ----------
    left, right : (H, W, 3) uint8 RGB or (H, W) grey
        Rectified pair; disparity ``d = x_left - x_right`` in ``[min_disp, max_disp]``.
    max_disp, min_disp : int, keyword-only
    segmentation, cost, planes, coop : parameter dataclasses, keyword-only
        ``hs, hr, M``; cost/aggregation; ``γ_segment, t_outlier, ε, δ``; ``κ, μ, ω_occ, γ``.
    data_radius : int, keyword-only
        Box radius of the pixel cost summed in the segment data term (Eq. 6.21); the segment itself is the
        aggregation window there, so only a light pre-smoothing is used (0 = raw pixel cost).
    data_cost : CostParams, keyword-only
        Pixel-cost parameters of the data term (Eq. 6.21) when they should differ from ``cost``.
    check_tolerance : float, keyword-only
        Tolerance of the left-right check of the integer WTA maps (Eq. 6.7; 0 = they must agree exactly).
    beta_scale : float, keyword-only
        Multiplier on β of Eq. 6.25 (1 = the thesis's choice).
    initial_cost : {"guided", "bpasw"}, keyword-only
        Aggregated cost of the initial map (§5.2): the guided-filter volume of :mod:`coopcost` (default) or
        issue 3's BPASW volume (:func:`bpasw_volume`, cross-checked the same way). BPASW gave worse planes
        here (Tsukuba plane map 5.69 vs 3.56 % nonocc; 12-number average 5.42 vs 5.37 before step 5).
    data_term : {"raw", "bpasw", "both"}, keyword-only
        Per-pixel cost of Eq. 6.21: the box-smoothed pixel cost (default), the BPASW aggregated cost as the
        residual above the pixel's best disparity times ``data_scale``, or their sum. Measured worse:
        average 6.39 / 6.19 (bpasw, scale 0.1 / 0.2), 5.51 / 5.68 (both, 0.05 / 0.1) against 5.37 —
        interpolating the peaky aggregated cost between integer disparities penalises slanted planes.
    data_scale : float, keyword-only
        Scale of the BPASW residual in the data term (cost units of the pixel cost).
    pixel_radius, pixel_margin, pixel_tol, pixel_agree : keyword-only
        Boundary step (stage 5): each pixel may take the plane of a segment within ``pixel_radius`` px when
        its BPASW aggregated cost (adaptive weights, symmetric) is lower than the own plane's by more than
        ``pixel_margin`` and it lies within ``pixel_tol`` of the BPASW winner at a pixel where the BPASW
        map passes the cross-check (and, with ``pixel_agree`` = 1, where the initial map agrees with it within
        ``pixel_tol``; with 2, only a move to a LARGER disparity needs that agreement — undoing fattening
        needs less evidence than creating it; 0, the default, no initial-map agreement: with the slope-sheared
        data term, 0 measured 4.21 -> 4.17 against 2, and 1 4.24). A pixel whose own plane leaves the right
        image keeps it. ``pixel_radius`` 0 = off.
    occlusion_fill, occ_tol : keyword-only
        Occlusion step (Eq. 6.22's occluded pixels, resolved after the fact): a pixel whose match in the
        right view is a reliable BPASW right-view pixel (cross-checked) that sees a farther surface
        (``d_R < d - occ_tol``) is taken as occluded and gets the background plane, the smaller of the planes
        of the nearest consistent pixels to its left and right on the row, extrapolated to the pixel
        (the foreground fattened into occluded background; average 5.03 -> 4.99). With ``occ_rematch``,
        such a pixel whose own BPASW match passes the cross-check at a smaller disparity is instead given
        the plane within ``pixel_radius`` closest to that disparity (visible after all; 4.86 -> 4.83).
    bpasw_planes : int, keyword-only
        Richer candidate planes (an addition to §6.1): after the optimisation and the refit round, each
        segment is also offered the plane fitted (Eqs. 6.1-6.10) to issue 3's cross-checked BPASW map (1),
        the merged-cluster planes of those fits (2), then planes refitted to the BPASW map over groups of
        segments sharing a plane (3); the optimisation resumes after each (0 = off; average 4.98 -> 4.91 ->
        4.90 -> 4.86).
    pixel_bplanes : int, keyword-only
        Planes the boundary step may pick besides the current planes of nearby segments: those segments'
        planes fitted to the BPASW map (1) and to the initial map (2) (0 = current planes only; average
        4.83 -> 4.78 -> 4.75).
    fine_hr, fine_min, fine_check : keyword-only
        Finer segments (an addition to §6.2): the segmentation is repeated with range radius ``fine_hr`` and
        minimum size ``fine_min`` and intersected with the segments; the fine segments that touch a segment on
        another plane start from their segment's plane and resume the cooperative optimisation, so that a
        segment straddling a depth edge can split along a weaker colour edge. A fine segment's move is kept
        only when at least ``fine_check`` more of its pixels where both cross-checked initial maps agree lie
        within 1 px of the new plane than of the old (the data term of a 10-pixel segment is noisy).
        The result's ``labels`` are then the fine segments (0 = off; average 4.49 -> 4.50 without the check,
        4.44 with it: Tsukuba 1.54/1.94/7.20 -> 1.39/1.79/6.42, Cones 2.23 -> 2.19, Teddy 4.72 -> 4.80).
    sweep_frac, sweep_slopes, sweep_keep, sweep_min_px, sweep_step, sweep_dil, sweep_hbox, sweep_nbr : keyword-only
        Candidate planes from a global sweep (:func:`segment_sweep_candidates`, after the BPASW rounds): the
        ``sweep_frac`` of the segments of at least ``sweep_min_px`` pixels whose current plane has the highest
        mean slanted-window cost (:mod:`slanted`, sampled every ``sweep_step`` px, window every ``sweep_dil``
        px) get, as candidates, the ``sweep_keep`` cheapest planes of a sweep of the centre disparity over the
        whole range (integer steps) x ``b`` in ``sweep_slopes`` x ``a`` in {0, current a}; the optimisation
        resumes with them (0 = off). Local plane searches cannot reach a steep floor from a fronto-parallel
        plane (Teddy: b ~ 0.07 against 0.8-1.1). With ``sweep_hbox`` >= 0 the pixel cost of the data term on
        those segments' pixels is boxed along the row only (radius ``sweep_hbox``): the default square box
        averages neighbouring rows at one disparity and so favours fronto-parallel planes on surfaces slanted
        in ``y`` (the correct sweep plane was dearer than the fronto-parallel one under it). ``sweep_nbr``
        also lets segments take their neighbours' sweep candidates (measured worse: 4.86). Average 4.75 ->
        4.745 (sweep, 10 %, square box), 4.70 (10 %, row box), 4.63 (20 %), 4.56 (35 %), 4.49 (50 %, the
        default), 4.81 (all segments). With the slope-sheared data term and ``pixel_agree`` 0: ``sweep_min_px``
        40 -> 20 (the default) 4.17 -> 4.14; ``sweep_frac`` 0.35 / 0.65 4.20 / 4.51 (at 40 px and agree 2).
    data_slopes : tuple of float, keyword-only
        Vertical disparity slopes ``b`` (px per row) of the data term's pixel-cost volumes
        (:func:`prismstereo.matching.coop.coopcost.sheared_costs`, an addition to Eq. 6.21): each plane's pixels read
        the volume of the slope nearest its ``b``, whose census window and smoothing box follow the slant (row
        ``dy`` compared ``b dy`` px away). Square windows charge a steep floor more at its true plane than at an
        aliased fronto-parallel one. Empty = one unsheared volume. Average 4.44 -> 4.21 (Teddy 4.80/8.49/13.37
        -> 4.19/7.74/11.83; 3 slopes 4.20, 7 slopes to ±1.5 4.21); Teddy peak RSS 1.07 -> 1.22 GB.
    split_evidence : bool, keyword-only
        The segments that failed the plane support test (split, see ``planes``) are not one plane (Bowling1's
        ball): their pieces' planes approximate the surface but miss its rim. Their pixels take the ``bpasw``
        matcher's map (:func:`bpasw_dense_map`) at the end; the other segments passed the test and keep their
        planes.
    group_moves : bool, keyword-only
        Group moves after the sweep (:func:`prismstereo.matching.coop.cooperative.expand_planes`, an addition to
        §6.2): each sweep candidate and each plane held across a segment boundary may move a connected region
        of segments at once (grown through segments whose data term it does not raise) when that lowers E;
        then the optimisation resumes. One segment at a time cannot leave a wrong plane shared by its
        neighbours (Teddy's floor: every segment alone would pay the smoothness term). Average 4.14 -> 3.93
        (Teddy 4.11/7.73/11.54 -> 3.63/7.45/10.11, Cones 2.16/6.78/6.39 -> 2.10/6.68/6.21, Tsukuba and Venus
        unchanged); sweep candidates only 3.96, boundary planes only 4.02, without resuming 4.01.
    post_median : int, keyword-only
        Radius of a colour-weighted median over the final map (issue 3's filter); it only replaces values
        it moves by more than 1 px, so subpixel plane disparities are kept (0 = off).
    refit_rounds : int, keyword-only
        After the cooperative optimisation, segments sharing a plane are refitted together (Eqs. 6.2-6.10
        on their union), the refitted planes offered as candidates, and the optimisation resumed; this many
        times (0 = off).

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
    tm: dict[str, float] = {}

    t = time.perf_counter()
    bvol: F32 | None = None
    if (initial_cost == "bpasw" or data_term in ("bpasw", "both") or bpasw_planes > 0 or pixel_radius > 0
            or occlusion_fill):
        bvol = bpasw_volume(lft, rgt, max_disp=max_disp, min_disp=min_disp)
    # cross-checked BPASW map (integer WTA must agree exactly), parabola subpixel
    brel0, bdisp0 = (_bpasw_reliable(bvol, min_disp) if bvol is not None
                     else (np.zeros(lft.shape[:2], bool), np.zeros(lft.shape[:2], np.float32)))
    raw: F32 | None = None
    if initial_cost == "bpasw":
        assert bvol is not None
        initial, reliable = initial_disparity(bvol, right_cost_volume(bvol, min_disp=min_disp),
                                              min_disp=min_disp, tolerance=check_tolerance)
    else:
        raw = raw_cost(lft, rgt, max_disp=max_disp, min_disp=min_disp, params=cp)
        agg_l, agg_r = aggregated_costs(lft, rgt, max_disp=max_disp, min_disp=min_disp, params=cp, raw=raw)
        initial, reliable = initial_disparity(agg_l, agg_r, min_disp=min_disp, tolerance=check_tolerance)
        del agg_r, agg_l
    tm["initial"] = time.perf_counter() - t

    t = time.perf_counter()
    labels = mean_shift_segment(lft, params=sp, disparity=initial if sp.depth_tau > 0 else None)
    tm["segmentation"] = time.perf_counter() - t

    t = time.perf_counter()
    # the evidence of the safety tests: both cross-checked initial maps (differently aggregated) agree
    evidence = reliable & brel0 & (np.abs(bdisp0 - initial) <= pixel_tol) if bvol is not None else reliable
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
    graph = build_segment_graph(labels, lft, beta_scale=beta_scale)
    if data_term == "both":
        assert bvol is not None
        if data_cost is not None or raw is None:
            raw = raw_cost(lft, rgt, max_disp=max_disp, min_disp=min_disp, params=data_cost or cp)
        dcost = _box3(raw, data_radius)
        dcost += (bvol - bvol.min(axis=2, keepdims=True)) * np.float32(data_scale)
    elif data_term == "bpasw":
        assert bvol is not None
        # residual above the pixel's best match: removes the texture-dependent offset of aggregated costs
        dcost = ((bvol - bvol.min(axis=2, keepdims=True)) * np.float32(data_scale)).astype(np.float32)
    elif data_slopes:
        raw = None  # the sheared volumes compute their own pixel costs: free the initial map's first
        dcost = sheared_costs(lft, rgt, max_disp=max_disp, min_disp=min_disp, params=data_cost or cp,
                              slopes=tuple(data_slopes), radius=data_radius)
    else:
        if data_cost is not None or raw is None:
            raw = raw_cost(lft, rgt, max_disp=max_disp, min_disp=min_disp, params=data_cost or cp)
        dcost = _box3(raw, data_radius)
    del raw
    slopes = tuple(float(b) for b in data_slopes) if data_slopes and data_term == "raw" else None

    def resume(a: npt.NDArray[np.int32], pset: npt.NDArray[np.float64], own_: npt.NDArray[np.int64],
               prm: CoopParams = op) -> tuple[npt.NDArray[np.int32], npt.NDArray[np.float64], dict[str, float]]:
        # the cooperative optimisation (Eqs. 6.18-6.25) on the coarse segments and the data term
        return cooperative_optimize(a, pset, index, graph, dcost, reliable, own=own_, min_disp=min_disp,
                                    params=prm, slopes=slopes)

    stages: dict[str, F32] = {}

    def snap(name: str) -> None:
        if keep_stages:
            stages[name] = render_planes(index, plane_set, assign).astype(np.float32)

    if keep_stages:
        stages["initial"] = initial.copy()
        stages["bpasw"] = bdisp0.copy()
        stages["evidence"] = evidence.astype(np.float32)
        stages["plane_map"] = plane_map.copy()
        stages["split"] = np.isfinite(ancestor[:, 0])[labels].astype(np.float32)
    assign, plane_set, info = resume(assign0, plane_set, own)
    info["split_pieces"] = float(split.size)
    e_first = info["energy_before"]
    snap("coop")
    for _ in range(refit_rounds):
        # refit one plane per group of segments sharing a label (wider support), offer it as a candidate
        refit = group_refit_planes(assign, plane_set, index, initial, reliable, params=pp)
        if refit is None:
            break
        plane_set, group_ids = refit
        own2 = own.copy()
        own2[:, 1] = group_ids
        assign, plane_set, info2 = resume(assign, plane_set, own2)
        info = {**info, **info2, "energy_before": e_first}
    snap("refit")
    # second plane hypotheses per segment from the cross-checked BPASW map, resuming the optimisation
    assign, plane_set, info3, bfit_ids = bpasw_candidate_rounds(assign, plane_set, own, index, pairs, bdisp0, brel0,
                                                                resume, planes=pp, rounds=bpasw_planes)
    if info3 is not None:
        info = {**info, **info3, "energy_before": e_first}
    snap("bpasw_planes")
    if sweep_frac > 0:
        plane_set, sw_ids = segment_sweep_candidates(lft, rgt, labels, index, assign, plane_set, min_disp=min_disp,
                                              max_disp=max_disp, frac=sweep_frac, slopes=tuple(sweep_slopes),
                                              keep=sweep_keep, min_px=sweep_min_px, step=sweep_step,
                                              dilation=sweep_dil)
        sw_op = dataclasses.replace(op, neighbour_own_planes=True) if sweep_nbr else op
        if sweep_hbox >= 0:
            # the selected segments' pixels: pixel cost boxed along the row only (a square box favours
            # fronto-parallel planes on surfaces slanted in y)
            selpix = (sw_ids[:, 0] >= 0)[labels]
            if slopes is None:
                raw2 = raw_cost(lft, rgt, max_disp=max_disp, min_disp=min_disp, params=data_cost or cp)
                hb = _box3(raw2, sweep_hbox, vertical=False)
                del raw2
                dcost[selpix] = hb[selpix]
            else:
                hb = sheared_costs(lft, rgt, max_disp=max_disp, min_disp=min_disp, params=data_cost or cp,
                                   slopes=slopes, radius=sweep_hbox, vertical=False)
                dcost[:, selpix] = hb[:, selpix]
            del hb
        for col in range(0, sw_ids.shape[1], 2):
            own6 = np.full((k, 2), -1, np.int64)
            own6[:, :min(2, sw_ids.shape[1] - col)] = sw_ids[:, col:col + 2]
            if (own6 >= 0).any():
                assign, plane_set, info2 = resume(assign, plane_set, own6, sw_op)
                info = {**info, **info2, "energy_before": e_first}
        info = {**info, "sweep_segments": float((sw_ids[:, 0] >= 0).sum())}
        snap("sweep")
        if group_moves:
            # sweep candidates and the planes across each segment's boundary, moved over whole regions
            cands = np.concatenate([sw_ids, neighbour_plane_candidates(graph, assign)], axis=1)
            assign, ginfo = expand_planes(assign, plane_set, index, graph, dcost, reliable, cands,
                                          min_disp=min_disp, params=op, slopes=slopes)
            assign, plane_set, info2 = resume(assign, plane_set, own)
            info = {**info, **info2, **ginfo, "energy_before": e_first}
            snap("group_moves")
    if fine_hr > 0:
        fs = refine_fine_segments(lft, labels, assign, plane_set, dcost, reliable, evidence, initial,
                                  segmentation=dataclasses.replace(sp, hr=fine_hr, min_region=fine_min),
                                  coop=op, min_disp=min_disp, beta_scale=beta_scale, check=fine_check,
                                  slopes=slopes)
        info = {**info, **fs.info, "energy_before": e_first}
        labels, index, assign, plane_set, k = fs.labels, fs.index, fs.assign, fs.planes, int(fs.parent.size)
        assign0 = assign0[fs.parent]
        own = own[fs.parent]
        if bfit_ids is not None:
            bfit_ids = bfit_ids[fs.parent]
        snap("fine")
    tm["cooperative"] = time.perf_counter() - t
    t = time.perf_counter()
    if pixel_radius > 0:
        assert bvol is not None
        brel, bdisp = brel0, bdisp0
        extra = []
        if pixel_bplanes and bfit_ids is not None:
            extra.append(bfit_ids)
        if pixel_bplanes > 1:
            extra.append(own[:, 0])
        bown = (np.stack(extra, axis=1) if extra else np.full((k, 1), -1)).astype(np.int32)
        bagree = brel & reliable & (np.abs(bdisp - initial) <= pixel_tol)
        if pixel_agree == 1:  # both initial maps must agree on the pixel
            brel = bagree
        final = boundary_pixel_planes(labels.astype(np.int32), assign.astype(np.int32), plane_set, bvol, int(min_disp),
                              int(pixel_radius), float(pixel_margin), brel, bdisp,
                              float(pixel_tol), bagree if pixel_agree else brel, bown)
    else:
        final = render_planes(index, plane_set, assign)
    if keep_stages:
        stages["boundary"] = final.copy()
    if occlusion_fill:
        assert bvol is not None
        rvol = right_cost_volume(bvol, min_disp=min_disp)
        dr_int = rvol.argmin(axis=2)
        dl_int = bvol.argmin(axis=2)
        xs = np.arange(final.shape[1])[None, :] + dr_int + min_disp
        rrel = (xs < final.shape[1]) & (np.take_along_axis(dl_int, np.clip(xs, 0, final.shape[1] - 1), axis=1)
                                         == dr_int)
        final, _occ = occlusion_background_fill(final.astype(np.float32), labels.astype(np.int32),
                                                assign.astype(np.int32), plane_set,
                                                (dr_int + min_disp).astype(np.float32), rrel, float(occ_tol),
                                                bdisp0, brel0, int(pixel_radius) if occ_rematch else 0)
        if keep_stages:
            stages["occlusion"] = final.copy()
    if post_median > 0:
        wm = weighted_median_filter(final, lft, radius=post_median)
        # the median works on integer bins: keep the subpixel plane disparity where it agrees within 1 px
        final = np.where(np.abs(wm - final) <= 1.0, final, wm)
    if split_evidence and nonplanar.any():
        assert bvol is not None
        # the segments that failed the plane support test are not planar: the local matcher's map there
        final = np.where(nonplanar, bpasw_dense_map(bvol, lft, min_disp=min_disp), final)
        info = {**info, "split_evidence_pixels": float(nonplanar.sum())}
    final = np.clip(final, min_disp, max_disp).astype(np.float32)
    tm["boundary"] = time.perf_counter() - t
    info = {**info, "segments": float(k), "planes_fitted": float(fin.size), "planes": float(len(plane_set)),
            "reliable_fraction": float(reliable.mean())}
    log.info("coop: %d segments, %d planes, E %.0f -> %.0f", k, len(plane_set), info["energy_before"],
             info["energy_after"])
    return CoopResult(labels=labels, initial=initial, reliable=reliable, plane_map=plane_map, disparity=final,
                      planes=plane_set, assign_initial=assign0, assign=assign, info=info, timings=tm,
                      stages=stages)


@register_matcher("coop")
class CoopMatcher:
    """Segment-based stereo with cooperative optimisation (thesis ch. 5-6) as a registry matcher.

    Parameters (keyword-only)
    -------------------------
    segmentation, cost, planes, coop : parameter dataclasses (defaults: the values used for all scenes).
    data_radius : int
        Pre-smoothing radius of the pixel cost in the segment data term.
    refit_rounds : int
        Rounds of joint refitting of segments that share a plane after the cooperative optimisation.
    pixel_radius, post_median : int
        Boundary step radius and final weighted-median radius (0 = off each; see :func:`coop_match`).

    ``compute`` returns a :class:`MatchResult` whose ``extras`` hold the stage maps: ``labels``,
    ``initial``, ``reliable``, ``plane_map``, ``planes``, ``assign`` and ``info``.
    """

    def __init__(self, *, segmentation: SegmentationParams | None = None, cost: CostParams | None = None,
                 planes: PlaneParams | None = None, coop: CoopParams | None = None, data_radius: int = 1,
                 refit_rounds: int = 1, pixel_radius: int = 5, post_median: int = 4):
        self.segmentation = segmentation
        self.cost = cost
        self.planes = planes
        self.coop = coop
        self.data_radius = int(data_radius)
        self.refit_rounds = int(refit_rounds)
        self.pixel_radius = int(pixel_radius)
        self.post_median = int(post_median)

    def compute(self, left: np.ndarray, right: np.ndarray, *, max_disp: int, min_disp: int = 0) -> MatchResult:
        res = coop_match(left, right, max_disp=max_disp, min_disp=min_disp, segmentation=self.segmentation,
                         cost=self.cost, planes=self.planes, coop=self.coop, data_radius=self.data_radius,
                         refit_rounds=self.refit_rounds, pixel_radius=self.pixel_radius,
                         post_median=self.post_median)
        raw = np.where(res.reliable, res.initial, np.nan).astype(np.float32)
        extras: dict[str, Any] = {"labels": res.labels, "initial": res.initial, "reliable": res.reliable,
                                  "plane_map": res.plane_map, "planes": res.planes, "assign": res.assign,
                                  "assign_initial": res.assign_initial, "info": res.info, "initial_raw": raw}
        return MatchResult(disparity=res.disparity, valid=np.isfinite(res.disparity), disparity_raw=None,
                           timings=dict(res.timings), extras=extras)
