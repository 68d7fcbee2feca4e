"""The depth pipeline: capture → virtual cameras → rectify → match → refine → triangulate, as ordered steps.

``run_depth(rig, image, config=DepthConfig(...))`` returns one :class:`DepthRun` for a pair of faces
or for every face of an N-face prism (``views="all"``). Each step is a plain function that takes typed
values and returns a small frozen dataclass, in this order:

pair of faces
    :func:`validate_inputs` → :func:`virtual_cameras` → :func:`rectify_geometry` → :func:`epipolar_curves` →
    (the capture warped, :func:`search_region`) → :func:`match_pair` → :func:`refine_matches` →
    :func:`remove_speckles` → :func:`triangulate_disparity` → :func:`diagnose`
all faces (N ≥ 3)
    :func:`validate_inputs` → :func:`search_region_all_views` → :func:`sweep_all_views` → :func:`diagnose`

The per-rig part of a pair run (cameras, rectification, epipolar curves, the exact-ray table of exact
triangulation, search region) is a :class:`DepthSetup` (:func:`prepare_depth`) that a sequence computes once
and shares between frames (:func:`run_depth_frame`); all but the search region are kept in the on-disk set-up
cache (:mod:`prismstereo.depth.setup_cache`), so a new process reads them instead of computing them.

Everything the user can get wrong (image size, views, depth range, region of interest, method) is checked
in :func:`validate_inputs` before any heavy work. The files of a run are written by
:func:`prismstereo.depth.outputs.write_depth_outputs`; its accuracy against ground truth is
:func:`prismstereo.evaluation.depth_metrics.evaluate_depth`.

The depth map of a pair run is the world Z (mm, real camera frame) of the point triangulated at each pixel
of the RECTIFIED LEFT view; that of an all-view run is on the REAL capture's grid (the reference face's
pixels). The point cloud holds the same points (valid ones only) in the world frame.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import numbers
import time
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from prismstereo import __version__
from prismstereo.cameras import VirtualView, calibrate_rig
from prismstereo.checks import check_fields, fail
from prismstereo.config import DEFAULT_DEPTH_RANGE_MM, Rig
from prismstereo.depth.apex_band import apex_band_info, apex_band_views
from prismstereo.depth.confidence import confident_fill, confident_growth, confident_matches, plane_interpolation
from prismstereo.depth.confidence import remove_speckles as drop_small_patches
from prismstereo.depth.memory import check_depth_memory, estimate_depth_memory, resident_bytes
from prismstereo.depth.search_range import (
    Coverage,
    RigRange,
    SearchRange,
    auto_search_range,
    auto_search_range_of_capture,
    depth_warnings,
    rig_range,
    scene_coverage,
)
from prismstereo.depth.setup_cache import (
    load_range,
    load_rays,
    load_setup,
    load_view,
    save_range,
    save_rays,
    save_setup,
    save_view,
)
from prismstereo.depth.smoothed import smoothed_config
from prismstereo.depth.triangulation import TRIANGULATIONS, RayTable, points_on_grid, ray_table, triangulate_matches
from prismstereo.errors import ConfigError, GeometryError, ImageError
from prismstereo.io.images import as_image
from prismstereo.io.jsonio import library_versions
from prismstereo.matching import available_matchers, match
from prismstereo.matching.registry import resolved_params
from prismstereo.matching.scale import ScaleParams
from prismstereo.matching.temporal import PriorBand
from prismstereo.multiview.prism import SweepParams, depth_all_views
from prismstereo.progress import progress_bar
from prismstereo.rectify import RectifiedPair, common_view, rectify_pair
from prismstereo.rectify.epipolar import EpipolarTable, epipolar_table

log = logging.getLogger(__name__)

__all__ = [
    "DEFAULT_DEPTH_RANGE_MM",
    "TRIANGULATIONS",
    "DepthConfig",
    "DepthRun",
    "DepthSetup",
    "Disparities",
    "Points",
    "SearchRegion",
    "coverage_of",
    "default_views",
    "diagnose",
    "epipolar_curves",
    "match_pair",
    "needs_dense_map",
    "prepare_depth",
    "rectify_capture",
    "rectify_geometry",
    "refine_matches",
    "remove_speckles",
    "run_depth",
    "run_depth_frame",
    "search_region",
    "search_region_all_views",
    "sweep_all_views",
    "triangulate_disparity",
    "validate_config",
    "validate_image",
    "validate_inputs",
    "virtual_cameras",
]


#: matchers whose map has no left–right check of its own (every value is a match): the sub-pixel check seeds the
#: right view with their values only where their own window confirms them (``seeds_checked`` of
#: :func:`~prismstereo.depth.confidence.confident_matches`)
UNCHECKED_MATCHERS = frozenset({"coop"})


@dataclass(frozen=True, kw_only=True)
class DepthConfig:
    """Configuration of one depth run (all of it, resolved, goes into ``run.json``).

    Attributes
    ----------
    method : str
        Matcher name (any of :func:`prismstereo.matching.available_matchers`).
    matcher_params : dict
        Keyword tuning parameters of the matcher; after :func:`validate_inputs`, every parameter of the
        matcher with its default (:func:`prismstereo.matching.registry.resolved_params`).
    depth_range : (min, max) or None
        World depths to search, mm; the disparity search range follows from it (clipped to what the
        common view of the two sub-images allows). None: derived from the rig and the images
        (:func:`prismstereo.depth.search_range.auto_search_range`).
    roi : (x, y, w, h) or None
        Region of interest in the rectified left image, pixels; None = the whole view.
    views : (i, j), "all" or None
        Faces to pair; ``"all"``: every face of an N ≥ 3 prism (plane sweep in a reference view,
        :func:`prismstereo.multiview.prism.depth_all_views`; a bi-prism's "all" is its pair); None = the
        default pair (:func:`default_views`).
    triangulation : str
        ``exact`` (default; exact refractive rays), ``midpoint`` (virtual pinhole rays, thesis Eq. 7.19),
        ``dlt`` (linear, virtual pinholes' P) or ``q`` (rectified Q reprojection, thesis Eq. 7.23).
    calibration : str
        Virtual camera model used for rectification and the pinhole triangulations: ``fit`` or ``thesis``.
    use_filled : bool
        Triangulate the hole-filled disparity too (dense but with guessed values). False (default) keeps
        only the matches that passed the matcher's left–right check.
    max_gap_mm : float or None
        Reject points whose two rays pass farther apart than this (exact / midpoint), mm. None = keep all.
    refine : bool
        Refine the matcher's disparities to sub-pixel precision (:func:`~prismstereo.depth.refine.
        refine_disparity`) before triangulating.
    refine_radius : int
        Half-size of the refinement window, px.
    min_confidence : float or None
        Keep only matches whose confidence (:func:`~prismstereo.depth.confidence.confident_matches`: ZNCC
        of the refined windows, 0 where the refinement could not confirm the match) is at least this.
        None keeps every match; the confidence of each point is in the outputs either way.
    speckle_fraction : float or None
        Remove connected patches of disparity (neighbours within 1 px) smaller than this fraction of the
        matched region (at least 20 px): isolated wrong matches (OpenCV ``filterSpeckles``). None keeps them.
    refine_iterations, refine_max_shift, refine_min_texture : int, float, float
        The refinement's Gauss–Newton iterations, largest move from the matcher's value (px) and least
        window texture (:func:`~prismstereo.depth.refine.refine_disparity`).
    refine_max_lr_gap : float or None
        Sub-pixel left–right check of the refined matches: confidence 0 where the refined disparity and
        the right view's refined disparity differ by more than this, px
        (:func:`~prismstereo.depth.confidence.confident_matches`); None: no check.
    refine_prefilter : float or None
        Standard deviation (px) of a Gaussian low-pass along the rows of both rectified views before the
        refinement (not the matching): it damps the fine texture whose sub-pixel-phase-dependent damping
        by the linear interpolation biases the refined disparities; None: none.
    refine_fill : bool
        Where no cross-checked match was kept, try again from the matcher's dense (hole-filled, smoothed)
        map and keep what the refinement, its sub-pixel left–right check and ``min_confidence`` confirm
        (:func:`~prismstereo.depth.confidence.confident_fill`): on weak texture the integer cross-check
        and the refinement from the raw values drop whole regions the matcher had right. Needs ``refine``
        and ``refine_max_lr_gap`` (without the check nothing tests the filled values: not used). Off by
        default: the points it adds are right but less precise (docs/EXPERIMENTS.md, issue 26); the
        default fills with ``refine_fill_agree`` instead. On, it keeps every confirmed filled value
        (``refine_fill_agree`` is not applied).
    refine_fill_agree : float or None
        Where no cross-checked match was kept, try again from the matcher's dense map and keep a value only
        where the ``refine_radius`` and the ``refine_retry_radius`` windows each confirm it and their
        refined disparities differ by less than this, px (``agree`` of
        :func:`~prismstereo.depth.confidence.confident_fill`). Needs ``refine``, ``refine_max_lr_gap`` and
        a ``refine_retry_radius`` other than ``refine_radius`` (otherwise not used); None: no such fill.
    refine_retry_radius : int or None
        Half-size of a second refinement window for the matches whose ``refine_radius`` window did not
        reach a confidence of ``refine_retry_below`` or was dropped (``retry_radius`` of
        :func:`~prismstereo.depth.confidence.confident_matches`): weak texture needs more pixels for a
        precise sub-pixel value, and the wider window's result replaces the first where the refinement and
        the sub-pixel left–right check confirm it; None: one window.
    refine_retry_below : float
        See ``refine_retry_radius``.
    refine_third_radius : int or None
        Half-size of a third refinement window for the kept matches whose confidence after the first two
        stayed below ``refine_third_below``: its result replaces theirs where the refinement, the sub-pixel
        left–right check and ``min_confidence`` confirm it with a higher ZNCC than theirs; it drops none.
        None (default): no third window; the smoothed-capture profile sets it
        (``refine_smoothed_third_radius``).
    refine_third_below : float
        See ``refine_third_radius``.
    refine_retry_drop : bool
        A match whose ``refine_radius`` window stayed below ``refine_retry_below`` and whose wider window
        is not confirmed gets confidence 0 (``min_confidence`` drops it) instead of keeping the small
        window's result (``retry_drop`` of :func:`~prismstereo.depth.confidence.confident_matches`).
    refine_grow_radius : int or None
        Where neither the matches nor the fill kept a value, refine the matcher's dense value once more with
        a window of this half-size and keep it where it lies within ``refine_grow_agree`` px of what the kept
        values around it say (``refine_grow_fit``; Gaussian weights of standard deviation
        ``refine_grow_sigma`` px), and those are alike (weighted spread below ``refine_grow_spread`` px)
        (:func:`~prismstereo.depth.confidence.confident_growth`): on texture too weak for the two
        windows. Needs ``refine`` and ``refine_max_lr_gap``; None: no such step.
    refine_grow_agree, refine_grow_sigma, refine_grow_spread : float, float, float or None
        See ``refine_grow_radius`` (``refine_grow_spread`` None: any spread).
    refine_grow_passes : int
        How many times to grow, each from the values kept before it.
    refine_grow_fit : {"mean", "plane"}
        What the kept values around a pixel say of it: their weighted mean, or the weighted plane through
        those within ``refine_grow_inlier`` px of the refined value, which must weigh ``refine_grow_share``
        of all (``fit`` of :func:`~prismstereo.depth.confidence.confident_growth`): a slanted surface's
        values spread about their mean by its gradient, and near a depth edge the other surface's values
        are not the pixel's.
    refine_grow_inlier, refine_grow_share : float, float
        See ``refine_grow_fit`` (``refine_grow_fit="mean"`` with ``refine_grow_agree`` 0.3 and
        ``refine_grow_spread`` 0.5 is the growth of stop 34).
    refine_grow_agree_depth : float or None
        With ``refine_grow_fit="plane"``, the plane may also lie this share of the pixel's depth from the
        refined value where that is more than ``refine_grow_agree`` px (``agree_depth`` of
        :func:`~prismstereo.depth.confidence.confident_growth`): one tolerance in depth for rigs whose pixel
        of disparity is a different share of depth. The default, 0.22 %, is ``refine_grow_agree`` (0.2 px)
        at the bi-prism's disparity of a scene at 1.4 m (91 px); None: px only.
    refine_grow_second_radius : int or None
        With ``refine_grow_fit="plane"``, where the ``refine_grow_radius`` window does not confirm a value,
        a window of this half-size is tried under the same tests (``second_radius`` of
        :func:`~prismstereo.depth.confidence.confident_growth`): near occlusions and depth edges the wide
        window reaches the other surface, and the plane test bounds the small one's noise on weak texture.
        None: one window.
    refine_grow_min_confidence : float or None
        With ``refine_grow_fit="plane"``, the growth's windows are confirmed from this ZNCC on where it is
        below ``min_confidence`` (the refinement within ``refine_max_shift`` and the sub-pixel check still asked):
        on the weakest texture (a far floor, leaves) a 33×33 window refines to the right value at a ZNCC the
        sensor noise keeps below 0.5, and the plane test is what bounds a grown value. None:
        ``min_confidence``.
    refine_grow_cut : float or None
        With ``refine_grow_fit="plane"``, where no whole window confirms a value beside a depth edge or an
        occlusion, the wide growth window is tried once more cut to the pixels of the value's own surface: the
        left ones whose kept (else dense) value lies within this many px of it and that the right view sees,
        the right ones whose value does (``cut`` of :func:`~prismstereo.depth.confidence.confident_growth`):
        a whole window beside an occluder holds the band the right view does not see and the occluder itself.
        None: whole windows only.
    refine_grow_gap : float or None
        With ``refine_grow_fit="plane"``, the kept neighbours farther than this many px from the value's plane
        are another surface, and ``refine_grow_share`` is asked of the others only (``gap`` of
        :func:`~prismstereo.depth.confidence.confident_growth`): beside an occluder the occluder's kept values
        are not evidence against the background's plane; those between ``refine_grow_inlier`` and this many px
        off still are. None: of all the kept neighbours.
    refine_interp_sigma : float or None
        Where the matches, the fill and the growth kept nothing, keep the Gaussian-weighted (σ this, px) plane
        through the kept values within ``refine_grow_inlier`` px of the matcher's dense value where those weigh
        ``refine_interp_support`` and ``refine_interp_share`` of all around, spread less than
        ``refine_interp_spread`` px about it and it lies within ``refine_interp_agree`` px of the dense value
        (:func:`~prismstereo.depth.confidence.plane_interpolation`): beside depth edges and on the weakest
        texture no window confirms the value, but the matcher found the surface the kept values continue.
        Its confidence is the inliers' weight. In ``refine_interp_passes`` passes; needs the dense map;
        None: no such step.
    refine_interp_support, refine_interp_share, refine_interp_spread, refine_interp_agree : float
        See ``refine_interp_sigma``.
    refine_interp_passes : int
        See ``refine_interp_sigma``.
    refine_smoothed_below : float or None
        A capture whose pixel-scale noise (:func:`~prismstereo.depth.smoothed.pixel_noise`, grey levels)
        is below this has lost its finest scale to compression or demosaicing (a real camera's capture):
        its refinement gets ``refine_retry_below`` = ``refine_smoothed_retry_below`` (the wider window for
        every match below that ZNCC) and ``refine_fill_agree`` = ``refine_smoothed_fill_agree``
        (:func:`~prismstereo.depth.smoothed.smoothed_config`; the run's ``config`` records what was used).
        None: never.
    refine_smoothed_retry_below, refine_smoothed_fill_agree : float, float or None
        See ``refine_smoothed_below`` (None: the fill agreement is left as it is).
    refine_smoothed_third_radius : int or None
        ``refine_third_radius`` on a smoothed capture (``refine_smoothed_below``; None: left as it is): the
        blurred weak texture pins a sub-pixel value only over more pixels, and a weak match's 33-px window
        is the more precise one where it is confirmed (docs/EXPERIMENTS.md, issue 26, stop 44).
    refine_smoothed_grow_fit, refine_smoothed_grow_agree, refine_smoothed_grow_spread : str, float, float or None
        The growth's ``refine_grow_fit``, ``refine_grow_agree`` and ``refine_grow_spread`` on a smoothed
        capture (``refine_smoothed_below``; None: left as it is): the plane's growth there adds values less
        precise than the map's, the mean's (0.3, 0.5 px) keeps its median.
    refine_smoothed_interp : bool
        Whether the plane interpolation (``refine_interp_sigma``) runs on a smoothed capture
        (``refine_smoothed_below``): off by default, its values there raise the median (docs/EXPERIMENTS.md,
        issue 26, stop 43).
    sweep : SweepParams
        The plane sweep of ``views="all"`` (:class:`~prismstereo.multiview.prism.SweepParams`).
    coarse_to_fine : {"auto", "on", "off"}
        Match a downsampled pair over the whole range, then the full resolution in tiles within a band
        around it (:mod:`prismstereo.matching.scale`; ``sgm``: a band per pixel); ``auto``: above
        ``ScaleParams.auto_pixels`` (``sgm``: ``ScaleParams.pixel_band_pixels``, 1 M pixels, over at least
        ``pixel_band_range``, 96 disparities).
    max_memory : int or None
        Peak-memory budget of the match, bytes (over it, the match is tiled; refused when no tile fits);
        None: 80 % of the machine's available memory.
    """

    method: str = "bpasw"
    matcher_params: dict[str, Any] = field(default_factory=dict)
    depth_range: tuple[float, float] | None = None
    roi: tuple[int, int, int, int] | None = None
    views: tuple[int, int] | str | None = None
    triangulation: str = "exact"
    calibration: str = "fit"
    use_filled: bool = False
    max_gap_mm: float | None = None
    refine: bool = True
    refine_radius: int = 5
    min_confidence: float | None = 0.5
    speckle_fraction: float | None = 0.001
    refine_iterations: int = 6
    refine_max_shift: float = 0.85
    refine_min_texture: float = 0.01
    refine_max_lr_gap: float | None = 0.45
    refine_prefilter: float | None = 0.7
    refine_fill: bool = False
    refine_retry_radius: int | None = 11
    refine_retry_below: float = 0.95
    refine_retry_drop: bool = True
    refine_third_radius: int | None = None
    refine_third_below: float = 0.95
    refine_fill_agree: float | None = 0.5
    refine_grow_radius: int | None = 16
    refine_grow_agree: float = 0.2
    refine_grow_sigma: float = 8.0
    refine_grow_spread: float | None = 0.35
    refine_grow_passes: int = 2
    refine_grow_fit: str = "plane"
    refine_grow_inlier: float = 1.0
    refine_grow_share: float = 0.9
    refine_grow_agree_depth: float | None = 0.0022
    refine_grow_second_radius: int | None = 5
    refine_grow_min_confidence: float | None = 0.3
    refine_grow_cut: float | None = 1.5
    refine_grow_gap: float | None = 1.5
    refine_interp_sigma: float | None = 8.0
    refine_interp_support: float = 0.3
    refine_interp_share: float = 0.95
    refine_interp_spread: float = 0.3
    refine_interp_agree: float = 0.5
    refine_interp_passes: int = 2
    refine_smoothed_below: float | None = 0.5
    refine_smoothed_retry_below: float = 0.99
    refine_smoothed_fill_agree: float | None = 1.0
    refine_smoothed_third_radius: int | None = 16
    refine_smoothed_grow_fit: str | None = "mean"
    refine_smoothed_grow_agree: float | None = 0.3
    refine_smoothed_grow_spread: float | None = 0.5
    refine_smoothed_interp: bool = False
    sweep: SweepParams = field(default_factory=SweepParams)
    coarse_to_fine: str = "auto"
    max_memory: int | None = None

    def __post_init__(self) -> None:
        """The ranges that do not depend on the rig (:func:`validate_config` checks the rest)."""
        check_fields(self, {"refine_radius": (1, 50), "min_confidence": (0.0, 1.0), "speckle_fraction": (0.0, 1.0),
                            "refine_iterations": (0, 100), "refine_max_shift": (None, 20.0),
                            "refine_min_texture": (0.0, None), "refine_max_lr_gap": (0.0, None),
                            "refine_prefilter": (0.0, 5.0),
                            "refine_retry_radius": (1, 50), "refine_retry_below": (0.0, 1.0),
                            "refine_third_radius": (1, 50), "refine_third_below": (0.0, 1.0),
                            "refine_smoothed_third_radius": (1, 50),
                            "refine_fill_agree": (0.0, None), "refine_grow_radius": (1, 50),
                            "refine_grow_agree": (0.0, None), "refine_grow_sigma": (0.0, 50.0),
                            "refine_grow_spread": (0.0, None), "refine_grow_passes": (1, 10),
                            "refine_grow_inlier": (0.0, None), "refine_grow_share": (0.0, 1.0),
                            "refine_grow_agree_depth": (0.0, 1.0), "refine_grow_second_radius": (1, 50),
                            "refine_grow_min_confidence": (0.0, 1.0),
                            "refine_grow_cut": (0.0, None), "refine_grow_gap": (0.0, None),
                            "refine_interp_sigma": (0.0, 50.0), "refine_interp_support": (0.0, 1.0),
                            "refine_interp_share": (0.0, 1.0),
                            "refine_interp_spread": (0.0, None), "refine_interp_agree": (0.0, None),
                            "refine_interp_passes": (1, 10),
                            "refine_smoothed_below": (0.0, None),
                            "refine_smoothed_retry_below": (0.0, 1.0), "refine_smoothed_fill_agree": (0.0, None),
                            "refine_smoothed_grow_agree": (0.0, None), "refine_smoothed_grow_spread": (0.0, None)},
                     positive=("max_gap_mm", "refine_max_shift", "refine_fill_agree", "refine_grow_agree",
                               "refine_grow_sigma", "refine_grow_spread", "refine_grow_inlier",
                               "refine_grow_agree_depth", "refine_grow_cut", "refine_grow_gap",
                               "refine_interp_sigma", "refine_interp_spread",
                               "refine_interp_agree",
                               "refine_smoothed_fill_agree", "refine_smoothed_grow_agree",
                               "refine_smoothed_grow_spread"))
        if not isinstance(self.method, str):
            fail(self, "method", "a matcher name", self.method)
        if not isinstance(self.matcher_params, Mapping):
            fail(self, "matcher_params", "a dict of the matcher's tuning parameters", self.matcher_params)
        if self.triangulation not in TRIANGULATIONS:
            fail(self, "triangulation", f"one of {', '.join(TRIANGULATIONS)}", self.triangulation)
        if self.calibration not in ("fit", "thesis"):
            fail(self, "calibration", "'fit' or 'thesis'", self.calibration)
        if self.refine_grow_fit not in ("mean", "plane"):
            fail(self, "refine_grow_fit", "'mean' or 'plane'", self.refine_grow_fit)
        if self.refine_smoothed_grow_fit not in (None, "mean", "plane"):
            fail(self, "refine_smoothed_grow_fit", "'mean', 'plane' or None", self.refine_smoothed_grow_fit)
        if self.depth_range is not None and (
                len(self.depth_range) != 2 or not all(isinstance(v, numbers.Real) and math.isfinite(v)
                                                      for v in self.depth_range)
                or not self.depth_range[0] < self.depth_range[1]):
            fail(self, "depth_range", "(min, max) in mm with min < max, or None", self.depth_range)
        if self.roi is not None and (len(self.roi) != 4 or not all(isinstance(v, numbers.Integral) for v in self.roi)
                                     or self.roi[0] < 0 or self.roi[1] < 0 or self.roi[2] <= 0 or self.roi[3] <= 0):
            fail(self, "roi", "(x, y, w, h) integers with x, y >= 0 and w, h > 0, or None", self.roi)
        if not isinstance(self.sweep, SweepParams):
            fail(self, "sweep", "SweepParams", self.sweep)

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON types (tuples as lists); :meth:`from_dict` reads it back."""
        d = asdict(self)
        d["depth_range"] = list(self.depth_range) if self.depth_range is not None else None
        d["roi"] = list(self.roi) if self.roi is not None else None
        d["views"] = list(self.views) if isinstance(self.views, tuple) else self.views
        return d

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> DepthConfig:
        """The configuration recorded by :meth:`to_dict` (``run.json``'s ``config``).

        Raises
        ------
        ConfigError
            A key that is not a field of the configuration.
        """
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise ConfigError(f"expected depth configuration keys among {', '.join(sorted(names))}, got {unknown}")
        d = dict(data)
        for key, n in (("depth_range", 2), ("roi", 4), ("views", 2)):
            v = d.get(key)
            if isinstance(v, list):
                if len(v) != n:
                    raise ConfigError(f"{key}: expected {n} values, got {v}")
                d[key] = tuple(v)
        if "matcher_params" in d:
            d["matcher_params"] = dict(d["matcher_params"] or {})
        if isinstance(d.get("sweep"), Mapping):
            try:
                d["sweep"] = SweepParams(**d["sweep"])
            except TypeError as exc:
                raise ConfigError(f"sweep: expected plane-sweep parameters, got {d['sweep']} ({exc})") from None
        return cls(**d)


# --------------------------------------------------------------------------- typed values between steps
@dataclass(frozen=True, eq=False)
class SearchRegion:
    """What a pair run searches: the pixels of the rectified left view and the disparities.

    Attributes
    ----------
    mask : (h, w) bool
        Region of interest ∩ the common view of the two faces in the depth range.
    disparity_range : (min, max)
        Integer disparity search range, px.
    depth_range : (min, max)
        Depths searched, mm.
    source : str
        Where the depth range came from: ``"given"``, ``"rig"`` or ``"rig+images"``.
    warnings : tuple of str
    right_excluded : (h, w) bool or None
        Pixels of the rectified right view no match may land on (the apex band,
        :mod:`prismstereo.depth.apex_band`); None: none.
    """

    mask: np.ndarray
    disparity_range: tuple[int, int]
    depth_range: tuple[float, float]
    source: str
    warnings: tuple[str, ...] = ()
    right_excluded: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class Disparities:
    """The matcher's output on the rectified left grid (NaN invalid and outside the region).

    Attributes
    ----------
    disparity : (h, w) float32
        Cross-checked matches (or the dense map with ``use_filled``) that land inside the right view.
    filled : (h, w) float32 or None
        The matcher's dense (hole-filled) output; None where the run does not read it (:func:`needs_dense_map`).
    raw : (h, w) float32
        The matcher's cross-checked output before the right-view check.
    timings : dict
        The matcher's own seconds per stage.
    info : dict
        How the match ran (:func:`~prismstereo.matching.scale.match_scaled`'s ``extras["scale"]``).
    """

    disparity: np.ndarray
    filled: np.ndarray | None
    raw: np.ndarray
    timings: dict[str, float]
    info: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class Points:
    """Triangulated points on a grid.

    Attributes
    ----------
    points : (h, w, 3) float64
        World points, mm, NaN invalid.
    depth : (h, w) float32
        Their world Z, mm, NaN invalid.
    gaps : (h, w) float32
        Ray gap of each point, mm (NaN for ``dlt``/``q`` and invalid).
    valid : (h, w) bool
    """

    points: np.ndarray
    depth: np.ndarray
    gaps: np.ndarray
    valid: np.ndarray


@dataclass(frozen=True, eq=False)
class DepthSetup:
    """The per-rig part of a pair run, computed once and shared by every frame of a sequence (batch).

    Attributes
    ----------
    rig : Rig
    config : DepthConfig
        Resolved (views filled in, matcher parameters with their defaults).
    views : tuple of VirtualView
        The virtual cameras.
    pair : RectifiedPair
        Rectification of the chosen pair, with its remap tables.
    region : SearchRegion
    epipolar : EpipolarTable or None
        The pair's epipolar curves (:func:`epipolar_curves`), which the refinement samples along.
    rays : RayTable or None
        The exact ray of every rectified pixel (:func:`~prismstereo.depth.triangulation.ray_table`) for
        ``triangulation="exact"``; None: traced per frame.
    rig_range : RigRange or None
        The rig-only part of the automatic search range (:func:`~prismstereo.depth.search_range.rig_range`);
        None: computed where needed.
    timings : dict
        Seconds spent on the set-up steps.
    """

    rig: Rig
    config: DepthConfig
    views: tuple[VirtualView, ...]
    pair: RectifiedPair
    region: SearchRegion
    epipolar: EpipolarTable | None = None
    rays: RayTable | None = None
    rig_range: RigRange | None = None
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def disparity_range(self) -> tuple[int, int]:
        return self.region.disparity_range

    @property
    def depth_range(self) -> tuple[float, float]:
        return self.region.depth_range

    @property
    def roi_mask(self) -> np.ndarray:
        return self.region.mask


@dataclass(frozen=True, eq=False)
class DepthRun:
    """Everything a depth run produced.

    The grid of the arrays is the rectified LEFT view for a pair run (``pair`` set) and the REAL capture
    for an all-view run (``pair`` None).

    Attributes
    ----------
    config : DepthConfig
        Resolved.
    rig : Rig
    image : (H, W, 3) uint8
        The capture.
    views : tuple of VirtualView
        The virtual cameras (empty for an all-view run, which calibrates its own).
    pair : RectifiedPair or None
        The rectification of the two views (pair runs).
    left : (h, w, 3) uint8
        The image on the result's grid (rectified left sub-image, or the capture): the points' colours.
    right : (h, w, 3) uint8 or None
        Rectified right sub-image (pair runs).
    disparity : (h, w) float32 or None
        Disparity used for triangulation, px, NaN invalid (pair runs).
    disparity_filled : (h, w) float32 or None
        The matcher's dense output (NaN outside the region; pair runs that read it, :func:`needs_dense_map`).
    raw_disparity : (h, w) float32 or None
        The matcher's cross-checked output (pair runs).
    points : (h, w, 3) float64
        Triangulated world points, mm, NaN invalid.
    depth : (h, w) float32
        World Z of ``points``, mm, NaN invalid.
    gaps : (h, w) float32 or None
        Ray gap of each point, mm.
    valid : (h, w) bool
    roi_mask : (h, w) bool
        The pixels searched: ROI ∩ common view (pair), or the reference face's region (all views).
    disparity_range : (min, max)
        Integer search range (pair runs; (0, 0) otherwise).
    depth_range : (min, max)
        The depths searched, mm.
    depth_range_source : str
        ``"given"``, ``"rig"`` or ``"rig+images"``.
    faces : tuple of int
        (left, right) of a pair; (reference, others...) of an all-view run.
    confidence : (h, w) float32 or None
        Confidence in [0, 1] of each point (:func:`~prismstereo.depth.confidence.confident_matches`; 0 for
        every point without refinement), NaN where ``valid`` is False.
    view_counts : (h, w) uint8 or None
        Views that triangulated each pixel (all-view runs).
    stage_counts : dict
        Pixels left after each filtering step (cross-checked matches, refined and confident, despeckled).
    timings, match_timings : dict
        Seconds per step, and the matcher's own seconds per stage.
    cpu_timings : dict
        CPU seconds (all threads of the process) per step of this run.
    warnings : tuple of str
        One-line warnings: the result may be unreliable (also logged and written to run.json).
    sweep : dict
        The all-view plane sweep's hypotheses (``n``, ``min_mm``, ``max_mm``); empty for pairs.
    accuracy : dict or None
        :func:`prismstereo.evaluation.depth_metrics.evaluate_depth`'s result, when the caller measured it
        (``dataclasses.replace(result, accuracy=...)``).
    coverage : Coverage or None
        The share of the common view at the depths found that got a point
        (:func:`~prismstereo.depth.search_range.scene_coverage`; pair runs), what the coverage warning and
        ``run.json``'s ``coverage`` report.
    """

    config: DepthConfig
    rig: Rig
    image: np.ndarray
    views: tuple[VirtualView, ...]
    pair: RectifiedPair | None
    left: np.ndarray
    right: np.ndarray | None
    disparity: np.ndarray | None
    disparity_filled: np.ndarray | None
    raw_disparity: np.ndarray | None
    points: np.ndarray
    depth: np.ndarray
    gaps: np.ndarray | None
    valid: np.ndarray
    roi_mask: np.ndarray
    disparity_range: tuple[int, int]
    depth_range: tuple[float, float]
    depth_range_source: str
    faces: tuple[int, ...]
    confidence: np.ndarray | None = None
    view_counts: np.ndarray | None = None
    stage_counts: dict[str, int] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    match_timings: dict[str, float] = field(default_factory=dict)
    match_info: dict[str, Any] = field(default_factory=dict)
    cpu_timings: dict[str, float] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    sweep: dict[str, Any] = field(default_factory=dict)
    accuracy: dict[str, Any] | None = None
    coverage: Coverage | None = None

    def point_cloud(self) -> tuple[np.ndarray, np.ndarray]:
        """Valid points (N, 3) mm (world frame) and their colours (N, 3) uint8 from :attr:`left`."""
        pts = self.points[self.valid]
        cols = self.left[self.valid] if self.left.ndim == 3 else np.repeat(self.left[self.valid][:, None], 3, 1)
        return pts, cols.astype(np.uint8)

    def grid_to_real(self, px: np.ndarray) -> np.ndarray:
        """Real capture pixels (N, 2) of grid pixels (N, 2) (x, y)."""
        if self.pair is None:
            return np.asarray(px, dtype=np.float64)
        return np.asarray(self.pair.rectified_to_real(px, "left"), dtype=np.float64)

    def searched(self) -> np.ndarray:
        """(h, w) bool: the pixels that could get a point (the region, inside the left view's valid area)."""
        if self.pair is None:
            return self.roi_mask
        return self.roi_mask & np.asarray(self.pair.valid_masks()[0], dtype=bool)

    def point_confidence(self) -> np.ndarray:
        """(h, w) float32 confidence of each point, NaN where ``valid`` is False (0 without refinement)."""
        assert self.valid is not None
        conf = self.confidence if self.confidence is not None else np.zeros(self.valid.shape, dtype=np.float32)
        return np.where(self.valid, conf, np.float32(np.nan)).astype(np.float32)

    def counts(self) -> dict[str, int]:
        return {
            "rectified_pixels": int(self.valid.size),
            "region_pixels": int(self.searched().sum()),
            **self.stage_counts,
            "points": int(self.valid.sum()),
        }

    def faces_dict(self) -> dict[str, Any]:
        if self.pair is not None:
            return {"left": self.faces[0], "right": self.faces[1]}
        return {"reference": self.faces[0], "others": list(self.faces[1:])}

    def summary(self) -> dict[str, Any]:
        """The JSON-able summary written to ``run.json`` (the resolved configuration included)."""
        out: dict[str, Any] = {
            "prismstereo": __version__,
            "versions": library_versions(),
            "rig": self.rig.to_dict(),
            "config": self.config.to_dict(),
            "faces": self.faces_dict(),
            "image_size": [int(self.image.shape[1]), int(self.image.shape[0])],
            "rectified_size": [int(self.left.shape[1]), int(self.left.shape[0])] if self.pair is not None else None,
            "disparity_range": list(self.disparity_range),
            "depth_range_mm": [round(float(v), 1) for v in self.depth_range],
            "depth_range_source": self.depth_range_source,
            "warnings": list(self.warnings),
            "baseline_mm": float(self.pair.baseline_mm) if self.pair is not None else None,
            "timings_s": {k: round(v, 4) for k, v in self.timings.items()},
            "cpu_s": {k: round(v, 4) for k, v in self.cpu_timings.items()},
            "matcher_timings_s": {k: round(v, 4) for k, v in self.match_timings.items()},
            "matching": dict(self.match_info) or None,
            "counts": self.counts(),
            "coverage": None if self.coverage is None else self.coverage.to_dict(),
            "accuracy": self.accuracy,
            "apex_band": apex_band_info(self.rig),
        }
        if self.view_counts is not None:
            per = np.bincount(self.view_counts.ravel(), minlength=len(self.faces) + 1)
            out["all_views"] = {"depth_hypotheses": dict(self.sweep),
                                "pixels_by_view_count": {str(k): int(v) for k, v in enumerate(per) if k > 0}}
        return out


# --------------------------------------------------------------------------- step 1: validation
def default_views(rig: Rig) -> tuple[int, int]:
    """The pair of faces used when none is given: (1, 0) for a bi-prism (left, right), else (0, 1)."""
    return (1, 0) if rig.prism.faces == 2 else (0, 1)


def validate_image(rig: Rig, image: Any) -> np.ndarray:
    """Check that ``image`` is a capture of ``rig``: H×W or H×W×3 of the rig's size; returns RGB uint8
    (:func:`prismstereo.io.images.as_image`: 16-bit and float captures scaled to 0..255)."""
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3):
        raise ImageError(f"expected an H×W or H×W×3 capture, got shape {img.shape}")
    w, h = rig.camera.width, rig.camera.height
    if img.shape[0] != h or img.shape[1] != w:
        raise ImageError(f"expected a {w}×{h} capture (the rig's camera), got {img.shape[1]}×{img.shape[0]}")
    return as_image(img, name="capture", channels=3)  # the one coercion rule (docs/conventions.md)


def validate_config(rig: Rig, config: DepthConfig) -> DepthConfig:
    """Check the configuration against the rig; return it resolved (views, matcher parameters' defaults).

    Raises
    ------
    ConfigError
        One-line "expected …, got …" messages.
    """
    if config.method.lower() not in available_matchers():
        raise ConfigError(f"DepthConfig.method: expected one of {', '.join(available_matchers())}, "
                          f"got {config.method!r}")
    if config.triangulation not in TRIANGULATIONS:
        raise ConfigError(f"DepthConfig.triangulation: expected one of {', '.join(TRIANGULATIONS)}, "
                          f"got {config.triangulation!r}")
    if config.calibration not in ("fit", "thesis"):
        raise ConfigError(f"DepthConfig.calibration: expected 'fit' or 'thesis', got {config.calibration!r}")
    depth_range: tuple[float, float] | None = None
    if config.depth_range is not None:
        zmin, zmax = (float(v) for v in config.depth_range)
        back = rig.prism.back_distance
        if not (math.isfinite(zmin) and math.isfinite(zmax)) or zmin <= back or zmax <= zmin:
            raise ConfigError(f"DepthConfig.depth_range: expected (min, max) mm with {back:g} (the prism's back "
                              f"plane) < min < max, got ({zmin:g}, {zmax:g})")
        depth_range = (zmin, zmax)
    n = rig.prism.faces
    views: tuple[int, int] | str
    if isinstance(config.views, str):
        if config.views.lower() != "all":
            raise ConfigError(f"DepthConfig.views: expected face indices (i, j) or 'all', got {config.views!r}")
        views = "all" if n >= 3 else default_views(rig)
    else:
        pair = config.views if config.views is not None else default_views(rig)
        if len(pair) != 2:
            raise ConfigError(f"DepthConfig.views: expected two face indices (i, j), got {list(pair)}")
        for v in pair:
            if not 0 <= int(v) < n:
                raise ConfigError(f"DepthConfig.views: expected face indices in 0..{n - 1}, got {list(pair)}")
        if int(pair[0]) == int(pair[1]):
            raise ConfigError(f"DepthConfig.views: expected two different faces, got {list(pair)}")
        views = (int(pair[0]), int(pair[1]))
    # the ranges that do not depend on the rig were checked when the configuration was made (__post_init__)
    ScaleParams(coarse_to_fine=config.coarse_to_fine, max_memory=config.max_memory)  # coarse_to_fine, max_memory
    method = config.method.lower()
    params = resolved_params(method, **config.matcher_params)
    return dataclasses.replace(config, views=views, method=method, depth_range=depth_range, matcher_params=params)


def validate_inputs(rig: Rig, image: Any, config: DepthConfig) -> tuple[np.ndarray, DepthConfig]:
    """Check everything a user can get wrong before any heavy work; return the image and resolved config.

    Raises
    ------
    ImageError, ConfigError, GeometryError
        One-line "expected …, got …" messages.
    """
    img = validate_image(rig, image)
    return img, validate_config(rig, config)


# --------------------------------------------------------------------------- pair steps
def virtual_cameras(rig: Rig, config: DepthConfig) -> tuple[VirtualView, ...]:
    """The virtual cameras of every face, with the configuration's model (thesis §3.2, §4.1)."""
    return tuple(calibrate_rig(rig, method=config.calibration))


def _pair_faces(config: DepthConfig) -> tuple[int, int]:
    if not isinstance(config.views, tuple):
        raise ConfigError(f"expected a resolved pair of views, got {config.views!r}")
    return config.views


def rectify_geometry(rig: Rig, views: Sequence[VirtualView], config: DepthConfig) -> RectifiedPair:
    """The rectification of the configuration's pair of faces (thesis §3.2.2), with its remap tables."""
    by_face = {v.face: v for v in views}
    a, b = _pair_faces(config)
    return rectify_pair(rig, by_face[a], by_face[b])


def epipolar_curves(pair: RectifiedPair) -> EpipolarTable:
    """Where a match really lies in the rectified right view: the row offset of the exact epipolar curve of
    each left pixel and disparity (:func:`~prismstereo.rectify.epipolar.epipolar_table`)."""
    return epipolar_table(pair)


def rectify_capture(pair: RectifiedPair, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rectified left and right sub-images of a capture."""
    left, right = pair.rectify_images(image)
    return np.asarray(left), np.asarray(right)


def _cached_common_view(rig: Rig, pair: RectifiedPair, config: DepthConfig, zmin: float, zmax: float
                        ) -> tuple[np.ndarray, tuple[int, int]]:
    """:func:`~prismstereo.rectify.common_view` of ``pair`` over ``zmin``..``zmax``, read from the set-up cache
    (keyed by the set-up and the two depths' exact bits) or computed and stored there: the same arrays."""
    faces = _pair_faces(config)
    shape = (pair.size[1], pair.size[0])
    depth = (float(zmin), float(zmax))
    found = load_view(rig, faces, config.calibration, depth_mm=depth, shape=shape)
    if found is None:
        found = common_view(pair, zmin, zmax)
        save_view(rig, faces, config.calibration, depth_mm=depth, region=found[0], disparity_px=found[1])
    return found


def search_region(rig: Rig, pair: RectifiedPair, config: DepthConfig, left: np.ndarray | None = None,
                  right: np.ndarray | None = None, *, known: RigRange | None = None,
                  cached: bool = False) -> SearchRegion:
    """The pixels and disparities to search.

    With the configuration's depth range: its common view; without one, the range the rig allows,
    narrowed by a coarse match of the rectified images when they are given
    (:func:`~prismstereo.depth.search_range.auto_search_range`; a sequence passes none, since one frame's
    content says nothing of the next's). ``known``: the pair's rig-only range
    (:func:`~prismstereo.depth.search_range.rig_range`), if the caller has it: the same region, sooner.
    ``cached``: read and store the common view in the set-up cache (:func:`_cached_common_view`).

    Raises
    ------
    ConfigError
        A region of interest outside the rectified left view.
    GeometryError
        Views that do not overlap in the depth range.
    """
    width = pair.size[0] if left is None else left.shape[1]
    if config.depth_range is None and left is not None and right is not None:
        found = auto_search_range(pair, rig.prism.back_distance, left, right, rig=known)
        zmin, zmax = found.depth_mm
        common, _ = _cached_common_view(rig, pair, config, zmin, zmax) if cached else common_view(pair, zmin, zmax)
        lo, hi = found.disparity_px
        source, warnings = found.source, tuple(found.warnings)
    else:
        source = "given" if config.depth_range is not None else "rig"
        if config.depth_range is not None:
            zmin, zmax = config.depth_range
            common, (lo, hi) = (_cached_common_view(rig, pair, config, zmin, zmax) if cached
                                else common_view(pair, zmin, zmax))
        else:
            everything = known if known is not None else rig_range(pair, rig.prism.back_distance)
            (zmin, zmax), common, (lo, hi) = everything.depth_mm, everything.region, everything.disparity_px
        warnings = ()
    hi = min(hi, width - 1)
    lo = min(lo, hi)
    h = common.shape[0]
    mask = np.zeros((h, width), dtype=bool)
    if config.roi is not None:
        x, y, w_, h_ = config.roi
        if x >= width or y >= h:
            raise ConfigError(f"DepthConfig.roi: expected a region inside the {width}×{h} rectified left view, "
                              f"got {list(config.roi)}")
        mask[y:y + h_, x:x + w_] = True
    else:
        mask[:] = True
    band = apex_band_views(rig, pair)  # the views mix there (the camera's f_number / focus_distance)
    if band is not None:
        mask &= ~band[0]
    return SearchRegion(mask=mask & common, disparity_range=(lo, hi), depth_range=(zmin, zmax), source=source,
                        warnings=warnings, right_excluded=None if band is None else band[1])


def _roi_box(mask: np.ndarray) -> tuple[int, int, int, int]:
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    if rows.size == 0:
        raise GeometryError("expected a non-empty region of the rectified left view to match, got none")
    return int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1


def needs_dense_map(config: DepthConfig) -> bool:
    """Whether a pair run reads the matcher's dense (hole-filled) map: it triangulates it (``use_filled``) or
    tries its values where no match was kept (:func:`_fill_rule`: ``refine_fill`` or ``refine_fill_agree``, with
    the refinement and its sub-pixel check; the growth; the plane interpolation, ``refine_interp_sigma``)."""
    return bool(config.use_filled or (config.refine and (_fill_rule(config)[0] or _grows(config)
                                                         or config.refine_interp_sigma is not None)))


def match_pair(left: np.ndarray, right: np.ndarray, pair: RectifiedPair, region: SearchRegion,
               config: DepthConfig, *, band: PriorBand | None = None) -> Disparities:
    """Match the region's bounding box with the configuration's matcher; keep matches inside the right view.
    The matcher's dense map (``filled``) only where the run reads it (:func:`needs_dense_map`), else None and
    the matcher's hole filling skipped (``info["dense_map"]`` False). ``band``: each pixel's search band on the
    rectified left grid (:func:`~prismstereo.matching.temporal.prior_band`, a stream's temporal prior), for a
    matcher of :data:`~prismstereo.matching.temporal.BANDED_MATCHERS` (``info["band_mean"]``: the disparities
    searched per pixel)."""
    lo, hi = region.disparity_range
    r0, r1, c0, c1 = _roi_box(region.mask)
    # the right image must reach hi pixels to the left of the region
    ca = max(0, c0 - hi)
    sub_l = left[r0:r1, ca:c1]
    sub_r = right[r0:r1, ca:c1]
    hi_eff = min(hi, sub_l.shape[1] - 1)
    lo_eff = min(lo, hi_eff)
    params = dict(config.matcher_params)
    dense = needs_dense_map(config)
    if not dense and params.get("fill") is True:
        # the matcher's hole filling (and its median) feeds only the dense map, which this run does not read:
        # the cross-checked matches are the same without it (a quarter of sgm's time at 0.8 MP)
        params["fill"] = False
    crop = (slice(r0, r1), slice(ca, c1))
    if band is not None:
        res = match(sub_l, sub_r, max_disp=hi_eff, min_disp=lo_eff, method=config.method,
                    band=(np.clip(band.lo[crop], lo_eff, hi_eff), np.clip(band.hi[crop], lo_eff, hi_eff)), **params)
    else:
        # the budget is the run's: the match gets what the process does not hold already (set-up, capture, maps)
        res = match(sub_l, sub_r, max_disp=hi_eff, min_disp=lo_eff, method=config.method,
                    scale=ScaleParams(coarse_to_fine=config.coarse_to_fine, max_memory=config.max_memory,
                                      held=resident_bytes()),
                    **params)
    raw_sub = res.disparity_raw if res.disparity_raw is not None else np.where(res.valid, res.disparity, np.nan)
    h, w = left.shape[:2]
    raw = np.full((h, w), np.nan, dtype=np.float32)
    dense_map = np.full((h, w), np.nan, dtype=np.float32)
    raw[r0:r1, ca:c1] = raw_sub
    dense_map[r0:r1, ca:c1] = res.disparity
    out = ~region.mask
    raw[out] = np.nan
    dense_map[out] = np.nan
    # a match must land inside the right view's valid region
    vr = np.asarray(pair.valid_masks()[1], dtype=bool)
    if region.right_excluded is not None:
        vr = vr & ~region.right_excluded
    src = dense_map if config.use_filled else raw
    ys, xs = np.nonzero(np.isfinite(src))
    xr = np.rint(xs - src[ys, xs]).astype(np.int64)
    inside = (xr >= 0) & (xr < w)
    inside[inside] &= vr[ys[inside], xr[inside]]
    bad = np.zeros((h, w), dtype=bool)
    bad[ys[~inside], xs[~inside]] = True
    src = src.copy()
    src[bad] = np.nan
    info = dict(res.extras.get("scale", {}))
    if band is not None:
        info.update({"temporal_band": True, "band_mean": res.extras.get("band_mean"),
                     "band_full_share": round(float(band.full[crop].mean()), 4)})
    # the matches passed the matcher's left–right check (coop's map has none: every value is a match)
    info["cross_checked"] = not config.use_filled and config.method not in UNCHECKED_MATCHERS
    if not dense:
        info["dense_map"] = False
    return Disparities(disparity=src, filled=dense_map if dense else None, raw=raw, timings=dict(res.timings),
                       info=info)


def refine_matches(left: np.ndarray, right: np.ndarray, pair: RectifiedPair, disparity: np.ndarray,
                   config: DepthConfig, *, epipolar: EpipolarTable | None,
                   filled: np.ndarray | None = None, right_excluded: np.ndarray | None = None,
                   checked: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel refinement, confidence and the confidence filter
    (:func:`~prismstereo.depth.confidence.confident_matches`), the right windows on the epipolar curves of
    ``epipolar`` (:func:`epipolar_curves`; None: on the left pixels' rows); with ``filled`` (the matcher's
    dense map) and ``refine_fill`` or ``refine_fill_agree``, a second try from it where none was kept
    (:func:`~prismstereo.depth.confidence.confident_fill`; none lands on ``right_excluded``), the growth
    (``refine_grow_radius``) and the plane interpolation (``refine_interp_sigma``); ``checked``:
    ``disparity`` passed the matcher's left–right check (False: a map without one, ``coop``'s; its values stand
    for the right view in the sub-pixel check only where their window confirms them, ``seeds_checked`` of
    :func:`~prismstereo.depth.confidence.confident_matches`); returns
    (disparity, confidence in [0, 1], 0 for every match when the refinement is off, NaN where there is no
    match)."""
    if not config.refine:
        return disparity, np.where(np.isfinite(disparity), np.float32(0.0), np.float32(np.nan))
    vl, vr = pair.valid_masks()
    kw: dict[str, Any] = dict(radius=config.refine_radius, iterations=config.refine_iterations,
                              max_shift=config.refine_max_shift,
                              min_texture=config.refine_min_texture, min_confidence=config.min_confidence,
                              max_lr_gap=config.refine_max_lr_gap, valid_left=vl, epipolar=epipolar,
                              prefilter=config.refine_prefilter, retry_radius=config.refine_retry_radius,
                              retry_below=config.refine_retry_below, retry_drop=config.refine_retry_drop)
    disp, conf = confident_matches(left, right, disparity, valid_right=vr, seeds_checked=checked, **kw)
    if config.refine_third_radius is not None and config.refine_third_radius != config.refine_radius:
        disp, conf = _third_window(left, right, disparity, disp, conf, config, kw, vr, checked)
    fill, agree = _fill_rule(config)
    vr_fill = vr if right_excluded is None else np.asarray(vr, dtype=bool) & ~right_excluded
    if filled is not None and fill:
        disp, conf = confident_fill(left, right, disp, conf, filled, valid_right=vr_fill, agree=agree, **kw)
    if filled is not None and _grows(config):
        assert config.refine_grow_radius is not None
        kw_grow = dict(kw)
        if (config.refine_grow_fit == "plane" and config.refine_grow_min_confidence is not None
                and config.min_confidence is not None):  # None keeps every match: nothing to lower
            kw_grow["min_confidence"] = min(config.min_confidence, config.refine_grow_min_confidence)
        disp, conf = confident_growth(left, right, disp, conf, filled, grow_radius=config.refine_grow_radius,
                                      sigma=config.refine_grow_sigma, agree=config.refine_grow_agree,
                                      max_spread=config.refine_grow_spread, passes=config.refine_grow_passes,
                                      fit=config.refine_grow_fit, inlier=config.refine_grow_inlier,
                                      min_share=config.refine_grow_share,
                                      agree_depth=config.refine_grow_agree_depth,
                                      disparity_offset=pair.disparity_offset,
                                      second_radius=config.refine_grow_second_radius,
                                      cut=config.refine_grow_cut, gap=config.refine_grow_gap,
                                      valid_right=vr_fill,
                                      **kw_grow)
    if filled is not None and config.refine_interp_sigma is not None:
        disp, conf = plane_interpolation(disp, conf, filled, sigma=config.refine_interp_sigma,
                                         inlier=config.refine_grow_inlier, min_support=config.refine_interp_support,
                                         min_share=config.refine_interp_share, max_spread=config.refine_interp_spread,
                                         agree=config.refine_interp_agree, passes=config.refine_interp_passes,
                                         valid_right=vr_fill)
    return disp, conf


def _third_window(left: np.ndarray, right: np.ndarray, disparity: np.ndarray, disp: np.ndarray, conf: np.ndarray,
                  config: DepthConfig, kw: dict[str, Any], vr: np.ndarray, checked: bool
                  ) -> tuple[np.ndarray, np.ndarray]:
    """``refine_third_radius``: the kept matches below ``refine_third_below`` refined again from the matcher's
    value with that window (the whole map standing for the right view in the sub-pixel check, as for the
    second window); its result replaces theirs where it is confirmed with a higher ZNCC (a wider window that
    matches worse reaches across a depth edge, as beside Jadeplant's leaves), none is dropped."""
    weak = np.isfinite(disp) & (conf < config.refine_third_below)
    if not weak.any():
        return disp, conf
    kw3 = {**kw, "radius": config.refine_third_radius, "retry_radius": None}
    d3, c3 = confident_matches(left, right, np.where(weak, np.asarray(disparity, dtype=np.float32), np.float32(np.nan)),
                               valid_right=vr, seeds_checked=checked, right_seeds=disparity, **kw3)
    take = weak & np.isfinite(d3) & (c3 > conf)
    return (np.where(take, d3, disp).astype(np.float32), np.where(take, c3, conf).astype(np.float32))


def _grows(config: DepthConfig) -> bool:
    """Whether :func:`refine_matches` grows from the kept values (``refine_grow_radius``, with the check)."""
    return config.refine_grow_radius is not None and config.refine_max_lr_gap is not None


def _fill_rule(config: DepthConfig) -> tuple[bool, float | None]:
    """Whether :func:`refine_matches` fills from the dense map, and its ``agree`` (None: every confirmed
    value, ``refine_fill``)."""
    if config.refine_max_lr_gap is None:
        return False, None
    if config.refine_fill:
        return True, None
    two = config.refine_retry_radius is not None and config.refine_retry_radius != config.refine_radius
    if config.refine_fill_agree is not None and two:
        return True, float(config.refine_fill_agree)
    return False, None


def remove_speckles(disparity: np.ndarray, region: SearchRegion, config: DepthConfig) -> np.ndarray:
    """Remove small connected patches of disparity (OpenCV ``filterSpeckles``); see ``speckle_fraction``."""
    if config.speckle_fraction is None:
        return disparity
    size = max(20, int(config.speckle_fraction * int(region.mask.sum())))
    return drop_small_patches(disparity, max_size=size)


def triangulate_disparity(rig: Rig, pair: RectifiedPair, views: Sequence[VirtualView], disparity: np.ndarray,
                          config: DepthConfig, *, rays: RayTable | None = None) -> Points:
    """Triangulate every finite disparity of the rectified left grid (thesis §7.2); filter by gap and depth.
    ``rays``: the pair's exact-ray table for ``triangulation="exact"`` (:class:`~prismstereo.depth.
    triangulation.RayTable`: the same points within 1e-5 relative, without tracing rays)."""
    h, w = disparity.shape
    ys, xs = np.nonzero(np.isfinite(disparity))
    d = disparity[ys, xs].astype(np.float64)
    tri = triangulate_matches(rig, pair, ys, xs, d, method=config.triangulation, views=views, rays=rays)
    ok = tri.valid.copy()
    if config.max_gap_mm is not None:
        ok &= ~(tri.gaps > config.max_gap_mm)
    ok &= tri.points[:, 2] > rig.prism.back_distance
    points, depth, gaps, valid = points_on_grid((h, w), ys, xs, tri.points, tri.gaps, ok)
    return Points(points=points, depth=depth, gaps=gaps, valid=valid)


def coverage_of(result: DepthRun) -> Coverage | None:
    """The share of the common view at the depths found that got a point
    (:func:`~prismstereo.depth.search_range.scene_coverage`; pair runs, else None)."""
    if result.pair is None or result.disparity is None:
        return None
    return scene_coverage(result.disparity, result.valid, result.depth, result.searched(),
                          np.asarray(result.pair.valid_masks()[1], dtype=bool))


def diagnose(result: DepthRun) -> tuple[str, ...]:
    """One-line warnings about a finished run (:func:`~prismstereo.depth.search_range.depth_warnings`;
    coverage of the common view at the depths found, :attr:`DepthRun.coverage`, where the run has it).

    The share of matches at a search limit counts, for a matcher without a left–right check of its own
    (``match_info["cross_checked"]`` False, e.g. ``coop``), only the pixels that kept a point: such a map has a
    value at every pixel, and those without a true match in a narrow range pile up at its limits (2–7 % on
    the tri-prism) whether or not the scene reaches them."""
    c = result.counts()
    limit_valid = None
    if not result.match_info.get("cross_checked", True) and result.disparity is not None:
        limit_valid = np.asarray(result.valid, dtype=bool) & np.isfinite(result.disparity)
    return tuple(depth_warnings(
        points=c["points"], region_pixels=c["region_pixels"], matched=c.get("matched", 0),
        confident=c.get("refined"), disparity=result.raw_disparity, valid=limit_valid,
        disparity_range=result.disparity_range, depth_range=result.depth_range, coverage=result.coverage))


# --------------------------------------------------------------------------- all-view steps
def search_region_all_views(rig: Rig, image: np.ndarray, config: DepthConfig) -> SearchRange:
    """The depth range of an all-view run: the configuration's, else the default pair's automatic range."""
    if config.depth_range is not None:
        return SearchRange(config.depth_range, (0, 0), "given")
    return auto_search_range_of_capture(rig, image, faces=default_views(rig), calibration=config.calibration)


def sweep_all_views(rig: Rig, image: np.ndarray, config: DepthConfig, found: SearchRange,
                    ) -> tuple[DepthRun, dict[str, float]]:
    """Plane sweep over every face and multi-ray triangulation (:func:`~prismstereo.multiview.prism.
    depth_all_views`), as a :class:`DepthRun` on the capture's grid; also the sweep's timings."""
    res = depth_all_views(rig, image, depth_range=found.depth_mm, calibration=config.calibration,
                          params=config.sweep)
    h, w = res.depth.shape
    points = np.full((h, w, 3), np.nan)
    points[res.pixels[:, 1], res.pixels[:, 0]] = res.points
    region = res.region if res.region is not None else res.valid
    sweep = {"n": int(res.depths.size), "min_mm": float(res.depths.min()), "max_mm": float(res.depths.max())}
    result = DepthRun(
        config=config, rig=rig, image=image, views=(), pair=None, left=image, right=None, disparity=None,
        disparity_filled=None, raw_disparity=None, points=points, depth=res.depth, gaps=None, valid=res.valid,
        roi_mask=region, disparity_range=(0, 0), depth_range=found.depth_mm, depth_range_source=found.source,
        faces=(res.reference, *res.views), view_counts=res.counts, warnings=tuple(found.warnings), sweep=sweep)
    return result, dict(res.timings)


# --------------------------------------------------------------------------- running the steps
class _Clock:
    """Seconds per step, a progress bar on a terminal, and the step logged."""

    def __init__(self, steps: Sequence[str], progress: bool | None) -> None:
        self.timings: dict[str, float] = {}
        self.cpu: dict[str, float] = {}
        self._bar = progress_bar(total=len(steps), desc="depth", unit="step", leave=False) \
            if progress is not False else None

    @contextmanager
    def step(self, name: str) -> Iterator[None]:
        if self._bar is not None:
            self._bar.set_description(f"depth: {name}")
        t, c = time.perf_counter(), time.process_time()
        yield
        again = name in self.timings  # a step timed in two parts adds up (and advances the bar once)
        self.timings[name] = self.timings.get(name, 0.0) + time.perf_counter() - t
        self.cpu[name] = self.cpu.get(name, 0.0) + time.process_time() - c
        log.info("step %s: %.2f s", name, self.timings[name])
        if self._bar is not None and not again:
            self._bar.update(1)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()


_SETUP_STEPS = ("cameras", "rectify", "rays")
_FRAME_STEPS = ("match", "refine", "speckles", "triangulate", "diagnose")


def _finish(result: DepthRun, clock: _Clock, t0: float) -> DepthRun:
    with clock.step("diagnose"):
        result = dataclasses.replace(result, coverage=coverage_of(result))
        warnings = result.warnings + diagnose(result)
    clock.close()
    timings = {**result.timings, **clock.timings, "total": time.perf_counter() - t0}
    for line in warnings:
        log.warning("%s", line)
    return dataclasses.replace(result, warnings=warnings, timings=timings, cpu_timings=dict(clock.cpu))


def _run_frame(setup: DepthSetup, image: np.ndarray, left: np.ndarray, right: np.ndarray, clock: _Clock,
               t0: float, band: PriorBand | None = None) -> DepthRun:
    cfg, pair, region = smoothed_config(setup.config, image), setup.pair, setup.region
    r0, r1, c0, c1 = _roi_box(region.mask)
    lo, hi = region.disparity_range
    # the plan again with the range the capture narrowed (the one before it was read bounds the rig's whole range)
    plan = estimate_depth_memory(setup.rig, cfg, shape=(r1 - r0, c1 - max(0, c0 - hi)), disparity_range=(lo, hi))
    log.info("depth: %s", plan.describe())
    with clock.step("match"):
        matched = match_pair(left, right, pair, region, cfg, band=band)
    counts = {"matched": int(np.isfinite(matched.disparity).sum())}
    with clock.step("refine"):
        filled = None if cfg.use_filled else matched.filled
        disp, conf = refine_matches(left, right, pair, matched.disparity, cfg, epipolar=setup.epipolar,
                                    filled=filled, right_excluded=region.right_excluded,
                                    checked=bool(matched.info.get("cross_checked", True)))
    if cfg.refine:
        counts["refined"] = int(np.isfinite(disp).sum())
    with clock.step("speckles"):
        despeckled = remove_speckles(disp, region, cfg)
    if despeckled is not disp:
        counts["despeckled"] = int(np.isfinite(despeckled).sum())
    with clock.step("triangulate"):
        pts = triangulate_disparity(setup.rig, pair, setup.views, despeckled, cfg, rays=setup.rays)
    result = DepthRun(
        config=cfg, rig=setup.rig, image=image, views=setup.views, pair=pair, left=left, right=right,
        disparity=despeckled, disparity_filled=matched.filled, raw_disparity=matched.raw, points=pts.points,
        depth=pts.depth, gaps=pts.gaps, valid=pts.valid, roi_mask=region.mask,
        disparity_range=region.disparity_range, depth_range=region.depth_range, depth_range_source=region.source,
        faces=(int(pair.left_face), int(pair.right_face)),
        confidence=np.where(pts.valid, conf, np.float32(np.nan)).astype(np.float32), stage_counts=counts,
        timings=dict(setup.timings), match_timings=matched.timings, match_info=matched.info,
        warnings=region.warnings)
    return _finish(result, clock, t0)


def _geometry(rig: Rig, cfg: DepthConfig, clock: _Clock
              ) -> tuple[tuple[VirtualView, ...], RectifiedPair, EpipolarTable, RayTable | None, RigRange | None]:
    """The virtual cameras, the rectified pair, its epipolar curves and (exact triangulation) its ray table,
    from the set-up cache when it holds them (:mod:`prismstereo.depth.setup_cache`), else computed and
    stored there. The clock's ``rectify`` step goes on in the caller (the capture's remap, the search
    region)."""
    faces = _pair_faces(cfg)
    with clock.step("cameras"):
        cached = load_setup(rig, faces, cfg.calibration)
        views = cached[0] if cached is not None else virtual_cameras(rig, cfg)
    with clock.step("rectify"):
        if cached is not None:
            pair, epipolar = cached[1], cached[2]
        else:
            pair = rectify_geometry(rig, views, cfg)
            epipolar = epipolar_curves(pair)
            save_setup(rig, faces, cfg.calibration, views, pair, epipolar)
    rays = None
    if cfg.triangulation == "exact":
        with clock.step("rays"):
            rays = load_rays(rig, faces, cfg.calibration, shape=(pair.size[1], pair.size[0]))
            if rays is None:
                rays = ray_table(rig, pair)
                save_rays(rig, faces, cfg.calibration, rays)
    known = None
    if cfg.depth_range is None:
        with clock.step("rectify"):
            known = load_range(rig, faces, cfg.calibration, shape=(pair.size[1], pair.size[0]))
            if known is None:
                known = rig_range(pair, rig.prism.back_distance)
                save_range(rig, faces, cfg.calibration, known)
    return views, pair, epipolar, rays, known


def run_depth(rig: Rig, image: Any, *, config: DepthConfig | None = None,
              progress: bool | None = None) -> DepthRun:
    """Recover depth from one prism capture (the steps of the module docstring).

    Parameters
    ----------
    rig : Rig
    image : (H, W) or (H, W, 3) array
        The capture (RGB); its size must be the rig camera's.
    config : DepthConfig, optional
    progress : bool, optional
        Show a progress bar per step; default: only when stderr is a terminal.

    Returns
    -------
    DepthRun

    Raises
    ------
    ImageError, ConfigError, GeometryError, MatchingError
        Bad input, found before any heavy work where possible.
    """
    t0 = time.perf_counter()
    img, cfg = validate_inputs(rig, image, config or DepthConfig())
    validated = time.perf_counter() - t0
    if cfg.views == "all":
        clock = _Clock(("range", "sweep", "diagnose"), progress)
        with clock.step("range"):
            found = search_region_all_views(rig, img, cfg)
        with clock.step("sweep"):
            result, sweep_timings = sweep_all_views(rig, img, cfg, found)
        result = dataclasses.replace(result, timings={"validate": validated}, match_timings=sweep_timings)
        return _finish(result, clock, t0)
    clock = _Clock(_SETUP_STEPS + _FRAME_STEPS, progress)
    views, pair, epipolar, rays, known = _geometry(rig, cfg, clock)
    with clock.step("rectify"):
        left, right = rectify_capture(pair, img)
        region = search_region(rig, pair, cfg, left, right, known=known, cached=True)
    setup = DepthSetup(rig=rig, config=cfg, views=views, pair=pair, region=region, epipolar=epipolar,
                       rays=rays, rig_range=known, timings={"validate": validated, **clock.timings})
    return _run_frame(setup, img, left, right, clock, t0)


# --------------------------------------------------------------------------- one set-up, many frames
def prepare_depth(rig: Rig, *, config: DepthConfig | None = None) -> DepthSetup:
    """The steps of a pair run that depend only on the rig and the configuration.

    The virtual cameras, the rectification maps, the common view and the disparity range are the same
    for every capture of a rig; :func:`run_depth_frame` then does the per-capture work. Without a
    configured depth range a sequence is searched over every depth at which the views share a field
    (source ``"rig"``), since one frame's content says nothing of the next's.

    Raises
    ------
    ConfigError, GeometryError
        As :func:`run_depth`, before any per-frame work; ``views="all"`` (the all-view sweep runs per
        capture).
    """
    cfg = validate_config(rig, config or DepthConfig())
    if cfg.views == "all":
        raise ConfigError("DepthConfig.views: expected a pair (i, j) for a sequence, got 'all' (the all-view sweep is "
                          "depth-only)")
    check_depth_memory(rig, cfg)
    clock = _Clock(_SETUP_STEPS, False)
    views, pair, epipolar, rays, known = _geometry(rig, cfg, clock)
    with clock.step("rectify"):
        region = search_region(rig, pair, cfg, known=known)
    return DepthSetup(rig=rig, config=cfg, views=views, pair=pair, region=region, epipolar=epipolar,
                      rays=rays, rig_range=known, timings=dict(clock.timings))


def run_depth_frame(setup: DepthSetup, image: Any, *, progress: bool | None = False,
                    band: PriorBand | None = None) -> DepthRun:
    """Recover depth from one capture with a prepared set-up (:func:`prepare_depth`).

    Parameters
    ----------
    setup : DepthSetup
    image : (H, W) or (H, W, 3) array
        The capture (RGB); its size must be the rig camera's.
    progress : bool, optional
        Show a progress bar per step (default: no).
    band : PriorBand, optional
        Each rectified left pixel's disparity band (a stream's temporal prior,
        :func:`~prismstereo.matching.temporal.prior_band` of an earlier frame's ``raw_disparity``), for a
        matcher of :data:`~prismstereo.matching.temporal.BANDED_MATCHERS`; None: the whole range.

    Returns
    -------
    DepthRun
        As :func:`run_depth`; the set-up steps cost (almost) nothing in its timings.

    Raises
    ------
    ImageError
        If the capture does not fit the rig.
    """
    t0 = time.perf_counter()
    img = validate_image(setup.rig, image)
    clock = _Clock(("rectify",) + _FRAME_STEPS, progress)
    timings = {"validate": time.perf_counter() - t0}
    with clock.step("rectify"):
        left, right = rectify_capture(setup.pair, img)
    frame_setup = dataclasses.replace(setup, timings=timings)
    return _run_frame(frame_setup, img, left, right, clock, t0, band)
