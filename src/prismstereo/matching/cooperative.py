"""Cooperative optimisation of the segment energy over disparity-plane labels (thesis §6.2).

Each segment ``s_j`` carries a disparity plane drawn from the set of fitted planes. Its energy is (Eq. 6.20)

    E_j(l) = E_data + E_occ + E_smooth

with (Eq. 6.21) the aggregated matching cost of its pixels at the plane's disparities, reliable pixels at full
weight and cross-check failures at ``unreliable_weight``; (Eq. 6.22) ``ω_occ`` for every pixel the plane sends
out of the right image or outside the search range; and (Eqs. 6.23-6.25) for every 4-neighbour pixel pair
across the segment's boundary whose plane disparities differ by at least ``smooth_threshold`` the
contrast-sensitive weight ``γ · exp(-β |I_p - I_q|²)``, ``β = (2 <|I_p - I_q|²>)⁻¹``.

The total energy is ``E = Σ_j E_j`` (Eq. 6.18). The cooperative scheme (Eq. 6.19) lets segment ``j`` minimise
``(1 - κ) E_j + κ Σ_i μ_ji E_i`` over its neighbours ``i``; as a function of ``l_j`` this equals
``(1 - κ) E_data,j + Σ_i (1 - κ + κ μ_ji) S_ji`` plus terms that do not depend on ``l_j``. The minimiser tries
every plane in the segment's candidate set (its own fitted plane, its merged-cluster plane, and its
neighbours' current planes), which is exact over that set (Powell's method of Appendix E searches the same
objective locally and continuously and cannot do better than the exhaustive search over the candidates it
would have to reach). A move is kept only when it lowers the cooperative objective and does not raise the
total energy E, so E never increases from one iteration to the next; iterations stop when no segment
changes. With ``κ = 0.5`` and ``μ_ji = 1`` the cooperative objective is exactly ``ΔE / 2``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from numba import njit

from prismstereo.matching.planes import SegmentIndex

log = logging.getLogger(__name__)

__all__ = ["CoopParams", "SegmentGraph", "build_segment_graph", "cooperative_optimize", "total_energy"]

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
I32 = npt.NDArray[np.int32]
I64 = npt.NDArray[np.int64]


@dataclass(frozen=True)
class CoopParams:
    """Parameters of the energy (Eqs. 6.20-6.25) and of the cooperative scheme (Eqs. 6.18-6.19).

    Attributes
    ----------
    kappa : float
        ``κ_j`` of Eq. 6.19 (thesis: 0.5), the weight of the neighbours' energies.
    mu : float
        ``μ_ji`` of Eq. 6.19, the same for every neighbour (1 keeps the scheme an exact descent of E).
    omega_occ : float
        ``ω_occ`` of Eq. 6.22, penalty per occluded pixel (cost units).
    gamma : float
        ``γ`` of Eq. 6.24, smoothness weight per boundary pixel pair (cost units).
    smooth_threshold : float
        Disparity jump (px) across a boundary from which Eq. 6.24 charges the penalty (thesis: 1).
    data_trunc : float
        Truncation of the per-pixel aggregated cost in Eq. 6.21 (robustness to occlusions).
    unreliable_weight : float
        Weight of cross-check failures in the data term (thesis: 0, only reliable pixels ``N_r``).
    max_iter : int
        Cap on the sweeps over all segments.
    """

    kappa: float = 0.5
    mu: float = 1.0
    omega_occ: float = 1.0
    gamma: float = 1.0
    smooth_threshold: float = 1.0
    data_trunc: float = 1.5
    unreliable_weight: float = 1.0
    max_iter: int = 30


@dataclass(frozen=True)
class SegmentGraph:
    """Adjacency of segments and their boundary pixel pairs.

    Attributes
    ----------
    pairs : (P, 2) int32
        Adjacent segments ``(lo, hi)``, ``lo < hi``.
    bstart : (P + 1,) int64
        Boundary pixel pairs of pair ``e`` are ``bp_lo[bstart[e]:bstart[e+1]]`` / ``bp_hi[...]``.
    bp_lo, bp_hi : (B,) int64
        Flat pixel index on the ``lo`` side and on the ``hi`` side of each boundary pixel pair.
    bw : (B,) float64
        ``exp(-β |I_p - I_q|²)`` of each boundary pixel pair (Eq. 6.24 without γ; distance 1).
    nstart : (K + 1,) int64
        Neighbours of segment ``j`` are ``nbr[nstart[j]:nstart[j+1]]`` through pairs ``nedge[...]``.
    nbr, nedge : (2P,) int64
    """

    pairs: I32
    bstart: I64
    bp_lo: I64
    bp_hi: I64
    bw: F64
    nstart: I64
    nbr: I64
    nedge: I64


def build_segment_graph(labels: npt.NDArray[np.integer], image: npt.NDArray[np.generic]) -> SegmentGraph:
    """Segment adjacency (Eq. 6.11) and contrast weights of boundary pixel pairs (Eqs. 6.24-6.25).

    Parameters
    ----------
    labels : (H, W) int, labels 0..K-1.
    image : (H, W, 3) or (H, W) reference image (0..255).
    """
    lab = np.asarray(labels).astype(np.int64)
    h, w = lab.shape
    k = int(lab.max()) + 1
    img = np.asarray(image, dtype=np.float64)
    if img.ndim == 2:
        img = img[:, :, None]
    idx = np.arange(h * w, dtype=np.int64).reshape(h, w)
    dh = ((img[:, :-1] - img[:, 1:]) ** 2).sum(axis=2)
    dv = ((img[:-1, :] - img[1:, :]) ** 2).sum(axis=2)
    beta = 1.0 / (2.0 * max(float(np.concatenate([dh.ravel(), dv.ravel()]).mean()), 1e-9))  # Eq. 6.25
    ps, qs, ds = [], [], []
    for a, b, p, q, d in ((lab[:, :-1], lab[:, 1:], idx[:, :-1], idx[:, 1:], dh),
                          (lab[:-1, :], lab[1:, :], idx[:-1, :], idx[1:, :], dv)):
        m = a != b
        swap = (a > b)[m]
        pm, qm = p[m], q[m]
        ps.append(np.where(swap, qm, pm))
        qs.append(np.where(swap, pm, qm))
        ds.append(d[m])
    p_lo = np.concatenate(ps)
    p_hi = np.concatenate(qs)
    dd = np.concatenate(ds)
    flat = lab.ravel()
    key = flat[p_lo] * k + flat[p_hi]
    order = np.argsort(key, kind="stable")
    key, p_lo, p_hi, dd = key[order], p_lo[order], p_hi[order], dd[order]
    uniq, first = np.unique(key, return_index=True)
    bstart = np.append(first, key.size).astype(np.int64)
    pairs = np.stack([uniq // k, uniq % k], axis=1).astype(np.int32)
    # neighbour lists
    npairs = pairs.shape[0]
    src = np.concatenate([pairs[:, 0], pairs[:, 1]]).astype(np.int64)
    dst = np.concatenate([pairs[:, 1], pairs[:, 0]]).astype(np.int64)
    edge = np.concatenate([np.arange(npairs), np.arange(npairs)]).astype(np.int64)
    o = np.argsort(src, kind="stable")
    nstart = np.zeros(k + 1, np.int64)
    np.cumsum(np.bincount(src, minlength=k), out=nstart[1:])
    return SegmentGraph(pairs, bstart, p_lo, p_hi, np.exp(-beta * dd), nstart, dst[o], edge[o])


@njit(cache=True)
def _data(j: int, pl: F64, order: I64, starts: I64, w: int, cost: F32, min_disp: int,
          reliable: npt.NDArray[np.bool_], omega_occ: float, trunc: float, wu: float) -> float:
    """E_data + E_occ of segment j under plane pl (Eqs. 6.21-6.22)."""
    nd = cost.shape[1]
    e = 0.0
    a, b, c = pl[0], pl[1], pl[2]
    for t in range(starts[j], starts[j + 1]):
        p = order[t]
        x = p % w
        y = p // w
        d = a * x + b * y + c
        k = d - min_disp
        if k < -0.5 or k > nd - 0.5 or x - d < -0.5:
            e += omega_occ
            continue
        k = min(max(k, 0.0), nd - 1.0)
        k0 = int(k)
        k1 = min(k0 + 1, nd - 1)
        f = k - k0
        v = (1.0 - f) * cost[p, k0] + f * cost[p, k1]
        v = min(v, trunc)
        e += v if reliable[p] else wu * v
    return e


@njit(cache=True)
def _smooth(j: int, i: int, edge: int, plj: F64, pli: F64, pairs: I32, bstart: I64, bp_lo: I64, bp_hi: I64,
            bw: F64, w: int, thr: float) -> float:
    """Σ over the boundary of (j, i) of exp(-β ΔI²) [|d_j(p) - d_i(q)| ≥ thr] (Eq. 6.24 without γ)."""
    s = 0.0
    jlo = pairs[edge, 0] == j
    for t in range(bstart[edge], bstart[edge + 1]):
        if jlo:
            pj = bp_lo[t]
            pi = bp_hi[t]
        else:
            pj = bp_hi[t]
            pi = bp_lo[t]
        dj = plj[0] * (pj % w) + plj[1] * (pj // w) + plj[2]
        di = pli[0] * (pi % w) + pli[1] * (pi // w) + pli[2]
        if abs(dj - di) >= thr:
            s += bw[t]
    return s


@njit(cache=True)
def _energy(assign: I32, planes: F64, order: I64, starts: I64, w: int, cost: F32, min_disp: int,
            reliable: npt.NDArray[np.bool_], pairs: I32, bstart: I64, bp_lo: I64, bp_hi: I64, bw: F64,
            omega_occ: float, trunc: float, wu: float, gamma: float, thr: float) -> float:
    k = starts.size - 1
    e = 0.0
    for j in range(k):
        e += _data(j, planes[assign[j]], order, starts, w, cost, min_disp, reliable, omega_occ, trunc, wu)
    for ed in range(pairs.shape[0]):
        lo = pairs[ed, 0]
        hi = pairs[ed, 1]
        if assign[lo] != assign[hi]:
            # each boundary appears in both segments' energies (Eq. 6.18)
            e += 2.0 * gamma * _smooth(lo, hi, ed, planes[assign[lo]], planes[assign[hi]], pairs, bstart,
                                       bp_lo, bp_hi, bw, w, thr)
    return e


@njit(cache=True)
def _coop(assign: I32, own: I64, planes: F64, order: I64, starts: I64, w: int, cost: F32, min_disp: int,
          reliable: npt.NDArray[np.bool_], pairs: I32, bstart: I64, bp_lo: I64, bp_hi: I64, bw: F64,
          nstart: I64, nbr: I64, nedge: I64, kappa: float, mu: float, omega_occ: float, trunc: float,
          wu: float, gamma: float, thr: float, max_iter: int) -> tuple[I32, int, int]:
    k = starts.size - 1
    a = assign.copy()
    cand = np.empty(64, np.int64)
    sweeps = 0
    changes_total = 0
    for _sweep in range(max_iter):
        sweeps += 1
        changes = 0
        for j in range(k):
            # candidate planes: current, own fitted/merged planes, neighbours' current planes
            nc = 0
            cand[nc] = a[j]
            nc += 1
            for extra in (own[2 * j], own[2 * j + 1]):
                if extra >= 0:
                    dup = False
                    for u in range(nc):
                        if cand[u] == extra:
                            dup = True
                    if not dup and nc < 64:
                        cand[nc] = extra
                        nc += 1
            for t in range(nstart[j], nstart[j + 1]):
                lab = a[nbr[t]]
                dup = False
                for u in range(nc):
                    if cand[u] == lab:
                        dup = True
                if not dup and nc < 64:
                    cand[nc] = lab
                    nc += 1
            if nc == 1:
                continue
            cur_e = 0.0
            best_f = 0.0
            best = a[j]
            for u in range(nc):
                lab = cand[u]
                dj = _data(j, planes[lab], order, starts, w, cost, min_disp, reliable, omega_occ, trunc, wu)
                sm_f = 0.0
                sm = 0.0
                for t in range(nstart[j], nstart[j + 1]):
                    i = nbr[t]
                    if a[i] == lab:
                        continue
                    s = gamma * _smooth(j, i, nedge[t], planes[lab], planes[a[i]], pairs, bstart, bp_lo, bp_hi,
                                        bw, w, thr)
                    sm += s
                    sm_f += (1.0 - kappa + kappa * mu) * s
                f = (1.0 - kappa) * dj + sm_f  # Eq. 6.19 as a function of l_j
                e = dj + 2.0 * sm  # the part of E (Eq. 6.18) that depends on l_j
                if u == 0:
                    cur_e, best_f = e, f
                elif f < best_f - 1e-9 and e <= cur_e + 1e-9:
                    best_f = f
                    best = lab
            if best != a[j]:
                a[j] = best
                changes += 1
        changes_total += changes
        if changes == 0:
            break
    return a, sweeps, changes_total


def _flat_cost(cost: F32) -> F32:
    h, w, d = cost.shape
    return np.ascontiguousarray(cost.reshape(h * w, d), dtype=np.float32)


def total_energy(assign: npt.NDArray[np.integer], planes: F64, index: SegmentIndex, graph: SegmentGraph,
                 cost: F32, reliable: npt.NDArray[np.bool_], *, min_disp: int = 0,
                 params: CoopParams | None = None) -> float:
    """Total energy ``E = Σ_j E_j`` (Eq. 6.18) of a plane assignment.

    Parameters
    ----------
    assign : (K,) int, plane index per segment.
    planes : (L, 3) float64 plane set ``(a, b, c)``.
    index, graph : segment pixels and adjacency.
    cost : (H, W, D) float32 aggregated cost of the left view, slice k = disparity ``min_disp + k``.
    reliable : (H, W) bool cross-check mask (Eq. 6.7).
    """
    p = params or CoopParams()
    return float(_energy(np.asarray(assign, np.int32), np.asarray(planes, np.float64), index.order,
                         index.starts, index.shape[1], _flat_cost(cost), int(min_disp),
                         np.asarray(reliable, np.bool_).ravel(), graph.pairs, graph.bstart, graph.bp_lo,
                         graph.bp_hi, graph.bw, p.omega_occ, p.data_trunc, p.unreliable_weight, p.gamma,
                         p.smooth_threshold))


def cooperative_optimize(assign: npt.NDArray[np.integer], planes: F64, index: SegmentIndex,
                         graph: SegmentGraph, cost: F32, reliable: npt.NDArray[np.bool_], *,
                         own: npt.NDArray[np.integer] | None = None, min_disp: int = 0,
                         params: CoopParams | None = None) -> tuple[I32, dict[str, float]]:
    """Cooperative optimisation of the plane labels (thesis §6.2, Eqs. 6.18-6.25).

    Parameters
    ----------
    assign : (K,) int
        Initial plane index per segment (every segment must have one).
    planes : (L, 3) float64
        The plane set (fitted and merged planes).
    index, graph : SegmentIndex, SegmentGraph
    cost : (H, W, D) float32
        Aggregated matching cost of the left view (slice k = disparity ``min_disp + k``).
    reliable : (H, W) bool
        Cross-check mask (Eq. 6.7).
    own : (K, 2) int, optional
        Extra candidate planes of each segment (its own fitted plane and its cluster plane; -1 = none).
    min_disp : int, keyword-only
    params : CoopParams, keyword-only

    Returns
    -------
    assign : (K,) int32
        Optimised plane index per segment.
    info : dict
        ``energy_before``, ``energy_after`` (Eq. 6.18), ``sweeps``, ``changes``.
    """
    p = params or CoopParams()
    a0 = np.asarray(assign, np.int32)
    k = a0.size
    own_arr = np.full((k, 2), -1, np.int64) if own is None else np.asarray(own, np.int64).reshape(k, 2)
    fc = _flat_cost(cost)
    rel = np.asarray(reliable, np.bool_).ravel()
    pl = np.ascontiguousarray(planes, np.float64)
    common = (index.order, index.starts, index.shape[1], fc, int(min_disp), rel, graph.pairs, graph.bstart,
              graph.bp_lo, graph.bp_hi, graph.bw)
    e0 = _energy(a0, pl, *common, p.omega_occ, p.data_trunc, p.unreliable_weight, p.gamma, p.smooth_threshold)
    a, sweeps, changes = _coop(a0, own_arr.ravel(), pl, *common, graph.nstart, graph.nbr, graph.nedge,
                               p.kappa, p.mu, p.omega_occ, p.data_trunc, p.unreliable_weight, p.gamma,
                               p.smooth_threshold, p.max_iter)
    e1 = _energy(a, pl, *common, p.omega_occ, p.data_trunc, p.unreliable_weight, p.gamma, p.smooth_threshold)
    log.debug("cooperative optimisation: E %.1f -> %.1f in %d sweeps (%d changes)", e0, e1, sweeps, changes)
    return a, {"energy_before": float(e0), "energy_after": float(e1), "sweeps": float(sweeps),
               "changes": float(changes)}
