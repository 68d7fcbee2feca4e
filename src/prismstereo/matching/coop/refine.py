"""Plane-label refinements run by the steps of :mod:`prismstereo.matching.coop.steps`.

The two-view ``coop`` and the global multi-view method both reach them through the steps: the BPASW plane
rounds (``bpasw_planes``), finer segments along plane boundaries (``fine``) and the per-pixel choice among
nearby planes (``boundary``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from numba import njit, prange

from prismstereo.matching.coop.cooperative import CoopParams, build_segment_graph, cooperative_optimize
from prismstereo.matching.segments.planes import (
    PlaneParams,
    SegmentIndex,
    build_segment_index,
    fit_planes,
    group_refit_planes,
    merge_planes,
)
from prismstereo.matching.segments.segmentation import SegmentationParams, mean_shift_segment

__all__ = ["DataTerm", "FineSegments", "Optimise", "boundary_pixel_planes", "bpasw_candidate_rounds",
           "refine_fine_segments"]

F32 = npt.NDArray[np.float32]


@njit(cache=True, parallel=True, nogil=True)
def boundary_pixel_planes(seg: npt.NDArray[np.int32], assign: npt.NDArray[np.int32], planes: npt.NDArray[np.float64],
                  cost: F32, min_disp: int, radius: int, margin: float,
                  active: npt.NDArray[np.bool_], dref: F32, tol: float,
                  active_up: npt.NDArray[np.bool_], assign2: npt.NDArray[np.int32]) -> F32:  # assign2: (K, M)
    """Per pixel, the disparity of the plane with the lowest aggregated cost among the planes of the segments
    within ``radius`` (its own first; another wins only when cheaper by more than ``margin``).

    Post-processing beyond the thesis (the ``boundary`` step) with no equation of its own; the planes are those of
    thesis Eq. 6.1.
    """
    h, w = seg.shape
    nd = cost.shape[2]
    out = np.empty((h, w), np.float32)
    nm = assign2.shape[1] + 1
    nseg = assign.shape[0]
    nlab = planes.shape[0]
    for y in prange(h):  # pixels are independent: rows in parallel, same result
        cand = np.empty(nm * (2 * radius + 1) ** 2, np.int64)
        # the candidates in order of first appearance in the window, deduplicated in O(1) by stamping each
        # segment and label seen with the pixel's column
        seen_seg = np.full(nseg, -1, np.int64)
        seen_lab = np.full(nlab, -1, np.int64)
        for x in range(w):
            own = assign[seg[y, x]]
            nc = 0
            if not active[y, x]:
                pl = planes[own]
                out[y, x] = pl[0] * x + pl[1] * y + pl[2]
                continue
            for yy in range(max(0, y - radius), min(h, y + radius + 1)):
                for xx in range(max(0, x - radius), min(w, x + radius + 1)):
                    sg = seg[yy, xx]
                    if seen_seg[sg] == x:
                        continue
                    seen_seg[sg] = x
                    for m in range(nm):
                        lab = assign[sg] if m == 0 else assign2[sg, m - 1]
                        if lab != own and lab >= 0 and seen_lab[lab] != x:
                            seen_lab[lab] = x
                            cand[nc] = lab
                            nc += 1
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


@njit(cache=True, nogil=True)
def _pair_ranks(a: npt.NDArray[np.int64], b: npt.NDArray[np.int64]) -> npt.NDArray[np.int32]:
    """Rank of each pixel's pair ``(a, b)`` among the distinct pairs in lexicographic order (labels >= 0):
    ``np.unique`` of the pairs' inverse, by two stable counting sorts.

    Implementation helper (ranking of label pairs) with no thesis equation of its own.
    """
    n = a.size
    out = np.empty(n, np.int32)
    if n == 0:
        return out
    order = np.arange(n)
    for key in (b, a):  # least significant key first
        m = int(key.max()) + 2
        cnt = np.zeros(m, np.int64)
        for i in range(n):
            cnt[key[i] + 1] += 1
        for j in range(m - 1):
            cnt[j + 1] += cnt[j]
        nxt = np.empty(n, np.int64)
        for t in range(n):
            i = order[t]
            nxt[cnt[key[i]]] = i
            cnt[key[i]] += 1
        order = nxt
    r = -1
    pa = -1
    pb = -1
    for t in range(n):
        i = order[t]
        if a[i] != pa or b[i] != pb:
            r += 1
            pa = a[i]
            pb = b[i]
        out[i] = r
    return out


@njit(cache=True, nogil=True)
def _plane_support(order: npt.NDArray[np.int64], starts: npt.NDArray[np.int64], w: int,
                   planes: npt.NDArray[np.float64], assign: npt.NDArray[np.int64], evidence: npt.NDArray[np.bool_],
                   reference: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Per segment, its ``evidence`` pixels within 1 px of ``reference`` under its plane ``assign``.

    The support count is like the outlier rule of thesis Eq. 6.9 (distance to the plane within 1 px); no equation of its
    own.
    """
    k = starts.size - 1
    out = np.zeros(k)
    for j in range(k):
        a, b, c = planes[assign[j], 0], planes[assign[j], 1], planes[assign[j], 2]
        n = 0
        for t in range(starts[j], starts[j + 1]):
            p = order[t]
            if evidence[p] and abs(a * float(p % w) + b * float(p // w) + c - reference[p]) <= 1.0:
                n += 1
        out[j] = n
    return out


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
    (-1 none).

    Planes fitted by thesis §6.1 (Eqs. 6.1-6.10) and merged by §6.1.3 (Eqs. 6.14-6.17), then the cooperative
    optimisation of §6.2 (Eq. 6.19).
    """
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


@dataclass(frozen=True)
class DataTerm:
    """The data term a cooperative optimisation reads (Eqs. 6.21-6.22; :func:`cooperative_optimize`'s ``cost``,
    ``reliable``, ``min_disp`` and ``slopes``).

    Attributes
    ----------
    cost : (H, W, D) or (S, H, W, D) float32   pixel cost, slice ``k`` at disparity ``min_disp + k`` (one volume
        per vertical slope of ``slopes`` when 4-D).
    reliable : (H, W) bool                     cross-check mask of the data term.
    min_disp : int                              disparity of slice 0.
    slopes : tuple of float or None            the slopes of a 4-D ``cost`` (None: one volume).
    """

    cost: F32
    reliable: npt.NDArray[np.bool_]
    min_disp: int = 0
    slopes: tuple[float, ...] | None = None


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
                         assign: npt.NDArray[np.int32], planes: npt.NDArray[np.float64], data: DataTerm,
                         evidence: npt.NDArray[np.bool_], reference: F32, *,
                         segmentation: SegmentationParams, coop: CoopParams, beta_scale: float = 1.0,
                         check: int | None = 1, fine: npt.NDArray[np.int32] | None = None) -> FineSegments:
    """Finer segments along plane boundaries resume the cooperative optimisation (an addition to §6.2).

    The image is segmented again with ``segmentation`` (a smaller range radius) and intersected with
    ``labels``; each fine segment starts from its segment's plane, and those touching a fine segment on
    another plane may take a neighbour's plane by the cooperative scheme (Eq. 6.19) on ``data``. A move is
    kept only when at least ``check`` more of the fine segment's ``evidence`` pixels lie within 1 px of
    ``reference`` under the new plane than under the old (0: not fewer; None = keep every move).

    Parameters
    ----------
    image : (H, W, 3) uint8 reference image.
    labels : (H, W) int32 segments; assign : (K,) plane per segment; planes : (L, 3).
    data : DataTerm the data term's cost volume(s), cross-check mask, first disparity and slopes.
    evidence : (H, W) bool pixels whose ``reference`` disparity is trusted.
    reference : (H, W) float32 disparity map the moves are checked against.
    fine : (H, W) int32, optional
        ``mean_shift_segment(image, params=segmentation)`` when already computed.
    """
    if fine is None:
        fine = mean_shift_segment(image, params=segmentation)
    flab = _pair_ranks(np.ascontiguousarray(labels.ravel(), dtype=np.int64),
                       np.ascontiguousarray(fine.ravel(), dtype=np.int64)).reshape(labels.shape)
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
    new, planes_out, info = cooperative_optimize(fa, planes, findex, fgraph, data.cost, data.reliable, own=fown,
                                                 min_disp=data.min_disp, active=active, slopes=data.slopes,
                                                 params=dataclasses.replace(coop, neighbour_own_planes=False))
    moved = np.flatnonzero(new != fa)
    if check is not None and moved.size:
        # the data term of a 10-pixel segment is noisy: the trusted initial disparities may veto the move
        w = labels.shape[1]
        ev = np.ascontiguousarray(evidence, dtype=bool).ravel()
        ref = np.ascontiguousarray(reference, dtype=np.float64).ravel()
        pl_out = np.ascontiguousarray(planes_out, dtype=np.float64)
        sn = _plane_support(findex.order, findex.starts, w, pl_out, np.asarray(new, np.int64), ev, ref)
        so = _plane_support(findex.order, findex.starts, w, pl_out, np.asarray(fa, np.int64), ev, ref)
        undo = moved[sn[moved] < so[moved] + check]
        new = new.copy()
        new[undo] = fa[undo]
    info = {**info, "fine_segments": float(parent.size), "fine_moves": float((new != fa).sum())}
    return FineSegments(flab, parent, findex, new.astype(np.int32), planes_out, info)
