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
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt
from numba import njit, prange

from prismstereo.checks import check_fields
from prismstereo.matching.segments.planes import SegmentIndex

log = logging.getLogger(__name__)

__all__ = ["CoopMemo", "CoopParams", "SegmentGraph", "build_segment_graph", "cooperative_optimize", "expand_planes",
           "neighbour_plane_candidates", "total_energy"]

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
    visibility : bool
        Count as occluded (Eq. 6.22) the pixels that another segment hides in the right view.
    occ_margin : float
        A pixel is hidden when another segment lands on its right-view pixel with a disparity larger by
        more than this (px).
    omega_border : float
        Cost of a pixel that the plane sends left of the right image's border (x - d < 0): no evidence
        either way, so a typical good-match cost rather than ``ω_occ`` (which would push segments at the
        left border towards small disparities).
    neighbour_own_planes : bool
        Also offer each segment its neighbours' own fitted and cluster planes (not only their current ones).
    refine_rounds : int
        Rounds of continuous per-segment refinement by Powell's method (Appendix E), each followed by
        discrete sweeps in which neighbours may adopt the refined planes (0 = discrete labels only).
    powell_cycles : int
        Direction-set cycles of Powell's method per segment and round.
    refine_min_size : int
        Segments smaller than this (pixels) are not refined continuously.
    """

    kappa: float = 0.5
    mu: float = 1.0
    omega_occ: float = 1.0
    gamma: float = 0.5
    smooth_threshold: float = 1.0
    data_trunc: float = 1.5
    unreliable_weight: float = 1.0
    max_iter: int = 30
    visibility: bool = True
    occ_margin: float = 1.0
    refine_rounds: int = 0
    omega_border: float = 1.0
    neighbour_own_planes: bool = False
    powell_cycles: int = 2
    refine_min_size: int = 1

    def __post_init__(self) -> None:
        """Validate the fields; implementation helper with no thesis equation of its own."""
        check_fields(self, {"kappa": (0.0, None), "mu": (0.0, None), "omega_occ": (0.0, None), "gamma": (0.0, None),
                            "smooth_threshold": (0.0, None), "unreliable_weight": (0.0, None), "max_iter": (0, 10_000),
                            "occ_margin": (0.0, None), "refine_rounds": (0, 100), "omega_border": (0.0, None),
                            "powell_cycles": (0, 100), "refine_min_size": (0, None)}, positive=("data_trunc",))


class KernelParams(NamedTuple):
    """:class:`CoopParams` as the numba kernels read them (:func:`_prm`): the energy's weights as float64, the
    flags as bool, and the vertical slopes of the cost volumes (a plane's data term reads the volume of the
    slope nearest its ``b``; ``[0.0]`` for one volume). Attributes as in :class:`CoopParams`."""

    kappa: float
    mu: float
    omega_occ: float
    data_trunc: float
    unreliable_weight: float
    gamma: float
    smooth_threshold: float
    occ_margin: float
    visibility: bool
    omega_border: float
    neighbour_own_planes: bool
    slopes: F64


class PixelData(NamedTuple):
    """The pixels of the segments and their matching costs, as the kernels read them (:func:`_pixel_data`).

    Attributes
    ----------
    order, starts : (H*W,), (K+1,) int64
        Flat pixel indices of segment ``j`` are ``order[starts[j]:starts[j+1]]`` (:class:`SegmentIndex`).
    w : int
        Image width.
    cost : (S, H*W, D) float32
        Pixel cost per slope volume, slice k = disparity ``min_disp + k`` (:func:`_flat_cost`).
    min_disp : int
    reliable : (H*W,) bool
        Cross-check mask (Eq. 6.7).
    """

    order: I64
    starts: I64
    w: int
    cost: F32
    min_disp: int
    reliable: npt.NDArray[np.bool_]


class GraphArrays(NamedTuple):
    """:class:`SegmentGraph`'s arrays as the kernels read them (:func:`_graph_arrays`); fields as there."""

    pairs: I32
    bstart: I64
    bp_lo: I64
    bp_hi: I64
    bw: F64
    nstart: I64
    nbr: I64
    nedge: I64


class SweepCache(NamedTuple):
    """What :func:`_sweep`, :func:`_energy_cached` and :func:`_expand` remember across calls (:func:`_new_cache`);
    the arrays are updated in place.

    Attributes
    ----------
    zc1, oc1, zc2 : (H*W,) float64, int64, float64
        The right-view z-buffer last computed (:func:`_zbuffer`): largest disparity, its segment, and the
        largest disparity of any other segment at each right-view pixel.
    zvalid : (1,) bool
        Whether ``zc1, oc1, zc2`` hold a z-buffer at all.
    zfor : (K,) int32
        The assignment the z-buffer is of.
    bbox : (K, 4) int64
        Each segment's x_min, x_max, y_min, y_max (:func:`_segment_bbox`).
    clab, cval : (K, 64) int64, float64
        Per segment, the planes whose data terms (Eqs. 6.21-6.22) are remembered and the terms.
    cn : (K,) int64
        How many of them are held.
    clean : (K,) bool
        Segments whose last sweep decision still holds (:func:`_sweep`).
    afor : (K,) int32
        The assignment ``clean`` is of.
    rstart, rp, rseg : (H+1,), (H*W,), (H*W,) int64
        The image's pixels by row and their segments (:func:`_zbuffer_rows`).
    sstart, srun : (K+1,), (R+1, 4) int64
        Each segment's runs of pixels of one row (:func:`_vis_flips`).
    elab, es : (P, 2) int64, (P,) float64
        Per boundary, the planes its smoothness term (Eq. 6.24) was last computed for, and the term; empty
        (0 entries) when not remembered (:func:`_take_cache` adds them for one call).
    """

    zc1: F64
    oc1: I64
    zc2: F64
    zvalid: npt.NDArray[np.bool_]
    zfor: I32
    bbox: I64
    clab: I64
    cval: F64
    cn: I64
    clean: npt.NDArray[np.bool_]
    afor: I32
    rstart: I64
    rp: I64
    rseg: I64
    sstart: I64
    srun: I64
    elab: I64
    es: F64


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


def build_segment_graph(labels: npt.NDArray[np.integer], image: npt.NDArray[np.generic], *,
                        beta_scale: float = 1.0) -> SegmentGraph:
    """Segment adjacency (Eq. 6.11) and contrast weights of boundary pixel pairs (Eqs. 6.24-6.25).

    Parameters
    ----------
    labels : (H, W) int, labels 0..K-1.
    image : (H, W, 3) or (H, W) reference image (0..255).
    beta_scale : float, keyword-only
        Multiplier on β of Eq. 6.25 (1 = the thesis's choice).
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
    beta = beta_scale / (2.0 * max(float(np.concatenate([dh.ravel(), dv.ravel()]).mean()), 1e-9))  # Eq. 6.25
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


@njit(cache=True, inline="always")
def _xy(p: int, w: int, inv_w: float) -> tuple[int, int]:
    """``(p % w, p // w)`` of a pixel index ``p >= 0`` by a multiply and one correction instead of an integer
    division (the hot loops' largest cost per pixel); exact: ``p · (1/w)`` is off by less than one row.

    Implementation helper (pixel-index arithmetic) with no thesis equation of its own.
    """
    y = int(p * inv_w)
    x = p - y * w
    if x < 0:
        y -= 1
        x += w
    elif x >= w:
        y += 1
        x -= w
    return x, y


@njit(cache=True)
def _zinsert(z1: F64, o1: I64, z2: F64, q: int, j: int, d: float) -> None:
    """Enter disparity ``d`` of segment ``j`` at right-view pixel ``q`` of the z-buffer ``z1, o1, z2``.

    Implementation helper of :func:`_zbuffer`, the visibility test that counts ``N_occ`` of thesis Eq. 6.22; no equation
    of its own.
    """
    if o1[q] == j:
        if d > z1[q]:
            z1[q] = d
    elif d > z1[q]:
        z2[q] = z1[q]
        z1[q] = d
        o1[q] = j
    elif d > z2[q]:
        z2[q] = d


@njit(cache=True)
def _zbuffer(assign: I32, planes: F64, order: I64, starts: I64, h: int, w: int,
             ) -> tuple[F64, I64, F64]:
    """Right-view z-buffer of a plane assignment: largest disparity landing on each right pixel (z1, owner
    segment o1) and the largest from any other segment (z2), for the visibility test of Eq. 6.22."""
    z1 = np.full(h * w, -1e9)
    z2 = np.full(h * w, -1e9)
    o1 = np.full(h * w, -1, np.int64)
    k = starts.size - 1
    inv_w = 1.0 / w
    for j in range(k):
        pl = planes[assign[j]]
        for t in range(starts[j], starts[j + 1]):
            p = order[t]
            x, y = _xy(p, w, inv_w)
            d = pl[0] * x + pl[1] * y + pl[2]
            xr = int(np.floor(x - d + 0.5))
            if xr < 0 or xr >= w:
                continue
            _zinsert(z1, o1, z2, y * w + xr, j, d)
    return z1, o1, z2


@njit(cache=True)
def slope_level(levels: F64, b: float) -> int:
    """Index of the vertical slope in ``levels`` (S,) nearest a plane's slope ``b``: the volume of a sheared
    data term the plane reads (the first on ties; 0 for a single level).

    Implementation helper of the data term (thesis Eq. 6.21): it chooses the volume to read, no equation of its own.
    """
    lev = 0
    if levels.size > 1:
        dmin = np.inf
        for i in range(levels.size):
            dd = abs(levels[i] - b)
            if dd < dmin:
                dmin = dd
                lev = i
    return lev


@njit(cache=True)
def interpolated_cost(cost: F32, lev: int, p: int, k: float, trunc: float) -> float:
    """Pixel ``p``'s cost in volume ``lev`` of ``cost`` (S, H*W, D) at the fractional slice ``k`` (clamped to the
    volume), linearly interpolated, truncated at ``trunc`` (the data term of Eq. 6.21)."""
    nd = cost.shape[2]
    k = min(max(k, 0.0), nd - 1.0)
    k0 = int(k)
    k1 = min(k0 + 1, nd - 1)
    f = k - k0
    v = (1.0 - f) * cost[lev, p, k0] + f * cost[lev, p, k1]
    return min(v, trunc)


@njit(cache=True)
def _data(j: int, pl: F64, dt: PixelData, prm: KernelParams, z1: F64, o1: I64, z2: F64) -> float:
    """E_data + E_occ of segment j under plane pl (Eqs. 6.21-6.22).

    A pixel is occluded when its plane disparity sends it outside the right image or the search range, or
    (visibility on) when another segment lands on the same right pixel with a disparity larger by more than
    ``occ_margin``; it then costs ``ω_occ`` instead of its matching cost.
    """
    order, starts, w, cost, min_disp, reliable = dt
    omega_occ = prm.omega_occ
    trunc = prm.data_trunc
    wu = prm.unreliable_weight
    margin = prm.occ_margin
    vis = prm.visibility
    nd = cost.shape[2]
    e = 0.0
    a, b, c = pl[0], pl[1], pl[2]
    lev = slope_level(prm.slopes, b)  # the cost volume of the slope nearest the plane's
    inv_w = 1.0 / w
    for t in range(starts[j], starts[j + 1]):
        p = order[t]
        x, y = _xy(p, w, inv_w)
        d = a * x + b * y + c
        k = d - min_disp
        if k < -0.5 or k > nd - 0.5:
            e += omega_occ
            continue
        if x - d < -0.5:
            e += prm.omega_border  # outside the right image: no evidence either way
            continue
        if vis:
            xr = int(np.floor(x - d + 0.5))
            if 0 <= xr < w:
                q = y * w + xr
                zo = z1[q] if o1[q] != j else z2[q]
                if zo > d + margin:
                    e += omega_occ
                    continue
        v = interpolated_cost(cost, lev, p, k, trunc)
        e += v if reliable[p] else wu * v
    return e


@njit(cache=True)
def _smooth(j: int, i: int, edge: int, plj: F64, pli: F64, pairs: I32, bstart: I64, bp_lo: I64, bp_hi: I64,
            bw: F64, w: int, thr: float) -> float:
    """Σ over the boundary of (j, i) of exp(-β ΔI²) [|d_j(p) - d_i(q)| ≥ thr] (Eq. 6.24 without γ)."""
    s = 0.0
    jlo = pairs[edge, 0] == j
    inv_w = 1.0 / w
    for t in range(bstart[edge], bstart[edge + 1]):
        if jlo:
            pj = bp_lo[t]
            pi = bp_hi[t]
        else:
            pj = bp_hi[t]
            pi = bp_lo[t]
        xj, yj = _xy(pj, w, inv_w)
        xi, yi = _xy(pi, w, inv_w)
        dj = plj[0] * xj + plj[1] * yj + plj[2]
        di = pli[0] * xi + pli[1] * yi + pli[2]
        if abs(dj - di) >= thr:
            s += bw[t]
    return s


@njit(cache=True)
def _add_smoothness(e: float, assign: I32, planes: F64, g: GraphArrays, w: int, gamma: float, thr: float) -> float:
    """``e`` plus the smoothness term of every boundary between differently labelled segments, added one
    boundary at a time (Eq. 6.24; each boundary appears in both segments' energies, Eq. 6.18)."""
    pairs, bstart, bp_lo, bp_hi, bw = g.pairs, g.bstart, g.bp_lo, g.bp_hi, g.bw
    for ed in range(pairs.shape[0]):
        lo = pairs[ed, 0]
        hi = pairs[ed, 1]
        if assign[lo] != assign[hi]:
            e += 2.0 * gamma * _smooth(lo, hi, ed, planes[assign[lo]], planes[assign[hi]], pairs, bstart, bp_lo,
                                       bp_hi, bw, w, thr)
    return e


@njit(cache=True)
def _add_smoothness_cached(e: float, assign: I32, planes: F64, g: GraphArrays, w: int, gamma: float, thr: float,
                           elab: I64, es: F64) -> float:
    """:func:`_add_smoothness` with each boundary's term remembered for the planes it was last computed for
    (``elab[e]``, ``es[e]``): the same terms, added in the same order.

    Smoothness term, thesis Eqs. 6.23-6.24 (summed over the segments as in Eq. 6.18); the cache is an implementation
    detail.
    """
    pairs, bstart, bp_lo, bp_hi, bw = g.pairs, g.bstart, g.bp_lo, g.bp_hi, g.bw
    for ed in range(pairs.shape[0]):
        lo = pairs[ed, 0]
        hi = pairs[ed, 1]
        if assign[lo] != assign[hi]:
            if elab[ed, 0] == assign[lo] and elab[ed, 1] == assign[hi]:
                sm = es[ed]
            else:
                sm = _smooth(lo, hi, ed, planes[assign[lo]], planes[assign[hi]], pairs, bstart, bp_lo, bp_hi, bw, w,
                             thr)
                elab[ed, 0] = assign[lo]
                elab[ed, 1] = assign[hi]
                es[ed] = sm
            e += 2.0 * gamma * sm
    return e


@njit(cache=True)
def _energy(assign: I32, planes: F64, dt: PixelData, g: GraphArrays, prm: KernelParams) -> float:
    """Total energy E (Eq. 6.18) of the assignment ``assign``: each segment's data and occlusion terms
    (Eqs. 6.21-6.22) under the assignment's right-view z-buffer, plus the smoothness terms (Eq. 6.24)."""
    order, starts, w, cost, min_disp, reliable = dt
    k = starts.size - 1
    h = cost.shape[1] // w
    z1, o1, z2 = _zbuffer(assign, planes, order, starts, h, w)
    gamma = prm.gamma
    thr = prm.smooth_threshold
    e = 0.0
    for j in range(k):
        e += _data(j, planes[assign[j]], dt, prm, z1, o1, z2)
    return _add_smoothness(e, assign, planes, g, w, gamma, thr)


_CACHE = 64  # data terms remembered per segment (its candidates of the last sweeps)


@njit(cache=True)
def _vis_flips(j: int, pl: F64, dt: PixelData, cache: SweepCache, margin: float, chg: npt.NDArray[np.bool_],
               pre: I64, rcnt: I64, z1: F64, o1: I64, z2: F64) -> bool:
    """Whether the visibility test of :func:`_data` (the occlusion term of Eq. 6.22; segment ``j``, plane ``pl``)
    gives another answer for some pixel under the new z-buffer ``z1, o1, z2`` than under the old ``zc1, oc1, zc2``
    (``cache``'s). ``chg`` flags the right-view pixels where they differ, ``pre[y]`` counts them along row ``y``
    and ``rcnt`` over the rows above (:func:`_cache_refresh`); the segment's pixels are the runs
    ``order[srun[r, 1]:srun[r + 1, 1]]`` for ``r`` in ``sstart[j]:sstart[j + 1]``, each in row ``srun[r, 0]`` and
    columns ``srun[r, 2]..srun[r, 3]``. The same arithmetic as :func:`_data`, so that no answer means the same
    sum."""
    order, w, nd, min_disp = dt.order, dt.w, dt.cost.shape[2], dt.min_disp  # only what it reads: a hot call
    sstart, srun, zc1, oc1, zc2 = cache.sstart, cache.srun, cache.zc1, cache.oc1, cache.zc2
    a, b, c = pl[0], pl[1], pl[2]
    for r in range(sstart[j], sstart[j + 1]):
        y = srun[r, 0]
        if rcnt[y + 1] == rcnt[y]:
            continue
        t0 = srun[r, 1]
        t1 = srun[r + 1, 1]
        # the right-view columns the row's pixels map to, with one pixel of slack for the rounding of the
        # per-pixel evaluation (x - d is linear in x): no changed pixel there, no changed answer
        xa = srun[r, 2]
        xb = srun[r, 3]
        va = xa - (a * xa + b * y + c)
        vb = xb - (a * xb + b * y + c)
        if np.isfinite(va) and np.isfinite(vb):
            c0 = max(int(np.floor(min(va, vb) + 0.5)) - 1, 0)
            c1 = min(int(np.floor(max(va, vb) + 0.5)) + 1, w - 1)
            if c0 > c1 or pre[y, c1 + 1] == pre[y, c0]:
                continue
        for t in range(t0, t1):
            x = order[t] - y * w
            d = a * x + b * y + c
            k = d - min_disp
            if k < -0.5 or k > nd - 0.5:
                continue
            if x - d < -0.5:
                continue
            xr = int(np.floor(x - d + 0.5))
            if 0 <= xr < w:
                q = y * w + xr
                if chg[q]:
                    zn = z1[q] if o1[q] != j else z2[q]
                    zo = zc1[q] if oc1[q] != j else zc2[q]
                    if (zn > d + margin) != (zo > d + margin):
                        return True
    return False


@njit(cache=True, parallel=True)
def _zbuffer_rows(a: I32, planes: F64, cache: SweepCache, w: int, rows: npt.NDArray[np.bool_], z1: F64, o1: I64,
                  z2: F64) -> None:
    """:func:`_zbuffer` (the visibility of Eq. 6.22) of ``a`` on the right-view rows flagged in ``rows``, written
    into ``z1, o1, z2`` (other rows untouched). A right-view pixel is reached only from its own row, and each
    row's pixels are taken in the order :func:`_zbuffer` takes them (``cache.rstart, rp, rseg``: the pixels of
    row ``y`` and their segments are ``rp[rstart[y]:rstart[y + 1]]``, ``rseg[...]``), so the rows are the same
    as :func:`_zbuffer`'s."""
    rstart, rp, rseg = cache.rstart, cache.rp, cache.rseg
    for y in prange(rows.size):
        if not rows[y]:
            continue
        for q in range(y * w, (y + 1) * w):
            z1[q] = -1e9
            z2[q] = -1e9
            o1[q] = -1
        for t in range(rstart[y], rstart[y + 1]):
            j = rseg[t]
            x = rp[t] - y * w
            pl = planes[a[j]]
            d = pl[0] * x + pl[1] * y + pl[2]
            xr = int(np.floor(x - d + 0.5))
            if xr < 0 or xr >= w:
                continue
            _zinsert(z1, o1, z2, y * w + xr, j, d)


@njit(cache=True, parallel=True)
def _cache_refresh(z1: F64, o1: I64, z2: F64, rows: npt.NDArray[np.bool_], cache: SweepCache, planes: F64,
                   dt: PixelData, prm: KernelParams) -> None:
    """Moves the cache to the right-view z-buffer ``z1, o1, z2`` (which differs from the cache's at most on the
    flagged ``rows``, and is read only there) and drops the remembered data terms (Eqs. 6.21-6.22) it changes.

    An entry of segment ``j`` under plane ``l`` is dropped when the visibility test of one of its pixels gives
    another answer under the new z-buffer (:func:`_vis_flips`); otherwise every pixel contributes what it did,
    in the same order, so a remembered value is always the one :func:`_data` would return now. A segment that
    loses an entry is no longer ``clean`` (:func:`_sweep`)."""
    order, starts, w, cost, min_disp, reliable = dt
    (zc1, oc1, zc2, zvalid, zfor, bbox, clab, cval, cn, clean, afor, rstart, rp, rseg, sstart, srun, elab,
     es) = cache
    n = z1.size
    h = n // w
    k = cn.size
    if not zvalid[0]:
        cn[:] = 0
        clean[:] = False
    elif prm.visibility:  # without the visibility test no data term reads the z-buffer
        margin = prm.occ_margin
        chg = np.zeros(n, np.bool_)
        # per row, the running count of the changed right-view pixels (rows with none are not filled)
        pre = np.empty((h, w + 1), np.int64)
        rcnt = np.zeros(h + 1, np.int64)  # changed pixels in the rows above y
        for y in prange(h):
            if not rows[y]:
                continue
            run = 0
            pre[y, 0] = 0
            for x in range(w):
                q = y * w + x
                if z1[q] != zc1[q] or o1[q] != oc1[q] or z2[q] != zc2[q]:
                    run += 1
                    chg[q] = True
                pre[y, x + 1] = run
            rcnt[y + 1] = run
        for y in range(h):
            rcnt[y + 1] += rcnt[y]
        if rcnt[h] > 0:
            for j in prange(k):
                if rcnt[bbox[j, 3] + 1] == rcnt[bbox[j, 2]]:
                    continue
                t = 0
                while t < cn[j]:
                    if _vis_flips(j, planes[clab[j, t]], dt, cache, margin, chg, pre, rcnt, z1, o1, z2):
                        cn[j] -= 1
                        clab[j, t] = clab[j, cn[j]]
                        cval[j, t] = cval[j, cn[j]]
                        clean[j] = False
                    else:
                        t += 1
    for y in prange(h):
        if rows[y] or not zvalid[0]:
            for q in range(y * w, (y + 1) * w):
                zc1[q] = z1[q]
                oc1[q] = o1[q]
                zc2[q] = z2[q]
    zvalid[0] = True


@njit(cache=True)
def _zbuffer_cached(a: I32, planes: F64, dt: PixelData, cache: SweepCache, prm: KernelParams) -> tuple[F64, I64, F64]:
    """:func:`_zbuffer` (Eq. 6.22) of ``a``, the cache's own, with the remembered data terms refreshed to it
    (:func:`_cache_refresh`): only the rows of the segments whose plane changed since it was computed for
    ``zfor`` are computed again. The caller must not keep it past the next refresh."""
    order, starts, w, cost, min_disp, reliable = dt
    h = cost.shape[1] // w
    (zc1, oc1, zc2, zvalid, zfor, bbox, clab, cval, cn, clean, afor, rstart, rp, rseg, sstart, srun, elab,
     es) = cache
    rows = np.zeros(h, np.bool_)
    if zvalid[0]:
        same = True
        for j in range(a.size):
            if a[j] != zfor[j]:
                same = False
                rows[bbox[j, 2]:bbox[j, 3] + 1] = True
        if same:
            return zc1, oc1, zc2
    else:
        rows[:] = True
    z1 = np.empty(h * w)
    o1 = np.empty(h * w, np.int64)
    z2 = np.empty(h * w)
    _zbuffer_rows(a, planes, cache, w, rows, z1, o1, z2)
    _cache_refresh(z1, o1, z2, rows, cache, planes, dt, prm)
    zfor[:] = a
    return zc1, oc1, zc2


@njit(cache=True)
def _data_cached(j: int, lab: int, planes: F64, dt: PixelData, prm: KernelParams, z1: F64, o1: I64, z2: F64,
                 clab: I64, cval: F64, cn: I64) -> float:
    """:func:`_data` (Eqs. 6.21-6.22) of segment ``j`` under plane ``lab``, remembered until the z-buffer changes
    under it."""
    for t in range(cn[j]):
        if clab[j, t] == lab:
            return cval[j, t]
    v = _data(j, planes[lab], dt, prm, z1, o1, z2)
    if cn[j] >= clab.shape[1]:
        cn[j] = 0
    clab[j, cn[j]] = lab
    cval[j, cn[j]] = v
    cn[j] += 1
    return v


@njit(cache=True, parallel=True)
def _energy_cached(assign: I32, planes: F64, dt: PixelData, g: GraphArrays, prm: KernelParams,
                   cache: SweepCache) -> float:
    """:func:`_energy` (E of Eq. 6.18) with the data terms (and, with ``es`` of one entry per boundary, the
    smoothness terms) remembered across calls (the same value)."""
    order, starts, w, cost, min_disp, reliable = dt
    clab, cval, cn, elab, es = cache.clab, cache.cval, cache.cn, cache.elab, cache.es
    k = starts.size - 1
    z1, o1, z2 = _zbuffer_cached(assign, planes, dt, cache, prm)
    gamma = prm.gamma
    thr = prm.smooth_threshold
    # the data terms in parallel (each segment's cache rows are written by one thread), summed in order: the
    # same sum as one serial loop
    dj = np.empty(k)
    for j in prange(k):
        dj[j] = _data_cached(j, assign[j], planes, dt, prm, z1, o1, z2, clab, cval, cn)
    e = 0.0
    for j in range(k):
        e += dj[j]
    if es.size == g.pairs.shape[0]:
        return _add_smoothness_cached(e, assign, planes, g, w, gamma, thr, elab, es)
    return _add_smoothness(e, assign, planes, g, w, gamma, thr)


@njit(cache=True)
def _segment_bbox(order: I64, starts: I64, w: int) -> I64:
    """(K, 4) x_min, x_max, y_min, y_max of every segment.

    Implementation helper (segment bounding boxes for the caches) with no thesis equation of its own.
    """
    k = starts.size - 1
    out = np.empty((k, 4), np.int64)
    for j in range(k):
        x0 = w
        x1 = -1
        y0 = 1 << 40
        y1 = -1
        for t in range(starts[j], starts[j + 1]):
            x = order[t] % w
            y = order[t] // w
            x0 = min(x0, x)
            x1 = max(x1, x)
            y0 = min(y0, y)
            y1 = max(y1, y)
        out[j, 0] = x0
        out[j, 1] = max(x1, x0)
        out[j, 2] = y0 if y1 >= 0 else 0
        out[j, 3] = max(y1, y0) if y1 >= 0 else 0
    return out


@njit(cache=True, inline="always")
def _add_candidate(cand: I64, nc: int, lab: int) -> int:
    """Append plane ``lab`` to the first ``nc`` entries of ``cand`` unless it is there already, it is -1 (none)
    or 64 are held; returns the new count.

    Implementation helper (the candidate label set of the minimiser of thesis Eq. 6.19) with no equation of its own.
    """
    if lab < 0:
        return nc
    for u in range(nc):
        if cand[u] == lab:
            return nc
    if nc < 64:
        cand[nc] = lab
        nc += 1
    return nc


@njit(cache=True)
def _candidates(j: int, a: I32, own: I64, nstart: I64, nbr: I64, prm: KernelParams, cand: I64) -> int:
    """Candidate planes of segment j into ``cand`` (the labels the minimiser of Eq. 6.19 tries, thesis §6.2):
    current, own fitted/merged planes, neighbours' current planes (and with ``neighbour_own_planes`` theirs);
    returns their number (at most 64)."""
    nc = 0
    cand[nc] = a[j]
    nc += 1
    for extra in (own[2 * j], own[2 * j + 1]):
        nc = _add_candidate(cand, nc, extra)
    for t in range(nstart[j], nstart[j + 1]):
        for m in range(3 if prm.neighbour_own_planes else 1):
            nc = _add_candidate(cand, nc, a[nbr[t]] if m == 0 else own[2 * nbr[t] + m - 1])
    return nc


@njit(cache=True)
def _sweep(a: I32, own: I64, planes: F64, dt: PixelData, g: GraphArrays, prm: KernelParams,
           active: npt.NDArray[np.bool_], cache: SweepCache) -> int:
    """One cooperative sweep over the active segments (Eq. 6.19), in place; returns the number of changes.
    The data terms are remembered across sweeps (:func:`_data_cached`).

    A segment's decision depends only on its plane, its neighbours' planes at its turn and its candidates' data
    terms; a segment that kept its plane at its last turn is ``clean`` until one of them changes (a neighbour
    moves, a remembered data term is dropped), and its turn is skipped: it would keep its plane again."""
    nstart, nbr = g.nstart, g.nbr
    clean, afor = cache.clean, cache.afor
    zb = _zbuffer_cached(a, planes, dt, cache, prm)
    # a segment or a neighbour moved outside the sweeps (an undone sweep, a group move): decide again
    for j in range(a.size):
        if a[j] != afor[j]:
            clean[j] = False
            for t in range(nstart[j], nstart[j + 1]):
                clean[nbr[t]] = False
    changes = _sweep_turns(a, own, planes, dt, g, prm, active, zb, cache.clab, cache.cval, cache.cn, clean)
    afor[:] = a
    return changes


@njit(cache=True, parallel=True)
def _sweep_turns(a: I32, own: I64, planes: F64, dt: PixelData, g: GraphArrays, prm: KernelParams,
                 active: npt.NDArray[np.bool_], zb: tuple[F64, I64, F64], clab: I64, cval: F64, cn: I64,
                 clean: npt.NDArray[np.bool_]) -> int:
    """The turns of :func:`_sweep` (Eq. 6.19) under the right-view z-buffer ``zb`` (``z1, o1, z2``), with the
    remembered data terms ``clab, cval, cn`` and the ``clean`` flags of :class:`SweepCache`, passed as arrays:
    the parallel loops run measurably slower when the arrays they write come out of the cache's tuple
    (docs/EXPERIMENTS.md, issue 28, branch h-coop28)."""
    order, starts, w, cost, min_disp, reliable = dt
    pairs, bstart, bp_lo, bp_hi, bw, nstart, nbr, nedge = g
    z1, o1, z2 = zb
    k = starts.size - 1
    kappa = prm.kappa
    mu = prm.mu
    gamma = prm.gamma
    thr = prm.smooth_threshold
    # the data terms of the candidates at the sweep's start, and their smoothness terms towards each neighbour's
    # plane at the start, in parallel (each segment's rows are written by one thread); the serial sweep below
    # reads them, and computes what its own changes made new: a new candidate, a neighbour that moved
    a0 = a.copy()
    plab = np.full((k, 64), -1, np.int64)
    psm = np.empty(64 * nstart[k])
    for j in prange(k):
        if not active[j] or clean[j]:
            continue
        cj = np.empty(64, np.int64)
        ncj = _candidates(j, a, own, nstart, nbr, prm, cj)
        if ncj > 1:
            deg = nstart[j + 1] - nstart[j]
            for u in range(ncj):
                lab = cj[u]
                plab[j, u] = lab
                _data_cached(j, lab, planes, dt, prm, z1, o1, z2, clab, cval, cn)
                for t in range(nstart[j], nstart[j + 1]):
                    i = nbr[t]
                    if a[i] != lab:
                        psm[64 * nstart[j] + u * deg + t - nstart[j]] = gamma * _smooth(
                            j, i, nedge[t], planes[lab], planes[a[i]], pairs, bstart, bp_lo, bp_hi, bw, w, thr)
    cand = np.empty(64, np.int64)
    changes = 0
    for j in range(k):
        if not active[j] or clean[j]:
            continue
        nc = _candidates(j, a, own, nstart, nbr, prm, cand)
        if nc == 1:
            clean[j] = True
            continue
        cur_e = 0.0
        best_f = 0.0
        best = a[j]
        deg = nstart[j + 1] - nstart[j]
        for u in range(nc):
            lab = cand[u]
            dj = _data_cached(j, lab, planes, dt, prm, z1, o1, z2, clab, cval, cn)
            pu = -1
            for v in range(64):
                if plab[j, v] == lab:
                    pu = v
                    break
                if plab[j, v] < 0:
                    break
            sm_f = 0.0
            sm = 0.0
            for t in range(nstart[j], nstart[j + 1]):
                i = nbr[t]
                if a[i] == lab:
                    continue
                if pu >= 0 and a[i] == a0[i]:
                    s = psm[64 * nstart[j] + pu * deg + t - nstart[j]]
                else:
                    s = gamma * _smooth(j, i, nedge[t], planes[lab], planes[a[i]], pairs, bstart, bp_lo, bp_hi, bw, w,
                                        thr)
                sm += s
                sm_f += (1.0 - kappa + kappa * mu) * s
            f = (1.0 - kappa) * dj + sm_f  # Eq. 6.19 as a function of l_j
            e = dj + 2.0 * sm  # the part of E (Eq. 6.18) that depends on l_j (visibility held fixed)
            if u == 0:
                cur_e, best_f = e, f
            elif f < best_f - 1e-9 and e <= cur_e + 1e-9:
                best_f = f
                best = lab
        if best != a[j]:
            a[j] = best
            changes += 1
            for t in range(nstart[j], nstart[j + 1]):
                clean[nbr[t]] = False
        else:
            clean[j] = True
    return changes


@njit(cache=True)
def _local_f(j: int, pl: F64, a: I32, planes: F64, dt: PixelData, g: GraphArrays, prm: KernelParams, z1: F64, o1: I64,
             z2: F64) -> tuple[float, float]:
    """Cooperative objective (Eq. 6.19) and local part of E (Eq. 6.18) of segment j under plane pl."""
    w = dt.w
    pairs, bstart, bp_lo, bp_hi, bw, nstart, nbr, nedge = g
    kappa = prm.kappa
    mu = prm.mu
    gamma = prm.gamma
    thr = prm.smooth_threshold
    dj = _data(j, pl, dt, prm, z1, o1, z2)
    sm = 0.0
    for t in range(nstart[j], nstart[j + 1]):
        i = nbr[t]
        sm += gamma * _smooth(j, i, nedge[t], pl, planes[a[i]], pairs, bstart, bp_lo, bp_hi, bw, w, thr)
    return (1.0 - kappa) * dj + (1.0 - kappa + kappa * mu) * sm, dj + 2.0 * sm


@njit(cache=True)
def _powell(j: int, a: I32, planes: F64, n_used: int, dt: PixelData, g: GraphArrays, prm: KernelParams, z1: F64,
            o1: I64, z2: F64, cycles: int) -> tuple[F64, float, float]:
    """Powell's direction-set minimisation (thesis Appendix E) of segment j's cooperative objective over its
    plane (a, b, c), starting from its current plane; line minimisations by golden-section search.

    Minimises the cooperative objective of thesis Eq. 6.19 (energy Eq. 6.20) as in thesis §6.2.2.
    """
    order, starts, w, cost, min_disp, reliable = dt
    s0 = starts[j]
    s1 = starts[j + 1]
    cx = 0.0
    cy = 0.0
    sx = 1.0
    sy = 1.0
    n = s1 - s0
    for t in range(s0, s1):
        cx += order[t] % w
        cy += order[t] // w
    cx /= n
    cy /= n
    for t in range(s0, s1):
        sx = max(sx, abs(order[t] % w - cx))
        sy = max(sy, abs(order[t] // w - cy))
    # parametrise by (slope_x, slope_y, disparity at the centroid): well-conditioned directions
    p0 = planes[a[j]]
    u = np.array([p0[0], p0[1], p0[0] * cx + p0[1] * cy + p0[2]])
    dirs = np.zeros((3, 3))
    dirs[0, 2] = 1.0        # disparity offset, px
    dirs[1, 0] = 1.0 / sx   # slope change moving the segment's edge by 1 px
    dirs[2, 1] = 1.0 / sy
    pl = np.empty(3)

    def to_plane(v: F64, out: F64) -> None:
        """The plane ``d = a x + b y + c`` of thesis Eq. 6.1 from parameters centred on the segment; implementation
        helper."""
        out[0] = v[0]
        out[1] = v[1]
        out[2] = v[2] - v[0] * cx - v[1] * cy

    to_plane(u, pl)
    f0, e0 = _local_f(j, pl, a, planes, dt, g, prm, z1, o1, z2)
    fbest = f0
    gr = 0.6180339887498949
    for _c in range(cycles):
        ustart = u.copy()
        for k in range(3):
            lo = -1.0
            hi = 1.0
            x1 = hi - gr * (hi - lo)
            x2 = lo + gr * (hi - lo)
            to_plane(u + x1 * dirs[k], pl)
            f1, _ = _local_f(j, pl, a, planes, dt, g, prm, z1, o1, z2)
            to_plane(u + x2 * dirs[k], pl)
            f2, _ = _local_f(j, pl, a, planes, dt, g, prm, z1, o1, z2)
            for _it in range(10):
                if f1 < f2:
                    hi = x2
                    x2 = x1
                    f2 = f1
                    x1 = hi - gr * (hi - lo)
                    to_plane(u + x1 * dirs[k], pl)
                    f1, _ = _local_f(j, pl, a, planes, dt, g, prm, z1, o1, z2)
                else:
                    lo = x1
                    x1 = x2
                    f1 = f2
                    x2 = lo + gr * (hi - lo)
                    to_plane(u + x2 * dirs[k], pl)
                    f2, _ = _local_f(j, pl, a, planes, dt, g, prm, z1, o1, z2)
            xm = x1 if f1 < f2 else x2
            fm = min(f1, f2)
            if fm < fbest:
                u = u + xm * dirs[k]
                fbest = fm
        # Powell's update: replace the first direction by the net displacement of the cycle
        disp = u - ustart
        nrm = np.sqrt((disp * disp).sum())
        if nrm < 1e-6:
            break
        dirs[0] = dirs[1]
        dirs[1] = dirs[2]
        dirs[2] = disp
    to_plane(u, pl)
    fb, eb = _local_f(j, pl, a, planes, dt, g, prm, z1, o1, z2)
    return pl.copy(), fb - f0, eb - e0


@njit(cache=True)
def _refine_pass(a: I32, planes: F64, n_used: int, dt: PixelData, g: GraphArrays, prm: KernelParams, cycles: int,
                 min_size: int) -> tuple[int, int]:
    """Continuous refinement of every segment's plane by Powell's method (thesis Appendix E, objective Eq. 6.19);
    new planes are appended to ``planes`` (capacity permitting) so that neighbours can adopt them in the next
    discrete sweep."""
    order, starts, w, cost, min_disp, reliable = dt
    k = starts.size - 1
    h = cost.shape[1] // w
    z1, o1, z2 = _zbuffer(a, planes, order, starts, h, w)
    changed = 0
    for j in range(k):
        if starts[j + 1] - starts[j] < min_size or n_used >= planes.shape[0]:
            continue
        pl, df, de = _powell(j, a, planes, n_used, dt, g, prm, z1, o1, z2, cycles)
        if df < -1e-6 and de <= 1e-9:
            planes[n_used] = pl
            a[j] = n_used
            n_used += 1
            changed += 1
    return n_used, changed


def _new_cache(index: SegmentIndex, k: int) -> SweepCache:
    """Empty remembered data terms for :func:`_sweep` / :func:`_energy_cached` / :func:`_expand`: the z-buffer
    they hold (z1, o1, z2, valid, the assignment it is of), the segments' boxes, per segment up to ``_CACHE``
    (plane, value), the segments whose last sweep decision still holds (clean, the assignment it is of), and
    the image's pixels by row (:func:`_zbuffer_rows`) and each segment's by row (:func:`_vis_flips`); no
    remembered smoothness terms (:func:`_take_cache` adds them for a graph).

    Implementation helper (cache set-up) with no thesis equation of its own.
    """
    h, w = int(index.shape[0]), int(index.shape[1])
    npx = h * w
    order = np.asarray(index.order, np.int64)
    seg = np.repeat(np.arange(k, dtype=np.int64), np.diff(index.starts))
    by_row = np.argsort(order // w, kind="stable")  # within a row, in the order of ``order``
    rstart = np.zeros(h + 1, np.int64)
    np.cumsum(np.bincount(order // w, minlength=h), out=rstart[1:])
    # each segment's runs of pixels of one row (one run per row when its pixels are in raster order)
    y = order // w
    new = np.ones(order.size, bool)
    new[1:] = (y[1:] != y[:-1]) | (seg[1:] != seg[:-1])
    first = np.flatnonzero(new)
    srun = np.zeros((first.size + 1, 4), np.int64)
    srun[:-1, 0] = y[first]
    srun[:-1, 1] = first
    if first.size:
        srun[:-1, 2] = np.minimum.reduceat(order - y * w, first)
        srun[:-1, 3] = np.maximum.reduceat(order - y * w, first)
    srun[-1, 1] = order.size
    sstart = np.searchsorted(first, np.asarray(index.starts, np.int64)).astype(np.int64)
    return SweepCache(zc1=np.empty(npx), oc1=np.empty(npx, np.int64), zc2=np.empty(npx), zvalid=np.zeros(1, np.bool_),
                      zfor=np.empty(k, np.int32), bbox=_segment_bbox(index.order, index.starts, index.shape[1]),
                      clab=np.empty((k, _CACHE), np.int64), cval=np.empty((k, _CACHE)), cn=np.zeros(k, np.int64),
                      clean=np.zeros(k, np.bool_), afor=np.empty(k, np.int32), rstart=rstart, rp=order[by_row],
                      rseg=seg[by_row], sstart=sstart, srun=srun, elab=np.zeros((0, 2), np.int64), es=np.zeros(0))


@njit(cache=True)
def _cache_keep(clab: I64, cval: F64, cn: I64, same: npt.NDArray[np.bool_]) -> None:
    """Drops the remembered data terms of the planes not flagged in ``same``.

    Implementation helper (cache refresh) with no thesis equation of its own.
    """
    for j in range(cn.size):
        t = 0
        while t < cn[j]:
            if clab[j, t] < same.size and same[clab[j, t]]:
                t += 1
            else:
                cn[j] -= 1
                clab[j, t] = clab[j, cn[j]]
                cval[j, t] = cval[j, cn[j]]


class CoopMemo:
    """Data terms (Eqs. 6.21-6.22) remembered from one call of :func:`cooperative_optimize` or
    :func:`expand_planes` to the next, for a caller that runs several on the same segments and data term.

    They are used again when the next call gets the same ``index``, ``cost`` and ``reliable`` objects (and the
    same data-term parameters), for the planes whose ``(a, b, c)`` did not change; the caller must not write
    into those arrays between the calls (pass a new array instead). The results are the same as without it.
    """

    def __init__(self) -> None:
        """An empty memo; implementation helper with no thesis equation of its own."""
        self._key: tuple[Any, ...] | None = None
        self._cache: SweepCache | None = None
        self._planes: F64 | None = None

    def take(self, index: SegmentIndex, cost: F32, reliable: npt.NDArray[np.bool_], prm: KernelParams, min_disp: int,
             planes: F64) -> SweepCache:
        """The remembered cache if it applies to this call (with the entries of changed planes dropped), else
        a new one; the next call's cache either way (:meth:`keep`).

        Implementation helper (cache refresh) with no thesis equation of its own.
        """
        key = (index, cost, reliable, *_data_key(prm), int(min_disp))
        old, cache, opl = self._key, self._cache, self._planes
        self._key = self._cache = self._planes = None
        if (old is None or cache is None or opl is None or old[0] is not index or old[1] is not cost
                or old[2] is not reliable or old[3:] != key[3:]):
            return _new_cache(index, int(index.starts.size - 1))
        m = min(opl.shape[0], planes.shape[0])
        same = np.zeros(opl.shape[0], np.bool_)
        same[:m] = (opl[:m] == planes[:m]).all(axis=1)
        if cache.zvalid[0] and not same[cache.zfor].all():
            cache.zvalid[0] = False  # the z-buffer is of planes that changed
        _cache_keep(cache.clab, cache.cval, cache.cn, same)
        cache.clean[:] = False  # the candidates are the new call's
        return cache

    def keep(self, index: SegmentIndex, cost: F32, reliable: npt.NDArray[np.bool_], prm: KernelParams, min_disp: int,
             planes: F64, cache: SweepCache) -> None:
        """Remember ``cache`` (computed with ``planes``) for the next call.

        Implementation helper (cache) with no thesis equation of its own.
        """
        self._key = (index, cost, reliable, *_data_key(prm), int(min_disp))
        self._cache = cache
        self._planes = planes.copy()


class _DataKey(NamedTuple):
    """The parameters the data term (Eqs. 6.21-6.22, :func:`_data`) reads (:func:`_data_key`)."""

    omega_occ: float
    data_trunc: float
    unreliable_weight: float
    occ_margin: float
    visibility: bool
    omega_border: float
    n_slopes: int
    slopes: bytes


def _data_key(prm: KernelParams) -> _DataKey:
    """The parameters the data term (Eqs. 6.21-6.22, :func:`_data`) reads: a remembered data term is valid
    for another call only when they are the same."""
    return _DataKey(prm.omega_occ, prm.data_trunc, prm.unreliable_weight, prm.occ_margin, prm.visibility,
                    prm.omega_border, prm.slopes.size, prm.slopes.tobytes())


def _take_cache(memo: CoopMemo | None, index: SegmentIndex, graph: SegmentGraph, cost: F32,
                reliable: npt.NDArray[np.bool_], prm: KernelParams, min_disp: int, planes: F64) -> SweepCache:
    """The memo's cache or a new one, with an empty store of the smoothness terms of ``graph``'s boundaries
    (kept for one call only).

    Implementation helper (cache set-up) with no thesis equation of its own.
    """
    if memo is None:
        cache = _new_cache(index, int(index.starts.size - 1))
    else:
        cache = memo.take(index, cost, reliable, prm, min_disp, planes)
    npairs = int(graph.pairs.shape[0])
    return cache._replace(elab=np.full((npairs, 2), -1, np.int64), es=np.empty(npairs))


def _flat_cost(cost: F32, slopes: tuple[float, ...] | None) -> F32:
    """(S, H*W, D) view of an (H, W, D) volume or of (S, H, W, D) volumes, one per vertical slope.

    Implementation helper (array layout of the data-term volumes of thesis Eq. 6.21) with no equation of its own.
    """
    c = np.asarray(cost)
    if c.ndim == 3:
        c = c[None]
    if c.ndim != 4:
        raise ValueError(f"expected a cost volume (H, W, D) or (S, H, W, D), got shape {c.shape}")
    ns, h, w, d = c.shape
    nslopes = 1 if slopes is None else len(slopes)
    if ns != nslopes:
        raise ValueError(f"expected one cost volume per slope ({nslopes}), got {ns}")
    return np.ascontiguousarray(c.reshape(ns, h * w, d), dtype=np.float32)


def _pixel_data(index: SegmentIndex, cost: F32, reliable: npt.NDArray[np.bool_], slopes: tuple[float, ...] | None,
                min_disp: int) -> PixelData:
    """The kernels' view of the segments' pixels, the cost volume(s) and the cross-check mask.

    Implementation helper (argument packing) with no thesis equation of its own.
    """
    return PixelData(order=index.order, starts=index.starts, w=index.shape[1], cost=_flat_cost(cost, slopes),
                     min_disp=int(min_disp), reliable=np.asarray(reliable, np.bool_).ravel())


def _graph_arrays(graph: SegmentGraph) -> GraphArrays:
    """The kernels' view of ``graph``.

    Implementation helper (argument packing) with no thesis equation of its own.
    """
    return GraphArrays(pairs=graph.pairs, bstart=graph.bstart, bp_lo=graph.bp_lo, bp_hi=graph.bp_hi, bw=graph.bw,
                       nstart=graph.nstart, nbr=graph.nbr, nedge=graph.nedge)


def _prm(p: CoopParams, slopes: tuple[float, ...] | None = None) -> KernelParams:
    """The kernels' view of ``p`` (floats as float64, flags as bool) and of the cost volumes' slopes.

    Implementation helper (argument packing of the parameters of thesis Eqs. 6.19-6.24) with no equation of its own.
    """
    lev = [0.0] if slopes is None else [float(b) for b in slopes]
    return KernelParams(kappa=float(p.kappa), mu=float(p.mu), omega_occ=float(p.omega_occ),
                        data_trunc=float(p.data_trunc), unreliable_weight=float(p.unreliable_weight),
                        gamma=float(p.gamma), smooth_threshold=float(p.smooth_threshold),
                        occ_margin=float(p.occ_margin), visibility=bool(p.visibility),
                        omega_border=float(p.omega_border), neighbour_own_planes=bool(p.neighbour_own_planes),
                        slopes=np.array(lev, np.float64))


def total_energy(assign: npt.NDArray[np.integer], planes: F64, index: SegmentIndex, graph: SegmentGraph,
                 cost: F32, reliable: npt.NDArray[np.bool_], *, min_disp: int = 0,
                 params: CoopParams | None = None, slopes: tuple[float, ...] | None = None) -> float:
    """Total energy ``E = Σ_j E_j`` (Eq. 6.18) of a plane assignment.

    Parameters
    ----------
    assign : (K,) int, plane index per segment.
    planes : (L, 3) float64 plane set ``(a, b, c)``.
    index, graph : segment pixels and adjacency.
    cost : (H, W, D) float32 pixel cost of the left view, slice k = disparity ``min_disp + k``; or
        (S, H, W, D), one volume per vertical slope in ``slopes`` (a plane reads the nearest slope's).
    reliable : (H, W) bool cross-check mask (Eq. 6.7).
    """
    p = params or CoopParams()
    return float(_energy(np.asarray(assign, np.int32), np.asarray(planes, np.float64),
                         _pixel_data(index, cost, reliable, slopes, min_disp), _graph_arrays(graph), _prm(p, slopes)))


def cooperative_optimize(assign: npt.NDArray[np.integer], planes: F64, index: SegmentIndex,
                         graph: SegmentGraph, cost: F32, reliable: npt.NDArray[np.bool_], *,
                         own: npt.NDArray[np.integer] | None = None, min_disp: int = 0,
                         params: CoopParams | None = None,
                         active: npt.NDArray[np.bool_] | None = None,
                         slopes: tuple[float, ...] | None = None,
                         memo: CoopMemo | None = None) -> tuple[I32, F64, dict[str, float]]:
    """Cooperative optimisation of the plane labels (thesis §6.2, Eqs. 6.18-6.25).

    Parameters
    ----------
    assign : (K,) int
        Initial plane index per segment (every segment must have one).
    planes : (L, 3) float64
        The plane set (fitted and merged planes).
    index, graph : SegmentIndex, SegmentGraph
    cost : (H, W, D) or (S, H, W, D) float32
        Pixel matching cost of the left view (slice k = disparity ``min_disp + k``); with ``slopes``, one
        volume per vertical disparity slope, and each plane's data term reads the volume of the slope nearest
        its ``b`` (:func:`prismstereo.matching.coop.coopcost.sheared_costs`).
    reliable : (H, W) bool
        Cross-check mask (Eq. 6.7).
    own : (K, 2) int, optional
        Extra candidate planes of each segment (its own fitted plane and its cluster plane; -1 = none).
    min_disp : int, keyword-only
    params : CoopParams, keyword-only
    active : (K,) bool, optional
        Segments allowed to change their plane (default: all).
    slopes : tuple of float, optional
        Vertical slopes of the volumes of a 4-D ``cost``.
    memo : CoopMemo, optional
        Data terms remembered across the caller's calls (the same result, less work).

    Returns
    -------
    assign : (K,) int32
        Optimised plane index per segment, into ``planes_out``.
    planes_out : (L', 3) float64
        The plane set extended by the planes found by the continuous (Powell) refinement.
    info : dict
        ``energy_before``, ``energy_after`` (Eq. 6.18), ``sweeps``, ``changes``, ``refined``.

    Notes
    -----
    Within a sweep the visibility (which pixels are occluded) is taken from the assignment at the start of
    the sweep; after the sweep the total energy is recomputed with the new visibility and the sweep is
    undone (and the iteration stopped) if it did not lower E, so E is non-increasing over iterations.
    """
    p = params or CoopParams()
    a = np.asarray(assign, np.int32).copy()
    k = a.size
    own_arr = np.full((k, 2), -1, np.int64) if own is None else np.asarray(own, np.int64).reshape(k, 2)
    act = np.ones(k, np.bool_) if active is None else np.asarray(active, np.bool_).reshape(k)
    n_used = int(planes.shape[0])
    rounds = max(int(p.refine_rounds), 0)
    pl = np.zeros((n_used + rounds * k, 3), np.float64)
    pl[:n_used] = planes
    prm = _prm(p, slopes)
    dt = _pixel_data(index, cost, reliable, slopes, min_disp)
    g = _graph_arrays(graph)
    # remembered data terms of (segment, plane) and the z-buffer they were computed under
    cache = _take_cache(memo, index, graph, cost, reliable, prm, int(min_disp), pl)
    e0 = _energy_cached(a, pl, dt, g, prm, cache)
    e_cur = e0
    sweeps = 0
    changes = 0
    refined = 0
    for rnd in range(rounds + 1):
        for _ in range(p.max_iter):
            prev = a.copy()
            n = _sweep(a, own_arr.ravel(), pl, dt, g, prm, act, cache)
            sweeps += 1
            if n == 0:
                break
            e_new = _energy_cached(a, pl, dt, g, prm, cache)
            if e_new > e_cur:
                a = prev
                break
            e_cur = e_new
            changes += n
        if rnd == rounds:
            break
        prev = a.copy()
        n_prev = n_used
        n_used, n = _refine_pass(a, pl, n_used, dt, g, prm,
                                 int(p.powell_cycles), int(p.refine_min_size))
        cache.zvalid[0] = False  # the refined planes were appended where rejected ones may have been
        cache.elab[:] = -1
        e_new = _energy(a, pl, dt, g, prm)
        if n == 0 or e_new > e_cur:
            a = prev
            n_used = n_prev
            break
        e_cur = e_new
        refined += n
    planes_out = pl[:n_used]
    if memo is not None:
        memo.keep(index, cost, reliable, prm, int(min_disp), pl, cache)
    log.debug("cooperative optimisation: E %.1f -> %.1f in %d sweeps (%d changes)", e0, e_cur, sweeps, changes)
    return a, planes_out, {"energy_before": float(e0), "energy_after": float(e_cur), "sweeps": float(sweeps),
                           "changes": float(changes), "refined": float(refined)}


@njit(cache=True)
def _expand(a: I32, planes: F64, cand: I64, seed_start: I64, seeds: I64, dt: PixelData, g: GraphArrays,
            prm: KernelParams, max_region: int, cache: SweepCache) -> int:
    """Group moves, in place: for each candidate plane, the connected region of segments grown from its seeds
    through segments whose data term it does not raise moves to it at once when that lowers E (Eq. 6.18).
    Data terms are remembered (:func:`_data_cached`); the cache always holds the z-buffer ``z1, o1, z2``
    they are read under."""
    order, starts, w, cost, min_disp, reliable = dt
    pairs, bstart, bp_lo, bp_hi, bw, nstart, nbr, nedge = g
    (zc1, oc1, zc2, zvalid, zfor, bbox, clab, cval, cn, clean, afor, rstart, rp, rseg, sstart, srun, elab,
     es) = cache
    k = starts.size - 1
    h = cost.shape[1] // w
    gamma = prm.gamma
    thr = prm.smooth_threshold
    in_s = np.zeros(k, np.bool_)
    seen = np.zeros(k, np.bool_)
    region = np.empty(k, np.int64)
    dnew = np.empty(k, np.float64)
    dold = np.empty(k, np.float64)
    prev = np.empty(k, np.int32)
    e_cur = _energy_cached(a, planes, dt, g, prm, cache)
    # the z-buffer of the kept assignment: the cache's (it holds the last one computed)
    z1, o1, z2 = zc1.copy(), oc1.copy(), zc2.copy()
    rows = np.zeros(h, np.bool_)
    accepted = 0
    for m in range(cand.size):
        lab = cand[m]
        pl = planes[lab]
        n = 0
        head = 0
        for t in range(seed_start[m], seed_start[m + 1]):
            s = seeds[t]
            if a[s] != lab and not seen[s]:
                seen[s] = True
                dn = _data_cached(s, lab, planes, dt, prm, z1, o1, z2, clab, cval, cn)
                do = _data_cached(s, a[s], planes, dt, prm, z1, o1, z2, clab, cval, cn)
                if dn <= do:
                    region[n] = s
                    dnew[n] = dn
                    dold[n] = do
                    in_s[s] = True
                    n += 1
        while head < n and n < max_region:
            j = region[head]
            head += 1
            for t in range(nstart[j], nstart[j + 1]):
                i = nbr[t]
                if seen[i] or a[i] == lab:
                    continue
                seen[i] = True
                dn = _data_cached(i, lab, planes, dt, prm, z1, o1, z2, clab, cval, cn)
                do = _data_cached(i, a[i], planes, dt, prm, z1, o1, z2, clab, cval, cn)
                if dn <= do and n < max_region:
                    region[n] = i
                    dnew[n] = dn
                    dold[n] = do
                    in_s[i] = True
                    n += 1
        de = 0.0
        for r in range(n):
            j = region[r]
            de += dnew[r] - dold[r]
            for t in range(nstart[j], nstart[j + 1]):
                i = nbr[t]
                before = 0.0
                if a[i] != a[j]:
                    before = _smooth(j, i, nedge[t], planes[a[j]], planes[a[i]], pairs, bstart, bp_lo, bp_hi, bw, w,
                                     thr)
                if in_s[i]:
                    de -= gamma * before  # visited from both sides: 2 γ S in E (Eq. 6.18)
                else:
                    after = 0.0
                    if a[i] != lab:
                        after = _smooth(j, i, nedge[t], pl, planes[a[i]], pairs, bstart, bp_lo, bp_hi, bw, w, thr)
                    de += 2.0 * gamma * (after - before)
        if n > 0 and de < -1e-9:
            rows[:] = False
            for r in range(n):
                prev[r] = a[region[r]]
                a[region[r]] = lab
                rows[bbox[region[r], 2]:bbox[region[r], 3] + 1] = True
            e_new = _energy_cached(a, planes, dt, g, prm, cache)
            if e_new < e_cur - 1e-9:
                e_cur = e_new
                accepted += 1
                # the cache's z-buffer is the new assignment's; it differs from the old on the region's rows
                for y in range(h):
                    if rows[y]:
                        z1[y * w:(y + 1) * w] = zc1[y * w:(y + 1) * w]
                        o1[y * w:(y + 1) * w] = oc1[y * w:(y + 1) * w]
                        z2[y * w:(y + 1) * w] = zc2[y * w:(y + 1) * w]
            else:
                for r in range(n):
                    a[region[r]] = prev[r]
                # back to the z-buffer of the kept assignment (the cache now holds the rejected one's)
                _cache_refresh(z1, o1, z2, rows, cache, planes, dt, prm)
                zfor[:] = a
        for r in range(n):
            in_s[region[r]] = False
        seen[:] = False  # also the segments visited but not taken
    return accepted


def expand_planes(assign: npt.NDArray[np.integer], planes: F64, index: SegmentIndex, graph: SegmentGraph,
                  cost: F32, reliable: npt.NDArray[np.bool_], candidates: npt.NDArray[np.integer], *,
                  min_disp: int = 0, params: CoopParams | None = None, slopes: tuple[float, ...] | None = None,
                  max_region: int = 400, memo: CoopMemo | None = None) -> tuple[I32, dict[str, float]]:
    """Group moves of candidate planes over connected regions of segments (an addition to §6.2).

    The cooperative scheme moves one segment at a time, so a surface split into many segments that all sit
    on a wrong plane cannot move to the right one when each segment alone would pay the smoothness cost
    against its neighbours. For every candidate plane (``candidates[j, t]`` proposed for segment ``j``), the
    region grown from the segments it was proposed for, through neighbours whose data term (Eqs. 6.21-6.22)
    it does not raise, moves to it at once when that lowers the total energy E (Eq. 6.18, checked with
    visibility); E never increases.

    Parameters
    ----------
    assign : (K,) int; planes : (L, 3); index, graph, cost, reliable, slopes : as :func:`cooperative_optimize`.
    candidates : (K, T) int
        Candidate plane indices per segment (-1 = none).
    max_region : int, keyword-only
        Largest region (segments) of one move.
    memo : CoopMemo, optional
        As :func:`cooperative_optimize`.

    Returns
    -------
    assign : (K,) int32; info : dict with ``group_moves``.
    """
    p = params or CoopParams()
    a = np.asarray(assign, np.int32).copy()
    cands = np.asarray(candidates, np.int64)
    segs, cols = np.nonzero(cands >= 0)
    labs = cands[segs, cols]
    if labs.size == 0:
        return a, {"group_moves": 0.0}
    order = np.argsort(labs, kind="stable")
    labs, segs = labs[order], segs[order]
    uniq, first = np.unique(labs, return_index=True)
    seed_start = np.append(first, labs.size).astype(np.int64)
    pl = np.asarray(planes, np.float64)
    prm = _prm(p, slopes)
    cache = _take_cache(memo, index, graph, cost, reliable, prm, int(min_disp), pl)
    n = _expand(a, pl, uniq.astype(np.int64), seed_start, segs.astype(np.int64),
                _pixel_data(index, cost, reliable, slopes, min_disp), _graph_arrays(graph), prm, int(max_region),
                cache)
    if memo is not None:
        memo.keep(index, cost, reliable, prm, int(min_disp), pl, cache)
    return a, {"group_moves": float(n)}


def neighbour_plane_candidates(graph: SegmentGraph, assign: npt.NDArray[np.integer]) -> I64:
    """The current planes across each segment's boundary, as a (K, T) candidate array for :func:`expand_planes`.

    Row ``j`` lists the distinct current planes of ``j``'s neighbours other than its own (-1 pads).

    Implementation helper (candidate labels for the minimiser of thesis Eq. 6.19; the neighbours of Eq. 6.11) with no
    equation of its own.
    """
    a = np.asarray(assign, np.int64)
    k = a.size
    pr = graph.pairs.astype(np.int64)
    diff = a[pr[:, 0]] != a[pr[:, 1]]
    segs = np.concatenate([pr[diff, 1], pr[diff, 0]])
    labs = np.concatenate([a[pr[diff, 0]], a[pr[diff, 1]]])
    if segs.size == 0:
        return np.full((k, 1), -1, np.int64)
    o = np.lexsort((labs, segs))
    segs, labs = segs[o], labs[o]
    first = np.ones(segs.size, bool)
    first[1:] = (segs[1:] != segs[:-1]) | (labs[1:] != labs[:-1])
    segs, labs = segs[first], labs[first]
    cnt = np.bincount(segs, minlength=k)
    out = np.full((k, int(cnt.max())), -1, np.int64)
    out[segs, np.arange(segs.size) - np.repeat(np.cumsum(cnt) - cnt, cnt)] = labs
    return out
