"""A temporal prior for a stream: the previous frame's disparities as a per-pixel search band for the next frame.

A stream's frames come from one rig, a tenth of a second apart: a pixel's disparity moves little from one frame to
the next, except where the scene moves across it (depth edges, disocclusions) or changes (a cut). :func:`prior_band`
turns the previous frame's matches into each pixel's band: the min … max of the previous disparities within
``radius`` pixels (what lateral motion of up to ``radius`` px per frame brings to the pixel), ± ``margin`` px
(motion in depth), clipped to the search range; a pixel with no previous match within ``radius`` (an occlusion, a
hole, the context columns left of the region) gets the same over ``wide_radius`` pixels, and one without any
there searches the whole range. A banded matcher (``sgm``'s
:meth:`~prismstereo.matching.local.sgm.SGMMatcher.compute_banded`) then costs pixels × band instead of pixels ×
range.

The band is a guess, so a banded frame is checked (:func:`band_failed`) and matched again over the whole range
when it fails: where the scene left the bands (a cut, a fast motion) the winners pile up at the bands' inner limits
and the left–right check rejects more. :class:`TemporalPrior` holds the rules, among them a full frame every
``keyframe_every`` frames.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import cv2
import numpy as np

from prismstereo.checks import check_fields

__all__ = ["BANDED_MATCHERS", "DEFAULT_PRIOR", "PriorBand", "TemporalPrior", "band_failed", "band_limit_share",
           "prior_band"]

#: matchers that search a per-pixel band (``compute_banded``)
BANDED_MATCHERS = frozenset({"sgm"})


@dataclass(frozen=True, kw_only=True)
class TemporalPrior:
    """How a stream uses the previous frame's disparities (module docstring).

    Attributes
    ----------
    radius : int
        Pixels around a pixel whose previous disparities make its band (the lateral motion per frame it
        allows).
    wide_radius : int
        The same for a pixel without a previous match within ``radius`` (no previous match within it either:
        the whole range).
    margin : int
        Pixels added below and above the band (motion in depth).
    keyframe_every : int
        A full-range frame at least every this many frames (1: every frame; the prior is then never used).
    max_full_share : float
        Search the whole range instead when more than this share of the pixels has no previous match within
        ``radius`` (the prior says too little).
    max_limit_share : float
        A banded frame fails when more than this share of its matches sits within half a pixel of an inner
        limit of its band (a limit that is not the search range's).
    min_matched_ratio : float
        A banded frame fails when its matches are fewer than this share of the last full frame's.
    """

    radius: int = 8
    wide_radius: int = 48
    margin: int = 3
    keyframe_every: int = 10
    max_full_share: float = 0.5
    max_limit_share: float = 0.02
    min_matched_ratio: float = 0.9

    def __post_init__(self) -> None:
        check_fields(self, {"radius": (0, 256), "wide_radius": (0, 256), "margin": (0, 256),
                            "keyframe_every": (1, None), "max_full_share": (0.0, 1.0), "max_limit_share": (0.0, 1.0),
                            "min_matched_ratio": (0.0, 1.0)})

    def to_dict(self) -> dict[str, float]:
        return dataclasses.asdict(self)


#: the stream's default rules
DEFAULT_PRIOR = TemporalPrior()


@dataclass(frozen=True, eq=False)
class PriorBand:
    """Each pixel's search band from a previous disparity map (:func:`prior_band`).

    Attributes
    ----------
    lo, hi : (H, W) int32
        Lowest and highest disparity searched, px, inclusive, within the search range.
    full : (H, W) bool
        Pixels without a previous match within the wide radius: they search the whole range.
    """

    lo: np.ndarray
    hi: np.ndarray
    full: np.ndarray

    @property
    def full_share(self) -> float:
        """Share of the pixels that search the whole range."""
        return float(self.full.mean()) if self.full.size else 1.0

    @property
    def mean_width(self) -> float:
        """Mean disparities searched per pixel."""
        return float((self.hi - self.lo + 1).mean()) if self.lo.size else 0.0


def prior_band(previous: np.ndarray, *, min_disp: int, max_disp: int, radius: int = 8, wide_radius: int = 48,
               margin: int = 3) -> PriorBand:
    """Per-pixel bands from the previous frame's disparities (module docstring).

    Parameters
    ----------
    previous : (H, W) float array
        The previous frame's matches on the same grid, px, NaN where none.
    min_disp, max_disp : int
        The search range, px (inclusive).
    radius, wide_radius, margin : int
        See :class:`TemporalPrior`.

    Returns
    -------
    PriorBand
    """
    d = np.asarray(previous, dtype=np.float32)
    finite = np.isfinite(d)
    big = np.float32(1e9)
    low, high = np.where(finite, d, big), np.where(finite, d, -big)
    dmin, dmax = _window_min_max(low, high, int(radius))
    near = dmin < big / 2
    if not near.all():
        wmin, wmax = _window_min_max(low, high, max(int(wide_radius), int(radius)))
        dmin, dmax = np.where(near, dmin, wmin), np.where(near, dmax, wmax)
    full = ~(dmin < big / 2)
    lo = np.where(full, min_disp, np.floor(np.where(full, 0, dmin)) - margin)
    hi = np.where(full, max_disp, np.ceil(np.where(full, 0, dmax)) + margin)
    lo = np.clip(lo, min_disp, max_disp).astype(np.int32)
    hi = np.clip(hi, min_disp, max_disp).astype(np.int32)
    hi = np.maximum(hi, lo)
    return PriorBand(lo=lo, hi=hi, full=full)


def _window_min_max(low: np.ndarray, high: np.ndarray, radius: int) -> tuple[np.ndarray, np.ndarray]:
    """The min of ``low`` and the max of ``high`` over (2·radius + 1)² windows (border replicated)."""
    kernel = np.ones((2 * radius + 1, 2 * radius + 1), np.uint8)
    return (cv2.erode(low, kernel, borderType=cv2.BORDER_REPLICATE),
            cv2.dilate(high, kernel, borderType=cv2.BORDER_REPLICATE))


def band_limit_share(disparity: np.ndarray, band: PriorBand, *, min_disp: int, max_disp: int) -> float:
    """Share of the finite matches of ``disparity`` within half a pixel of an inner limit of their band (a band
    limit that is not ``min_disp`` / ``max_disp``): the share that the band may have cut (0 without matches)."""
    d = np.asarray(disparity, dtype=np.float32)
    ok = np.isfinite(d)
    n = int(ok.sum())
    if n == 0:
        return 0.0
    with np.errstate(invalid="ignore"):
        at_lo = (band.lo > min_disp) & (d <= band.lo + 0.5)
        at_hi = (band.hi < max_disp) & (d >= band.hi - 0.5)
    return float(((at_lo | at_hi) & ok).sum()) / n


def band_failed(disparity: np.ndarray, band: PriorBand, *, min_disp: int, max_disp: int, reference_matches: int,
                rules: TemporalPrior) -> str:
    """Why a banded frame's matches ``disparity`` are not trusted, or ``""``: more than ``max_limit_share`` of them
    at an inner band limit (:func:`band_limit_share`), or fewer than ``min_matched_ratio`` × ``reference_matches``
    (the last full frame's count)."""
    share = band_limit_share(disparity, band, min_disp=min_disp, max_disp=max_disp)
    if share > rules.max_limit_share:
        return f"{100 * share:.1f} % of the matches at a band limit"
    n = int(np.isfinite(disparity).sum())
    if n < rules.min_matched_ratio * reference_matches:
        return f"{n} matches against {reference_matches} in the last full frame"
    return ""
