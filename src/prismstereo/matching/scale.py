"""Coarse-to-fine and memory-bounded matching around any registered matcher (issue 30).

Every matcher builds an ``H × W × D`` cost volume, so its time and memory grow with pixels × disparities.
:func:`match_scaled` wraps a matcher without touching its internals:

1. **coarse level** — the pair downsampled by ``factor`` (area average) is matched with the whole range
   (``[⌊min/f⌋, ⌈max/f⌉]``), itself coarse-to-fine again while it is still above the automatic size;
2. **tiles with a band** — the full-resolution left image is split into core tiles; each tile gets the
   disparity sub-range ``[lo, hi]`` of the coarse map (dense, × ``factor``) over the core dilated by the
   context ``overlap``, ± ``margin``. Where the coarse map is unreliable (fewer than ``min_valid`` of the
   region's coarse pixels passed the coarse left–right check — occlusions, thin structures, no texture)
   the tile falls back to the full range. The matcher then runs on the tile plus its context with the
   right image shifted by ``lo`` (``min_disp = 0``, ``max_disp = hi - lo``), so a tile costs
   ``(tile + context) × band`` instead of ``tile × range``. A matcher that takes a band per row segment
   (``bpasw``; ``ScaleParams.band = "segment"``) gets one per ``segment`` columns of each row instead (the
   coarse map's min…max around them), in tiles that span the row, and only those slices are summed
   (:class:`~prismstereo.matching.local.aggregation.SegmentBand`);
3. **stitching** — each output pixel comes from the one tile whose core holds it; the core's context (the
   ``overlap`` on every side, plus ``hi - lo`` columns to the left for the right view) is matched but
   dropped, so aggregation windows, SGM paths and segments see the same neighbourhood on both sides of a
   seam.

The same tiling bounds memory: :func:`estimate_memory` predicts one untiled match's peak resident memory
from the image size, the disparity count and the matcher (``bytes = base + a·H·W + b·H·W·D``, coefficients
measured with ``ru_maxrss``); a match over ``max_memory`` runs in horizontal strips (full-range search, row
overlap) or smaller tiles, and raises :class:`MatchingError` only when no tile fits. A matcher with its own
strips (:data:`_OWN_STRIPS`: ``coop``, whose segments and planes lose accuracy in tiles and whose range a band
per tile barely narrows) runs, with ``auto``, in the fewest full-range strips of at most its strip bytes each
(with its context rows) wherever its untiled match would take more, whatever the budget. :func:`planned_memory`
is the peak of the whole scaled match as :func:`match_scaled` will run it (its coarse levels, the stitched
maps, its largest tile), known from the sizes alone, before any image is read; ``ScaleParams.held`` is what
the caller's process holds besides the match (a depth run's set-up and maps), which the budget covers too.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import time
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from prismstereo.errors import ConfigError, MatchingError
from prismstereo.matching.local.aggregation import SegmentBand
from prismstereo.matching.registry import Matcher, MatchResult, get_matcher

log = logging.getLogger(__name__)

__all__ = ["C2F_MODES", "ScaleParams", "default_memory_budget", "estimate_memory", "match_scaled",
           "parse_memory", "planned_memory"]

#: values of ``ScaleParams.coarse_to_fine``
C2F_MODES = ("auto", "on", "off")

#: peak-memory model per matcher: (bytes per pixel, bytes per pixel and disparity) of one match, on top of
#: the process base; measured with ``ru_maxrss`` after a warm-up (``benchmarks/bench_memory.py``)
_MEMORY_MODEL: dict[str, tuple[float, float]] = {
    "sgm": (100.0, 4.0),  # the cost volume and one volume of path sums (uint16 each)
    "sgbm": (60.0, 4.5),
    "bpasw": (400.0, 13.5),
    "sad": (120.0, 9.0),
    "ssd": (120.0, 9.0),
    "ncc": (160.0, 9.0),
    "shd": (160.0, 9.0),
    "coop": (1500.0, 42.0),
}
#: matchers that ``auto`` does not run coarse-to-fine below ``auto_pixels`` (for memory, ``auto_bytes`` or the
#: budget, they run whole or in full-range strips):
#: coop's segments and plane fits see only a tile and its context, which costs it accuracy on the scenes it
#: is measured on (Middlebury v2, bad > 1 px nonocc 1.72 → 1.90 with 128 px tiles; more context helps
#: Tsukuba and hurts Teddy); over the budget it runs in strips
_FULL_BELOW_AUTO_PIXELS = frozenset({"coop"})
#: matchers whose untiled match ``auto`` runs in full-range horizontal strips where the image has at least
#: so many pixels and the match would take more than these bytes of its own (:func:`estimate_memory` without
#: the base), whatever the machine's budget: (pixels, bytes per strip at most, rows of context above and below
#: each strip's core). The pixels keep the images coop is measured on whole (Middlebury v2, 2014 at Q with
#: Jadeplant's 2.7 GB, the 0.8 MP captures), where its maps stay the full search's. coop's volumes (42 B per
#: pixel·disparity) are 11 GB at 3 MP over 138 disparities; a strip's segments and planes see its context
#: rows (32 above and below: as accurate as 48 on the 2048 captures, and where it saves a strip, cheaper); one
#: band per strip or per 256–512 px tile is nearly the whole range on the captures it was measured on, so a
#: coarse level would not narrow the search
_OWN_STRIPS: dict[str, tuple[int, int, int]] = {"coop": (1_000_000, 1792 * 2**20, 32)}
#: a matcher without a measured model is assumed to be as heavy as the heaviest one
_UNKNOWN_MODEL = (2500.0, 40.0)
#: resident memory of the process before the match (interpreter, numpy, numba, OpenCV), bytes
PROCESS_BASE = 300 * 2**20
#: per full-resolution pixel held by the tiled run (the float32 pair, the stitched maps)
_STITCH_PER_PIXEL = 48.0


@dataclass(frozen=True, kw_only=True)
class ScaleParams:
    """Coarse-to-fine and tiling parameters of :func:`match_scaled`.

    Attributes
    ----------
    coarse_to_fine : {"auto", "on", "off"}
        ``auto``: coarse-to-fine when the range has at least ``auto_range`` disparities and the image has at
        least ``auto_pixels`` pixels, or the full search's volumes would take more than ``auto_bytes``, or it
        would exceed the memory budget (else the full search, in strips when over budget), or, for a matcher
        that takes a band per row segment (``bpasw``, with ``band="segment"``), when the range has at least
        ``band_range`` disparities whatever the image's size; ``on`` / ``off`` force it.
    auto_pixels, auto_range : int
        The automatic size (pixels, disparities).
    auto_bytes : int
        The automatic size in memory: the untiled match's own bytes (:func:`estimate_memory` without the
        process base) above which ``auto`` matches coarse-to-fine.
    factor : int
        Downsampling factor of the coarse level (≥ 2).
    margin : int
        Full-resolution pixels added on both sides of a tile's coarse min/max.
    tile : int
        Side of a core tile (pixels) at full resolution.
    overlap : int
        Context matched on each side of a core tile and dropped (pixels).
    min_valid : float
        Fraction of the region's coarse pixels that must have passed the coarse left–right check; below
        it the tile searches the whole range (the coarse map is not trusted there).
    band : {"segment", "tile"}
        ``segment``: a matcher that searches a band per row segment (``supports_band``, e.g. ``bpasw``) gets,
        for every ``segment`` columns of a row, the coarse map's min…max over ``band_radius`` full-resolution
        pixels around them (± ``margin``; where fewer than ``min_valid`` of those coarse pixels passed the
        coarse check, the same over a tile's region, and where that is not trusted either, the whole range);
        only the rows of the tile's core dilated by ``band_context`` pixels are matched, and the context
        columns beside them only where they compete for the core's right pixels (:func:`_segment_band`);
        ``tile``: one band per tile (the min…max over the tile and its context).
    band_radius, segment, band_context : int
        See ``band`` (full-resolution pixels).
    band_range : int or None
        With ``auto``, a matcher that takes a band per row segment searches one (coarse-to-fine) at every size
        where the range has at least this many disparities: each pixel then searches the coarse map's min…max
        around it instead of the whole range, which a wide range's false minima would otherwise win (its
        cross-checked map covers more, and its values are right more often). None: by size and memory only.
    strip_pixels, strip_bytes, strip_overlap : int or None
        For a matcher with its own strips (``coop``): with ``auto``, an untiled match of at least
        ``strip_pixels`` pixels and above ``strip_bytes`` of its own runs in full-range horizontal strips of at
        most that many bytes, with ``strip_overlap`` rows of context above and below each core (None: the
        matcher's, :data:`_OWN_STRIPS`).
    band_tile_cols : int
        Width of a core tile with ``band="segment"`` (``tile`` rows high; narrower where the budget asks): the
        tiles' context, which every tile's weights and costs cover again, is then above and below only.
    pixel_band_pixels, pixel_band_range : int
        With ``auto`` and ``band="segment"``, a matcher that takes a band per pixel (``sgm``) runs coarse-to-fine
        from this many pixels over at least this many disparities (``auto_pixels`` where that is smaller): its
        full-resolution match then costs pixels × band instead of pixels × range, and the band (≈ 30–40
        disparities with the coarse map's min…max around each pixel, ± ``margin``, at 1.5× the full search's
        cost per pixel·disparity) pays only over a wide range. ``fast`` at 3 MP: robot (1.85 M rectified
        pixels, 138 disparities) the match −26 % CPU; Adirondack and Jadeplant (61 and 72 disparities) +7 and
        +10 %; at 0.8 MP robot (0.46 M, 74) the same CPU (docs/EXPERIMENTS.md, issue 30, stop 44).
    band_pixels : int
        With ``band="segment"`` and a matcher that takes it, a coarse level of at least this many pixels (and
        ``auto_range`` disparities) is itself coarse-to-fine (its bands from a coarser level), whatever ``auto``
        decides for its size.
    max_memory : int or None
        Peak-memory budget of the process in bytes (what it holds, ``held``, and the match); None:
        :func:`default_memory_budget`.
    held : int or None
        Bytes the process holds besides the match (interpreter, libraries, the caller's arrays); None: a
        process that holds nothing else (:data:`PROCESS_BASE`).
    """

    coarse_to_fine: str = "auto"
    auto_pixels: int = 4_000_000
    auto_range: int = 48
    auto_bytes: int = 2 * 2**30
    factor: int = 2
    margin: int = 4
    tile: int = 256
    overlap: int = 32
    min_valid: float = 0.25
    band: str = "segment"
    band_radius: int = 16
    segment: int = 32
    band_context: int = 16
    band_pixels: int = 250_000
    pixel_band_pixels: int = 1_000_000
    pixel_band_range: int = 96
    band_range: int | None = 48
    band_tile_cols: int = 2048
    strip_pixels: int | None = None
    strip_bytes: int | None = None
    strip_overlap: int | None = None
    max_memory: int | None = None
    held: int | None = None

    def __post_init__(self) -> None:
        if self.coarse_to_fine not in C2F_MODES:
            raise ConfigError(f"expected coarse_to_fine among {', '.join(C2F_MODES)}, got {self.coarse_to_fine!r}")
        if self.factor < 2 or self.margin < 0 or self.tile < 16 or self.overlap < 0:
            raise ConfigError(f"expected factor >= 2, margin >= 0, tile >= 16 and overlap >= 0, got factor="
                              f"{self.factor}, margin={self.margin}, tile={self.tile}, overlap={self.overlap}")
        if self.band_range is not None and self.band_range < 0:
            raise ConfigError(f"expected band_range >= 0 disparities (or None), got {self.band_range}")
        if self.auto_pixels < 0 or self.auto_range < 0 or self.auto_bytes < 0 or not 0.0 <= self.min_valid <= 1.0:
            raise ConfigError(f"expected auto_pixels >= 0, auto_range >= 0, auto_bytes >= 0 and 0 <= min_valid <= 1, "
                              f"got {self.auto_pixels}, {self.auto_range}, {self.auto_bytes}, {self.min_valid}")
        if self.band not in ("segment", "tile"):
            raise ConfigError(f"expected band 'segment' or 'tile', got {self.band!r}")
        if (self.band_radius < 0 or self.segment < 1 or self.band_context < 0 or self.band_pixels < 0
                or self.band_tile_cols < 16 or self.pixel_band_pixels < 0 or self.pixel_band_range < 0):
            raise ConfigError(f"expected band_radius >= 0, segment >= 1, band_context >= 0, band_pixels >= 0, "
                              f"band_tile_cols >= 16, pixel_band_pixels >= 0 and pixel_band_range >= 0, got "
                              f"{self.band_radius}, {self.segment}, {self.band_context}, {self.band_pixels}, "
                              f"{self.band_tile_cols}, {self.pixel_band_pixels}, {self.pixel_band_range}")
        if (self.strip_bytes is not None and self.strip_bytes <= 0
                or any(v is not None and v < 0 for v in (self.strip_pixels, self.strip_overlap))):
            raise ConfigError(f"expected strip_pixels >= 0, strip_bytes > 0 and strip_overlap >= 0 (or None for the "
                              f"matcher's), got {self.strip_pixels}, {self.strip_bytes}, {self.strip_overlap}")
        if self.max_memory is not None and self.max_memory <= 0:
            raise ConfigError(f"expected max_memory > 0 bytes (or None for the machine's), got {self.max_memory}")
        if self.held is not None and self.held < 0:
            raise ConfigError(f"expected held >= 0 bytes (or None), got {self.held}")

    @property
    def base(self) -> int:
        """Bytes held besides the match (``held``, else :data:`PROCESS_BASE`)."""
        return PROCESS_BASE if self.held is None else int(self.held)


def parse_memory(text: str | int | None) -> int | None:
    """Bytes of a memory size: an integer, or a number with K, M, G or T (powers of 1024, e.g. ``"6G"``).

    Raises
    ------
    ConfigError
        Not a positive size.
    """
    if text is None or isinstance(text, int) and not isinstance(text, bool):
        if text is not None and text <= 0:
            raise ConfigError(f"expected max_memory > 0, got {text}")
        return text
    s = str(text).strip().upper().removesuffix("B").removesuffix("I")
    mult = 1
    if s and s[-1] in "KMGT":
        mult = 1024 ** ("KMGT".index(s[-1]) + 1)
        s = s[:-1]
    try:
        value = float(s)
    except ValueError:
        value = float("nan")
    if not math.isfinite(value) or value <= 0:
        raise ConfigError(f"expected max_memory as a positive size such as 6G or 512M, got {text!r}")
    return int(value * mult)


def default_memory_budget() -> int:
    """What a match may use on this machine: 80 % of the available memory (``/proc/meminfo``'s
    MemAvailable, else the physical memory from ``os.sysconf``), bytes."""
    avail = None
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    avail = int(line.split()[1]) * 1024
                    break
    except OSError:
        avail = None
    if avail is None:
        try:
            avail = int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
        except (ValueError, OSError, AttributeError):
            avail = 8 * 2**30
    return int(0.8 * avail)


def estimate_memory(method: str, height: int, width: int, ndisp: int, *, base: bool = True) -> int:
    """Predicted peak resident memory (bytes) of one untiled match of an ``height × width`` pair over
    ``ndisp`` disparities: ``base + a·H·W + b·H·W·D`` with the matcher's measured ``(a, b)``.

    Within a factor 1.5 of the measured ``ru_maxrss`` (tested; ``benchmarks/bench_memory.py``).
    """
    a, b = _MEMORY_MODEL.get(str(method).lower(), _UNKNOWN_MODEL)
    n = float(height) * float(width)
    return int((PROCESS_BASE if base else 0) + a * n + b * n * float(ndisp))


@dataclass(frozen=True)
class _Tile:
    y0: int
    y1: int
    x0: int
    x1: int
    lo: int
    hi: int
    full: bool  # the band fell back to the whole range


def _use_c2f(p: ScaleParams, h: int, w: int, nd: int, over_budget: bool, method: str, top: bool,
             banded: bool = False, pixel_banded: bool = False) -> bool:
    """Whether :func:`match_scaled` runs this level coarse-to-fine (``ScaleParams.coarse_to_fine``;
    ``banded``: the matcher takes a band per row segment with ``band="segment"``; ``pixel_banded``: a band per
    pixel, ``pixel_band_pixels``)."""
    if p.coarse_to_fine == "off":
        return False
    small = min(h, w) < 4 * p.factor or nd < 4 * p.factor
    if p.coarse_to_fine == "on":
        return not small
    if top and h * w < p.auto_pixels and str(method).lower() in _FULL_BELOW_AUTO_PIXELS:
        return False  # a coarse level only gives the bands: it may be coarse-to-fine again
    if top and banded and p.band_range is not None and nd >= max(p.band_range, 4 * p.factor) and not small:
        return True  # a band per row segment: every pixel searches around the coarse map, not the whole range
    heavy = estimate_memory(method, h, w, nd, base=False) > p.auto_bytes
    pixels = min(p.auto_pixels, p.pixel_band_pixels) if pixel_banded and nd >= p.pixel_band_range else p.auto_pixels
    return not small and nd >= p.auto_range and (h * w >= pixels or heavy or over_budget)


def _takes_pixel_band(p: ScaleParams, matcher: Matcher) -> bool:
    """Whether ``matcher`` searches a band per pixel under ``p`` (``band="segment"`` and its
    ``supports_pixel_band``: ``sgm``'s ``compute_banded``)."""
    return p.band == "segment" and bool(getattr(matcher, "supports_pixel_band", False))


def _takes_band(p: ScaleParams, matcher: Matcher) -> bool:
    """Whether ``matcher`` searches a band per row segment under ``p`` (``band="segment"`` and its
    ``supports_band``)."""
    return p.band == "segment" and bool(getattr(matcher, "supports_band", False))


def _grid(n: int, size: int) -> list[tuple[int, int]]:
    k = max(1, int(round(n / size)))
    edges = np.linspace(0, n, k + 1).round().astype(int)
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True) if b > a]


def _downsample(img: np.ndarray, f: int) -> np.ndarray:
    h, w = img.shape[:2]
    out = cv2.resize(img, (max(1, w // f), max(1, h // f)), interpolation=cv2.INTER_AREA)
    return np.asarray(out, dtype=img.dtype)


def _crop_cols(t: _Tile, w: int, overlap: int) -> tuple[int, int]:
    """Left-image columns [a, b) matched for tile ``t`` (the right image's are ``[a - lo, b - lo)``)."""
    a = max(t.x0 - overlap - (t.hi - t.lo), t.lo)
    b = min(t.x1 + overlap, w)
    return a, b


def _pixel_band_estimate(method: str, h: int, w: int, total: int) -> int:
    """Peak bytes of one untiled match with a band per pixel, ``total`` pixel·disparities in all (the ragged
    cost volume and the two scans' path sums, uint16 each, beside the per-pixel maps)."""
    per_pixel = estimate_memory(method, h, w, 1, base=False) / max(h * w, 1)
    return int(per_pixel * h * w + 6 * total)


def _tile_estimate(method: str, t: _Tile, h: int, w: int, overlap: int) -> int:
    a, b = _crop_cols(t, w, overlap)
    rows = min(t.y1 + overlap, h) - max(t.y0 - overlap, 0)
    return estimate_memory(method, rows, max(b - a, 1), t.hi - t.lo + 1, base=False)


@dataclass(frozen=True)
class _PixelBand:
    """Full-resolution disparity band per pixel from the coarse map (:func:`_pixel_bands`)."""

    lo: np.ndarray  # (h, w) int32, inclusive
    hi: np.ndarray  # (h, w) int32, inclusive


def _window_band(cd: np.ndarray, cv: np.ndarray, r: int, min_valid: float) -> tuple[np.ndarray, np.ndarray,
                                                                                      np.ndarray]:
    """min and max of the finite coarse disparities within ``r`` coarse pixels, and where at least ``min_valid``
    of those coarse pixels passed the coarse check (and one is finite)."""
    k = 2 * r + 1
    finite = np.isfinite(cd)
    big = np.float32(1e9)
    kernel = np.ones((k, k), np.uint8)
    cmin = cv2.erode(np.where(finite, cd, big).astype(np.float32), kernel, borderType=cv2.BORDER_REPLICATE)
    cmax = cv2.dilate(np.where(finite, cd, -big).astype(np.float32), kernel, borderType=cv2.BORDER_REPLICATE)
    ok = np.asarray(cv, dtype=np.float32)
    n_ok = cv2.boxFilter(ok, -1, (k, k), normalize=False, borderType=cv2.BORDER_CONSTANT)
    n_all = cv2.boxFilter(np.ones_like(ok), -1, (k, k), normalize=False, borderType=cv2.BORDER_CONSTANT)
    trusted = (n_ok >= min_valid * n_all - 1e-3) & (cmin < big / 2) & (n_ok > 0)
    return cmin, cmax, trusted


def _pixel_bands(coarse: MatchResult, f: int, h: int, w: int, lo: int, hi: int, p: ScaleParams) -> _PixelBand:
    """Per full-resolution pixel: the coarse map's min…max (× ``f``, ± ``p.margin``, within ``[lo, hi]``) over
    the coarse pixels within ``p.band_radius`` full-resolution pixels; where fewer than ``p.min_valid`` of them
    passed the coarse left–right check, the same over a tile's region (``p.tile / 2 + p.overlap``: what one band
    per tile would search), and where that is not trusted either, the whole range."""
    cd = np.asarray(coarse.disparity, dtype=np.float32)
    cv = np.asarray(coarse.valid, dtype=bool)
    ch, cw = cd.shape
    n1, x1, t1 = _window_band(cd, cv, -(-p.band_radius // f), p.min_valid)
    n2, x2, t2 = _window_band(cd, cv, -(-(p.tile // 2 + p.overlap) // f), p.min_valid)
    cmin = np.where(t1, n1, np.where(t2, n2, np.float32(lo) / f))
    cmax = np.where(t1, x1, np.where(t2, x2, np.float32(hi) / f))
    wide = ~t1 & ~t2
    c_lo = np.clip(np.where(wide, lo, np.floor(cmin * f) - p.margin), lo, hi).astype(np.int32)
    c_hi = np.clip(np.where(wide, hi, np.ceil(cmax * f) + p.margin), lo, hi).astype(np.int32)
    rows = np.minimum(np.arange(h) // f, ch - 1)
    cols = np.minimum(np.arange(w) // f, cw - 1)
    ix = np.ix_(rows, cols)
    return _PixelBand(lo=c_lo[ix], hi=c_hi[ix])


def _segment_band(t: _Tile, pb: _PixelBand, h: int, w: int, p: ScaleParams) -> tuple[_Tile, np.ndarray | None]:
    """Tile ``t`` with its band narrowed to the union of its pixels' (the core dilated by ``p.band_context``), and
    the slice band per row segment of its crop (:func:`_crop_cols`; ``(rows, segments, 2)`` inclusive); None
    where no pixel of the crop is matched.

    The dilated core's pixels search their own band. So that the right view's winners (the left–right check)
    see every candidate they would see with one band per tile, a crop pixel left or right of it searches the
    part of its band that lands on a right pixel the dilated core's bands reach (``x - d`` within the row's
    ``[min(x - hi), max(x - lo)]`` over the dilated core); rows outside the dilated core search nothing."""
    ctx = min(p.band_context, p.overlap)  # within the crop
    ry0, ry1 = max(t.y0 - ctx, 0), min(t.y1 + ctx, h)
    rx0, rx1 = max(t.x0 - ctx, 0), min(t.x1 + ctx, w)

    def bands(c0: int, c1: int, lo: int, hi: int) -> tuple[np.ndarray, np.ndarray]:
        region = (slice(ry0, ry1), slice(c0, c1))
        return np.maximum(pb.lo[region], lo), np.minimum(pb.hi[region], hi)

    ilo, ihi = bands(rx0, rx1, t.lo, t.hi)
    t2 = dataclasses.replace(t, lo=int(ilo.min()), hi=int(ihi.max()))
    a, b = _crop_cols(t2, w, p.overlap)
    ya, yb = max(t2.y0 - p.overlap, 0), min(t2.y1 + p.overlap, h)
    if b <= a or min(rx1, b) <= max(rx0, a):
        return t2, None
    plo, phi = bands(a, b, t2.lo, t2.hi)
    xs = np.arange(a, b)[None, :]
    inner = (xs >= rx0) & (xs < rx1)
    big = np.int64(2**40)
    r_min = np.where(inner, xs - phi, big).min(axis=1, keepdims=True)
    r_max = np.where(inner, xs - plo, -big).max(axis=1, keepdims=True)
    plo = np.where(xs >= rx1, np.maximum(plo, xs - r_max), plo)
    phi = np.where(xs < rx0, np.minimum(phi, xs - r_min), phi)
    seg = p.segment
    nseg = -(-(b - a) // seg)
    clo = np.full((yb - ya, nseg * seg), big, np.int64)
    chi = np.full((yb - ya, nseg * seg), -big, np.int64)
    keep = plo <= phi
    clo[ry0 - ya:ry1 - ya, :b - a] = np.where(keep, plo - t2.lo, big)
    chi[ry0 - ya:ry1 - ya, :b - a] = np.where(keep, phi - t2.lo, -big)
    nd = min(t2.hi - t2.lo, b - a - 1)
    bounds = np.empty((yb - ya, nseg, 2), np.int64)
    bounds[:, :, 0] = clo.reshape(yb - ya, nseg, seg).min(axis=2)
    bounds[:, :, 1] = np.minimum(chi.reshape(yb - ya, nseg, seg).max(axis=2), nd)
    empty = bounds[:, :, 0] > bounds[:, :, 1]
    bounds[empty] = (1, 0)
    return t2, bounds


def _run_tiles(matcher: Matcher, left: np.ndarray, right: np.ndarray, tiles: list[_Tile], overlap: int,
               pixel_band: _PixelBand | None = None, p: ScaleParams | None = None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, dict[str, float], list[_Tile], int]:
    """Match every tile and stitch the cores; with ``pixel_band`` (and ``p``) each tile searches its band per
    row segment (:func:`_segment_band`). Returns the maps, the summed timings, the tiles as run and the
    pixel·disparities searched (the crops' with one band per tile)."""
    h, w = left.shape[:2]
    disp = np.full((h, w), np.nan, dtype=np.float32)
    raw: np.ndarray | None = None
    valid = np.zeros((h, w), dtype=bool)
    timings: dict[str, float] = {}
    ran: list[_Tile] = []
    searched = 0
    for t in tiles:
        kw: dict[str, Any] = {}
        if pixel_band is not None and p is not None:
            t, bounds = _segment_band(t, pixel_band, h, w, p)
            if bounds is None:
                continue
            kw["band"] = SegmentBand(bounds=bounds, segment=p.segment)
        ran.append(t)
        a, b = _crop_cols(t, w, overlap)
        if b <= a or t.x1 <= a:
            continue
        ya, yb = max(t.y0 - overlap, 0), min(t.y1 + overlap, h)
        searched += kw["band"].pixels(yb - ya, b - a) if kw else (yb - ya) * (b - a) * (t.hi - t.lo + 1)
        lt = np.ascontiguousarray(left[ya:yb, a:b])
        rt = np.ascontiguousarray(right[ya:yb, a - t.lo:b - t.lo])
        nd = min(t.hi - t.lo, b - a - 1)
        res = matcher.compute(lt, rt, max_disp=nd, min_disp=0, **kw)
        for k, v in res.timings.items():
            timings[k] = timings.get(k, 0.0) + float(v)
        cx0 = max(t.x0, a)
        sy, sx = slice(t.y0 - ya, t.y1 - ya), slice(cx0 - a, t.x1 - a)
        disp[t.y0:t.y1, cx0:t.x1] = res.disparity[sy, sx] + np.float32(t.lo)
        valid[t.y0:t.y1, cx0:t.x1] = res.valid[sy, sx]
        if res.disparity_raw is not None:
            if raw is None:
                raw = np.where(valid, disp, np.nan).astype(np.float32)
            raw[t.y0:t.y1, cx0:t.x1] = res.disparity_raw[sy, sx] + np.float32(t.lo)
        elif raw is not None:
            raw[t.y0:t.y1, cx0:t.x1] = np.where(res.valid[sy, sx], res.disparity[sy, sx] + np.float32(t.lo),
                                                np.nan)
    return disp, valid, raw, timings, ran, searched


def _strip_tiles(method: str, h: int, w: int, lo: int, hi: int, budget: int, overlap: int,
                 base: int = PROCESS_BASE, fewest: bool = False) -> list[_Tile]:
    """Full-range tiles (strips of rows, then columns too) whose estimate fits ``budget`` (``base``: bytes
    held besides the match); ``fewest``: the fewest full-width strips that fit, before halving."""
    avail = budget - base - int(_STITCH_PER_PIXEL * h * w)
    rows, cols = h, w
    if fewest:  # halving overshoots, and every strip matches its context rows again
        k = 1
        while -(-h // k) > max(16, overlap) and max(
                _tile_estimate(method, _Tile(y0, y1, 0, w, lo, hi, True), h, w, overlap)
                for y0, y1 in _grid(h, -(-h // k))) > avail:
            k += 1
        rows = -(-h // k)
    while True:
        tiles = [_Tile(y0, y1, x0, x1, lo, hi, True) for y0, y1 in _grid(h, rows) for x0, x1 in _grid(w, cols)]
        worst = max(_tile_estimate(method, t, h, w, overlap) for t in tiles)
        if worst <= avail:
            return tiles
        if rows > max(16, overlap):
            rows = max(rows // 2, 16)
        elif cols > max(16, overlap):
            cols = max(cols // 2, 16)
        else:
            need = base + int(_STITCH_PER_PIXEL * h * w) + worst
            raise MatchingError(f"expected a max_memory that fits one tile of the {w}×{h} pair over "
                                f"{hi - lo + 1} disparities ({need / 2**30:.2f} GiB with method {method!r}), "
                                f"got {budget / 2**30:.2f} GiB: raise max_memory or narrow the disparity range")


def _band_tiles(method: str, coarse: MatchResult, f: int, h: int, w: int, lo: int, hi: int, p: ScaleParams,
                budget: int, cols: int | None = None) -> list[_Tile]:
    """Tiles of side ``p.tile`` (``cols`` wide if given; smaller where the budget asks) with their coarse band."""
    cd = coarse.disparity
    cv = coarse.valid
    ch, cw = cd.shape
    avail = budget - p.base - int(_STITCH_PER_PIXEL * h * w)

    def band(y0: int, y1: int, x0: int, x1: int) -> _Tile:
        ry0, ry1 = max(y0 - p.overlap, 0) // f, min(-(-(y1 + p.overlap) // f), ch)
        rx0, rx1 = max(x0 - p.overlap, 0) // f, min(-(-(x1 + p.overlap) // f), cw)
        vals = cd[ry0:max(ry1, ry0 + 1), rx0:max(rx1, rx0 + 1)]
        ok = np.isfinite(vals)
        frac = float(cv[ry0:max(ry1, ry0 + 1), rx0:max(rx1, rx0 + 1)].mean()) if vals.size else 0.0
        if not ok.any() or frac < p.min_valid:
            return _Tile(y0, y1, x0, x1, lo, hi, True)
        t_lo = max(lo, int(math.floor(float(vals[ok].min()) * f)) - p.margin)
        t_hi = min(hi, int(math.ceil(float(vals[ok].max()) * f)) + p.margin)
        return _Tile(y0, y1, x0, x1, min(t_lo, t_hi), t_hi, False)

    out: list[_Tile] = []
    stack = [(y0, y1, x0, x1) for y0, y1 in _grid(h, p.tile) for x0, x1 in _grid(w, cols or p.tile)]
    while stack:
        y0, y1, x0, x1 = stack.pop()
        t = band(y0, y1, x0, x1)
        if _tile_estimate(method, t, h, w, p.overlap) <= avail:
            out.append(t)
        elif y1 - y0 > 16:
            m = (y0 + y1) // 2
            stack += [(y0, m, x0, x1), (m, y1, x0, x1)]
        elif x1 - x0 > 16:
            m = (x0 + x1) // 2
            stack += [(y0, y1, x0, m), (y0, y1, m, x1)]
        else:
            need = p.base + int(_STITCH_PER_PIXEL * h * w) + _tile_estimate(method, t, h, w, p.overlap)
            raise MatchingError(f"expected a max_memory that fits one {x1 - x0}×{y1 - y0} tile over "
                                f"{t.hi - t.lo + 1} disparities ({need / 2**30:.2f} GiB with method {method!r}), "
                                f"got {budget / 2**30:.2f} GiB: raise max_memory")
    return out


def _own_strips(p: ScaleParams, method: str, h: int, w: int, nd: int) -> tuple[int, int] | None:
    """(bytes per strip, context rows) where ``auto`` runs the matcher in its own strips
    (:data:`_OWN_STRIPS`), else None."""
    own = _OWN_STRIPS.get(str(method).lower())
    if own is None or p.coarse_to_fine != "auto":
        return None
    pixels = own[0] if p.strip_pixels is None else int(p.strip_pixels)
    cap = own[1] if p.strip_bytes is None else int(p.strip_bytes)
    ctx = own[2] if p.strip_overlap is None else int(p.strip_overlap)
    return (cap, ctx) if h * w >= pixels and estimate_memory(method, h, w, nd, base=False) > cap else None


def _untiled_strips(method: str, p: ScaleParams, h: int, w: int, lo: int, hi: int, budget: int
                    ) -> tuple[list[_Tile], int] | None:
    """Full-range strips of a match that does not run coarse-to-fine, and their context rows: the matcher's own
    (:func:`_own_strips`, within ``budget`` too), or the budget's; None: it runs untiled."""
    own = _own_strips(p, method, h, w, hi - lo + 1)
    if own is not None:
        cap, ctx = own
        strips = min(budget, p.base + int(_STITCH_PER_PIXEL * h * w) + cap)
        return _strip_tiles(method, h, w, lo, hi, strips, ctx, p.base, fewest=True), ctx
    if p.base + estimate_memory(method, h, w, hi - lo + 1, base=False) <= budget:
        return None
    return _strip_tiles(method, h, w, lo, hi, budget, p.overlap, p.base), p.overlap


def _coarse_range(lo: int, hi: int, f: int, cw: int) -> tuple[int, int]:
    chi = min(-(-hi // f), cw - 1)
    return min(lo // f, chi), chi


def _sub_params(p: ScaleParams) -> ScaleParams:
    """The parameters of a coarse level (``on`` forces the first level only)."""
    return dataclasses.replace(p, coarse_to_fine="auto" if p.coarse_to_fine == "on" else p.coarse_to_fine)


def planned_memory(method: str, height: int, width: int, *, max_disp: int, min_disp: int = 0,
                   scale: ScaleParams | None = None, _level: int = 0) -> int:
    """Peak resident memory (bytes) of :func:`match_scaled` on an ``height × width`` pair, from the sizes alone:
    the process's ``scale.base`` plus the largest of the untiled match (when it runs untiled), the coarse
    levels (each planned the same way), and the stitched maps with the largest tile. A tile's band is not
    known before the coarse match; the plan takes the whole range (a tile whose coarse map is unreliable
    searches it), at most what the budget leaves (larger tiles are split).

    Raises
    ------
    MatchingError
        No tile fits the budget (as :func:`match_scaled` would).
    """
    p = scale or ScaleParams()
    budget = p.max_memory if p.max_memory is not None else default_memory_budget()
    lo, hi = int(min_disp), int(max_disp)
    nd = hi - lo + 1
    h, w = int(height), int(width)
    est_full = p.base + estimate_memory(method, h, w, nd, base=False)
    planned = get_matcher(method)
    if not _use_c2f(p, h, w, nd, est_full > budget, method, _level == 0, _takes_band(p, planned),
                    _takes_pixel_band(p, planned)):
        strips = _untiled_strips(method, p, h, w, lo, hi, budget)
        if strips is None:
            return est_full
        tiles, ctx = strips
        return p.base + int(_STITCH_PER_PIXEL * h * w) + max(_tile_estimate(method, t, h, w, ctx) for t in tiles)
    f = p.factor
    ch, cw = max(1, h // f), max(1, w // f)
    clo, chi = _coarse_range(lo, hi, f, cw)
    coarse = planned_memory(method, ch, cw, max_disp=chi, min_disp=clo, scale=_sub_params(p), _level=_level + 1)
    stitch = p.base + int(_STITCH_PER_PIXEL * h * w)
    avail = budget - stitch
    ty, tx = (max(b - a for a, b in _grid(n, p.tile)) for n in (h, w))  # the grid's largest tile

    def tile_bytes(ty: int, tx: int) -> int:  # an inner tile over the whole range, with its context
        rows, cols = min(ty + 2 * p.overlap, h), min(tx + 2 * p.overlap + nd - 1, w)
        return estimate_memory(method, rows, cols, nd, base=False)

    while tile_bytes(ty, tx) > avail:  # split as _band_tiles would, down to 16 px; refused below that
        if ty > 16:
            ty = max(ty // 2, 1)
        elif tx > 16:
            tx = max(tx // 2, 1)
        else:
            need = stitch + tile_bytes(ty, tx)
            raise MatchingError(f"expected a max_memory that fits one {tx}×{ty} tile over {nd} disparities "
                                f"({need / 2**30:.2f} GiB with method {method!r}), got {budget / 2**30:.2f} GiB: "
                                "raise max_memory")
    worst = tile_bytes(ty, tx)
    if _takes_pixel_band(p, planned):
        # a band per pixel runs untiled where it fits the budget (the tiles otherwise); its bands are known only
        # after the coarse match: at most the whole range at every pixel
        return max(coarse, stitch + worst, min(budget, p.base + _pixel_band_estimate(method, h, w, h * w * nd)))
    return max(coarse, stitch + worst)


def match_scaled(left: np.ndarray, right: np.ndarray, *, max_disp: int, min_disp: int = 0, method: str,
                 params: dict[str, Any] | None = None, scale: ScaleParams | None = None,
                 _level: int = 0) -> MatchResult:
    """Match a validated pair coarse-to-fine and within a memory budget (module doc).

    Parameters
    ----------
    left, right : ndarray, (H, W) or (H, W, 3)
        Validated rectified pair (:func:`~prismstereo.matching.api.validate_pair`).
    max_disp, min_disp : int, keyword-only
        Inclusive search range (validated).
    method : str, keyword-only
        A registered matcher; ``params`` its tuning parameters.
    scale : ScaleParams, keyword-only
        Coarse-to-fine mode and tiling; default ``ScaleParams()``.

    Returns
    -------
    MatchResult
        As the matcher's, with ``extras["scale"]``: whether coarse-to-fine ran (``coarse_to_fine``), the
        levels, tiles, mean band (of the tiles as run), tiles that fell back to the whole range, the memory
        estimate and budget (bytes), ``band`` (``segment`` or ``tile``, as run) and ``searched_per_pixel``
        (pixel·disparities the full resolution's tiles searched, over its pixels) and ``overlap`` (the context
        rows / columns of its tiles, a strip's own for a matcher with its own strips). The matcher's own extras
        are kept only for an untiled run. ``timings`` adds ``coarse`` (seconds of the coarse levels) to the
        matcher's stages summed over the tiles.

    Raises
    ------
    MatchingError
        No tile fits ``scale.max_memory``.
    """
    p = scale or ScaleParams()
    prm = dict(params or {})
    matcher = get_matcher(method, **prm)
    budget = p.max_memory if p.max_memory is not None else default_memory_budget()
    h, w = left.shape[:2]
    lo, hi = int(min_disp), int(max_disp)
    nd = hi - lo + 1
    est_full = p.base + estimate_memory(method, h, w, nd, base=False)
    banded = _takes_band(p, matcher)
    c2f = _use_c2f(p, h, w, nd, est_full > budget, method, _level == 0, banded, _takes_pixel_band(p, matcher))
    if banded and _level > 0 and not c2f and p.coarse_to_fine != "off" and h * w >= p.band_pixels:
        # a coarse level of a banded matcher: its own bands cost less than its full search
        c2f = _use_c2f(dataclasses.replace(p, coarse_to_fine="on"), h, w, nd, False, method, False) \
            and nd >= p.auto_range
    info: dict[str, Any] = {"coarse_to_fine": c2f, "mode": p.coarse_to_fine, "levels": _level + 1,
                            "estimate_bytes": est_full, "budget_bytes": int(budget), "tiles": 1,
                            "band_mean": float(nd), "full_range_tiles": 0}
    overlap = p.overlap
    if not c2f:
        strips = _untiled_strips(method, p, h, w, lo, hi, budget)
        if strips is None:
            if _level == 0:
                log.info("match %s %d×%d, %d disparities: peak memory estimate %.2f GiB (budget %.2f GiB)",
                         method, w, h, nd, est_full / 2**30, budget / 2**30)
            res = matcher.compute(left, right, max_disp=hi, min_disp=lo)
            return dataclasses.replace(res, extras={**res.extras, "scale": info})
        tiles, overlap = strips
        pixel_band: _PixelBand | None = None
        coarse_s = 0.0
        coarse_est = 0
    else:
        f = p.factor
        pixel_band = None
        t0 = time.perf_counter()
        cl, cr = _downsample(left, f), _downsample(right, f)
        clo, chi = _coarse_range(lo, hi, f, cl.shape[1])
        # the band is read from the coarse level's dense map: its holes filled even where the full resolution's
        # are not (the depth pipeline skips that filling when it reads only the cross-checked matches)
        coarse_prm = {**prm, "fill": True} if prm.get("fill") is False else prm
        coarse = match_scaled(cl, cr, max_disp=chi, min_disp=clo, method=method, params=coarse_prm,
                              scale=_sub_params(p), _level=_level + 1)
        coarse_s = time.perf_counter() - t0
        info["levels"] = int(coarse.extras.get("scale", {}).get("levels", _level + 2))
        # the coarse levels ran first, in the same process: the run's peak is the larger of theirs and the tiles'
        coarse_est = int(coarse.extras.get("scale", {}).get("estimate_bytes", 0))
        if _takes_pixel_band(p, matcher):
            # every pixel its own band (tSGM): one untiled match that costs pixels × band, where it fits
            pb = _pixel_bands(coarse, f, h, w, lo, hi, p)
            widths = (pb.hi.astype(np.int64) - pb.lo + 1)
            total = int(widths.sum())
            est = max(coarse_est, p.base + _pixel_band_estimate(method, h, w, total))
            if est <= budget:
                del coarse
                if _level == 0:
                    log.info("match %s %d×%d, %d disparities: coarse-to-fine, a band per pixel (mean %.1f), "
                             "peak memory estimate %.2f GiB (budget %.2f GiB; untiled full search %.2f GiB)", method,
                             w, h, nd, total / max(h * w, 1), est / 2**30, budget / 2**30, est_full / 2**30)
                res = matcher.compute_banded(left, right, max_disp=hi, min_disp=lo,  # type: ignore[attr-defined]
                                             band_lo=pb.lo, band_hi=pb.hi)
                info.update({"estimate_bytes": est, "band_mean": round(total / max(h * w, 1), 2), "band": "pixel",
                             "full_range_pixels": round(float((widths == nd).mean()), 4),
                             "searched_per_pixel": round(total / max(h * w, 1), 2), "overlap": 0})
                return MatchResult(disparity=res.disparity, valid=res.valid, disparity_raw=res.disparity_raw,
                                   timings={**res.timings, "coarse": coarse_s}, extras={"scale": info})
        # a banded matcher's tiles are wide: their weights and costs are computed once per row, not per tile
        tiles = _band_tiles(method, coarse, f, h, w, lo, hi, p, budget, p.band_tile_cols if banded else None)
        if banded:
            pixel_band = _pixel_bands(coarse, f, h, w, lo, hi, p)
        del coarse
    est = max(coarse_est, p.base + int(_STITCH_PER_PIXEL * h * w) + max(_tile_estimate(method, t, h, w, overlap)
                                                                        for t in tiles))
    if _level == 0:
        log.info("match %s %d×%d, %d disparities: %s, %d tiles, peak memory estimate %.2f GiB (budget %.2f "
                 "GiB; untiled full search %.2f GiB)", method, w, h, nd,
                 "coarse-to-fine" if c2f else "strips", len(tiles), est / 2**30, budget / 2**30, est_full / 2**30)
    disp, valid, raw, timings, tiles, searched = _run_tiles(matcher, left, right, tiles, overlap, pixel_band, p)
    timings["coarse"] = coarse_s
    areas = np.array([(t.y1 - t.y0) * (t.x1 - t.x0) for t in tiles], dtype=np.float64)
    bands = np.array([t.hi - t.lo + 1 for t in tiles], dtype=np.float64)
    info.update({"tiles": len(tiles), "estimate_bytes": est,
                 "band_mean": round(float((areas * bands).sum() / areas.sum()), 2),
                 "full_range_tiles": int(sum(t.full for t in tiles)) if c2f else 0,
                 "band": p.band if pixel_band is not None else "tile",
                 "searched_per_pixel": round(searched / max(h * w, 1), 2), "overlap": overlap})
    return MatchResult(disparity=disp, valid=valid, disparity_raw=raw, timings=timings, extras={"scale": info})
