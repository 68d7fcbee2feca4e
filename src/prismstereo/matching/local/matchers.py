"""Local matchers of thesis Table 5.1 (SAD, SSD, NCC, SHD, BPASW) behind the registry.

Each builds an aggregated cost volume, selects the winner (thesis Eq. 5.15), and — unless switched
off — checks left–right consistency (Eq. 6.7, the right view's disparity read along the diagonals of
the same volume), refines to subpixel and fills the invalid pixels for a dense output.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Any, ClassVar, Literal

import numpy as np

from prismstereo.checks import Range, check_fields, fail
from prismstereo.errors import MatchingError
from prismstereo.matching.local import aggregation, costs, selection
from prismstereo.matching.local.aggregation import SegmentBand
from prismstereo.matching.registry import MatchResult, register_matcher

log = logging.getLogger(__name__)

__all__ = ["BPASWMatcher", "LocalMatcher", "NCCMatcher", "SADMatcher", "SHDMatcher", "SSDMatcher"]


@dataclass(frozen=True, kw_only=True)
class LocalMatcher:
    """Common post-processing of the local matchers.

    Parameters
    ----------
    cross_check : bool
        Left–right check (thesis Eq. 6.7); failing pixels are invalid.
    tolerance : float
        Cross-check tolerance in pixels.
    subpixel : bool
        Parabola subpixel refinement.
    fill : bool
        Fill invalid pixels (scanline background fill + weighted median) for a dense map.
    weighted_median : bool
        Smooth the filled pixels with a colour-weighted median (numba) instead of a plain 5×5 median.
    final_median : bool
        After filling, pass a colour-weighted median (radius 9) over the whole dense map (needs
        ``weighted_median``); removes isolated mismatches that passed the check.
    keep_cost : bool
        Return the aggregated cost volume in ``extras["cost"]``.
    """

    cross_check: bool = True
    tolerance: float = 1.0
    subpixel: bool = True
    fill: bool = True
    weighted_median: bool = False
    final_median: bool = False
    keep_cost: bool = False

    #: the ranges of the subclass's own fields, checked with ``tolerance``'s in ``__post_init__``
    _RANGES: ClassVar[dict[str, Range]] = {}
    _POSITIVE: ClassVar[tuple[str, ...]] = ()

    def __post_init__(self) -> None:
        check_fields(self, {"tolerance": (0.0, None), **self._RANGES}, positive=self._POSITIVE)

    @property
    def supports_band(self) -> bool:
        """Whether :meth:`compute` takes a ``band`` (a search per row segment)."""
        return False

    def cost_volume(self, left: np.ndarray, right: np.ndarray, *, max_disp: int,
                    min_disp: int) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def banded_cost_volume(self, left: np.ndarray, right: np.ndarray, *, max_disp: int, min_disp: int,
                           band: SegmentBand) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def compute(self, left: np.ndarray, right: np.ndarray, *, max_disp: int,
                min_disp: int = 0, band: SegmentBand | None = None) -> MatchResult:
        """Disparity of ``left`` (float32 H×W, NaN invalid) for ``min_disp <= d <= max_disp``.

        ``band`` (where :attr:`supports_band`): only its slices are searched, per row segment; the pixels it
        gives none are invalid, and the hole filling and final median run on the box of the others."""
        if band is not None:
            return self._compute_banded(left, right, max_disp=max_disp, min_disp=min_disp, band=band)
        timings: dict[str, float] = {}
        t = time.perf_counter()
        vol = self.cost_volume(left, right, max_disp=max_disp, min_disp=min_disp)
        timings["cost+aggregation"] = time.perf_counter() - t
        t = time.perf_counter()
        disp = selection.winner_take_all(vol, min_disp=min_disp)
        if self.cross_check:
            disp_r = selection.right_disparity(vol, min_disp=min_disp)
            valid = selection.cross_check(disp, disp_r, tolerance=self.tolerance)
        else:
            valid = np.ones(disp.shape, dtype=bool)
        if self.subpixel:
            disp = selection.subpixel_refine(vol, disp, min_disp=min_disp)
        timings["selection"] = time.perf_counter() - t
        raw = np.where(valid, disp, np.float32(np.nan)).astype(np.float32)
        extras: dict[str, object] = {"cost": vol} if self.keep_cost else {}
        if self.fill and self.cross_check and not valid.all():
            t = time.perf_counter()
            dense = selection.fill_holes(raw, valid, image=left if self.weighted_median else None)
            if self.final_median and self.weighted_median and np.isfinite(dense).all():
                dense = selection.weighted_median_filter(dense, left, radius=9)
            timings["fill"] = time.perf_counter() - t
            return MatchResult(dense, valid, raw, timings, extras)
        return MatchResult(raw, valid, None, timings, extras)

    def _compute_banded(self, left: np.ndarray, right: np.ndarray, *, max_disp: int, min_disp: int,
                        band: SegmentBand) -> MatchResult:
        """:meth:`compute` inside ``band``."""
        if not self.supports_band:
            raise MatchingError(f"expected no band for {type(self).__name__} (it searches every slice), got one")
        h, w = left.shape[:2]
        busy = band.mask(h, w)
        timings: dict[str, float] = {}
        t = time.perf_counter()
        vol = self.banded_cost_volume(left, right, max_disp=max_disp, min_disp=min_disp, band=band)
        timings["cost+aggregation"] = time.perf_counter() - t
        t = time.perf_counter()
        disp = selection.winner_take_all(vol, min_disp=min_disp)
        if self.cross_check:
            disp_r = selection.right_disparity(vol, min_disp=min_disp)
            valid = selection.cross_check(disp, disp_r, tolerance=self.tolerance) & busy
        else:
            valid = busy.copy()
        if self.subpixel:
            disp = selection.subpixel_refine(vol, disp, min_disp=min_disp)
        timings["selection"] = time.perf_counter() - t
        raw = np.where(valid, disp, np.float32(np.nan)).astype(np.float32)
        extras: dict[str, object] = {"cost": vol} if self.keep_cost else {}
        rows, cols = np.flatnonzero(busy.any(axis=1)), np.flatnonzero(busy.any(axis=0))
        if self.fill and self.cross_check and rows.size and not valid[busy].all():
            t = time.perf_counter()
            box = (slice(int(rows[0]), int(rows[-1]) + 1), slice(int(cols[0]), int(cols[-1]) + 1))
            img = left[box] if self.weighted_median else None
            sub = selection.fill_holes(raw[box], valid[box], image=img, median_where=busy[box])
            if self.final_median and self.weighted_median and np.isfinite(sub).all():
                sub = selection.weighted_median_filter(sub, left[box], mask=busy[box], radius=9)
            dense = np.full((h, w), np.float32(np.nan), dtype=np.float32)
            dense[box] = sub
            timings["fill"] = time.perf_counter() - t
            return MatchResult(dense, valid, raw, timings, extras)
        return MatchResult(raw, valid, None, timings, extras)


def check_census_window(owner: object, window: object) -> None:
    """Raise ConfigError ``<Class>.census_window: ...`` unless ``window`` is two odd integers ``(h, w)`` with
    ``h·w - 1 <= 64`` (the census code's bits)."""
    ok = isinstance(window, tuple | list) and len(window) == 2
    ok = ok and all(isinstance(v, int | np.integer) and not isinstance(v, bool) and v >= 1 and v % 2 == 1
                    for v in window)  # type: ignore[attr-defined]
    if not ok or int(window[0]) * int(window[1]) - 1 > 64:  # type: ignore[index]
        fail(owner, "census_window", "two odd integers (height, width) of at most 65 pixels", window)


@register_matcher("sad")
@dataclass(frozen=True, kw_only=True)
class SADMatcher(LocalMatcher):
    """Sum of absolute differences over a ``(2·radius+1)²`` box window (thesis §2.6, Table 5.1)."""

    radius: int = 4

    _RANGES: ClassVar[dict[str, Range]] = {"radius": (0, 100)}

    def cost_volume(self, left: np.ndarray, right: np.ndarray, *, max_disp: int,
                    min_disp: int) -> np.ndarray:
        return costs.cost_sad_window(left, right, max_disp=max_disp, min_disp=min_disp, radius=self.radius)


@register_matcher("ssd")
@dataclass(frozen=True, kw_only=True)
class SSDMatcher(LocalMatcher):
    """Sum of squared differences over a box window (thesis §2.6, Table 5.1)."""

    radius: int = 4

    _RANGES: ClassVar[dict[str, Range]] = {"radius": (0, 100)}

    def cost_volume(self, left: np.ndarray, right: np.ndarray, *, max_disp: int,
                    min_disp: int) -> np.ndarray:
        return costs.cost_ssd(left, right, max_disp=max_disp, min_disp=min_disp, radius=self.radius)


@register_matcher("ncc")
@dataclass(frozen=True, kw_only=True)
class NCCMatcher(LocalMatcher):
    """Zero-mean normalised cross-correlation over a box window, cost ``1 - ZNCC`` (Table 5.1)."""

    radius: int = 4

    _RANGES: ClassVar[dict[str, Range]] = {"radius": (0, 100)}

    def cost_volume(self, left: np.ndarray, right: np.ndarray, *, max_disp: int,
                    min_disp: int) -> np.ndarray:
        return costs.cost_ncc(left, right, max_disp=max_disp, min_disp=min_disp, radius=self.radius)


@register_matcher("shd")
@dataclass(frozen=True, kw_only=True)
class SHDMatcher(LocalMatcher):
    """Sum of census Hamming distances over a box window (Table 5.1)."""

    radius: int = 4
    census_window: tuple[int, int] = (7, 9)

    _RANGES: ClassVar[dict[str, Range]] = {"radius": (0, 100)}

    def __post_init__(self) -> None:
        super().__post_init__()
        check_census_window(self, self.census_window)

    def cost_volume(self, left: np.ndarray, right: np.ndarray, *, max_disp: int,
                    min_disp: int) -> np.ndarray:
        vol = costs.cost_census(left, right, max_disp=max_disp, min_disp=min_disp,
                                window=(int(self.census_window[0]), int(self.census_window[1])))
        return costs._box_volume(vol, self.radius)


@register_matcher("bpasw")
@dataclass(frozen=True, kw_only=True)
class BPASWMatcher(LocalMatcher):
    """BPASW: S_AD cost (thesis Eq. 5.6) aggregated with symmetric Weber–Fechner weights (Eqs. 5.7–5.14).

    See :func:`prismstereo.matching.local.aggregation.aggregate_bpasw` for the weights and the reading of the
    Weber–Fechner law. ``continuity=True`` runs a second pass with the continuity law (Eqs. 5.9, 5.12)
    using the first pass's winners as the neighbours' disparities (off by default: it raised the Middlebury
    error; docs/EXPERIMENTS.md).

    Defaults (chosen on the four Middlebury v2 scenes, bad > 1 px after cross-check and filling;
    docs/EXPERIMENTS.md): a 33×33 window sampled every 2 px, S_AD with ω = 0.5 and truncations 20 / 8 grey
    levels, plus ``census_weight`` × the census Hamming distance (7×9), Weber–Fechner colour threshold
    S0 = 28 ΔE. ``subpixel`` is off by default because the parabola fit did not lower the 1-px error here;
    switch it on for depth. The dense map gets a final colour-weighted median (``final_median``).
    """

    subpixel: bool = False
    weighted_median: bool = True
    final_median: bool = True
    radius: int = 16
    dilation: int = 2
    omega: float = 0.5
    tau_color: float | None = 20.0
    tau_gradient: float | None = 8.0
    census_weight: float = 0.5
    kernel: Literal["weber", "exp"] = "weber"
    similarity_s0: float = 28.0
    gamma_color: float = 7.0
    gamma_proximity: float = 17.5
    continuity: bool = False
    continuity_weight: float = 0.2

    _RANGES: ClassVar[dict[str, Range]] = {
        "radius": (0, 100), "dilation": (1, 50), "omega": (0.0, 1.0), "tau_color": (0.0, None),
        "tau_gradient": (0.0, None), "census_weight": (0.0, None), "continuity_weight": (0.0, None)}
    _POSITIVE: ClassVar[tuple[str, ...]] = ("similarity_s0", "gamma_color", "gamma_proximity")

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.kernel not in ("weber", "exp"):
            fail(self, "kernel", "'weber' or 'exp'", self.kernel)

    def pixel_cost(self, left: np.ndarray, right: np.ndarray, *, max_disp: int, min_disp: int,
                   band: SegmentBand | None = None) -> np.ndarray:
        """The per-pixel cost before aggregation, float32 ``(H, W, D)``: S_AD (thesis Eq. 5.6) plus
        ``census_weight`` × the census Hamming distance; with ``band``, only its entries (0 elsewhere)."""
        return costs.cost_s_ad_census(left, right, max_disp=max_disp, min_disp=min_disp, omega=self.omega,
                                      tau_color=self.tau_color, tau_gradient=self.tau_gradient,
                                      census_weight=self.census_weight, band=band)

    @property
    def supports_band(self) -> bool:
        """A band per row segment (not with the continuity pass, which reads every slice's winner)."""
        return not self.continuity

    def banded_cost_volume(self, left: np.ndarray, right: np.ndarray, *, max_disp: int, min_disp: int,
                           band: SegmentBand) -> np.ndarray:
        """:meth:`cost_volume`'s entries inside ``band`` (the same values), +inf outside."""
        # the pixel cost only where the aggregation's windows read it
        h, w = left.shape[:2]
        vol = self.pixel_cost(left, right, max_disp=max_disp, min_disp=min_disp,
                              band=band.dilated(rows=self.radius, cols=self.radius, height=h, width=w))
        return aggregation.aggregate_bpasw(vol, left, right, radius=self.radius, dilation=self.dilation,
                                           min_disp=min_disp, kernel=self.kernel, similarity_s0=self.similarity_s0,
                                           gamma_color=self.gamma_color, gamma_proximity=self.gamma_proximity,
                                           band=band)

    def cost_volume(self, left: np.ndarray, right: np.ndarray, *, max_disp: int,
                    min_disp: int) -> np.ndarray:
        vol = self.pixel_cost(left, right, max_disp=max_disp, min_disp=min_disp)
        kw: dict[str, Any] = dict(radius=self.radius, dilation=self.dilation, min_disp=min_disp, kernel=self.kernel,
                  similarity_s0=self.similarity_s0, gamma_color=self.gamma_color,
                  gamma_proximity=self.gamma_proximity)
        agg = aggregation.aggregate_bpasw(vol, left, right, **kw)
        if self.continuity:
            prior = np.argmin(agg, axis=2)
            agg = aggregation.aggregate_bpasw(vol, left, right, prior=prior,
                                              continuity_weight=self.continuity_weight, **kw)
        return agg
