"""Disparity plane estimation per segment (thesis §6.1): robust fitting and merging of neighbours.

Every segment ``j`` of the reference image gets a disparity plane ``d = a x + b y + c`` (Eq. 6.1), fitted by
least squares through the SVD pseudo-inverse of ``AᵀA`` (Eqs. 6.2-6.6) on its reliable pixels. Outliers are
removed by the thesis's three rules: the left-right cross-check (Eq. 6.7), the unreliable-segment ratio
(Eq. 6.8), and the distance to the current plane (Eq. 6.9), iterated until the parameters settle
(Eq. 6.10). The iteration is seeded by a small deterministic RANSAC (best of random pixel triples), so that a
segment whose initial disparities are half wrong still converges to the right plane. Neighbouring planes
that are nearly the same surface are then merged (§6.1.3, Eqs. 6.14-6.17) and refitted.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from numba import njit, prange

from prismstereo.checks import check_fields
from prismstereo.matching.segments.segmentation import split_segments

log = logging.getLogger(__name__)

__all__ = ["PlaneParams", "SegmentIndex", "build_segment_index", "fit_one_plane", "fit_planes", "fit_planes_splitting",
           "merge_planes",
           "segment_label_map",
           "plane_similarity", "render_planes", "fill_missing_planes"]

F64 = npt.NDArray[np.float64]
I32 = npt.NDArray[np.int32]


@dataclass(frozen=True)
class PlaneParams:
    """Parameters of the plane estimation (thesis §6.1).

    Attributes
    ----------
    gamma_segment : float
        ``γ_segment`` of Eq. 6.8: a segment whose fraction of unreliable pixels exceeds it gets no plane.
    t_outlier : float
        ``t_outlier`` of Eq. 6.9, pixels: reliable pixels farther from the plane are outliers.
    epsilon : float
        ``ε`` of the convergence test Eq. 6.10, ``exp(-(|Δa| + |Δb| + |Δc|)) > ε``.
    max_iter : int
        Cap on the Eq. 6.9/6.10 iterations.
    min_pixels : int
        Fewest reliable pixels for a plane; with fewer than ``3 * min_pixels`` only ``c`` is fitted.
    ransac_trials : int
        Random pixel triples tried to seed the iteration (0 = seed with the plain least-squares fit).
    max_slope : float
        Largest accepted ``|a|`` and ``|b|`` (px per px); steeper fits fall back to a constant plane.
    delta : float
        ``δ`` of Eq. 6.17: neighbours merge when their similarity (Eq. 6.16) exceeds it.
    min_support, split_min_pixels, piece_min_pixels, split_rounds : float, int, int, int
        Plane support test (:func:`fit_planes_splitting`, an addition to §6.1): a segment of at least
        ``split_min_pixels`` pixels whose plane lies within ``t_outlier`` of fewer than ``min_support`` of its
        evidence pixels is not one plane (a curved surface, or two surfaces of one colour); it is split into
        quarters and refitted, at most ``split_rounds`` times (0 = off); pieces of a split segment may be split
        again down to ``piece_min_pixels``.
    """

    gamma_segment: float = 0.9
    t_outlier: float = 1.0
    epsilon: float = 0.99
    max_iter: int = 10
    min_pixels: int = 6
    ransac_trials: int = 48
    max_slope: float = 1.0
    delta: float = 0.8
    min_support: float = 0.9
    split_min_pixels: int = 2000
    piece_min_pixels: int = 200
    split_rounds: int = 4

    def __post_init__(self) -> None:
        check_fields(self, {"gamma_segment": (0.0, 1.0), "t_outlier": (0.0, None), "epsilon": (0.0, 1.0),
                            "max_iter": (0, 1000), "min_pixels": (1, None), "ransac_trials": (0, 100_000),
                            "max_slope": (0.0, None), "delta": (0.0, 1.0), "min_support": (0.0, 1.0),
                            "split_min_pixels": (1, None), "piece_min_pixels": (1, None), "split_rounds": (0, 100)},
                     positive=("t_outlier",))


@dataclass(frozen=True)
class SegmentIndex:
    """Pixels of every segment in compressed-row form.

    Attributes
    ----------
    order : (N,) int64
        Flat pixel indices sorted by segment.
    starts : (K + 1,) int64
        Segment ``j`` owns ``order[starts[j]:starts[j + 1]]``.
    shape : tuple
        (H, W) of the label map.
    """

    order: npt.NDArray[np.int64]
    starts: npt.NDArray[np.int64]
    shape: tuple[int, int]

    @property
    def n_segments(self) -> int:
        return int(self.starts.size - 1)


@njit(cache=True, nogil=True)
def _counting_sort(lab: npt.NDArray[np.int64], k: int) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """Pixels sorted by label, in increasing pixel order within a label (a stable argsort in O(N))."""
    starts = np.zeros(k + 1, np.int64)
    for i in range(lab.size):
        starts[lab[i] + 1] += 1
    for j in range(k):
        starts[j + 1] += starts[j]
    fill = starts[:k].copy()
    order = np.empty(lab.size, np.int64)
    for i in range(lab.size):
        j = lab[i]
        order[fill[j]] = i
        fill[j] += 1
    return order, starts


def build_segment_index(labels: npt.NDArray[np.integer]) -> SegmentIndex:
    """Index the pixels of each segment of a (H, W) label map with labels 0..K-1."""
    lab = np.ascontiguousarray(np.asarray(labels).ravel(), dtype=np.int64)
    order, starts = _counting_sort(lab, int(lab.max()) + 1)
    return SegmentIndex(order, starts, (int(labels.shape[0]), int(labels.shape[1])))


@njit(cache=True)
def _lsq(xs: F64, ys: F64, ds: F64, cx: float, cy: float, full: bool) -> tuple[float, float, float]:
    """Least squares plane (Eqs. 6.2-6.6: SVD pseudo-inverse of AᵀA) in coordinates centred on (cx, cy)."""
    n = xs.size
    if not full:
        return 0.0, 0.0, float(np.mean(ds))
    ata = np.zeros((3, 3))
    atb = np.zeros(3)
    for i in range(n):
        u = xs[i] - cx
        v = ys[i] - cy
        row = (u, v, 1.0)
        for r in range(3):
            atb[r] += row[r] * ds[i]
            for c in range(3):
                ata[r, c] += row[r] * row[c]
    sol = np.linalg.pinv(ata) @ atb
    return sol[0], sol[1], sol[2]


@njit(cache=True)
def fit_one_plane(xs: F64, ys: F64, ds: F64, t_out: float, eps: float, max_iter: int, min_pix: int,
                  trials: int, max_slope: float, seed: int) -> tuple[float, float, float, int]:
    """Robust plane ``d = a·(x - x̄) + b·(y - ȳ) + c`` of one segment's reliable pixels (thesis Eqs. 6.1-6.10).

    ``xs, ys, ds``: (N,) float64 pixel coordinates and disparities; ``t_out``, ``eps``, ``max_iter``,
    ``min_pix``, ``trials`` and ``max_slope`` as in :class:`PlaneParams`; ``seed`` seeds the random triples.
    Returns (a, b, c_centred, n_inliers).
    """
    n = xs.size
    cx = float(np.mean(xs))
    cy = float(np.mean(ys))
    full = bool(n >= 3 * min_pix and (np.max(xs) - np.min(xs)) >= 2 and (np.max(ys) - np.min(ys)) >= 2)
    # seed: median constant, then the best random triple (inlier count within t_outlier)
    a = 0.0
    b = 0.0
    c = float(np.median(ds))
    best = 0
    for i in range(n):
        if abs(ds[i] - c) <= t_out:
            best += 1
    if full and trials > 0:
        state = np.uint64(seed * 2654435761 + 12345)
        for _t in range(trials):
            # small deterministic LCG (Knuth MMIX constants): reproducible, no global RNG state
            state = state * np.uint64(6364136223846793005) + np.uint64(1442695040888963407)
            i0 = int((state >> np.uint64(33)) % np.uint64(n))
            state = state * np.uint64(6364136223846793005) + np.uint64(1442695040888963407)
            i1 = int((state >> np.uint64(33)) % np.uint64(n))
            state = state * np.uint64(6364136223846793005) + np.uint64(1442695040888963407)
            i2 = int((state >> np.uint64(33)) % np.uint64(n))
            u0, v0 = xs[i0] - cx, ys[i0] - cy
            u1, v1 = xs[i1] - cx, ys[i1] - cy
            u2, v2 = xs[i2] - cx, ys[i2] - cy
            det = (u1 - u0) * (v2 - v0) - (u2 - u0) * (v1 - v0)
            if abs(det) < 1e-9:
                continue
            d10 = ds[i1] - ds[i0]
            d20 = ds[i2] - ds[i0]
            aa = (d10 * (v2 - v0) - d20 * (v1 - v0)) / det
            bb = ((u1 - u0) * d20 - (u2 - u0) * d10) / det
            if abs(aa) > max_slope or abs(bb) > max_slope:
                continue
            cc = ds[i0] - aa * u0 - bb * v0
            cnt = 0
            for i in range(n):
                if abs(ds[i] - (aa * (xs[i] - cx) + bb * (ys[i] - cy) + cc)) <= t_out:
                    cnt += 1
            if cnt > best:
                best = cnt
                a, b, c = aa, bb, cc
    # Eq. 6.9 / 6.10 iteration
    mask = np.zeros(n, np.bool_)
    ninl = 0
    for _it in range(max_iter):
        ninl = 0
        for i in range(n):
            m = abs(ds[i] - (a * (xs[i] - cx) + b * (ys[i] - cy) + c)) <= t_out
            mask[i] = m
            if m:
                ninl += 1
        if ninl < min_pix:
            break
        xi = xs[mask]
        yi = ys[mask]
        di = ds[mask]
        ok_full = bool(full and ninl >= 3 * min_pix)
        a2, b2, c2 = _lsq(xi, yi, di, cx, cy, ok_full)
        if abs(a2) > max_slope or abs(b2) > max_slope:
            a2, b2, c2 = _lsq(xi, yi, di, cx, cy, False)
        conv = np.exp(-(abs(a - a2) + abs(b - b2) + abs(c - c2))) > eps
        a, b, c = a2, b2, c2
        if conv:
            break
    return a, b, float(c - a * cx - b * cy), ninl


@njit(cache=True, parallel=True, nogil=True)
def _fit_all(order: npt.NDArray[np.int64], starts: npt.NDArray[np.int64], w: int, disp: F64,
             reliable: npt.NDArray[np.bool_], gamma: float, t_out: float, eps: float, max_iter: int,
             min_pix: int, trials: int, max_slope: float) -> tuple[F64, I32]:
    k = starts.size - 1
    planes = np.full((k, 3), np.nan)
    ninl = np.zeros(k, np.int32)
    # segments are independent (each seeds its own random triples): fit them in parallel, interleaved so
    # that each thread's share mixes large and small segments
    nb = 64
    for b in prange(nb):
        _fit_stride(order, starts, w, disp, reliable, gamma, t_out, eps, max_iter, min_pix, trials, max_slope,
                    b, nb, planes, ninl)
    return planes, ninl


@njit(cache=True, nogil=True)
def _fit_stride(order: npt.NDArray[np.int64], starts: npt.NDArray[np.int64], w: int, disp: F64,
                reliable: npt.NDArray[np.bool_], gamma: float, t_out: float, eps: float, max_iter: int,
                min_pix: int, trials: int, max_slope: float, first: int, stride: int, planes: F64,
                ninl: I32) -> None:
    """The planes of segments ``first, first + stride, ...`` into ``planes`` and ``ninl``."""
    for j in range(first, starts.size - 1, stride):
        s0 = starts[j]
        s1 = starts[j + 1]
        nseg = s1 - s0
        nrel = 0
        for t in range(s0, s1):
            if reliable[order[t]]:
                nrel += 1
        # Eq. 6.8: too many unreliable pixels -> no plane for this segment
        if nrel < min_pix or (nseg - nrel) > gamma * nseg:
            continue
        xs = np.empty(nrel)
        ys = np.empty(nrel)
        ds = np.empty(nrel)
        q = 0
        for t in range(s0, s1):
            p = order[t]
            if reliable[p]:
                xs[q] = p % w
                ys[q] = p // w
                ds[q] = disp[p]
                q += 1
        a, b, c, n_in = fit_one_plane(xs, ys, ds, t_out, eps, max_iter, min_pix, trials, max_slope, j + 1)
        if n_in >= min_pix:
            planes[j, 0] = a
            planes[j, 1] = b
            planes[j, 2] = c
            ninl[j] = n_in


def fit_planes(index: SegmentIndex, disparity: npt.NDArray[np.floating], reliable: npt.NDArray[np.bool_], *,
               params: PlaneParams | None = None) -> tuple[F64, I32]:
    """Fit one disparity plane per segment (thesis Eqs. 6.1-6.10).

    Parameters
    ----------
    index : SegmentIndex
        Pixels of each segment (``build_segment_index(labels)``).
    disparity : (H, W) float
        Initial disparity map (d = x_left - x_right), NaN allowed where ``reliable`` is False.
    reliable : (H, W) bool
        Pixels passing the cross-check (Eq. 6.7).
    params : PlaneParams, keyword-only

    Returns
    -------
    planes : (K, 3) float64
        ``(a, b, c)`` per segment, image coordinates (x = column, y = row); NaN rows for segments that
        failed Eq. 6.8 or kept too few inliers.
    inliers : (K,) int32
        Reliable pixels within ``t_outlier`` of the final plane.
    """
    p = params or PlaneParams()
    d = np.nan_to_num(np.asarray(disparity, dtype=np.float64).ravel(), nan=0.0)
    rel = np.asarray(reliable, dtype=np.bool_).ravel() & np.isfinite(np.asarray(disparity).ravel())
    return _fit_all(index.order, index.starts, index.shape[1], d, rel, p.gamma_segment, p.t_outlier,
                    p.epsilon, p.max_iter, p.min_pixels, p.ransac_trials, p.max_slope)


def fit_planes_splitting(labels: npt.NDArray[np.integer], image: npt.NDArray[np.generic],
                         disparity: npt.NDArray[np.floating], reliable: npt.NDArray[np.bool_],
                         evidence: npt.NDArray[np.bool_] | None = None, *,
                         params: PlaneParams | None = None, min_region: int = 20
                         ) -> tuple[I32, SegmentIndex, F64, F64]:
    """:func:`fit_planes`, splitting segments whose plane the cross-checked evidence does not support.

    One plane per segment (§6.1) is only right when the segment is one planar surface. Mean shift (§5.1)
    makes very large segments on low-texture or repetitive surfaces (a third of the image on Middlebury
    *Bowling1*), and their robust fit then keeps the plane of a minority of the pixels. A segment of at least
    ``params.split_min_pixels`` pixels whose plane agrees (within ``t_outlier``) with fewer than
    ``params.min_support`` of its ``evidence`` pixels is split into quarters at its centroid
    (:func:`~prismstereo.matching.segments.segmentation.split_segments`) and the pieces refitted, up to
    ``params.split_rounds`` times. The split is only a hypothesis (where the reliable pixels are wrong in one
    part of the segment, the pieces follow them): each piece keeps its unsplit segment's plane in
    ``ancestor`` so that the data term can choose between them.

    Parameters
    ----------
    labels : (H, W) int segments 0..K-1; image : (H, W, 3) reference image (for merging tiny pieces).
    disparity, reliable : (H, W) initial map and its cross-check mask, as :func:`fit_planes`.
    evidence : (H, W) bool, optional
        Pixels whose ``disparity`` is trusted for the support test (default ``reliable``; ``coop`` passes the
        pixels where two differently aggregated cross-checked maps agree).
    min_region : int, keyword-only  pieces smaller than this merge into a neighbour.

    Returns
    -------
    labels : (H, W) int32 (split) segments; index : their SegmentIndex;
    planes : (K', 3) float64 as :func:`fit_planes`;
    ancestor : (K', 3) float64 plane of the original segment a piece was split from (NaN rows: not split).
    """

    p = params or PlaneParams()
    lab = np.asarray(labels).astype(np.int32)
    dmap = np.asarray(disparity, np.float64)
    ev = np.asarray(reliable if evidence is None else evidence, bool) & np.isfinite(dmap)
    index = build_segment_index(lab)
    planes, _ = fit_planes(index, disparity, reliable, params=p)
    ancestor = np.full(planes.shape, np.nan)
    for _r in range(max(p.split_rounds, 0)):
        k = planes.shape[0]
        sizes = np.diff(index.starts)
        fitted = np.isfinite(planes[:, 0])
        near = ev & (np.abs(render_planes(index, np.nan_to_num(planes), np.arange(k, dtype=np.int32)) - dmap)
                     <= p.t_outlier)
        nev = np.bincount(lab.ravel(), weights=ev.ravel(), minlength=k)
        nin = np.bincount(lab.ravel(), weights=near.ravel(), minlength=k)
        big = (sizes >= p.split_min_pixels) | (np.isfinite(ancestor[:, 0]) & (sizes >= p.piece_min_pixels))
        weak = fitted & big & (nin < p.min_support * nev)
        if not weak.any():
            break
        log.debug("plane support: splitting %d segments (%d px)", int(weak.sum()), int(sizes[weak].sum()))
        new = split_segments(lab, image, weak, min_region=min_region)
        old_of_new = np.zeros(int(new.max()) + 1, np.int64)
        old_of_new[new.ravel()] = lab.ravel()  # every piece lies inside one old segment
        anc = np.where(np.isfinite(ancestor[:, :1]) | ~weak[:, None], ancestor, planes)
        ancestor = anc[old_of_new]
        lab = new
        index = build_segment_index(lab)
        planes, _ = fit_planes(index, disparity, reliable, params=p)
    return lab, index, planes, ancestor


def plane_similarity(pa: F64, pb: F64, ca: F64, cb: F64) -> F64:
    """Similarity of neighbouring disparity planes (thesis Eqs. 6.14-6.16).

    The planes ``d = a x + b y + c`` are surfaces in (x, y, d) space with normals ``(a, b, -1)``. The
    intersection angle θ of Eq. 6.14 is taken between these normals (folded to ``min(θ, π - θ)``), and the
    parallel distance of Eq. 6.15 is the mean point-to-plane distance between the two planes over the two
    segments' centroids. Eq. 6.16 scores each property by ``exp(-·)``; since two planes can be nearly parallel
    yet far apart, both properties are required together: ``simfun = exp(-θ) · exp(-d_dist)``.

    Parameters
    ----------
    pa, pb : (P, 3)
        Plane parameters of the two members of each pair.
    ca, cb : (P, 2)
        Centroids (x, y) of the two segments.

    Returns
    -------
    (P,) similarity in (0, 1].
    """
    na = np.stack([pa[:, 0], pa[:, 1], -np.ones(len(pa))], axis=1)
    nb = np.stack([pb[:, 0], pb[:, 1], -np.ones(len(pb))], axis=1)
    cos = np.abs((na * nb).sum(1)) / np.sqrt((na * na).sum(1) * (nb * nb).sum(1))
    theta = np.arccos(np.clip(cos, -1.0, 1.0))

    def ev(p: F64, c: F64) -> F64:
        return p[:, 0] * c[:, 0] + p[:, 1] * c[:, 1] + p[:, 2]

    gap = 0.5 * (np.abs(ev(pa, ca) - ev(pb, ca)) + np.abs(ev(pa, cb) - ev(pb, cb)))
    dist = gap / np.sqrt((na * na).sum(1))
    return np.asarray(np.exp(-theta) * np.exp(-dist), dtype=np.float64)


@njit(cache=True, nogil=True)
def _uf_find(parent: npt.NDArray[np.int64], i: int) -> int:
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = int(parent[i])
    return i


@njit(cache=True, nogil=True)
def _greedy_roots(pr: npt.NDArray[np.int64], sim: F64, order: npt.NDArray[np.int64], delta: float,
                  k: int) -> npt.NDArray[np.int64]:
    """Union of the pairs ``pr`` in ``order`` while their similarity exceeds ``delta`` (Eq. 6.17); the root
    (smallest member) of each segment's cluster."""
    parent = np.arange(k, dtype=np.int64)
    for e in order:
        if sim[e] <= delta:
            break
        ra = _uf_find(parent, pr[e, 0])
        rb = _uf_find(parent, pr[e, 1])
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)
    roots = np.empty(k, np.int64)
    for i in range(k):
        roots[i] = _uf_find(parent, i)
    return roots


@njit(cache=True, nogil=True)
def _assign_clusters(order: npt.NDArray[np.int64], starts: npt.NDArray[np.int64], w: int, planes: F64,
                     merged: F64, roots: npt.NDArray[np.int64], has: npt.NDArray[np.bool_],
                     sizes: npt.NDArray[np.int64], d: F64, rel: npt.NDArray[np.bool_], t_out: float
                     ) -> tuple[I32, F64]:
    """Cluster index and plane per segment with a plane, numbered in segment order: a member of a multi-segment
    cluster takes the merged plane unless it fits the member's reliable pixels worse by more than 0.1."""
    k = planes.shape[0]
    cluster = np.full(k, -1, np.int32)
    out = np.empty((k, 3))
    root_to_c = np.full(k, -1, np.int64)
    n_out = 0
    for j in range(k):
        if not has[j]:
            continue
        r = roots[j]
        use_merged = sizes[r] > 1 and np.isfinite(merged[r, 0])
        if use_merged:
            n = 0
            n_own = 0
            n_mer = 0
            for t in range(starts[j], starts[j + 1]):
                p = order[t]
                if not rel[p]:
                    continue
                n += 1
                x = float(p % w)
                y = float(p // w)
                if abs(d[p] - (planes[j, 0] * x + planes[j, 1] * y + planes[j, 2])) <= t_out:
                    n_own += 1
                if abs(d[p] - (merged[r, 0] * x + merged[r, 1] * y + merged[r, 2])) <= t_out:
                    n_mer += 1
            if n:
                use_merged = n_mer / n >= n_own / n - 0.1
        if use_merged:
            if root_to_c[r] < 0:
                root_to_c[r] = n_out
                out[n_out] = merged[r]
                n_out += 1
            cluster[j] = root_to_c[r]
        else:
            cluster[j] = n_out
            out[n_out] = planes[j]
            n_out += 1
    return cluster, out[:n_out].copy()


def merge_planes(index: SegmentIndex, planes: F64, pairs: I32, disparity: npt.NDArray[np.floating],
                 reliable: npt.NDArray[np.bool_], *, params: PlaneParams | None = None,
                 ) -> tuple[I32, F64]:
    """Cluster neighbouring segments with similar planes and refit each cluster (thesis §6.1.3).

    Parameters
    ----------
    index : SegmentIndex
    planes : (K, 3) float64
        Per-segment planes from :func:`fit_planes` (NaN = none).
    pairs : (P, 2) int32
        Adjacent segment pairs (Eq. 6.11, from ``segment_adjacency``).
    disparity, reliable : (H, W)
        As for :func:`fit_planes`.
    params : PlaneParams, keyword-only
        ``delta`` is the threshold δ of Eq. 6.17.

    Returns
    -------
    cluster : (K,) int32
        Cluster index per segment (-1 for segments without a plane).
    cluster_planes : (C, 3) float64
        Refitted plane of each cluster (a member that the refitted plane no longer fits keeps its own
        plane as a cluster of its own).
    """
    p = params or PlaneParams()
    k = planes.shape[0]
    h, w = index.shape
    has = np.isfinite(planes[:, 0])
    pix_x = (index.order % w).astype(np.float64)
    pix_y = (index.order // w).astype(np.float64)
    seg_of = np.repeat(np.arange(k), np.diff(index.starts))
    cnt = np.maximum(np.diff(index.starts), 1)
    cent = np.stack([np.bincount(seg_of, pix_x, k) / cnt, np.bincount(seg_of, pix_y, k) / cnt], axis=1)
    ok = has[pairs[:, 0]] & has[pairs[:, 1]]
    pr = pairs[ok]
    sim = plane_similarity(planes[pr[:, 0]], planes[pr[:, 1]], cent[pr[:, 0]], cent[pr[:, 1]])
    # greedy clustering in decreasing similarity (Eq. 6.17: merge while simfun > δ)
    roots = _greedy_roots(pr.astype(np.int64), sim, np.argsort(-sim, kind="stable").astype(np.int64),
                          float(p.delta), k)
    roots[~has] = -1
    # refit every multi-segment cluster on the union of its members' reliable pixels
    relabel = np.where(has, roots, k)  # label map over clusters, k = none
    cl_lab = relabel[np.asarray(segment_label_map(index))]
    cidx = build_segment_index(cl_lab.reshape(h, w))
    merged, _ = fit_planes(cidx, disparity, reliable, params=p)
    sizes = np.bincount(roots[has], minlength=k).astype(np.int64)
    d = np.ascontiguousarray(np.asarray(disparity, dtype=np.float64).ravel())
    rel = np.asarray(reliable, dtype=bool).ravel() & np.isfinite(d)
    # keep a member in its cluster only if the merged plane explains its reliable pixels about as well
    cluster, cplanes = _assign_clusters(index.order, index.starts, w, np.ascontiguousarray(planes, np.float64),
                                        np.ascontiguousarray(merged, np.float64), roots, has, sizes, d, rel,
                                        float(p.t_outlier))
    log.debug("plane merging: %d planes -> %d clusters", int(has.sum()), cplanes.shape[0])
    return cluster, cplanes


def segment_label_map(index: SegmentIndex) -> npt.NDArray[np.int64]:
    """Flat (H*W,) segment label of every pixel, rebuilt from the index."""
    k = index.n_segments
    lab = np.empty(index.order.size, np.int64)
    lab[index.order] = np.repeat(np.arange(k), np.diff(index.starts))
    return lab


def fill_missing_planes(assign: I32, pairs: I32, contrast: F64) -> I32:
    """Give every segment without a plane (-1) the plane of its most similar-coloured labelled neighbour.

    Parameters
    ----------
    assign : (K,) int32
        Plane index per segment, -1 = none.
    pairs : (P, 2) int32
        Adjacent pairs; ``contrast`` (P,) their colour contrast (lower = more similar).

    Returns
    -------
    (K,) int32 with -1 left only for segments with no labelled segment in their connected component
    (and every -1 replaced by 0 when no segment has a plane at all).
    """
    a = assign.copy()
    order = np.argsort(contrast, kind="stable")
    p0, p1 = pairs[order, 0], pairs[order, 1]
    for _ in range(1000):
        miss = a < 0
        if not miss.any():
            break
        changed = False
        for u, v in ((p0, p1), (p1, p0)):
            sel = miss[u] & (a[v] >= 0)
            uu, vv = u[sel], v[sel]
            # first (most similar) labelled neighbour wins
            first = np.unique(uu, return_index=True)[1]
            if first.size:
                a[uu[first]] = np.where(a[uu[first]] < 0, a[vv[first]], a[uu[first]])
                changed = True
            miss = a < 0
        if not changed:
            break
    if (a < 0).all():
        a[:] = 0
    return a


def render_planes(index: SegmentIndex, planes: F64,
                  assign: npt.NDArray[np.integer]) -> npt.NDArray[np.float32]:
    """Disparity map of a plane assignment.

    Parameters
    ----------
    index : SegmentIndex
    planes : (L, 3) float64 plane set.
    assign : (K,) int
        Plane index per segment (-1 = none -> NaN).

    Returns
    -------
    (H, W) float32 disparity, ``a x + b y + c`` of the segment's plane at every pixel.
    """
    h, w = index.shape
    return _render(index.order, index.starts, w, np.ascontiguousarray(planes, dtype=np.float64),
                   np.ascontiguousarray(assign, dtype=np.int64)).reshape(h, w)


@njit(cache=True, nogil=True)
def _render(order: npt.NDArray[np.int64], starts: npt.NDArray[np.int64], w: int, planes: F64,
            assign: npt.NDArray[np.int64]) -> npt.NDArray[np.float32]:
    out = np.empty(order.size, np.float32)
    for j in range(starts.size - 1):
        lab = assign[j]
        for t in range(starts[j], starts[j + 1]):
            p = order[t]
            if lab < 0:
                out[p] = np.nan
            else:
                # the float64 products and sums in numpy's order, then rounded once to float32
                out[p] = np.float32(planes[lab, 0] * float(p % w) + planes[lab, 1] * float(p // w) + planes[lab, 2])
    return out


def group_refit_planes(
    assign: npt.NDArray[np.integer], plane_set: npt.NDArray[np.float64], index: SegmentIndex,
    disparity: npt.NDArray[np.floating] | None = None, reliable: npt.NDArray[np.bool_] | None = None, *,
    params: PlaneParams | None = None,
    fit: Callable[[SegmentIndex], npt.NDArray[np.float64]] | None = None,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]] | None:
    """Refit one plane per group of segments that share a plane label (refit of merged planes, §6.1.3).

    Segments currently assigned the same plane are pooled and fitted again on ``disparity``'s reliable
    pixels (:func:`fit_planes` with ``params``), or by ``fit`` (the groups' index -> (G, 3) planes, NaN where
    no fit) when given; the refitted planes are appended to ``plane_set`` as new candidates.

    Returns
    -------
    (plane_set, ids) or None
        The extended (P', 3) plane set and, per segment, the id of its group's refitted plane (−1 where
        the group has no fit); ``None`` when no group could be refitted.
    """
    groups = build_segment_index(assign[segment_label_map(index)].reshape(index.shape))
    if fit is not None:
        group_planes = fit(groups)
    else:
        if disparity is None or reliable is None:
            raise ValueError("group_refit_planes needs disparity and reliable, or fit")
        group_planes, _ = fit_planes(groups, disparity, reliable, params=params or PlaneParams())
    used = np.unique(assign)
    ok = np.isfinite(group_planes[used, 0])
    if not ok.any():
        return None
    new_ids = np.full(plane_set.shape[0], -1, np.int64)
    new_ids[used[ok]] = plane_set.shape[0] + np.arange(int(ok.sum()))
    return np.concatenate([plane_set, group_planes[used[ok]]]), new_ids[assign]


def _segment_sums(lab: npt.NDArray[np.int64], k: int, rows: F64, target: F64,
                  use: npt.NDArray[np.bool_]) -> tuple[F64, F64]:
    """Normal equations of a per-segment least-squares fit: (K, m, m) ``Σ rᵢ rⱼ`` and (K, m) ``Σ rᵢ t`` over
    the pixels in ``use``."""
    m = rows.shape[1]
    lu, ru, tu = lab[use], rows[use], target[use]
    ata = np.empty((k, m, m))
    for i in range(m):
        for j in range(i, m):
            ata[:, i, j] = ata[:, j, i] = np.bincount(lu, weights=ru[:, i] * ru[:, j], minlength=k)
    atb = np.stack([np.bincount(lu, weights=ru[:, i] * tu, minlength=k) for i in range(m)], axis=1)
    return ata, atb.astype(np.float64)


def _solve(ata: F64, atb: F64) -> F64:
    # a tiny ridge keeps degenerate segments (a line of pixels) solvable; they fail the tests after
    ridge = 1e-9 * (np.trace(ata, axis1=1, axis2=2) + 1.0)
    eye = np.eye(ata.shape[1])[None]
    return np.asarray(np.linalg.solve(ata + ridge[:, None, None] * eye, atb[..., None])[..., 0], np.float64)


def curved_segment_surfaces(labels: npt.NDArray[np.integer], disparity: npt.NDArray[np.floating],
                            planar: npt.NDArray[np.bool_], evidence: npt.NDArray[np.bool_],
                            reference: npt.NDArray[np.floating], *, min_evidence: int = 100,
                            min_coverage: float = 0.3, tol: float = 1.0, max_rms_ratio: float = 0.6,
                            min_amplitude: float = 0.3, iterations: int = 3, max_shift: float = 1.0
                            ) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.bool_]]:
    """A segment whose evidence shows a curved surface takes the quadratic fitted to that evidence.

    One plane per segment (Eq. 6.1) cannot follow a curved surface (cloth, a ball): the robust fit keeps the
    evidence within ``t_outlier`` of the plane, and the plane drifts off the surface by up to that much at the
    segment's ends, where the evidence bends away. Per segment, the residual ``reference - disparity`` of its
    evidence pixels on its own plane (``planar``) within ``tol`` is fitted by a quadric
    ``q(u, v) = c₀u² + c₁uv + c₂v² + c₃u + c₄v + c₅`` (coordinates centred and scaled on the evidence), the
    inliers re-chosen within ``tol`` of it ``iterations`` times (as Eq. 6.9). The quadric replaces the plane
    only when the evidence supports a curve, not an offset or a tilt of the plane: at least ``min_evidence``
    inliers covering ``min_coverage`` of the segment, an RMS residual at most ``max_rms_ratio`` of the best
    plane's through the same inliers, and a curved part (quadric less that plane) of at least
    ``min_amplitude`` px somewhere on the segment. It is evaluated only inside the evidence's bounding box
    (clamped outside: no extrapolation of the curvature) and shifts a pixel by at most ``max_shift`` px.

    Parameters
    ----------
    labels : (H, W) int       segments 0..K-1.
    disparity : (H, W) float  current map.
    planar : (H, W) bool      pixels whose disparity is their segment's own plane (the only ones changed).
    evidence : (H, W) bool    trusted pixels of ``reference`` (both cross-checked initial maps agree).
    reference : (H, W) float  the evidence's disparity.

    Returns
    -------
    disparity : (H, W) float32 with the accepted segments' quadrics; curved : (K,) bool accepted segments.
    """
    lab = np.asarray(labels).ravel().astype(np.int64)
    h, w = np.asarray(labels).shape
    k = int(lab.max()) + 1 if lab.size else 0
    disp = np.asarray(disparity, np.float64).ravel()
    plan = np.asarray(planar, bool).ravel()
    ev = plan & np.asarray(evidence, bool).ravel() & np.isfinite(np.asarray(reference).ravel())
    r = np.where(ev, np.asarray(reference, np.float64).ravel() - disp, 0.0)
    sizes = np.bincount(lab, minlength=k)
    curved = np.zeros(k, bool)
    out = np.asarray(disparity, np.float32).copy()
    if k == 0 or not ev.any():
        return out, curved
    xs = (np.arange(h * w) % w).astype(np.float64)
    ys = (np.arange(h * w) // w).astype(np.float64)
    inl = ev & (np.abs(r) <= tol)
    n = np.bincount(lab, weights=inl, minlength=k)
    cx = np.bincount(lab, weights=xs * inl, minlength=k) / np.maximum(n, 1)
    cy = np.bincount(lab, weights=ys * inl, minlength=k) / np.maximum(n, 1)
    big = np.float64(h + w)
    x0 = np.full(k, big)
    x1 = np.full(k, -big)
    y0 = np.full(k, big)
    y1 = np.full(k, -big)
    np.minimum.at(x0, lab[inl], xs[inl])
    np.maximum.at(x1, lab[inl], xs[inl])
    np.minimum.at(y0, lab[inl], ys[inl])
    np.maximum.at(y1, lab[inl], ys[inl])
    scale = np.maximum(np.maximum(x1 - x0, y1 - y0), 1.0)
    cand = (n >= min_evidence) & (x1 - x0 >= 2) & (y1 - y0 >= 2)
    if not cand.any():
        return out, curved
    # only the candidates and their pixels (renumbered 0..C-1): every sum below is per segment, so the others'
    # pixels change nothing
    cs = np.flatnonzero(cand)
    cid = np.zeros(k, np.int64)
    cid[cs] = np.arange(cs.size)
    sub = np.flatnonzero(cand[lab])
    kc = cs.size
    lab, xs, ys, r, ev, inl = cid[lab[sub]], xs[sub], ys[sub], r[sub], ev[sub], inl[sub]
    cx, cy, scale = cx[cs], cy[cs], scale[cs]
    u = (xs - cx[lab]) / scale[lab]
    v = (ys - cy[lab]) / scale[lab]
    quad = np.stack([u * u, u * v, v * v, u, v, np.ones_like(u)], axis=1)
    sol = _solve(*_segment_sums(lab, kc, quad, r, inl))
    for _ in range(max(iterations, 0)):
        inl = ev & (np.abs((quad * sol[lab]).sum(1) - r) <= tol)
        sol = _solve(*_segment_sums(lab, kc, quad, r, inl))
    n = np.bincount(lab, weights=inl, minlength=kc)
    # the final inliers' bounding box: where the quadric is evaluated
    x0, x1, y0, y1 = np.full(kc, big), np.full(kc, -big), np.full(kc, big), np.full(kc, -big)
    np.minimum.at(x0, lab[inl], xs[inl])
    np.maximum.at(x1, lab[inl], xs[inl])
    np.minimum.at(y0, lab[inl], ys[inl])
    np.maximum.at(y1, lab[inl], ys[inl])
    lin = _solve(*_segment_sums(lab, kc, quad[:, 3:], r, inl))
    res2 = np.bincount(lab, weights=inl * ((quad * sol[lab]).sum(1) - r) ** 2, minlength=kc)
    res1 = np.bincount(lab, weights=inl * ((quad[:, 3:] * lin[lab]).sum(1) - r) ** 2, minlength=kc)
    # the curved part over the segment, the quadric evaluated inside the evidence's bounding box only
    uc = (np.clip(xs, x0[lab], x1[lab]) - cx[lab]) / scale[lab]
    vc = (np.clip(ys, y0[lab], y1[lab]) - cy[lab]) / scale[lab]
    qc = np.stack([uc * uc, uc * vc, vc * vc, uc, vc, np.ones_like(uc)], axis=1)
    q_all = (qc * sol[lab]).sum(1)
    bend = np.abs(q_all - (qc[:, 3:] * lin[lab]).sum(1))
    amp = np.zeros(kc)
    np.maximum.at(amp, lab, bend)
    curved[cs] = ((n >= min_evidence) & (n >= min_coverage * sizes[cs]) & (res2 <= max_rms_ratio ** 2 * res1)
                  & (amp >= min_amplitude))
    change = curved[cs][lab] & plan[sub]
    px = sub[change]
    out.ravel()[px] = (disp[px] + np.clip(q_all[change], -max_shift, max_shift)).astype(np.float32)
    return out, curved
