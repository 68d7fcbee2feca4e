"""A depth run's peak memory, known before its capture is read (issue 30).

A pair run holds, through its frame, the process (interpreter, libraries, the matcher's compiled code), the
rig's set-up (rectification maps, valid masks, the exact-ray table), the capture and its rectified pair; on
top of that comes, one after the other, the match (:func:`~prismstereo.matching.scale.planned_memory`: untiled,
or coarse-to-fine / in strips under the budget) and the steps after it (sub-pixel refinement, triangulation,
the result's maps and point cloud, the written outputs). :func:`estimate_depth_memory` adds these up from the
rectified size and the disparity range: those of the rig's cached set-up when it is cached
(:mod:`~prismstereo.depth.setup_cache`, read without loading its tables), else bounds from the camera (a
rectified view no larger than the sensor, every disparity up to its width).

The budget (``DepthConfig.max_memory``, default :func:`~prismstereo.matching.scale.default_memory_budget`)
is the whole run's: the match gets what the process does not already hold when it starts (measured then,
``ScaleParams.held``), and :func:`check_depth_memory` refuses a run whose part outside the match cannot fit,
in one line, before any image is read.

The bytes per pixel below were measured with ``benchmarks/bench_memory.py`` (each step's own high-water mark,
``VmHWM`` after ``/proc/self/clear_refs``) at 0.8, 3 and 12 megapixels (docs/EXPERIMENTS.md, issue 30,
branch h-mem).
"""

from __future__ import annotations

import logging
import resource
import zipfile
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from prismstereo.config import Rig
from prismstereo.depth.setup_cache import cache_folder, setup_key
from prismstereo.errors import ConfigError, MatchingError
from prismstereo.matching.scale import PROCESS_BASE, ScaleParams, default_memory_budget, planned_memory

if TYPE_CHECKING:
    from prismstereo.depth.pipeline import DepthConfig

log = logging.getLogger(__name__)

__all__ = ["DepthMemory", "check_depth_memory", "estimate_depth_memory", "resident_bytes"]

#: held per rectified pixel through a frame: the remap tables of both views (2 × 8 B), valid masks, the
#: rig-only common view, the rectified pair (2 × 3 B), the match's maps in the pipeline (raw, dense, ...)
_HELD_PER_PIXEL = 60.0
#: the exact-ray table (:class:`~prismstereo.depth.triangulation.RayTable`, 96 B) read for exact triangulation
_RAYS_PER_PIXEL = 96.0
#: held per capture pixel: the decoded capture (3 B) and its coercion
_HELD_PER_CAPTURE_PIXEL = 6.0
#: the largest transient after the match, per rectified pixel: refinement (float32 images, gradients,
#: windows), triangulation (indices, float64 points), the result's (h, w, 3) float64 points
_AFTER_PER_PIXEL = 160.0
#: the process beyond :data:`~prismstereo.matching.scale.PROCESS_BASE` per matcher (its compiled kernels,
#: allocator pools)
_MATCHER_CODE = {"coop": 500 * 2**20, "bpasw": 60 * 2**20}


@dataclass(frozen=True, kw_only=True)
class DepthMemory:
    """Planned peak resident memory of a pair run (bytes; module doc).

    Attributes
    ----------
    shape : (h, w)
        Rectified view the plan is for.
    ndisp : int
        Disparities searched.
    source : str
        ``"set-up cache"`` (the rig's rectified size and range) or ``"camera bounds"``.
    held : int
        The process, the set-up and the frame's arrays, held through the frame.
    match : int
        The match's peak above ``held``.
    after : int
        The steps after the match, above ``held``.
    budget : int
        The run's budget.
    """

    shape: tuple[int, int]
    ndisp: int
    source: str
    held: int
    match: int
    after: int
    budget: int

    def __post_init__(self) -> None:
        if min(self.held, self.match, self.after, self.budget, self.ndisp) < 0:
            raise ConfigError(f"expected non-negative memory figures, got {self}")

    @property
    def peak(self) -> int:
        """The run's planned peak: what it holds plus the larger of the match and the steps after it."""
        return self.held + max(self.match, self.after)

    def describe(self) -> str:
        g = 2**30
        return (f"peak memory estimate {self.peak / g:.2f} GiB (budget {self.budget / g:.2f} GiB): held "
                f"{self.held / g:.2f}, match +{self.match / g:.2f}, refine/triangulate +{self.after / g:.2f}; "
                f"rectified {self.shape[1]}×{self.shape[0]}, {self.ndisp} disparities ({self.source})")


def resident_bytes() -> int:
    """The process's resident memory now (``/proc/self/statm``), or :data:`PROCESS_BASE` where unknown."""
    try:
        with open("/proc/self/statm", encoding="ascii") as fh:
            pages = int(fh.read().split()[1])
        return pages * resource.getpagesize()
    except (OSError, ValueError, IndexError):
        return PROCESS_BASE


def _cached_size(rig: Rig, faces: tuple[int, int], calibration: str
                 ) -> tuple[tuple[int, int], tuple[int, int] | None] | None:
    """Rectified (h, w) and rig-only disparity range of a cached set-up, read without its tables."""
    folder = cache_folder()
    if folder is None:
        return None
    key = setup_key(rig, faces, calibration)
    try:
        with np.load(folder / f"setup-{key}.npz", allow_pickle=False) as z:  # reads only the members asked for
            w, h = (int(v) for v in z["size"])
        disp: tuple[int, int] | None = None
        rpath = folder / f"range-{key}.npz"
        if rpath.is_file():
            with np.load(rpath, allow_pickle=False) as z:
                lim = np.asarray(z["range_limits"], dtype=np.float64)
            disp = (int(lim[2]), int(lim[3]))
    except (OSError, ValueError, KeyError, TypeError, IndexError, EOFError, zipfile.BadZipFile):
        return None
    return (h, w), disp


def estimate_depth_memory(rig: Rig, config: DepthConfig, *, shape: tuple[int, int] | None = None,
                          disparity_range: tuple[int, int] | None = None) -> DepthMemory:
    """The planned peak of a pair run of ``config`` (a resolved :class:`~prismstereo.depth.pipeline.
    DepthConfig`) on ``rig`` (module doc).

    Parameters
    ----------
    shape, disparity_range : optional
        The rectified view (h, w) and the disparities (min, max) to plan for; by default the rig's cached
        set-up's, else the camera bounds.

    Raises
    ------
    MatchingError
        With ``shape`` and ``disparity_range`` given: the match cannot fit the budget even tiled
        (:func:`~prismstereo.matching.scale.planned_memory`).
    """
    cfg = config
    method = str(cfg.method).lower()
    views = cfg.views
    source = "given"
    if shape is None or disparity_range is None:
        found = _cached_size(rig, views, str(cfg.calibration)) if isinstance(views, tuple) else None
        if found is not None:
            shape = shape or found[0]
            disparity_range = disparity_range or found[1]
            source = "set-up cache"
        else:
            source = "camera bounds"
    h, w = shape if shape is not None else (rig.camera.height + 1, rig.camera.width)
    lo, hi = disparity_range if disparity_range is not None else (0, w - 1)
    hi = min(int(hi), w - 1)
    lo = min(int(lo), hi)
    n = float(h) * float(w)
    m = float(rig.camera.height) * float(rig.camera.width)
    per_pixel = _HELD_PER_PIXEL + (_RAYS_PER_PIXEL if cfg.triangulation == "exact" else 0.0)
    held = int(PROCESS_BASE + _MATCHER_CODE.get(method, 0) + per_pixel * n + _HELD_PER_CAPTURE_PIXEL * m)
    max_memory = cfg.max_memory
    budget = int(max_memory) if max_memory is not None else default_memory_budget()
    scale = ScaleParams(coarse_to_fine=str(cfg.coarse_to_fine), max_memory=budget, held=held)
    # the match runs on the region's bounding box, at most the rectified view
    try:
        match_peak = planned_memory(method, h, w, max_disp=hi, min_disp=lo, scale=scale)
    except MatchingError:
        if source == "given":
            raise
        # over a bound of the range (before the capture narrows it) not even one tile fits: the match will be
        # tiled to the budget, or refused once its range is known
        match_peak = budget
    after = int(_AFTER_PER_PIXEL * n)
    return DepthMemory(shape=(int(h), int(w)), ndisp=hi - lo + 1, source=source, held=held,
                       match=max(0, match_peak - held), after=after, budget=budget)


def check_depth_memory(rig: Rig, config: DepthConfig) -> DepthMemory:
    """Plan a pair run's memory before its capture is read, log it, and refuse in one line a run whose part
    outside the match cannot fit the budget (the match itself is tiled to fit what is left).

    Raises
    ------
    ConfigError
        The set-up, the frame's arrays and the steps after the match exceed ``max_memory``.
    """
    plan = estimate_depth_memory(rig, config)
    log.info("depth: %s", plan.describe())
    outside = plan.held + plan.after
    if outside > plan.budget:
        raise ConfigError(f"expected a max_memory of at least {outside / 2**30:.2f} GiB for a "
                          f"{plan.shape[1]}×{plan.shape[0]} rectified view (its set-up, maps and refinement, "
                          f"without the match), got {plan.budget / 2**30:.2f} GiB: raise max_memory or use a "
                          "region of interest")
    return plan
