"""The depth range a run searches when none is given, and the warnings that say a result is unreliable.

A fixed default range (say 0.8–5 m) silently fails for every scene outside it: the matcher returns the
nearest allowed disparity and the run reports success. Instead the range is derived

1. from the rig: the depths at which the two rectified views share a sizeable part of their field
   (:func:`~prismstereo.rectify.view_overlap`, the sampled form of
   :func:`~prismstereo.rectify.common_view`: at least a quarter of the largest shared fraction, up to 100 m), and
2. from the images: a coarse OpenCV SGBM match over that whole range on downsampled rectified views;
   of the clusters its consistent disparities form, those the images confirm (the right view warped by
   the coarse map reproduces the left view there) are the scene's, and their 1st–99th percentiles,
   padded, give the range actually searched (:func:`estimate_disparity_range`). A tri-prism's common view
   over the rig's depths is several times the scene's, and the coarse matches on its unlit part form
   false clusters far from the scene that plain percentiles would take in.

When the images give too little support (noise, a photo that is no prism capture, no texture) the rig
range is kept and a warning says so. :func:`depth_warnings` turns coverage, match confidence and the
share of matches at the search limits into one-line warnings (also written to ``run.json``).

Coverage (:func:`scene_coverage`) is measured against the common view at the depths the run found, not the
common view of the whole searched range: a searched range left wide (the coarse match could not narrow it)
makes the latter several times larger than what the scene can fill, and a good result would read as a
failure. The found depths are the 1st–99th percentiles of the points' disparities; with too few points to
tell, the denominator is the searched common view again.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import cv2
import numpy as np

from prismstereo.cameras import calibrate_rig
from prismstereo.cameras.overlap import overlap_depths, overlap_span
from prismstereo.config import Rig
from prismstereo.errors import GeometryError
from prismstereo.matching.diagnostics import LIMIT_SHARE, limit_shares
from prismstereo.rectify import RectifiedPair, common_view, rectify_pair, view_overlap

log = logging.getLogger(__name__)

__all__ = ["Coverage", "RigRange", "SearchRange", "auto_search_range", "confident_coarse", "depth_warnings",
           "disparity_clusters", "estimate_disparity_range", "rig_depth_range", "rig_range", "scene_coverage",
           "view_overlap"]

#: largest disparity span of the coarse match, px at the coarse scale (sets the downsampling factor)
COARSE_SPAN = 128
#: consistent coarse matches (share of the common view) needed to trust the image-based range
MIN_SUPPORT = 0.05
#: coarse matches the images confirm (share of the common view) needed to judge the clusters
MIN_CONFIRMED = 0.01
#: a cluster of coarse disparities is the scene's where it holds this share of the confirmed matches ...
CLUSTER_SUPPORT = 0.01
#: ... and at least this many
MIN_CLUSTER_CONFIRMED = 5
#: empty integer disparities (at the coarse scale) a cluster may span
CLUSTER_GAP = 2
#: the confirmation of a coarse match: window (px at the coarse scale), least ZNCC, least texture (grey levels)
CONFIDENT_WINDOW = 9
CONFIDENT_ZNCC = 0.9
CONFIDENT_STD = 1.0
#: warnings: fewer points than this share of the matched region
MIN_COVERAGE = 0.2
#: warnings: fewer confident (refined) matches than this share of the matcher's consistent ones
MIN_CONFIDENT = 0.4
#: coverage: percentiles of the points' disparities taken as the scene's range (a few outliers aside)
SCENE_PERCENTILES = (1.0, 99.0)
#: coverage: fewer points than this do not tell the scene's range; the searched common view is used
MIN_SCENE_POINTS = 100


@dataclass(frozen=True)
class Coverage:
    """The share of a common view that got a depth (:func:`scene_coverage`).

    Attributes
    ----------
    points : int  points inside the view.
    pixels : int  pixels of the view.
    of : str  ``"found"`` (the common view at the disparities the points span) or ``"searched"`` (the
        common view of the whole searched range: too few points to tell the scene's range).
    disparity_px : (min, max) or None  the disparities of the view (``"found"``), px.
    depth_mm : (min, max) or None  the points' depths at the same percentiles, mm.
    """

    points: int
    pixels: int
    of: str
    disparity_px: tuple[int, int] | None = None
    depth_mm: tuple[float, float] | None = None

    @property
    def share(self) -> float:
        return self.points / max(self.pixels, 1)

    def describe(self, searched_mm: tuple[float, float]) -> str:
        """What the share is of, in words (for messages)."""
        if self.of == "found" and self.depth_mm is not None:
            return f"the common view at the depths found ({self.depth_mm[0]:.0f}–{self.depth_mm[1]:.0f} mm)"
        return f"the common view of the searched depths ({searched_mm[0]:.0f}–{searched_mm[1]:.0f} mm)"

    def to_dict(self) -> dict[str, object]:
        return {"share": round(self.share, 4), "points": self.points, "pixels": self.pixels, "of": self.of,
                "disparity_px": None if self.disparity_px is None else list(self.disparity_px),
                "depth_mm": None if self.depth_mm is None else [round(v, 1) for v in self.depth_mm]}


def scene_coverage(disparity: np.ndarray, valid: np.ndarray, depth: np.ndarray, searched: np.ndarray,
                   valid_right: np.ndarray) -> Coverage:
    """The share of the common view at the depths found that got a point.

    The view: searched pixels for which some disparity between the 1st and 99th percentile of the points'
    (rounded outwards) lands in the right view's valid region.

    Parameters
    ----------
    disparity : (h, w) float  the disparities triangulated, px, NaN none.
    valid : (h, w) bool  pixels with a point.
    depth : (h, w) float  the points' depths, mm.
    searched : (h, w) bool  the pixels that could get a point (the searched common view).
    valid_right : (h, w) bool  the right view's valid region.
    """
    ok = valid & np.isfinite(disparity)
    n = int(ok.sum())
    if n < MIN_SCENE_POINTS:
        return Coverage(points=int((valid & searched).sum()), pixels=int(searched.sum()), of="searched")
    p_lo, p_hi = SCENE_PERCENTILES
    d_lo, d_hi = np.percentile(disparity[ok], [p_lo, p_hi])
    z_near, z_far = np.percentile(depth[ok], [p_lo, p_hi])
    lo, hi = int(math.floor(d_lo)), int(math.ceil(d_hi))
    h, w = searched.shape
    # right-view pixels in [x − hi, x − lo] per row, by a running count
    run = np.zeros((h, w + 1), dtype=np.int32)
    np.cumsum(np.asarray(valid_right, dtype=bool), axis=1, out=run[:, 1:])
    x = np.arange(w)
    a = np.clip(x - hi, 0, w)
    b = np.clip(x - lo + 1, 0, w)
    view = searched & (run[:, b] > run[:, a])
    return Coverage(points=int((valid & view).sum()), pixels=int(view.sum()), of="found", disparity_px=(lo, hi),
                    depth_mm=(float(z_near), float(z_far)))


@dataclass(frozen=True)
class SearchRange:
    """A resolved search range.

    Attributes
    ----------
    depth_mm : (min, max)  world depths searched, mm.
    disparity_px : (min, max)  integer disparities searched in the rectified pair.
    source : str  ``"rig"`` (rig overlap only), ``"rig+images"`` (coarse match) or ``"given"``.
    warnings : tuple of str
    """

    depth_mm: tuple[float, float]
    disparity_px: tuple[int, int]
    source: str
    warnings: tuple[str, ...] = ()


def _rig_range(pair: RectifiedPair, back_mm: float) -> tuple[np.ndarray, np.ndarray, tuple[float, float]]:
    depths = overlap_depths(back_mm, 32, margin=1.02)
    frac, disp = view_overlap(pair, depths, stride=6)
    if not (frac > 0).any():
        raise GeometryError("expected the two views to share part of the scene at some depth, got views that "
                            "never overlap (choose other views)")
    # the kept samples themselves, not the interpolated crossings: every run's default range is these
    return depths, disp, overlap_span(depths, frac, interpolate=False)


def _depth_of(d: float, depths: np.ndarray, disp: np.ndarray) -> float:
    """World depth whose median disparity is ``d`` (disparity falls with depth)."""
    ok = np.isfinite(disp)
    dd, zz = disp[ok][::-1], np.log(depths[ok][::-1])  # increasing disparity
    return float(np.exp(np.interp(d, dd, zz)))


def _local_stats(a: np.ndarray, b: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ZNCC of ``a`` and ``b`` over k×k windows, and each image's standard deviation there (float32, (h, w))."""
    ma, mb = cv2.blur(a, (k, k)), cv2.blur(b, (k, k))
    va = np.maximum(cv2.blur(a * a, (k, k)) - ma * ma, 0.0)
    vb = np.maximum(cv2.blur(b * b, (k, k)) - mb * mb, 0.0)
    cov = cv2.blur(a * b, (k, k)) - ma * mb
    return cov / np.sqrt(np.maximum(va * vb, 1e-12)), np.sqrt(va), np.sqrt(vb)


def confident_coarse(d: np.ndarray, ok: np.ndarray, left: np.ndarray, right: np.ndarray, inside_left: np.ndarray,
                     inside_right: np.ndarray, *, window: int = CONFIDENT_WINDOW,
                     min_zncc: float = CONFIDENT_ZNCC, min_std: float = CONFIDENT_STD) -> np.ndarray:
    """The coarse matches the images themselves confirm.

    A match is confirmed where the right view, warped by the coarse disparity map, reproduces the left view
    around it: the ZNCC of the two over a ``window``-wide square is at least ``min_zncc``, both are textured
    there (standard deviation ``min_std`` grey levels or more) and both windows lie inside their view's valid
    region. The false matches that spread a tri-prism's range are not: they sit on flat unlit background
    between two edges that happen to line up (SGBM's smoothness carries a disparity into them), or on texture
    whose true match lies outside the other view.

    Parameters
    ----------
    d : (h, w) float32  coarse disparities, px at the coarse scale.
    ok : (h, w) bool  the matches to judge.
    left, right : (h, w) uint8  the coarse grey views.
    inside_left, inside_right : (h, w) bool  the views' valid regions at the coarse scale.
    window, min_zncc, min_std : the window (odd, px), the least ZNCC and the least texture.

    Returns
    -------
    (h, w) bool
    """
    h, w = d.shape
    dd = np.where(ok, d, 0.0).astype(np.float32)
    xs = np.arange(w, dtype=np.float32)[None, :] - dd
    ys = np.broadcast_to(np.arange(h, dtype=np.float32)[:, None], (h, w))
    warped = cv2.remap(right.astype(np.float32), np.ascontiguousarray(xs), np.ascontiguousarray(ys),
                       cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    zncc, sl, sr = _local_stats(left.astype(np.float32), warped, window)
    # a window touching a view's border would match the other view's border, not the scene
    r = window // 2 + 1
    kernel = np.ones((2 * r + 1, 2 * r + 1), np.uint8)
    in_l = cv2.erode(np.asarray(inside_left, dtype=np.uint8), kernel).astype(bool)
    in_r = cv2.erode(np.asarray(inside_right, dtype=np.uint8), kernel).astype(bool)
    xr = np.clip(np.rint(xs).astype(np.int64), 0, w - 1)
    seen = in_r[np.arange(h)[:, None], xr]
    return ok & in_l & seen & (zncc >= min_zncc) & (sl >= min_std) & (sr >= min_std)


def disparity_clusters(values: np.ndarray, *, gap: int = CLUSTER_GAP) -> list[tuple[int, int]]:
    """Runs of integer disparities holding coarse matches, joined across gaps of up to ``gap`` empty values.

    Parameters
    ----------
    values : (n,) float  coarse disparities.

    Returns
    -------
    list of (first, last)  inclusive integer bounds, increasing.
    """
    if values.size == 0:
        return []
    bins = np.unique(np.rint(values).astype(np.int64))  # rint: the same rounding the caller bins with
    breaks = np.flatnonzero(np.diff(bins) > gap + 1)
    starts = np.concatenate([[0], breaks + 1])
    ends = np.concatenate([breaks, [bins.size - 1]])
    return [(int(bins[a]), int(bins[b])) for a, b in zip(starts, ends, strict=True)]


@dataclass(frozen=True, eq=False)
class _CoarseMatch:
    """The coarse SGBM match of :func:`estimate_disparity_range`, at the coarse scale (h, w)."""

    disparity: np.ndarray  # (h, w) float32, px at the coarse scale
    consistent: np.ndarray  # (h, w) bool, the matches within the rig's range
    factor: int  # the downsampling factor
    gray_left: np.ndarray  # (h, w) uint8
    gray_right: np.ndarray
    valid_left: np.ndarray  # (h, w) bool, the views' valid regions
    valid_right: np.ndarray
    region_pixels: int  # pixels of the (eroded) common view


def _coarse_match(left: np.ndarray, right: np.ndarray, region: np.ndarray, *, lo: int, hi: int,
                  valid_left: np.ndarray | None, valid_right: np.ndarray | None) -> _CoarseMatch:
    """The coarse SGBM match of :func:`estimate_disparity_range`."""
    s = max(1, int(math.ceil((hi - lo) / float(COARSE_SPAN))))
    h, w = left.shape[:2]
    size = (max(8, w // s), max(8, h // s))
    gl = left.copy() if left.ndim == 2 else cv2.cvtColor(np.ascontiguousarray(left), cv2.COLOR_RGB2GRAY)
    gr = right.copy() if right.ndim == 2 else cv2.cvtColor(np.ascontiguousarray(right), cv2.COLOR_RGB2GRAY)
    rng = np.random.default_rng(0)
    for img, valid in ((gl, valid_left), (gr, valid_right)):
        if valid is not None:
            out = ~np.asarray(valid, dtype=bool)
            img[out] = rng.integers(0, 256, int(out.sum()), dtype=np.uint8)
    cl = cv2.resize(gl, size, interpolation=cv2.INTER_AREA)
    cr = cv2.resize(gr, size, interpolation=cv2.INTER_AREA)
    cm = cv2.resize(region.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST).astype(bool)
    cm = cv2.erode(cm.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    cvl, cvr = (np.ones(cl.shape, dtype=bool) if v is None else
                cv2.resize(np.asarray(v, dtype=np.uint8), size, interpolation=cv2.INTER_AREA) > 0
                for v in (valid_left, valid_right))
    dmin = int(math.floor(lo / s))
    num = int(16 * math.ceil((math.ceil(hi / s) - dmin + 2) / 16.0))
    # padding on the left keeps SGBM from dropping the first min+num columns of the left view
    pad = dmin + num
    cl_p = cv2.copyMakeBorder(cl, 0, 0, pad, 0, cv2.BORDER_CONSTANT, value=0)
    cr_p = cv2.copyMakeBorder(cr, 0, 0, pad, 0, cv2.BORDER_CONSTANT, value=0)
    block = 5
    sgbm = cv2.StereoSGBM_create(  # type: ignore[attr-defined]
        minDisparity=dmin, numDisparities=num, blockSize=block, P1=8 * block * block, P2=32 * block * block,
        disp12MaxDiff=1, uniquenessRatio=15, speckleWindowSize=50, speckleRange=2, mode=cv2.STEREO_SGBM_MODE_SGBM)
    d = sgbm.compute(cl_p, cr_p)[:, pad:].astype(np.float32) / 16.0
    # SGBM searches up to dmin + num − 1 (num rounded up to 16): what lands beyond the rig's own largest
    # disparity, or on the last disparity searched (where a match from beyond the range piles up), is no
    # match of the scene (5–10 % of the coarse matches of a tri-prism's thin common view sat there)
    ok = cm & (d >= dmin) & (d <= hi / s) & (d < dmin + num - 1)
    return _CoarseMatch(disparity=d, consistent=ok, factor=s, gray_left=cl, gray_right=cr, valid_left=cvl,
                        valid_right=cvr, region_pixels=int(cm.sum()))


def _padded(p_lo: float, p_hi: float, s: int, lo: int, hi: int) -> tuple[int, int] | None:
    margin = max(3.0 * s, 0.1 * (p_hi - p_lo) * s, 4.0)
    rlo = max(lo, int(math.floor(p_lo * s - margin)))
    rhi = min(hi, int(math.ceil(p_hi * s + margin)))
    return None if rhi <= rlo else (rlo, rhi)


def _padded_percentiles(values: np.ndarray, s: int, lo: int, hi: int) -> tuple[int, int] | None:
    """The padded 1st–99th percentile of all the coarse matches ``values`` (the range where no cluster can be
    told from another)."""
    p1, p99 = np.percentile(values, [1.0, 99.0])
    return _padded(float(p1), float(p99), s, lo, hi)


def estimate_disparity_range(left: np.ndarray, right: np.ndarray, region: np.ndarray, *, lo: int, hi: int,
                             valid_left: np.ndarray | None = None, valid_right: np.ndarray | None = None
                             ) -> tuple[tuple[int, int] | None, float]:
    """Disparity range of the scene from a coarse SGBM match of the rectified views.

    The consistent coarse disparities fall into clusters (:func:`disparity_clusters`). A cluster is the
    scene's where the images confirm enough of its matches (:func:`confident_coarse`: at least
    :data:`CLUSTER_SUPPORT` of all confirmed matches, and :data:`MIN_CLUSTER_CONFIRMED`); every such cluster
    is kept, so a scene of separate depth layers keeps each of them, and within a kept cluster the range
    follows all its matches, confirmed or not (a slanted floor, thin parts that match coarsely but weakly).
    The range is the 1st–99th percentile of each kept cluster's matches, their union, padded. Clusters
    without that support, such as the false matches a tri-prism's wide common view gathers outside the
    scene, are left out. Where the images confirm too few matches to tell (fewer than
    :data:`MIN_CONFIRMED` of the region), the 1st–99th percentile of all matches is kept, as wide as it
    comes, and the log says so.

    Parameters
    ----------
    left, right : (h, w, 3) or (h, w) uint8  rectified views.
    region : (h, w) bool  the common view (pixels that may match).
    lo, hi : int  the widest range the rig allows, px.
    valid_left, valid_right : (h, w) bool, optional
        The views' valid regions; outside them the images are filled with independent noise, so that the
        edges of the black borders cannot match each other (they would add a false cluster of disparities).

    Returns
    -------
    ((min, max) or None, support)
        The padded range (None when fewer than :data:`MIN_SUPPORT` of the region matched), and the share of
        the region that matched.
    """
    cm = _coarse_match(left, right, region, lo=lo, hi=hi, valid_left=valid_left, valid_right=valid_right)
    d, ok, s, n_region = cm.disparity, cm.consistent, cm.factor, cm.region_pixels
    support = float(ok.sum()) / max(n_region, 1)
    if support < MIN_SUPPORT:
        return None, support
    values = d[ok]
    log.debug("coarse disparities x%d: support %.3f, percentiles 0/1/2/5/50/95/98/99/100: %s", s, support,
              np.percentile(values, [0, 1, 2, 5, 50, 95, 98, 99, 100]) * s)
    confirmed = confident_coarse(d, ok, cm.gray_left, cm.gray_right, cm.valid_left, cm.valid_right)
    n_conf = int(confirmed.sum())
    if n_conf < MIN_CONFIRMED * n_region:
        log.info("search range: the images confirm only %d of %d coarse matches (%.1f %% of the common view, "
                 "fewer than %.0f %%): too few to tell the scene's clusters from false ones, keeping the "
                 "percentiles of all matches", n_conf, values.size, 100.0 * n_conf / max(n_region, 1),
                 100.0 * MIN_CONFIRMED)
        return _padded_percentiles(values, s, lo, hi), support
    bins, conf_bins = np.rint(values), np.rint(d[confirmed])
    need = max(MIN_CLUSTER_CONFIRMED, CLUSTER_SUPPORT * n_conf)
    spans: list[tuple[float, float]] = []
    for a, b in disparity_clusters(values):
        inside = (bins >= a) & (bins <= b)
        n_in = int(((conf_bins >= a) & (conf_bins <= b)).sum())
        if n_in >= need:
            p_lo, p_hi = np.percentile(values[inside], [1.0, 99.0])
            spans.append((float(p_lo), float(p_hi)))
        else:
            log.info("search range: left out %d coarse matches at %d–%d px (%d confirmed by the images, fewer "
                     "than %.0f)", int(inside.sum()), a * s, b * s, n_in, need)
    if not spans:  # every cluster holds a little: nothing stands out as the scene
        log.info("search range: no cluster of coarse matches holds %.0f confirmed ones: keeping the percentiles "
                 "of all matches", need)
        return _padded_percentiles(values, s, lo, hi), support
    return _padded(min(a for a, _ in spans), max(b for _, b in spans), s, lo, hi), support


@dataclass(frozen=True, eq=False)
class RigRange:
    """The rig-only part of the automatic search range of a rectified pair, computed once per set-up.

    Attributes
    ----------
    depths, disparity : (32,) float64
        World depths sampled from just beyond the prism to 100 m and the views' median disparity there
        (:func:`~prismstereo.rectify.view_overlap`; NaN where they do not overlap).
    depth_mm : (min, max)
        Every depth at which the views share a field (:func:`rig_depth_range`).
    region : (h, w) bool
        Their common view over that range (:func:`~prismstereo.rectify.common_view`).
    disparity_px : (min, max)
        Its integer disparities.
    """

    depths: np.ndarray
    disparity: np.ndarray
    depth_mm: tuple[float, float]
    region: np.ndarray
    disparity_px: tuple[int, int]

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Plain arrays (for an ``.npz``; :meth:`from_arrays` reads them back)."""
        return {"range_depths": self.depths, "range_disparity": self.disparity,
                "range_limits": np.array([*self.depth_mm, *self.disparity_px], dtype=np.float64),
                "range_region": self.region}

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> RigRange:
        lim = np.asarray(arrays["range_limits"], dtype=np.float64)
        if lim.shape != (4,):
            raise ValueError("range limits of another layout")
        return cls(depths=np.asarray(arrays["range_depths"], dtype=np.float64),
                   disparity=np.asarray(arrays["range_disparity"], dtype=np.float64),
                   depth_mm=(float(lim[0]), float(lim[1])), region=np.asarray(arrays["range_region"], dtype=bool),
                   disparity_px=(int(lim[2]), int(lim[3])))


def rig_range(pair: RectifiedPair, back_mm: float) -> RigRange:
    """The rig-only part of :func:`auto_search_range` (:class:`RigRange`)."""
    depths, disp, (zmin, zmax) = _rig_range(pair, back_mm)
    region, (dlo, dhi) = common_view(pair, zmin, zmax)
    return RigRange(depths=depths, disparity=disp, depth_mm=(zmin, zmax), region=region,
                    disparity_px=(int(dlo), int(dhi)))


def rig_depth_range(pair: RectifiedPair, back_mm: float) -> tuple[float, float]:
    """Every depth (mm) at which the two views of ``pair`` share a field.

    What a sequence searches without a configured range: one frame's content says nothing of the next's.
    """
    return _rig_range(pair, back_mm)[2]


def auto_search_range(pair: RectifiedPair, back_mm: float, left: np.ndarray, right: np.ndarray, *,
                      rig: RigRange | None = None) -> SearchRange:
    """The depth and disparity range to search when the user gave none (see the module docstring).
    ``rig``: the pair's :func:`rig_range`, when the caller has it (the same result, without recomputing it)."""
    known = rig if rig is not None else rig_range(pair, back_mm)
    depths, disp, (zmin, zmax) = known.depths, known.disparity, known.depth_mm
    region, (dlo, dhi) = known.region, known.disparity_px
    dhi = min(dhi, left.shape[1] - 1)
    dlo = min(dlo, dhi)
    vl, vr = (np.asarray(m, dtype=bool) for m in pair.valid_masks())  # type: ignore[attr-defined]
    est, support = estimate_disparity_range(left, right, region, lo=dlo, hi=dhi, valid_left=vl, valid_right=vr)
    if est is None:
        msg = (f"could not find the scene's disparities in the images (only {100 * support:.1f} % of the common "
               f"view matched coarsely: too little texture, or not a capture of this prism): searching the whole "
               f"range the rig allows, {zmin:.0f}–{zmax:.0f} mm; set DepthConfig.depth_range "
               "(MIN, MAX mm) to narrow it")
        return SearchRange((zmin, zmax), (dlo, dhi), "rig", (msg,))
    lo, hi = est
    z_near = _depth_of(hi, depths, disp)
    z_far = _depth_of(lo, depths, disp) if lo > np.nanmin(disp) else zmax
    z_near, z_far = max(z_near, zmin), min(max(z_far, z_near * 1.01), zmax)
    return SearchRange((z_near, z_far), (lo, hi), "rig+images")


def depth_warnings(*, points: int, region_pixels: int, matched: int, confident: int | None,
                   disparity: np.ndarray | None, valid: np.ndarray | None, disparity_range: tuple[int, int],
                   depth_range: tuple[float, float], coverage: Coverage | None = None) -> list[str]:
    """One-line warnings about a finished depth run (empty when nothing looks wrong).

    Parameters
    ----------
    points : valid triangulated points.  region_pixels : pixels of the matched region.
    matched : matches that passed the matcher's left–right check.  confident : of those, the refined
        confident ones (None when refinement was off).
    disparity, valid : the matcher's raw disparity and the pixels whose values count for the limit shares
        (None: every finite one).
    disparity_range, depth_range : what was searched.
    coverage : the share of the common view at the depths found (:func:`scene_coverage`); None: points over
        ``region_pixels``.
    """
    zr = f"{depth_range[0]:.0f}–{depth_range[1]:.0f} mm"
    if points == 0:
        return [f"no depth recovered: nothing in the searched depth range {zr} matched (wrong DepthConfig.depth_range, "
                "or the image is not a capture of this prism rig)"]
    out: list[str] = []
    cov = coverage if coverage is not None else Coverage(points=points, pixels=region_pixels, of="searched")
    if cov.share < MIN_COVERAGE:
        out.append(f"only {100 * cov.share:.1f} % of {cov.describe(depth_range)} got a depth: the result is "
                   f"unreliable (scene outside {zr}, too little texture, or not a capture of this prism rig)")
    if confident is not None and matched > 0 and confident / matched < MIN_CONFIDENT:
        out.append(f"only {100 * confident / matched:.1f} % of the matches are confident after refinement: the "
                   "images do not look like two views of one scene (not a prism capture of this rig?)")
    if disparity is not None:
        lo, hi = disparity_range
        at_lo, at_hi, n = limit_shares(disparity, valid, min_disp=lo, max_disp=hi)
        if n and at_hi > LIMIT_SHARE:
            out.append(f"{100 * at_hi:.1f} % of the matches sit at the nearest searched depth ({hi} px): parts "
                       f"of the scene are probably nearer than {zr} (widen DepthConfig.depth_range)")
        if n and at_lo > LIMIT_SHARE and lo > 0:
            out.append(f"{100 * at_lo:.1f} % of the matches sit at the farthest searched depth ({lo} px): parts "
                       f"of the scene are probably farther than {zr} (widen DepthConfig.depth_range)")
    return out


def auto_search_range_of_capture(rig: Rig, image: np.ndarray, *, faces: tuple[int, int],
                                 calibration: str = "fit") -> SearchRange:
    """:func:`auto_search_range` for a capture: calibrates and rectifies the pair ``faces`` first."""
    by_face = {v.face: v for v in calibrate_rig(rig, method=calibration)}
    pair = rectify_pair(rig, by_face[faces[0]], by_face[faces[1]])
    left, right = pair.rectify_images(image)
    return auto_search_range(pair, rig.prism.back_distance, np.asarray(left), np.asarray(right))
