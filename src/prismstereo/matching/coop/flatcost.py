"""Where the local matcher's cost has no distinct minimum: the fallback step's evidence for ``sgm``'s map.

A segment that fails the plane support test falls back to a local map (an addition to thesis §6.1). On a wide,
weakly textured surface (a wall, the body of a piano) the ``bpasw`` matcher's aggregated cost (§5.2) is nearly
flat over the disparities: its winner is a guess, and its left-right check passes anyway, because both views read
the same flat volume. The ``sgm`` matcher propagates costs along eight paths across the whole image, so the
disparity of the surface's textured border reaches its inside; where its own check then keeps a fair share of the
segment, its map is the one with evidence.

The flatness of a pixel's cost is the peak ratio ``(c2 - c1) / c1`` of the best cost ``c1`` and the best cost
``c2`` farther than one level from the winner (0: a second minimum as low as the first).

A segment can also be outvoted: where the two local matchers, each passing its own left-right check, agree with
each other within a pixel and both lie many pixels away from the segment's final disparity, the segment's plane
was carried there by its neighbours or the smoothness term against two independent pieces of evidence
(:func:`outvoted_segments`); such segments join the fallback.

The two matchers' checks can also contradict each other: in a fallback segment where both left-right checks hold
on many pixels but the two maps lie more than a pixel apart there, a check passed for two different disparities,
so it cannot tell which is right. The colour cost's check is the weaker one: a radiometric difference between the
views (a brightness offset, a shading gradient, a glow on a bare wall) moves the minimum of BPASW's colour cost,
and both views read the same biased volume, so its check passes at the moved minimum; ``sgm``'s census cost is
unchanged by such differences and its paths carry the disparity of the surface's textured border inward
(:func:`contradicted_segments`); such segments take ``sgm``'s map.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from numba import njit

__all__ = ["contradicted_segments", "flat_cost_segments", "outvoted_segments", "peak_ratio"]

F32 = npt.NDArray[np.float32]
B = npt.NDArray[np.bool_]


@njit(cache=True, nogil=True)
def _peak_ratio(vol: F32, winner: npt.NDArray[np.int64], where: B) -> F32:
    """Peak ratio ``(c2 - c1) / c1`` (H, W) float32 of ``vol`` (H, W, D) at ``winner`` where ``where``: an addition to
    thesis §6.1 (module docstring) with no thesis equation of its own."""
    h, w, nd = vol.shape
    out = np.full((h, w), np.inf, np.float32)
    for y in range(h):
        for x in range(w):
            if not where[y, x]:
                continue
            k = winner[y, x]
            c1 = vol[y, x, k]
            # the levels next to the winner are its own peak, not a second minimum (clipped as np.clip)
            lo = max(0, min(k - 1, nd - 1))
            hi = max(0, min(k + 1, nd - 1))
            c2 = np.inf
            for d in range(nd):
                if d < lo or d > hi:
                    c2 = min(c2, vol[y, x, d])
            out[y, x] = np.float32((c2 - c1) / max(c1, np.float32(1e-6)))
    return out


def peak_ratio(vol: F32, winner: npt.NDArray[np.int64], where: B) -> F32:
    """Peak ratio of an aggregated cost volume at its winners (see the module docstring).

    An addition to thesis §6.1 (module docstring) with no thesis equation of its own.

    Parameters
    ----------
    vol : (H, W, D) float32  aggregated cost (lower is better).
    winner : (H, W) int64  ``vol.argmin(axis=2)``.
    where : (H, W) bool  pixels wanted.

    Returns
    -------
    (H, W) float32, ``(c2 - c1) / max(c1, 1e-6)`` at ``where`` (inf elsewhere, and where no level lies farther
    than one from the winner).
    """
    return np.asarray(_peak_ratio(np.ascontiguousarray(vol, np.float32), np.ascontiguousarray(winner, np.int64),
                                  np.ascontiguousarray(where, np.bool_)), np.float32)


def _segment_medians(lab: npt.NDArray[np.int64], values: npt.NDArray[np.float64], n: int) -> npt.NDArray[np.float64]:
    """Median of ``values`` per label 0..n-1 (NaN for an absent label), as :func:`numpy.median`.

    Implementation helper (per-label median) with no thesis equation of its own.
    """
    order = np.lexsort((values, lab))
    ls, vs = lab[order], values[order]
    starts = np.searchsorted(ls, np.arange(n))
    ends = np.searchsorted(ls, np.arange(n), side="right")
    cnt = ends - starts
    out = np.full(n, np.nan)
    ok = cnt > 0
    lo = starts[ok] + (cnt[ok] - 1) // 2
    hi = starts[ok] + cnt[ok] // 2
    out[ok] = 0.5 * (vs[lo] + vs[hi])
    return out


def flat_cost_segments(labels: npt.NDArray[np.int32], where: B, ratio: F32, sgm_support: B, bpasw_support: B, *,
                       max_ratio: float, min_support: float, support_margin: float) -> B:
    """The segments whose ``where`` pixels should take ``sgm``'s map because ``bpasw``'s cost is flat there.

    An addition to thesis §6.1 (module docstring) with no thesis equation of its own.

    Parameters
    ----------
    labels : (H, W) int32  segments.
    where : (H, W) bool  the pixels being replaced.
    ratio : (H, W) float32  :func:`peak_ratio` of the ``bpasw`` volume (read at ``where``).
    sgm_support, bpasw_support : (H, W) bool  pixels each matcher's own left-right check keeps.
    max_ratio : float, keyword-only
        A segment qualifies when the median peak ratio of its ``where`` pixels is below this (0: never)...
    min_support, support_margin : float, keyword-only
        ... and ``sgm``'s check keeps at least ``min_support`` of them and no less than ``bpasw``'s share minus
        ``support_margin``.

    Returns
    -------
    (H, W) bool, the ``where`` pixels of the qualifying segments.
    """
    if max_ratio <= 0 or not where.any():
        return np.zeros(labels.shape, np.bool_)
    lab = labels[where].astype(np.int64)
    n = int(labels.max()) + 1
    cnt = np.maximum(np.bincount(lab, minlength=n), 1).astype(np.float64)
    s_sgm = np.bincount(lab, weights=sgm_support[where].astype(np.float64), minlength=n) / cnt
    s_bp = np.bincount(lab, weights=bpasw_support[where].astype(np.float64), minlength=n) / cnt
    med = _segment_medians(lab, ratio[where].astype(np.float64), n)
    take = (med < max_ratio) & (s_sgm >= min_support) & (s_sgm >= s_bp - support_margin)
    return np.asarray(where & take[labels], np.bool_)


def outvoted_segments(labels: npt.NDArray[np.int32], final: F32, bpasw: F32, bpasw_support: B, sgm: F32,
                      sgm_support: B, *, tol: float, min_share: float, min_size: float) -> B:
    """The pixels of the segments whose final map both local matchers contradict.

    An addition to thesis §6.1 (module docstring) with no thesis equation of its own.

    Parameters
    ----------
    labels : (H, W) int32  segments.
    final : (H, W) float32  the map before the fallback.
    bpasw, sgm : (H, W) float32  the two local matchers' dense maps.
    bpasw_support, sgm_support : (H, W) bool  pixels each matcher's own left-right check keeps.
    tol : float, keyword-only
        A pixel votes against ``final`` when both checks keep it, the two maps agree within 1 px and both lie
        more than ``tol`` px from ``final`` (0: never).
    min_share, min_size : float, keyword-only
        A segment is outvoted when at least ``min_share`` of its pixels vote against it and it covers at least
        ``min_size`` of the image (small segments at depth edges are where both local maps fatten the foreground).

    Returns
    -------
    (H, W) bool, every pixel of the outvoted segments.
    """
    if tol <= 0:
        return np.zeros(labels.shape, np.bool_)
    votes = (bpasw_support & sgm_support & (np.abs(bpasw - sgm) <= 1.0) & (np.abs(final - bpasw) > tol)
             & (np.abs(final - sgm) > tol))
    take = _voted_segments(labels, np.ones(labels.shape, np.bool_), votes, min_share=min_share, min_size=min_size)
    return np.asarray(take[labels], np.bool_)


def _voted_segments(labels: npt.NDArray[np.int32], where: B, votes: B, *, min_share: float,
                    min_size: float) -> B:
    """(n_segments,) bool: the segments whose ``where`` pixels cover at least ``min_size`` of the image and are
    ``votes`` on at least ``min_share`` of them (and on one at least)."""
    n = int(labels.max()) + 1
    cnt = np.bincount(labels[where].astype(np.int64), minlength=n).astype(np.float64)
    against = np.bincount(labels[where & votes].astype(np.int64), minlength=n).astype(np.float64)
    return np.asarray((cnt >= min_size * labels.size) & (against >= min_share * np.maximum(cnt, 1.0))
                      & (against > 0), np.bool_)


def contradicted_segments(labels: npt.NDArray[np.int32], where: B, bpasw: F32, bpasw_support: B, sgm: F32,
                          sgm_support: B, *, min_share: float, min_size: float) -> B:
    """The segments whose ``where`` pixels should take ``sgm``'s map because the two matchers' checks contradict.

    An addition to thesis §6.1 (module docstring) with no thesis equation of its own.

    Parameters
    ----------
    labels : (H, W) int32  segments.
    where : (H, W) bool  the pixels being replaced.
    bpasw, sgm : (H, W) float32  the two local matchers' dense maps (read at ``where``).
    bpasw_support, sgm_support : (H, W) bool  pixels each matcher's own left-right check keeps.
    min_share : float, keyword-only
        A segment qualifies when at least this share of its ``where`` pixels have both checks holding and the two
        maps more than 1 px apart (0: never)...
    min_size : float, keyword-only
        ... and its ``where`` pixels cover at least this share of the image.

    Returns
    -------
    (H, W) bool, the ``where`` pixels of the qualifying segments.
    """
    if min_share <= 0 or not where.any():
        return np.zeros(labels.shape, np.bool_)
    both = bpasw_support & sgm_support & (np.abs(bpasw - sgm) > 1.0)
    take = _voted_segments(labels, where, both, min_share=min_share, min_size=min_size)
    return np.asarray(where & take[labels], np.bool_)
