"""Semi-global matching (Hirschmüller, PAMI 2008) in numba: the fast preset's matcher.

Pipeline: a census cost (optionally plus a truncated horizontal-gradient term, or BPASW's initial
S_AD + census cost, thesis Eq. 5.6) in a ``uint16`` volume, semi-global aggregation along 8 paths,
winner-take-all with a uniqueness test, parabola sub-pixel, a left–right check (thesis Eq. 6.7) on the
right view's disparities read along the diagonals of the same aggregated volume, OpenCV's speckle
filter, then (optional) hole filling and a colour-weighted median.

The path costs follow Hirschmüller's recursion

    L_r(p, d) = C(p, d) + min(L_r(p-r, d), L_r(p-r, d±1) + P1, min_k L_r(p-r, k) + P2) - min_k L_r(p-r, k)

with ``P2`` lowered across intensity edges, ``P2' = max(P1, P2 / (1 + |I(p) - I(p-r)| / γ))``. The 8 paths
are run as two raster scans (forward: left, up-left, up, up-right; backward: the opposite four), one per
thread, each keeping only the previous image row of its path costs; the two partial sums stay ``uint16``.
The matcher runs each scan first over the half of the image it reaches first, keeping those sums, then on
into the other half, where it adds the other scan's sums and selects each pixel at once
(:func:`sgm_aggregate_select`).

Volumes are ``(H, W, D)`` with slice ``i`` = disparity ``min_disp + i`` and ``d = x_left - x_right``, as
in :mod:`prismstereo.matching.local.costs`.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np

from prismstereo.checks import check_fields, fail
from prismstereo.errors import ConfigError
from prismstereo.matching.local import costs, selection
from prismstereo.matching.local._sgm import census_codes, census_kernel, select_kernel, sgm_kernel, sgm_select_kernel
from prismstereo.matching.local._sgm_band import census_band_kernel, select_band_kernel, sgm_band_kernel
from prismstereo.matching.local.matchers import BPASWMatcher, check_census_window
from prismstereo.matching.registry import MatchResult, register_matcher

log = logging.getLogger(__name__)

__all__ = ["SGMMatcher", "census_cost_volume", "sgm_aggregate", "sgm_aggregate_select", "sgm_select"]

def census_cost_volume(left: np.ndarray, right: np.ndarray, *, max_disp: int, min_disp: int = 0,
                       window: tuple[int, int] = (7, 9), scale: int = 1, grad_weight: float = 0.0,
                       grad_tau: float = 8.0) -> np.ndarray:
    """Census Hamming cost (plus an optional truncated horizontal-gradient term) as a uint16 volume.

    Parameters
    ----------
    left, right : ndarray, (H, W) or (H, W, 3)
        Rectified pair, 0..255 scale.
    max_disp, min_disp : int
        Inclusive disparity range.
    window : (int, int)
        Odd census window (height, width), at most 65 pixels.
    scale : int
        Integer weight of one differing census bit.
    grad_weight, grad_tau : float
        Weight and truncation (grey levels) of ``|∂x I_l(x) - ∂x I_r(x - d)|``; 0 switches it off.

    Returns
    -------
    ndarray, uint16, (H, W, max_disp - min_disp + 1)
        Out-of-range matches (``x - d < 0``) get the largest value the cost can take.
    """

    return _census_volume(costs.to_gray(left), costs.to_gray(right), max_disp=max_disp, min_disp=min_disp,
                          window=window, scale=scale, grad_weight=grad_weight, grad_tau=grad_tau)


def _census_volume(gray_left: np.ndarray, gray_right: np.ndarray, *, max_disp: int, min_disp: int,
                   window: tuple[int, int], scale: int, grad_weight: float, grad_tau: float) -> np.ndarray:
    """:func:`census_cost_volume` of the float32 (H, W) grey views (``costs.to_gray`` of the pair, which
    returns a grey view itself unchanged: the same volume)."""
    cl, cr, gxl, gxr, invalid = _census_inputs(gray_left, gray_right, window=window, scale=scale,
                                               grad_weight=grad_weight, grad_tau=grad_tau)
    return census_kernel(cl, cr, gxl, gxr, int(min_disp), int(max_disp) - int(min_disp) + 1, int(scale),
                          float(grad_weight), float(grad_tau), invalid)


def _census_inputs(gray_left: np.ndarray, gray_right: np.ndarray, *, window: tuple[int, int], scale: int,
                   grad_weight: float, grad_tau: float
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
    """What the census cost kernels read (the full volume's and the banded one's): both views' census codes
    and horizontal gradients, and the cost of an invalid match; the window and the uint16 range checked."""
    wh, ww = int(window[0]), int(window[1])
    if wh % 2 == 0 or ww % 2 == 0 or wh < 1 or ww < 1 or wh * ww - 1 > 64:
        raise ConfigError(f"expected an odd census window with at most 65 pixels, got {window}")
    pad = ((wh // 2, wh // 2), (ww // 2, ww // 2))
    cl = census_codes(np.pad(gray_left, pad, mode="edge"), wh // 2, ww // 2)
    cr = census_codes(np.pad(gray_right, pad, mode="edge"), wh // 2, ww // 2)
    gxl, _ = costs.image_gradients(gray_left)
    gxr, _ = costs.image_gradients(gray_right)
    nbits = int(window[0]) * int(window[1]) - 1
    invalid = int(scale * nbits + grad_weight * grad_tau + 0.5)
    if invalid > 65535:
        raise ConfigError(f"expected a cost that fits uint16 (scale·bits + grad_weight·grad_tau <= 65535), "
                          f"got {invalid}")
    return cl, cr, gxl, gxr, invalid


def sgm_aggregate(cost: np.ndarray, gray: np.ndarray, *, p1: int, p2: int,
                  p2_gamma: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Semi-global aggregation along 8 paths (Hirschmüller 2008, Eq. 13).

    Parameters
    ----------
    cost : ndarray, uint16, (H, W, D)
        Matching cost per pixel and disparity.
    gray : ndarray, float32, (H, W)
        Guidance image for the edge-adaptive ``P2``.
    p1, p2 : int
        Penalties for a disparity change of 1 and of more than 1 between path neighbours.
    p2_gamma : float
        ``P2' = max(P1, P2 / (1 + |ΔI| / γ))``; 0 keeps ``P2`` constant.

    Returns
    -------
    (ndarray, ndarray), uint16, (H, W, D) each
        Sums of the four forward and of the four backward path costs; the aggregated cost is their sum.
    """
    c, cmax = _checked_volume(cost, p1, p2)
    return sgm_kernel(c, np.ascontiguousarray(gray, dtype=np.float32), int(p1), int(p2), float(p2_gamma), cmax)


def _checked_volume(cost: np.ndarray, p1: int, p2: int) -> tuple[np.ndarray, int]:
    """The volume as C-contiguous uint16 and its largest cost (0 if empty), checked against the path sums'
    uint16 range."""
    c = np.ascontiguousarray(cost, dtype=np.uint16)
    cmax = int(c.max(initial=0))
    top = cmax + int(p2)
    if 4 * top > 65535:
        raise ConfigError(f"expected 4·(max cost + P2) <= 65535 for uint16 path sums, got {4 * top}")
    if not 0 <= p1 <= p2:
        raise ConfigError(f"expected 0 <= P1 <= P2, got P1={p1}, P2={p2}")
    return c, cmax


def sgm_aggregate_select(cost: np.ndarray, gray: np.ndarray, *, p1: int, p2: int, p2_gamma: float = 0.0,
                         min_disp: int = 0, uniqueness: int = 10, tolerance: int = 1,
                         subpixel: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """:func:`sgm_select` of :func:`sgm_aggregate` in one pass, the same maps: each raster scan selects the
    pixels of the half of the image it reaches second, so that selection runs on both threads and only one
    uint16 volume of path sums (half of each scan's) is held.

    Parameters and returns as those two functions'.
    """
    c, cmax = _checked_volume(cost, p1, p2)
    disp, _, code = sgm_select_kernel(c, np.ascontiguousarray(gray, dtype=np.float32), int(p1), int(p2),
                                      float(p2_gamma), cmax, int(min_disp), int(uniqueness), int(tolerance),
                                      bool(subpixel))
    return disp, code


def sgm_select(fwd: np.ndarray, bwd: np.ndarray, *, min_disp: int = 0, uniqueness: int = 10,
               tolerance: int = 1, subpixel: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Disparity from the two partial SGM sums: WTA, uniqueness, sub-pixel, left–right check.

    Parameters
    ----------
    fwd, bwd : ndarray, uint16, (H, W, D)
        Outputs of :func:`sgm_aggregate`.
    uniqueness : int
        Percent margin by which the winner must beat every disparity not adjacent to it (0: off).
    tolerance : int
        Left–right check tolerance in integer disparities (thesis Eq. 6.7).

    Returns
    -------
    disparity : ndarray, float32, (H, W)
        NaN where a check rejected the pixel.
    reject : ndarray, uint8, (H, W)
        0 kept, 1 not unique, 2 failed the left–right check.
    """

    disp, _, code = select_kernel(np.ascontiguousarray(fwd), np.ascontiguousarray(bwd), int(min_disp),
                                   int(uniqueness), int(tolerance), bool(subpixel))
    return disp, code


def _band_indices(shape: tuple[int, int], band_lo: np.ndarray, band_hi: np.ndarray, *, min_disp: int,
                  max_disp: int) -> tuple[np.ndarray, np.ndarray]:
    """The bands as C-contiguous int32 volume indices (``disparity - min_disp``), checked."""
    lo = np.asarray(band_lo)
    hi = np.asarray(band_hi)
    if lo.shape != tuple(shape) or hi.shape != tuple(shape):
        raise ConfigError(f"band_lo/band_hi: expected two {shape[1]}×{shape[0]} maps, got shapes {lo.shape} and "
                          f"{hi.shape}")
    if lo.size and (int(lo.min()) < min_disp or int(hi.max()) > max_disp or bool((lo > hi).any())):
        raise ConfigError(f"band_lo/band_hi: expected bands with {min_disp} <= band_lo <= band_hi <= {max_disp}, "
                          f"got {int(lo.min())}..{int(hi.max())}" + (" with empty bands" if (lo > hi).any() else ""))
    return (np.ascontiguousarray(lo - int(min_disp), dtype=np.int32),
            np.ascontiguousarray(hi - int(min_disp), dtype=np.int32))


def _speckle_filter(disp: np.ndarray, *, window: int, max_diff: float) -> np.ndarray:
    """Invalidate connected regions of fewer than ``window`` pixels (neighbours within ``max_diff``)."""
    if window <= 0:
        return disp
    finite = np.isfinite(disp)
    d16 = np.where(finite, np.rint(disp * 16.0), -16).astype(np.int16)
    cv2.filterSpeckles(d16, -16, int(window), int(round(16 * max_diff)))
    out = disp.copy()
    out[d16 == -16] = np.nan
    return out


@register_matcher("sgm")
@dataclass(frozen=True, kw_only=True)
class SGMMatcher:
    """Semi-global matching (Hirschmüller 2008) on a census cost, numba, 8 paths (see module doc).

    Parameters
    ----------
    cost : {"census", "bpasw"}
        ``census``: Hamming distance of ``census_window`` census codes (``census_scale`` per bit) plus
        ``grad_weight``·min(|∂x I_l - ∂x I_r|, ``grad_tau``). ``bpasw``: BPASW's initial cost, S_AD (thesis
        Eq. 5.6, ω = 0.5, truncations 20 / 8) + 0.5 × census 7×9, times ``bpasw_scale``, rounded.
    p1, p2, p2_gamma : int, int, float
        Path penalties in cost units and the edge adaptation of ``P2`` (:func:`sgm_aggregate`).
    uniqueness : int
        Percent; 0 switches the uniqueness test off.
    tolerance : int
        Left–right check tolerance (integer disparities).
    subpixel : bool
        Parabola sub-pixel refinement of the aggregated cost.
    speckle_window, speckle_range : int, float
        Regions of fewer pixels whose disparities differ by at most ``speckle_range`` are removed
        (OpenCV ``filterSpeckles``); window 0 switches it off. At most a twentieth of the image.
    fill : bool
        Fill rejected pixels (scanline background fill + colour-weighted median, as the local matchers).
    median_radius : int
        After filling, a colour-weighted median of this radius over the whole map (0: off). The median
        works on whole-disparity bins, so the dense map then holds whole disparities, like ``bpasw``'s;
        ``disparity_raw`` keeps the sub-pixel values, and ``depth`` refines to sub-pixel on its own.

    One parameter set for every scene; the defaults were chosen on the four Middlebury v2 scenes and
    checked on the validation scenes (docs/EXPERIMENTS.md).
    """

    cost: Literal["census", "bpasw"] = "census"
    census_window: tuple[int, int] = (7, 9)
    census_scale: int = 1
    grad_weight: float = 2.0
    grad_tau: float = 8.0
    bpasw_scale: float = 1.0
    p1: int = 8
    p2: int = 96
    p2_gamma: float = 10.0
    uniqueness: int = 5
    tolerance: int = 1
    subpixel: bool = True
    speckle_window: int = 100
    speckle_range: float = 2.0
    fill: bool = True
    median_radius: int = 3

    def __post_init__(self) -> None:
        check_fields(self, {"census_scale": (1, None), "grad_weight": (0.0, None), "grad_tau": (0.0, None),
                            "p1": (0, None), "p2": (0, None), "p2_gamma": (0.0, None), "uniqueness": (0, 99),
                            "tolerance": (0, None), "speckle_window": (0, None), "speckle_range": (0.0, None),
                            "median_radius": (0, 100)}, positive=("bpasw_scale",))
        if self.cost not in ("census", "bpasw"):
            fail(self, "cost", "'census' or 'bpasw'", self.cost)
        if self.p2 < self.p1:
            fail(self, "p2", f"an integer >= p1 = {self.p1}", self.p2)
        check_census_window(self, self.census_window)

    @property
    def supports_pixel_band(self) -> bool:
        """Whether :meth:`compute_banded` takes this configuration (the census cost): coarse-to-fine
        (:func:`~prismstereo.matching.scale.match_scaled`) then gives every pixel its own band."""
        return self.cost == "census"

    def cost_volume(self, left: np.ndarray, right: np.ndarray, *, max_disp: int, min_disp: int,
                    gray_left: np.ndarray | None = None) -> np.ndarray:
        """The uint16 matching cost volume ``(H, W, D)`` before aggregation; ``gray_left``: ``costs.to_gray`` of
        ``left`` if the caller has it (the census cost reads the grey views)."""
        if self.cost == "bpasw":
            vol = BPASWMatcher().pixel_cost(left, right, max_disp=max_disp, min_disp=min_disp)
            vol *= np.float32(self.bpasw_scale)
            np.rint(vol, out=vol)
            if float(vol.max(initial=0.0)) > 65535:
                raise ConfigError(f"expected bpasw_scale to keep the cost within uint16, got {self.bpasw_scale}")
            return vol.astype(np.uint16)
        gl = costs.to_gray(left) if gray_left is None else gray_left
        return _census_volume(gl, costs.to_gray(right), max_disp=max_disp, min_disp=min_disp,
                              window=(int(self.census_window[0]), int(self.census_window[1])),
                              scale=self.census_scale, grad_weight=self.grad_weight, grad_tau=self.grad_tau)

    def compute(self, left: np.ndarray, right: np.ndarray, *, max_disp: int,
                min_disp: int = 0) -> MatchResult:
        """Disparity of ``left`` (float32 H×W) for ``min_disp <= d <= max_disp``; see the class doc."""
        timings: dict[str, float] = {}
        t = time.perf_counter()
        gray = costs.to_gray(left)  # the census cost's and the edge-adaptive P2's guidance: computed once
        vol = self.cost_volume(left, right, max_disp=max_disp, min_disp=min_disp, gray_left=gray)
        timings["cost"] = time.perf_counter() - t
        t = time.perf_counter()
        # aggregation and the selection of the winners in one pass (sgm_aggregate_select)
        disp, code = sgm_aggregate_select(vol, gray, p1=self.p1, p2=self.p2, p2_gamma=self.p2_gamma,
                                          min_disp=min_disp, uniqueness=self.uniqueness, tolerance=self.tolerance,
                                          subpixel=self.subpixel)
        del vol
        timings["aggregation"] = time.perf_counter() - t
        return self._finish(left, disp, code, timings)

    def compute_banded(self, left: np.ndarray, right: np.ndarray, *, max_disp: int, min_disp: int = 0,
                       band_lo: np.ndarray, band_hi: np.ndarray) -> MatchResult:
        """:meth:`compute` with each pixel searching only its own disparities ``band_lo .. band_hi`` (inclusive,
        px, within ``min_disp .. max_disp``): tSGM's per-pixel ranges (Rothermel et al. 2012,
        :mod:`~prismstereo.matching.local._sgm_band`). Costs and path sums are computed inside the bands only,
        so the time follows pixels × band. With every band the whole range, the maps are :meth:`compute`'s.

        Parameters
        ----------
        band_lo, band_hi : (H, W) int arrays
            Each pixel's lowest and highest disparity searched, px; ``band_lo <= band_hi``.

        Raises
        ------
        ConfigError
            Bands of another shape than ``left``'s, empty ones or ones outside ``min_disp .. max_disp``; the
            ``bpasw`` cost (census only).
        """
        if self.cost != "census":
            raise ConfigError(f"cost: expected 'census' for a banded match, got {self.cost!r}")
        blo, bhi = _band_indices(left.shape[:2], band_lo, band_hi, min_disp=min_disp, max_disp=max_disp)
        timings: dict[str, float] = {}
        t = time.perf_counter()
        gray = costs.to_gray(left)
        cl, cr, gxl, gxr, invalid = _census_inputs(
            gray, costs.to_gray(right), window=(int(self.census_window[0]), int(self.census_window[1])),
            scale=self.census_scale, grad_weight=self.grad_weight, grad_tau=self.grad_tau)
        nd = int(max_disp) - int(min_disp) + 1
        widths = (bhi - blo + 1).ravel().astype(np.int64)
        off = (np.cumsum(widths) - widths).reshape(blo.shape)  # the ragged volumes' start of each pixel
        total = int(widths.sum())
        vol = census_band_kernel(cl, cr, gxl, gxr, int(min_disp), blo, bhi, off, total, int(self.census_scale),
                                 float(self.grad_weight), float(self.grad_tau), invalid)
        timings["cost"] = time.perf_counter() - t
        t = time.perf_counter()
        top = invalid + int(self.p2)  # the largest cost the census can take, plus P2
        if 4 * top > 65535:
            raise ConfigError(f"expected 4·(max cost + P2) <= 65535 for uint16 path sums, got {4 * top}")
        fwd, bwd = sgm_band_kernel(vol, np.ascontiguousarray(gray, dtype=np.float32), blo, bhi, off, nd,
                                   int(self.p1), int(self.p2), float(self.p2_gamma), invalid)
        del vol
        disp, _, code = select_band_kernel(fwd, bwd, blo, bhi, off, nd, int(min_disp), int(self.uniqueness),
                                           int(self.tolerance), bool(self.subpixel))
        del fwd, bwd
        timings["aggregation"] = time.perf_counter() - t
        res = self._finish(left, disp, code, timings)
        searched = total / max(blo.size, 1)
        return dataclasses.replace(res, extras={**res.extras, "band_mean": round(searched, 2)})

    def _finish(self, left: np.ndarray, disp: np.ndarray, code: np.ndarray, timings: dict[str, float]
                ) -> MatchResult:
        """The speckle filter and (``fill``) the dense map of a selected map; ``timings`` gets their seconds."""
        t = time.perf_counter()
        # a speckle is small against the image: on tiny images (a small region of interest) the window
        # would otherwise remove every region
        window = min(self.speckle_window, disp.size // 20)
        disp = _speckle_filter(disp, window=window, max_diff=self.speckle_range)
        valid = np.isfinite(disp)
        timings["selection"] = time.perf_counter() - t
        extras = {"rejected_unique": int((code == 1).sum()), "rejected_lr": int((code == 2).sum())}
        if self.fill and not valid.all() and valid.any():
            t = time.perf_counter()
            if self.median_radius > 0:
                # the whole-map median below also smooths the filled pixels: no separate median of the holes
                dense = selection.fill_holes(disp, valid, median_radius=0)
                dense = selection.weighted_median_filter(dense, left, radius=self.median_radius)
            else:
                dense = selection.fill_holes(disp, valid, image=left)
            timings["fill"] = time.perf_counter() - t
            return MatchResult(dense, valid, disp, timings, extras)
        return MatchResult(disp, valid, None, timings, extras)
