"""Per-match confidence and the filters that turn the matcher's disparities into the points of a depth run.

The pipeline's ``refine`` and ``speckles`` steps are these plain functions on arrays:

- :func:`confident_matches` refines every cross-checked match to sub-pixel precision
  (:func:`~prismstereo.depth.refine.refine_disparity`) and gives it a confidence in [0, 1]: the zero-mean
  normalised cross-correlation of the two refined windows (negative values clipped to 0) where the
  refinement could confirm the match, 0 where it could not (window without texture or off a view, the
  refinement moved it by a pixel or more: the matcher's value was off, or the right view's own refined
  disparity at x − d disagrees: a window pulled across a depth edge). Where the window is cut by the
  edge of a view, it is cut to the pixels both views have (``min_pixels`` of
  :func:`~prismstereo.depth.refine.refine_disparity`): near the edges of a small common view (a
  tri-prism's) that is a large share of it. With ``retry_radius`` the matches whose window stayed below
  ``retry_below`` (or were dropped) are refined and checked again with a wider window, whose result
  replaces the first where it is confirmed: on weak texture a small window's sub-pixel value is noisy.
  With ``retry_drop`` a match the wider window could not confirm gets confidence 0 (it had already
  failed to reach ``retry_below`` in the small one).
  Matches below ``min_confidence`` are dropped; ``min_confidence=None`` keeps them all with their
  confidence, for the user to filter.
- :func:`remove_speckles` drops connected patches of disparity smaller than a share of the matched region.
- :func:`confident_fill` tries again, from the matcher's dense (hole-filled, smoothed) map, where no
  cross-checked match was kept: on weak texture the integer cross-check and the refinement from the raw
  values drop whole regions the matcher had right; the same refinement, sub-pixel left–right check and
  confidence threshold confirm or drop each of them. With ``agree`` a filled value is kept only where the
  two windows (``radius`` and ``retry_radius``), each confirmed on its own, agree: the dense map's
  values are guesses, and two independent sub-pixel values that agree are what tells a right one.
- :func:`confident_growth` tries once more where neither kept a value, with a wider window, and keeps a
  value only where it agrees with what the kept neighbours around it say (their Gaussian-weighted mean, or
  the weighted plane through those on the value's own surface, :func:`neighbour_plane`):
  on texture too weak for the two windows, a value that the wide window confirms on its own and that
  continues the surface around it is right far more often than one that only a window confirms.
- :func:`plane_interpolation` keeps, where none of those kept a value, the weighted plane through the kept
  neighbours on one surface where the matcher's dense value lies on it: beside a depth edge and on the
  weakest texture every window reaches the other surface or has nothing to match, but the matcher's
  aggregated cost still found the surface that the kept values around the pixel continue.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numba import njit, prange

from prismstereo.depth._lrcheck import lr_gap, mirror, read_by_check, seen_from_right
from prismstereo.depth.refine import refine_disparity
from prismstereo.errors import ConfigError
from prismstereo.rectify.epipolar import EpipolarTable

__all__ = ["confident_fill", "confident_growth", "confident_matches", "neighbour_disparity", "neighbour_plane",
           "plane_interpolation", "remove_speckles"]


def confident_matches(left: np.ndarray, right: np.ndarray, disparity: np.ndarray, *, radius: int = 5,
                      iterations: int = 6, max_shift: float = 1.0, min_texture: float = 0.01,
                      min_confidence: float | None = None,
                      border_radius: int | None = 3, max_lr_gap: float | None = 0.45,
                      valid_left: np.ndarray | None = None,
                      valid_right: np.ndarray | None = None,
                      epipolar: EpipolarTable | None = None,
                      prefilter: float | None = 0.7,
                      right_seeds: np.ndarray | None = None,
                      retry_radius: int | None = None,
                      retry_below: float = 0.95,
                      retry_drop: bool = False,
                      seeds_checked: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Refine matches, rate them and keep the confident ones.

    With ``retry_radius``, every match whose ``radius`` window did not reach a confidence of ``retry_below``
    (dropped ones included) is refined and checked again with the wider window, and the wider window's
    result replaces it where that one is confirmed (refined, within ``max_shift``, through the sub-pixel
    check; its confidence is the wider window's ZNCC). A window's ZNCC is about its texture's share of
    signal over sensor noise: a low one is a window too small for its texture, whose sub-pixel value is
    noisy (or, at a depth edge, mixed: the check drops those), and four times the pixels halve the noise.

    Parameters
    ----------
    left, right : (H, W) or (H, W, 3) arrays
        The rectified pair.
    disparity : (H, W) float array
        The matcher's disparities of ``left``, px, NaN = no match.
    radius : int
        Half-size of the refinement window, px.
    iterations, max_shift : int, float
        The refinement's Gauss–Newton iterations and largest move from the matcher's value, px.
    min_texture : float
        Mean squared horizontal gradient (grey levels²/px²) a window needs to be refined.
    min_confidence : float or None
        Drop matches whose confidence is below this; None keeps every match.
    border_radius : int or None
        Where the ``radius`` window is cut by the edge of the image or of a view (rectified left, or right
        at the match), the window is cut to its pixels inside both and refined if it keeps at least as many
        as a full ``border_radius`` window, (2·border_radius + 1)²; None: such matches are not refined.
    max_lr_gap : float or None
        Sub-pixel left–right check: the right view's disparities are refined too (from the matches seen
        from the right, ``seeds_checked``) and a match whose refined disparity differs from the right view's
        at ``x − d`` by more than this (px) gets confidence 0. A window across a depth edge is pulled towards the
        surface with more texture differently from the two sides; the check finds those. None: no check.
    valid_left, valid_right : (H, W) bool, optional
        Valid regions of the rectified views.
    epipolar : EpipolarTable, optional
        The pair's epipolar curves: the right windows (and the left ones of the check) are sampled on the
        rows the optics put the match on (δy at the matcher's disparity), not on the left pixel's row.
    prefilter : float or None
        Gaussian low-pass (standard deviation, px) along the rows of both views before the refinement
        (``prefilter`` of :func:`~prismstereo.depth.refine.refine_disparity`); None: none.
    right_seeds : (H, W) float array, optional
        The left view's disparities whose moves to x − d give the right view's matches of the sub-pixel
        check (default: ``disparity``); :func:`confident_fill` checks a few left pixels against the right
        view of a whole map.
    retry_radius : int or None
        Half-size of the second, wider window (see above); None: one window.
    retry_below : float
        Matches whose first confidence is below this (or that were dropped) get the wider window.
    retry_drop : bool
        A retried match that the wider window does not confirm gets confidence 0 (so ``min_confidence``
        drops it) instead of keeping its first window's result: its small window was weak, and the wide
        one, with four times the pixels, failed the refinement or the sub-pixel check.
    seeds_checked : bool
        The values of ``right_seeds`` passed a left–right check of their own (the matcher's integer
        cross-check): every one stands for the right view in the sub-pixel check. False (a dense map:
        ``coop``'s, which has no cross-check, or a hole-filled one): at each right pixel the largest value
        landing there that its own window confirms stands for it (refined, ``min_confidence`` reached
        before the check), an unconfirmed one only where none does (:func:`_seen_confirmed`).

    Returns
    -------
    disparity : (H, W) float32
        Refined disparities (the matcher's value where the refinement could not confirm it), NaN where
        there is no match or it was dropped.
    confidence : (H, W) float32
        Confidence in [0, 1] of each remaining match, NaN where ``disparity`` is NaN.
    """
    kw: dict[str, Any] = dict(iterations=iterations, max_shift=max_shift, min_texture=min_texture,
                              border_radius=border_radius, max_lr_gap=max_lr_gap, valid_left=valid_left,
                              valid_right=valid_right, epipolar=epipolar, prefilter=prefilter,
                              right_seeds=disparity if right_seeds is None else right_seeds,
                              seeds_checked=seeds_checked)
    disp, conf = _rated(left, right, disparity, radius=radius, min_confidence=min_confidence, **kw)
    if retry_radius is not None and retry_radius != radius:
        d_in = np.asarray(disparity, dtype=np.float32)
        retry = np.isfinite(d_in) & ~(conf >= retry_below)
        if retry.any():
            d2, c2 = _rated(left, right, np.where(retry, d_in, np.float32(np.nan)), radius=retry_radius,
                            min_confidence=min_confidence, **kw)
            take = retry & np.isfinite(d2) & (c2 > 0.0)
            disp, conf = np.where(take, d2, disp), np.where(take, c2, conf)
            if retry_drop:
                conf = np.where(retry & ~take & np.isfinite(disp), np.float32(0.0), conf)
    keep = np.isfinite(disp) if min_confidence is None else np.isfinite(disp) & (conf >= min_confidence)
    nan = np.float32(np.nan)
    return np.where(keep, disp, nan).astype(np.float32), np.where(keep, conf, nan).astype(np.float32)


def _rated(left: np.ndarray, right: np.ndarray, disparity: np.ndarray, *, radius: int, iterations: int,
           max_shift: float, min_texture: float, min_confidence: float | None, border_radius: int | None,
           max_lr_gap: float | None, valid_left: np.ndarray | None, valid_right: np.ndarray | None,
           epipolar: EpipolarTable | None, prefilter: float | None, right_seeds: np.ndarray,
           seeds_checked: bool) -> tuple[np.ndarray, np.ndarray]:
    """One window: (H, W) float32 refined disparities (the input value where the refinement could not
    confirm it, NaN where there is no match) and their confidence (0 where unconfirmed or failing the
    check, NaN where there is no match); nothing dropped yet."""
    min_pixels = None if border_radius is None else (2 * border_radius + 1) ** 2
    rows = None if epipolar is None else epipolar.row_offset_map(disparity)
    disp, zncc = refine_disparity(left, right, disparity, radius=radius, iterations=iterations,
                                  max_shift=max_shift, min_texture=min_texture,
                                  valid_left=valid_left, valid_right=valid_right, min_pixels=min_pixels,
                                  row_offset=rows, prefilter=prefilter)
    matched = np.isfinite(disp)
    conf = np.where(np.isfinite(zncc), np.clip(zncc, 0.0, 1.0), np.float32(0.0)).astype(np.float32)
    if max_lr_gap is not None:
        # the right view's matches: the left's moved to x − d (the nearer surface wins a pixel), refined
        # on the mirrored pair, where the right view is the left one; only at the right pixels the check
        # reads (each pixel is refined on its own, so the others change nothing)
        asked = conf > 0.0 if min_confidence is None else conf >= max(min_confidence, np.nextafter(0.0, 1.0))
        seen = (_seen_from_right(right_seeds) if seeds_checked
                else _seen_confirmed(right_seeds, disparity, asked & matched))
        disp_r = _right_refined(left, right, seen, disp, asked & matched, epipolar, radius=radius,
                                iterations=iterations, max_shift=max_shift, min_texture=min_texture,
                                min_pixels=min_pixels, valid_left=valid_left, valid_right=valid_right,
                                prefilter=prefilter)
        conf[_lr_gap(disp, disp_r) > max_lr_gap] = 0.0
    return disp.astype(np.float32), np.where(matched, conf, np.float32(np.nan)).astype(np.float32)


def confident_fill(left: np.ndarray, right: np.ndarray, disparity: np.ndarray, confidence: np.ndarray,
                   filled: np.ndarray, *, valid_right: np.ndarray | None = None, agree: float | None = None,
                   **kwargs: Any) -> tuple[np.ndarray, np.ndarray]:
    """Add the confident matches of the matcher's dense (hole-filled, post-processed) map where
    :func:`confident_matches` kept none of its cross-checked ones.

    The second try starts each remaining pixel from ``filled`` (the matcher's own dense output, its
    smoothing included) and checks it like any match: the refinement must converge within ``max_shift``,
    the sub-pixel left–right check (against the right view of the whole ``filled`` map) must agree, and
    the confidence must reach ``min_confidence``. On weak texture the matcher's integer cross-check and
    the refinement from its raw values drop whole regions that this confirms.

    Parameters
    ----------
    left, right : (H, W) or (H, W, 3) arrays
        The rectified pair.
    disparity, confidence : (H, W) float32
        :func:`confident_matches`' result on the cross-checked matches (NaN = none kept).
    filled : (H, W) float array
        The matcher's dense disparities, px, NaN outside the searched region.
    valid_right : (H, W) bool, optional
        Valid region of the rectified right view (a filled value whose right pixel is outside is skipped).
    agree : float or None
        Keep a filled value only where its ``radius`` window and its ``retry_radius`` window are each
        confirmed (refinement, sub-pixel check, ``min_confidence``; a confidence > 0 without it) and their
        refined disparities differ by less than this, px; the value kept is the wider window's where the
        first one's confidence is below ``retry_below``, as in :func:`confident_matches`. None: every
        confirmed filled value (one pass of :func:`confident_matches`).
    **kwargs
        The other keyword arguments of :func:`confident_matches` (``max_lr_gap`` must not be None: the
        check is what tests a filled value).

    Returns
    -------
    disparity, confidence : (H, W) float32
        ``disparity`` and ``confidence`` with the confirmed filled matches added.

    Raises
    ------
    ConfigError
        ``max_lr_gap`` None, or ``agree`` without a ``retry_radius`` other than ``radius``.
    """
    _require_lr_check(kwargs, "confident_fill", "a filled value")
    kwargs.pop("seeds_checked", None)  # the dense map's values are not cross-checked
    if agree is not None and kwargs.get("retry_radius") in (None, kwargs.get("radius", 5)):
        raise ConfigError(f"confident_fill agree: needs a second window (retry_radius other than radius), got "
                          f"retry_radius {kwargs.get('retry_radius')!r}; pass agree=None for one window")
    d = np.asarray(disparity, dtype=np.float32)
    f = np.asarray(filled, dtype=np.float32)
    seeds = _seeds_seen(f, np.isfinite(f), valid_right)
    retry = np.where(~np.isfinite(d), seeds, np.float32(np.nan))
    if not np.isfinite(retry).any():
        return d, np.asarray(confidence, dtype=np.float32)
    if agree is None:
        d2, c2 = confident_matches(left, right, retry, valid_right=valid_right, right_seeds=seeds,
                                   seeds_checked=False, **kwargs)
    else:
        d2, c2 = _agreeing(left, right, retry, seeds, valid_right=valid_right, agree=agree, **kwargs)
    add = ~np.isfinite(d) & np.isfinite(d2)
    return (np.where(add, d2, d).astype(np.float32),
            np.where(add, c2, np.asarray(confidence, dtype=np.float32)).astype(np.float32))


def _agreeing(left: np.ndarray, right: np.ndarray, seeds: np.ndarray, right_seeds: np.ndarray, *,
              valid_right: np.ndarray | None, agree: float, **kwargs: Any) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) float32 disparities and confidences of the ``seeds`` that both windows confirm and that agree
    within ``agree`` px (see :func:`confident_fill`), NaN elsewhere."""
    below = float(kwargs.pop("retry_below", 0.95))
    wide = int(kwargs.pop("retry_radius"))
    small = int(kwargs.pop("radius", 5))
    kwargs.pop("retry_drop", None)
    d1, c1 = confident_matches(left, right, seeds, radius=small, valid_right=valid_right, right_seeds=right_seeds,
                               seeds_checked=False, **kwargs)
    d2, c2 = confident_matches(left, right, seeds, radius=wide, valid_right=valid_right, right_seeds=right_seeds,
                               seeds_checked=False, **kwargs)
    with np.errstate(invalid="ignore"):
        both = (c1 > 0.0) & (c2 > 0.0) & (np.abs(d1 - d2) < agree)
    first = c1 >= below
    nan = np.float32(np.nan)
    return (np.where(both, np.where(first, d1, d2), nan).astype(np.float32),
            np.where(both, np.where(first, c1, c2), nan).astype(np.float32))


def neighbour_disparity(disparity: np.ndarray, *, sigma: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What the finite disparities around each pixel say of it: their Gaussian-weighted mean, the weights'
    sum and the weighted spread (standard deviation) about that mean.

    Parameters
    ----------
    disparity : (H, W) float array
        Px, NaN = none.
    sigma : float
        Standard deviation of the Gaussian weights, px (the kernel reaches 3 sigma).

    Returns
    -------
    mean, support, spread : (H, W) float32
        The weighted mean (NaN where no finite value is in reach), the sum of the weights of the finite
        values (1 where every pixel in reach has one) and the weighted standard deviation (NaN with the mean).
    """
    d = np.asarray(disparity, dtype=np.float32)
    finite = np.isfinite(d)
    v = finite.astype(np.float32)
    # about the map's median: the second moment of disparities of ~100 px in float32 would lose the spread
    ref = np.float32(np.median(d[finite])) if finite.any() else np.float32(0.0)
    x = np.where(finite, d - ref, np.float32(0.0)).astype(np.float32)
    k = 2 * int(np.ceil(3.0 * sigma)) + 1

    def blur(a: np.ndarray) -> np.ndarray:
        return np.asarray(cv2.GaussianBlur(a, (k, k), float(sigma), borderType=cv2.BORDER_CONSTANT))

    support = blur(v)
    ok = support > 1e-3
    den = np.maximum(support, np.float32(1e-6))
    m1 = blur(x) / den
    m2 = blur(x * x) / den
    nan = np.float32(np.nan)
    mean = np.where(ok, m1 + ref, nan).astype(np.float32)
    spread = np.where(ok, np.sqrt(np.maximum(m2 - m1 * m1, 0.0)), nan).astype(np.float32)
    return mean, support.astype(np.float32), spread


def neighbour_plane(disparity: np.ndarray, ys: np.ndarray, xs: np.ndarray, values: np.ndarray, *, sigma: float,
                    inlier: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """What the finite disparities around some pixels that agree with a value of each say of it, slant
    included: the Gaussian-weighted least-squares plane (d ≈ a + b·u + c·v over the offsets u, v from the
    pixel) through the neighbours within ``inlier`` px of the value, then refit through those within
    ``inlier`` px of that plane, read at the pixel.

    A surface slanted in disparity (a floor, a wall seen obliquely) spreads its values about their mean by
    its gradient times the kernel's reach, and near a depth edge the neighbours hold two surfaces: the
    plane through the neighbours on the value's own surface is what that surface says of the pixel, and
    their share of the neighbours' weight says how much of the pixel's surroundings is that surface.

    Parameters
    ----------
    disparity : (H, W) float array
        Px, NaN = none.
    ys, xs : (N,) int arrays
        The pixels.
    values : (N,) float array
        The value each pixel is asked about, px.
    sigma : float
        Standard deviation of the Gaussian weights, px (the kernel reaches 3 sigma).
    inlier : float
        Largest distance of a neighbour's value from the pixel's value (then from the first plane) to take
        part in the fit, px.

    Returns
    -------
    plane, spread, inliers, support : (N,) float64
        The second plane's value at the pixel (the inliers' weighted mean where a plane is not determined:
        they lie on a line; NaN where no neighbour is within ``inlier``), the weighted standard deviation of
        its inliers about it, their weight and the weight of every finite neighbour (1 where every pixel in
        reach has a value; Gaussian weights of unit sum).
    """
    d = np.asarray(disparity, dtype=np.float32)
    out = _inlier_planes(d, np.asarray(ys, dtype=np.int64), np.asarray(xs, dtype=np.int64),
                         np.asarray(values, dtype=np.float64), float(sigma), float(inlier), np.inf)
    return out[:, 0], out[:, 1], out[:, 2], out[:, 3]


@njit(cache=True, parallel=True, nogil=True)
def _inlier_planes(d: np.ndarray, ys: np.ndarray, xs: np.ndarray, values: np.ndarray, sigma: float,
                   inlier: float, gap: float) -> np.ndarray:  # pragma: no cover - numba
    """(N, 5): :func:`neighbour_plane`'s four columns and the weight of the neighbours farther than ``gap``
    px from the plane the last fit started from (the first one: about the value; the second: the first
    plane)."""
    h, w = d.shape
    r = int(np.ceil(3.0 * sigma))
    g = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    g = g / g.sum()
    n = ys.size
    out = np.full((n, 5), np.nan)
    for k in prange(n):
        y0, x0, v0 = ys[k], xs[k], values[k]
        # first the neighbours within ``inlier`` of the value, then those within it of their plane: on a
        # steep slope the first band is narrow, the second reaches the whole surface
        a = b = c = 0.0
        for _step in range(2):
            total = far = 0.0
            s = su = sv = suu = suv = svv = se = sue = sve = see = 0.0
            for dy in range(max(-r, -y0), min(r, h - 1 - y0) + 1):
                for dx in range(max(-r, -x0), min(r, w - 1 - x0) + 1):
                    dv = d[y0 + dy, x0 + dx]
                    if not np.isfinite(dv):
                        continue
                    wt = g[dy + r] * g[dx + r]
                    total += wt
                    e = dv - v0  # about the value: the sums keep the residuals' precision
                    off = abs(e - (a + b * dx + c * dy))
                    if off > gap:
                        far += wt
                    if off > inlier:
                        continue
                    s += wt
                    su += wt * dx
                    sv += wt * dy
                    suu += wt * dx * dx
                    suv += wt * dx * dy
                    svv += wt * dy * dy
                    se += wt * e
                    sue += wt * dx * e
                    sve += wt * dy * e
                    see += wt * e * e
            out[k, 2] = s
            out[k, 3] = total
            out[k, 4] = far
            out[k, 0] = np.nan
            out[k, 1] = np.nan
            if s <= 0.0:
                break
            # the 3×3 normal equations by cofactors
            c00 = suu * svv - suv * suv
            c01 = sv * suv - su * svv
            c02 = su * suv - sv * suu
            det = s * c00 + su * c01 + sv * c02
            if det <= 1e-9 * s ** 3 * max(sigma, 1.0) ** 4:
                a, b, c = se / s, 0.0, 0.0
                out[k, 0] = v0 + a
                out[k, 1] = np.sqrt(max(see / s - a * a, 0.0))
                continue
            c11 = s * svv - sv * sv
            c12 = sv * su - s * suv
            c22 = s * suu - su * su
            a = (c00 * se + c01 * sue + c02 * sve) / det
            b = (c01 * se + c11 * sue + c12 * sve) / det
            c = (c02 * se + c12 * sue + c22 * sve) / det
            out[k, 0] = v0 + a
            out[k, 1] = np.sqrt(max((see - a * se - b * sue - c * sve) / s, 0.0))
    return out


def confident_growth(left: np.ndarray, right: np.ndarray, disparity: np.ndarray, confidence: np.ndarray,
                     filled: np.ndarray, *, grow_radius: int = 16, sigma: float = 8.0, agree: float = 0.3,
                     min_support: float = 0.1, max_spread: float | None = 0.5, passes: int = 1,
                     fit: str = "mean", inlier: float = 1.0, min_share: float = 0.9,
                     agree_depth: float | None = None, disparity_offset: float = 0.0,
                     second_radius: int | None = None, cut: float | None = None, gap: float | None = None,
                     valid_right: np.ndarray | None = None,
                     **kwargs: Any) -> tuple[np.ndarray, np.ndarray]:
    """Add the matcher's dense values that a wide window confirms and that continue the kept surface around
    them, where nothing was kept.

    Each pixel without a kept value whose kept neighbours are enough (:func:`neighbour_disparity`: weights
    ``min_support`` or more) and alike (spread below ``max_spread`` px: not across a depth edge) is refined
    from its ``filled`` value with one ``grow_radius`` window and checked as any match (refinement within
    ``max_shift``, the sub-pixel left–right check against the kept map, completed by ``filled`` where it
    has no value, ``min_confidence``); it is kept where the refined value lies within ``agree`` px of its
    neighbours' weighted mean. A window wide enough for the weakest texture is noisy only where the
    neighbours do not bound it, and its wrong values (a window pulled across a depth edge, a weak match
    locked one pixel off) mostly break with the surface around them.

    Parameters
    ----------
    left, right : (H, W) or (H, W, 3) arrays
        The rectified pair.
    disparity, confidence : (H, W) float32
        The kept matches so far (:func:`confident_matches`, :func:`confident_fill`; NaN = none).
    filled : (H, W) float array
        The matcher's dense disparities, px, NaN outside the searched region.
    grow_radius : int
        Half-size of the window, px.
    sigma : float
        Standard deviation of the neighbours' Gaussian weights, px.
    agree : float
        Largest distance of the refined value from the neighbours' weighted mean, px.
    min_support : float
        Least sum of the neighbours' weights (1: every pixel in reach has a kept value).
    max_spread : float or None
        Largest weighted standard deviation of the neighbours' values, px; None: any.
    passes : int
        How many times to grow: each pass's neighbours include the values the passes before it kept.
    fit : {"mean", "plane"}
        What the neighbours say of a pixel. "mean": their weighted mean, the spread theirs about it, tested
        before the window is refined. "plane": every pixel whose neighbours weigh ``min_support`` is refined,
        and its value is tested against the weighted plane through the neighbours within ``inlier`` px of it
        (:func:`neighbour_plane`): those must weigh ``min_share`` of all its neighbours and ``min_support``,
        spread less than ``max_spread`` px about the plane, and the plane's value at the pixel must lie
        within ``agree`` px of the refined one (or ``agree_depth`` of its depth, if more), which is the
        value kept.
    inlier, min_share : float, float
        See ``fit``.
    agree_depth : float or None
        With ``fit="plane"``: the plane may also lie this share of the pixel's depth from the refined
        value d, ``agree_depth · (d + disparity_offset)`` px, where that is more than ``agree`` (on a rig
        whose pixel of disparity is a smaller share of depth, the same depth error is more pixels); None:
        ``agree`` only.
    disparity_offset : float
        The pair's d₀, px (the true disparity of a match d is d + d₀, its depth inversely proportional
        to it).
    second_radius : int or None
        With ``fit="plane"``: where the ``grow_radius`` window does not confirm a value, refine and check it
        with a window of this half-size instead, under the same tests (near an occlusion or a depth edge
        the wide window reaches the other surface); None: one window.
    cut : float or None
        With ``fit="plane"``: where no whole window confirms a value beside a depth edge or an occlusion,
        refine and check it once more with the ``grow_radius`` window cut to the pixels of its own surface
        (:func:`_surface_cut`: the left pixels whose value in the map of kept and dense values lies within
        ``cut`` px of it and that the right view sees, the right pixels whose value lies within ``cut`` px
        of it), under the same tests. None: whole windows only.
    gap : float or None
        With ``fit="plane"``: the neighbours farther than ``gap`` px from the first plane are another surface
        (an occluder's kept values beside the pixel), and ``min_share`` is asked of the others only; those
        between ``inlier`` and ``gap`` px off still count against the plane. None: of all the neighbours.
    valid_right : (H, W) bool, optional
        Valid region of the rectified right view (a value whose right pixel is outside is not tried).
    **kwargs
        The other keyword arguments of :func:`confident_matches` (its ``radius`` and second window are not
        used; ``max_lr_gap`` must not be None).

    Returns
    -------
    disparity, confidence : (H, W) float32
        ``disparity`` and ``confidence`` with the grown values added.

    Raises
    ------
    ConfigError
        ``max_lr_gap`` None, or ``fit`` not one of "mean", "plane".
    """
    _require_lr_check(kwargs, "confident_growth", "a grown value")
    if fit not in ("mean", "plane"):
        raise ConfigError(f"confident_growth fit: expected 'mean' or 'plane', got {fit!r}")
    for key in ("radius", "retry_radius", "retry_below", "retry_drop", "right_seeds", "seeds_checked"):
        kwargs.pop(key, None)
    d = np.asarray(disparity, dtype=np.float32)
    conf = np.asarray(confidence, dtype=np.float32)
    f = np.asarray(filled, dtype=np.float32)
    for _ in range(passes):
        d2, c2 = _grown(left, right, d, f, grow_radius=grow_radius, sigma=sigma, agree=agree,
                        min_support=min_support, max_spread=max_spread, fit=fit, inlier=inlier,
                        min_share=min_share, agree_depth=agree_depth, disparity_offset=disparity_offset,
                        second_radius=second_radius, cut=cut, gap=gap, valid_right=valid_right, **kwargs)
        add = np.isfinite(d2)
        if not add.any():
            break
        d, conf = np.where(add, d2, d).astype(np.float32), np.where(add, c2, conf).astype(np.float32)
    return d, conf


def _grown(left: np.ndarray, right: np.ndarray, d: np.ndarray, f: np.ndarray, *, grow_radius: int, sigma: float,
           agree: float, min_support: float, max_spread: float | None, fit: str, inlier: float, min_share: float,
           agree_depth: float | None, disparity_offset: float, second_radius: int | None, cut: float | None,
           gap: float | None, valid_right: np.ndarray | None, **kwargs: Any) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) float32 disparities and confidences of one pass of :func:`confident_growth` (the values it adds,
    NaN elsewhere)."""
    nan = np.full(d.shape, np.nan, dtype=np.float32)
    mean, support, spread = neighbour_disparity(d, sigma=sigma)
    with np.errstate(invalid="ignore"):
        cand = ~np.isfinite(d) & np.isfinite(f) & np.isfinite(mean) & (support >= min_support)
        if max_spread is not None and fit == "mean":
            cand &= spread < max_spread
    seeds = _seeds_seen(f, cand, valid_right)
    if not np.isfinite(seeds).any():
        return nan, nan
    right_seeds = np.where(np.isfinite(d), d, f).astype(np.float32)
    d2, c2 = confident_matches(left, right, seeds, radius=grow_radius, valid_right=valid_right,
                               right_seeds=right_seeds, seeds_checked=False, **kwargs)
    if fit == "mean":
        with np.errstate(invalid="ignore"):
            add = np.isfinite(d2) & (np.abs(d2 - mean) < agree)
        return np.where(add, d2, nan).astype(np.float32), np.where(add, c2, nan).astype(np.float32)
    if second_radius is not None:
        retry = np.isfinite(seeds) & ~np.isfinite(d2)
        if retry.any():
            d3, c3 = confident_matches(left, right, np.where(retry, seeds, np.float32(np.nan)).astype(np.float32),
                                       radius=second_radius, valid_right=valid_right, right_seeds=right_seeds,
                                       seeds_checked=False, **kwargs)
            d2, c2 = np.where(retry, d3, d2).astype(np.float32), np.where(retry, c3, c2).astype(np.float32)
    if cut is not None:
        # the wide window only: cut to one surface it still holds more texture than the small one (the small
        # one cut adds 0.0–0.1 % of the view at twice the cut's cost, stop 44)
        retry = np.isfinite(seeds) & ~np.isfinite(d2)
        if retry.any():
            d3, c3 = _surface_cut(left, right, np.where(retry, seeds, np.float32(np.nan)).astype(np.float32),
                                  right_seeds, radius=grow_radius, cut=cut, valid_right=valid_right, **kwargs)
            take = retry & np.isfinite(d3)
            d2, c2 = np.where(take, d3, d2).astype(np.float32), np.where(take, c3, c2).astype(np.float32)
    ys, xs = np.nonzero(np.isfinite(d2))
    v = d2[ys, xs].astype(np.float64)
    fit_out = _inlier_planes(d, ys.astype(np.int64), xs.astype(np.int64), v, float(sigma), float(inlier),
                             np.inf if gap is None else float(gap))
    plane, p_spread, inl, total = fit_out[:, 0], fit_out[:, 1], fit_out[:, 2], fit_out[:, 3] - fit_out[:, 4]
    tol = agree if agree_depth is None else np.maximum(agree, agree_depth * (v + disparity_offset))
    with np.errstate(invalid="ignore"):
        ok = (np.abs(plane - v) < tol) & (inl >= min_support) & (inl >= min_share * total)
        if max_spread is not None:
            ok &= p_spread < max_spread
    out_d, out_c = nan.copy(), nan.copy()
    out_d[ys[ok], xs[ok]] = v[ok].astype(np.float32)
    out_c[ys[ok], xs[ok]] = c2[ys[ok], xs[ok]]
    return out_d, out_c


@dataclass(frozen=True, eq=False)
class _CroppedEpipolar(EpipolarTable):
    """An :class:`EpipolarTable` read for a crop of the pair whose first pixel is the table's ``(x0, y0)``."""

    y0: int = 0
    x0: int = 0

    def row_offset(self, ys: np.ndarray, xs: np.ndarray, d: np.ndarray) -> np.ndarray:
        return super().row_offset(np.asarray(ys) + self.y0, np.asarray(xs) + self.x0, d)


def _surface_cut(left: np.ndarray, right: np.ndarray, seeds: np.ndarray, surface: np.ndarray, *, radius: int,
                 cut: float, valid_right: np.ndarray | None, **kwargs: Any) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) float32 disparities and confidences of the ``seeds`` beside a depth edge or an occlusion that
    :func:`confident_matches` confirms with ``radius`` windows cut to the seed's own surface, NaN elsewhere.

    ``surface`` is the map of what is known of each pixel (the kept values, the dense ones elsewhere), and
    the right view's, :func:`_seen_from_right` of it (the nearer surface wins a right pixel). A left window
    pixel counts where its value lies within ``cut`` px of the seed and the right view sees it (no nearer
    value lands on its right pixel: an occluded pixel's content is nowhere in the right view), a right one
    where its value lies within ``cut`` px of the seed: a whole window beside an occlusion holds the band
    the right view does not see and the occluder, which no disparity of the seed matches, and its ZNCC or
    its left–right check drops a right value. The seeds are refined in groups of one integer value (the
    window's surface is cut about it), each on the crop of the pair its windows reach; a seed whose window
    holds one surface only, seen by both views, is not tried (its whole window was).
    """
    h, w = seeds.shape
    nan = np.full((h, w), np.nan, dtype=np.float32)
    s = np.asarray(surface, dtype=np.float32)
    vl = kwargs.pop("valid_left", None)
    vl = np.ones((h, w), dtype=bool) if vl is None else np.asarray(vl, dtype=bool)
    vr = np.ones((h, w), dtype=bool) if valid_right is None else np.asarray(valid_right, dtype=bool)
    epipolar = kwargs.pop("epipolar", None)
    s_r = _seen_from_right(s)
    ys, xs = np.nonzero(np.isfinite(s))
    xr = np.rint(xs - s[ys, xs]).astype(np.int64)
    inside = (xr >= 0) & (xr < w)
    hidden = np.zeros((h, w), dtype=bool)
    with np.errstate(invalid="ignore"):
        hidden[ys[inside], xs[inside]] = s_r[ys[inside], xr[inside]] > s[ys[inside], xs[inside]] + cut
    k = 2 * radius + 1
    box = np.ones((k, k), np.uint8)
    hi = cv2.dilate(np.where(np.isfinite(s), s, -np.inf).astype(np.float32), box)
    lo = cv2.erode(np.where(np.isfinite(s), s, np.inf).astype(np.float32), box)
    with np.errstate(over="ignore", invalid="ignore"):  # windows without a value: ±inf, or cv2's ±FLT_MAX border
        edge = (hi - lo > cut) | (cv2.dilate(hidden.astype(np.uint8), box) > 0)
    ys, xs = np.nonzero(np.isfinite(seeds) & edge)
    if ys.size == 0:
        return nan, nan.copy()
    v = seeds[ys, xs]
    groups = np.rint(v).astype(np.int64)
    reach = radius + int(np.ceil(float(kwargs.get("max_shift", 1.0)))) + 8  # taps, the prefilter's reach
    out_d, out_c = nan, nan.copy()
    for g in np.unique(groups):
        sel = groups == g
        gy, gx = ys[sel], xs[sel]
        y0, y1 = max(int(gy.min()) - reach, 0), min(int(gy.max()) + reach + 1, h)
        x0 = max(int(gx.min()) - max(int(np.ceil(g + cut)), 0) - reach, 0)
        x1 = min(int(gx.max()) + max(int(np.ceil(cut - g)), 0) + reach + 1, w)
        crop = (slice(y0, y1), slice(x0, x1))
        sc, src = s[crop], s_r[crop]
        with np.errstate(invalid="ignore"):
            vlc = vl[crop] & ~hidden[crop] & (np.abs(sc - g) <= cut)
            vrc = vr[crop] & (np.abs(src - g) <= cut)
        sd = np.full(sc.shape, np.nan, dtype=np.float32)
        sd[gy - y0, gx - x0] = v[sel]
        epi = None if epipolar is None else _CroppedEpipolar(offsets=epipolar.offsets, step=epipolar.step,
                                                              d_start=epipolar.d_start, d_step=epipolar.d_step,
                                                              y0=y0, x0=x0)
        d2, c2 = confident_matches(left[crop], right[crop], sd, radius=radius, valid_left=vlc, valid_right=vrc,
                                   epipolar=epi, right_seeds=sc, seeds_checked=False, **kwargs)
        ok = np.isfinite(d2[gy - y0, gx - x0])
        out_d[gy[ok], gx[ok]] = d2[gy[ok] - y0, gx[ok] - x0]
        out_c[gy[ok], gx[ok]] = c2[gy[ok] - y0, gx[ok] - x0]
    return out_d, out_c


def plane_interpolation(disparity: np.ndarray, confidence: np.ndarray, filled: np.ndarray, *, sigma: float = 8.0,
                        inlier: float = 1.0, min_support: float = 0.3, min_share: float = 0.95,
                        max_spread: float = 0.3, agree: float = 0.5, passes: int = 2,
                        valid_right: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Add the kept neighbours' plane where the matcher's dense value lies on it and nothing was kept.

    At each pixel without a kept value whose ``filled`` value lands inside the right view, the weighted
    plane through the kept neighbours within ``inlier`` px of that value, refit through those within
    ``inlier`` px of the first plane (:func:`neighbour_plane`), is kept where (a) those inliers weigh at
    least ``min_support`` and ``min_share`` of all the kept neighbours (one surface around the pixel, not two),
    (b) they spread less than ``max_spread`` px about it, and (c) the plane's value at the pixel lies within
    ``agree`` px of the dense value. The value kept is the plane's. Beside a depth edge every refinement
    window reaches the other surface, and on the weakest texture it has nothing to match; but the matcher's
    aggregated cost found the value there, and where it is the surface the kept values around the pixel
    continue, their plane is a better estimate than the dense (integer) value itself.

    Parameters
    ----------
    disparity, confidence : (H, W) float32
        The kept matches so far (NaN = none).
    filled : (H, W) float array
        The matcher's dense disparities, px, NaN outside the searched region.
    sigma : float
        Standard deviation of the neighbours' Gaussian weights, px.
    inlier : float
        See :func:`neighbour_plane`, px.
    min_support, min_share : float, float
        Least weight of the plane's inliers (1: every pixel in reach holds one), and least share of the
        weight of all kept neighbours.
    max_spread : float
        Largest weighted standard deviation of the inliers about the plane, px.
    agree : float
        Largest distance of the plane's value at the pixel from the dense value, px.
    passes : int
        How many times to interpolate: each pass's neighbours include the values the passes before it kept.
    valid_right : (H, W) bool, optional
        Valid region of the rectified right view (a dense value whose right pixel is outside is not used).

    Returns
    -------
    disparity, confidence : (H, W) float32
        ``disparity`` and ``confidence`` with the interpolated values added; an interpolated value's
        confidence is its inliers' weight (no window confirmed it: the share of its surroundings that holds
        kept values of its surface).
    """
    d = np.asarray(disparity, dtype=np.float32).copy()
    conf = np.asarray(confidence, dtype=np.float32).copy()
    f = np.asarray(filled, dtype=np.float32)
    seen = np.isfinite(_seeds_seen(f, np.isfinite(f), valid_right))
    for _ in range(passes):
        ys, xs = np.nonzero(~np.isfinite(d) & seen)
        if ys.size == 0:
            break
        v = f[ys, xs].astype(np.float64)
        plane, spread, inl, total = neighbour_plane(d, ys, xs, v, sigma=sigma, inlier=inlier)
        with np.errstate(invalid="ignore"):
            ok = ((inl >= min_support) & (inl >= min_share * total) & (spread < max_spread)
                  & (np.abs(plane - v) < agree))
        if not ok.any():
            break
        # every pixel of a pass reads the map before it: the result does not depend on the order
        d[ys[ok], xs[ok]] = plane[ok].astype(np.float32)
        conf[ys[ok], xs[ok]] = np.minimum(inl[ok], 1.0).astype(np.float32)
    return d, conf


def _require_lr_check(kwargs: dict[str, Any], function: str, tested: str) -> None:
    """Refuse ``max_lr_gap=None`` among ``kwargs``: the sub-pixel left–right check is what tests ``tested``."""
    if kwargs.get("max_lr_gap", 0.45) is None:
        raise ConfigError(f"{function} max_lr_gap: expected a number of px (the sub-pixel left–right check is what "
                          f"tests {tested}), got None; pass the pipeline's refine_max_lr_gap")


def _seeds_seen(filled: np.ndarray, candidates: np.ndarray, valid_right: np.ndarray | None) -> np.ndarray:
    """(H, W) float32: ``filled`` (px) at the ``candidates`` (H, W) bool whose right pixel ``x − filled`` lies
    inside the view and in ``valid_right`` (None: any), NaN elsewhere."""
    h, w = filled.shape
    ys, xs = np.nonzero(candidates)
    xr = np.rint(xs - filled[ys, xs]).astype(np.int64)
    inside = (xr >= 0) & (xr < w)
    if valid_right is not None:
        inside[inside] &= np.asarray(valid_right, dtype=bool)[ys[inside], xr[inside]]
    seeds = np.full((h, w), np.nan, dtype=np.float32)
    seeds[ys[inside], xs[inside]] = filled[ys[inside], xs[inside]]
    return seeds


def remove_speckles(disparity: np.ndarray, *, max_size: int) -> np.ndarray:
    """Drop connected patches of disparity (neighbours within 1 px) of at most ``max_size`` pixels.

    OpenCV ``filterSpeckles`` on the disparity in 1/16 px; a map too large for its 16-bit range is returned
    unchanged.

    Parameters
    ----------
    disparity : (H, W) float array
        Px, NaN = none.
    max_size : int
        Largest patch removed, pixels.

    Returns
    -------
    (H, W) float32
        ``disparity`` with the small patches set to NaN.
    """
    disp = np.asarray(disparity, dtype=np.float32)
    finite = np.isfinite(disp)
    if not finite.any() or float(np.nanmax(disp)) * 16 > 32000:
        return disp
    d16 = np.where(finite, np.rint(disp * 16.0), -16).astype(np.int16)
    cv2.filterSpeckles(d16, -16, int(max_size), 16)
    return np.where(d16 == -16, np.float32(np.nan), disp).astype(np.float32)


def _right_refined(left: np.ndarray, right: np.ndarray, seen: np.ndarray, disp: np.ndarray, where: np.ndarray,
                   epipolar: EpipolarTable | None, *, radius: int, iterations: int, max_shift: float,
                   min_texture: float, min_pixels: int | None, valid_left: np.ndarray | None,
                   valid_right: np.ndarray | None, prefilter: float | None) -> np.ndarray:
    """(H, W) float32: the right view's disparities ``seen`` (:func:`_seen_from_right`) refined on the
    mirrored pair, where the right view is the left one, at the right pixels the check of the left pixels
    ``where`` reads (each pixel is refined on its own, so the others change nothing); NaN elsewhere."""
    seeds = np.where(_read_by_check(disp, where), seen, np.float32(np.nan))
    rows_r = None if epipolar is None else _right_row_offsets(epipolar, seeds)
    d_r, _ = refine_disparity(_mirror(right), _mirror(left), _mirror(seeds),
                              radius=radius, iterations=iterations, max_shift=max_shift,
                              min_texture=min_texture, min_pixels=min_pixels,
                              valid_left=None if valid_right is None else _mirror(valid_right),
                              valid_right=None if valid_left is None else _mirror(valid_left),
                              row_offset=None if rows_r is None else _mirror(rows_r),
                              prefilter=prefilter)
    return _mirror(d_r)


def _mirror(a: np.ndarray) -> np.ndarray:
    """Left–right mirror image (a right view becomes a left one, disparities keep their sign)."""
    return mirror(np.asarray(a))


def _right_row_offsets(epipolar: EpipolarTable, disparity_right: np.ndarray) -> np.ndarray:
    """(H, W) row offsets of the right view's matches (left row − right row): the right pixel (x, y) at
    disparity d sees the point the left pixel (x + d, y − δy) sees, δy ≈ δy(x + d, y, d) (δy changes by
    ≪ 0.01 px over a row's fraction)."""
    out = np.full(disparity_right.shape, np.nan, dtype=np.float32)
    ys, xs = np.nonzero(np.isfinite(disparity_right))
    d = disparity_right[ys, xs]
    out[ys, xs] = -epipolar.row_offset(ys, xs + d, d)
    return out


def _seen_confirmed(right_seeds: np.ndarray, disparity: np.ndarray, confirmed: np.ndarray) -> np.ndarray:
    """(H, W) float32: the right view's seeds of the check, :func:`_seen_from_right` of ``right_seeds``, but
    at each right pixel the largest of the values landing there that this window confirmed, where one did.
    A value that this window refined from the same value (``disparity``) and did not confirm (``confirmed``
    False: not refined, or below the confidence threshold before the check) stands for the right view only
    where no confirmed one lands. A map without a cross-check of its own (``coop``'s, a dense map) has
    values wherever the region reaches, also where the scene is not seen in the right view; moved to
    x − d they win right pixels (the largest disparity wins) from the true matches there, and the check
    then drops those: a value whose own window does not match is no evidence of what the right view sees."""
    rs = np.asarray(right_seeds, dtype=np.float32)
    d = np.asarray(disparity, dtype=np.float32)
    with np.errstate(invalid="ignore"):
        drop = np.isfinite(d) & ~confirmed & (d == rs)
    every = _seen_from_right(rs)
    if not drop.any():
        return every
    seen = _seen_from_right(np.where(drop, np.float32(np.nan), rs))
    return np.where(np.isfinite(seen), seen, every).astype(np.float32)


def _seen_from_right(disparity: np.ndarray) -> np.ndarray:
    """(H, W) float32: the left view's disparities at their right pixels x − d (rounded), the largest where
    several land on one pixel (the nearer surface hides the other), NaN where none lands."""
    return seen_from_right(np.ascontiguousarray(disparity, dtype=np.float32))


def _read_by_check(disparity: np.ndarray, where: np.ndarray) -> np.ndarray:
    """(H, W) bool: the right pixels :func:`_lr_gap` reads for the left pixels ``where`` of the (H, W) float32
    map ``disparity`` (floor(x − d) and the next one)."""
    return read_by_check(np.ascontiguousarray(disparity, dtype=np.float32), np.ascontiguousarray(where, dtype=bool))


def _lr_gap(disparity: np.ndarray, disparity_right: np.ndarray) -> np.ndarray:
    """(H, W) float32: |d(x) − d_right(x − d(x))| of two (H, W) float32 maps (d_right interpolated along the
    row; the one finite neighbour where the other is NaN), NaN where either is missing."""
    return lr_gap(np.ascontiguousarray(disparity, dtype=np.float32),
                  np.ascontiguousarray(disparity_right, dtype=np.float32))
