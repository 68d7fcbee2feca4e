"""The end-to-end depth pipeline: capture → virtual cameras → rectify → match → triangulate.

``run_depth(rig, image, config=DepthConfig(...))`` runs a registry of named stages (pandora style) over
one shared state and returns a :class:`DepthResult`; :func:`write_depth_outputs` writes the files of
docs/cli.md (``disparity.pfm``, ``disparity.png``, ``depth.pfm``, ``points.ply``, ``report.png``,
``run.json``) through a staging folder, so a failed run leaves nothing behind.

Everything the user can get wrong (image size, views, depth range, region of interest, method) is checked
in :func:`validate_inputs` before any heavy work.

The depth map is the world Z (mm, real camera frame) of the point triangulated at each pixel of the
RECTIFIED LEFT view; the point cloud holds the same points (valid ones only) in the world frame.
"""

from __future__ import annotations

import logging
import math
import platform
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from prismstereo import __version__
from prismstereo.config import Rig
from prismstereo.depth.triangulation import (
    Triangulation,
    rectified_to_world,
    triangulate_dlt,
    triangulate_exact,
    triangulate_midpoint,
)
from prismstereo.errors import ConfigError, GeometryError, ImageError

log = logging.getLogger(__name__)

__all__ = [
    "STAGES",
    "TRIANGULATIONS",
    "DepthConfig",
    "DepthResult",
    "DepthSetup",
    "default_views",
    "prepare_depth",
    "run_depth",
    "run_depth_frame",
    "validate_inputs",
]

#: triangulation methods: exact refractive rays, midpoint / DLT of the virtual pinholes, Q of the pair
TRIANGULATIONS = ("exact", "midpoint", "dlt", "q")
DEFAULT_DEPTH_RANGE_MM = (800.0, 5000.0)


@dataclass(frozen=True, kw_only=True)
class DepthConfig:
    """Resolved configuration of one depth run (all of it goes into ``run.json``).

    Attributes
    ----------
    method : str
        Matcher name (any of :func:`prismstereo.matching.available_matchers`).
    matcher_params : dict
        Keyword tuning parameters of the matcher.
    depth_range : (min, max) or None
        World depths to search, mm; the disparity search range follows from it (clipped to what the
        common view of the two sub-images allows). None: derived from the rig and the images
        (:func:`prismstereo.depth.search_range.auto_search_range`).
    roi : (x, y, w, h) or None
        Region of interest in the rectified left image, pixels; None = the whole view.
    views : (i, j) or None
        Faces to pair; None = the default pair (:func:`default_views`).
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
    refine_min_texture : float
        Mean squared horizontal gradient (grey levels²/px²) a window needs to be refined.
    min_confidence : float or None
        Keep only matches whose confidence (:func:`~prismstereo.depth.confidence.confident_matches`: ZNCC
        of the refined windows, 0 where the refinement could not confirm the match) is at least this.
        None keeps every match; the confidence of each point is in the outputs either way.
    speckle_fraction : float or None
        Remove connected patches of disparity (neighbours within 1 px) smaller than this fraction of the
        matched region (at least 20 px): isolated wrong matches (OpenCV ``filterSpeckles``). None keeps them.
    """

    method: str = "bpasw"
    matcher_params: dict[str, Any] = field(default_factory=dict)
    depth_range: tuple[float, float] | None = None
    roi: tuple[int, int, int, int] | None = None
    views: tuple[int, int] | None = None
    triangulation: str = "exact"
    calibration: str = "fit"
    use_filled: bool = False
    max_gap_mm: float | None = None
    refine: bool = True
    refine_radius: int = 5
    refine_min_texture: float = 0.01
    min_confidence: float | None = 0.5
    speckle_fraction: float | None = 0.001

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["depth_range"] = list(self.depth_range) if self.depth_range is not None else None
        d["roi"] = list(self.roi) if self.roi is not None else None
        d["views"] = list(self.views) if self.views is not None else None
        return d


@dataclass
class DepthResult:
    """Everything a depth run produced (arrays in the rectified LEFT view unless said otherwise).

    Attributes
    ----------
    config : DepthConfig
        With ``views`` resolved.
    rig : Rig
    image : (H, W, 3) uint8
        The capture.
    pair : RectifiedPair
        The rectification of the two views (see :mod:`prismstereo.rectify`).
    left, right : (h, w, 3) uint8
        Rectified sub-images.
    disparity : (h, w) float32
        Disparity used for triangulation, px, NaN invalid (outside the ROI too).
    disparity_filled : (h, w) float32
        The matcher's dense output (NaN outside the ROI).
    points : (h, w, 3) float64
        Triangulated world points, mm, NaN invalid.
    depth : (h, w) float32
        World Z of ``points``, mm, NaN invalid.
    gaps : (h, w) float32
        Ray gap of each point, mm (NaN for ``dlt``/``q`` and invalid).
    valid : (h, w) bool
    disparity_range : (min, max)
        Integer search range used.
    timings : dict
        Seconds per stage.
    roi_mask : (h, w) bool
        The pixels matched: region of interest ∩ the common view of the two faces in the depth range.
    confidence : (h, w) float32 or None
        Confidence in [0, 1] of each point (:func:`~prismstereo.depth.confidence.confident_matches`; 0 for
        every point without refinement), NaN where ``valid`` is False.
    stage_counts : dict
        Pixels left after each filtering stage (cross-checked matches, refined and confident, despeckled).
    accuracy : dict or None
        Filled by :func:`prismstereo.evaluation.depth_metrics.evaluate_depth` when ground truth is known
        (``ground_truth`` then holds the :class:`~prismstereo.evaluation.depth_metrics.DepthGroundTruth`).
    """

    config: DepthConfig
    rig: Rig
    image: np.ndarray
    pair: Any = None
    views: list[Any] = field(default_factory=list)
    left: np.ndarray | None = None
    right: np.ndarray | None = None
    disparity: np.ndarray | None = None
    disparity_filled: np.ndarray | None = None
    points: np.ndarray | None = None
    depth: np.ndarray | None = None
    gaps: np.ndarray | None = None
    valid: np.ndarray | None = None
    roi_mask: np.ndarray | None = None  # pixels matched: ROI ∩ common view of the two faces
    disparity_range: tuple[int, int] = (0, 0)
    timings: dict[str, float] = field(default_factory=dict)
    match_timings: dict[str, float] = field(default_factory=dict)
    accuracy: dict[str, Any] | None = None
    ground_truth: Any = None
    confidence: np.ndarray | None = None
    stage_counts: dict[str, int] = field(default_factory=dict)
    #: the depths searched (mm) and where they came from ("given", "rig", "rig+images")
    depth_range: tuple[float, float] = (0.0, 0.0)
    depth_range_source: str = "given"
    #: one-line warnings: the result may be unreliable (also logged and written to run.json)
    warnings: list[str] = field(default_factory=list)
    raw_disparity: np.ndarray | None = None
    raw_valid: np.ndarray | None = None

    @property
    def faces(self) -> tuple[int, int]:
        """(left face, right face) of the rectified pair."""
        return (int(self.pair.left_face), int(self.pair.right_face))

    def point_cloud(self) -> tuple[np.ndarray, np.ndarray]:
        """Valid points (N, 3) mm (world frame) and their colours (N, 3) uint8 from the rectified left view."""
        assert self.points is not None and self.valid is not None and self.left is not None
        pts = self.points[self.valid]
        cols = self.left[self.valid] if self.left.ndim == 3 else np.repeat(self.left[self.valid][:, None], 3, 1)
        return pts, cols.astype(np.uint8)

    def point_confidence(self) -> np.ndarray:
        """(h, w) float32 confidence of each point, NaN where ``valid`` is False (0 without refinement)."""
        assert self.valid is not None
        conf = self.confidence if self.confidence is not None else np.zeros(self.valid.shape, dtype=np.float32)
        return np.where(self.valid, conf, np.float32(np.nan)).astype(np.float32)

    def counts(self) -> dict[str, int]:
        assert self.valid is not None and self.roi_mask is not None and self.disparity_filled is not None
        region = self.roi_mask & self.pair_valid_left()
        return {
            "rectified_pixels": int(self.valid.size),
            "region_pixels": int(region.sum()),
            **self.stage_counts,
            "points": int(self.valid.sum()),
        }

    def pair_valid_left(self) -> np.ndarray:
        masks = self.pair.valid_masks()
        return np.asarray(masks[0], dtype=bool)

    def summary(self) -> dict[str, Any]:
        """The JSON-able summary written to ``run.json``."""
        return {
            "prismstereo": __version__,
            "versions": _versions(),
            "rig": self.rig.to_dict(),
            "config": self.config.to_dict(),
            "faces": {"left": self.faces[0], "right": self.faces[1]},
            "image_size": [int(self.image.shape[1]), int(self.image.shape[0])],
            "rectified_size": [int(self.left.shape[1]), int(self.left.shape[0])] if self.left is not None else None,
            "disparity_range": list(self.disparity_range),
            "depth_range_mm": [round(float(v), 1) for v in self.depth_range],
            "depth_range_source": self.depth_range_source,
            "warnings": list(self.warnings),
            "baseline_mm": float(getattr(self.pair, "baseline_mm", float("nan"))),
            "timings_s": {k: round(v, 4) for k, v in self.timings.items()},
            "matcher_timings_s": {k: round(v, 4) for k, v in self.match_timings.items()},
            "counts": self.counts(),
            "accuracy": self.accuracy,
        }


def _versions() -> dict[str, str]:
    import cv2
    import numba
    import scipy

    return {"python": platform.python_version(), "numpy": np.__version__, "scipy": scipy.__version__,
            "opencv": cv2.__version__, "numba": numba.__version__}


# --------------------------------------------------------------------------- validation
def default_views(rig: Rig) -> tuple[int, int]:
    """The pair of faces used when none is given: (1, 0) for a bi-prism (left, right), else (0, 1)."""
    return (1, 0) if rig.prism.faces == 2 else (0, 1)


def validate_image(rig: Rig, image: Any) -> np.ndarray:
    """Check that ``image`` is a capture of ``rig``: H×W or H×W×3 of the rig's size; returns RGB uint8."""
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3):
        raise ImageError(f"expected an H×W or H×W×3 capture, got shape {img.shape}")
    w, h = rig.camera.width, rig.camera.height
    if img.shape[0] != h or img.shape[1] != w:
        raise ImageError(f"expected a {w}×{h} capture (the rig's camera), got {img.shape[1]}×{img.shape[0]}")
    if img.dtype == np.uint16:
        img = (img // 257).astype(np.uint8)
    elif img.dtype != np.uint8:
        if img.dtype.kind != "f" or not np.isfinite(img).all():
            raise ImageError(f"expected a uint8 or finite float capture, got dtype {img.dtype}")
        img = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    return np.ascontiguousarray(img)


def validate_inputs(rig: Rig, image: Any, config: DepthConfig) -> tuple[np.ndarray, DepthConfig]:
    """Check everything a user can get wrong before any heavy work; return the image and resolved config.

    Raises
    ------
    ImageError, ConfigError, GeometryError
        One-line "expected …, got …" messages.
    """
    from prismstereo.matching import available_matchers

    img = validate_image(rig, image)
    if config.method.lower() not in available_matchers():
        raise ConfigError(f"--method: expected one of {', '.join(available_matchers())}, got {config.method!r}")
    if config.triangulation not in TRIANGULATIONS:
        raise ConfigError(f"--triangulation: expected one of {', '.join(TRIANGULATIONS)}, "
                          f"got {config.triangulation!r}")
    if config.calibration not in ("fit", "thesis"):
        raise ConfigError(f"calibration: expected 'fit' or 'thesis', got {config.calibration!r}")
    depth_range: tuple[float, float] | None = None
    if config.depth_range is not None:
        zmin, zmax = (float(v) for v in config.depth_range)
        back = rig.prism.back_distance
        if not (math.isfinite(zmin) and math.isfinite(zmax)) or zmin <= back or zmax <= zmin:
            raise ConfigError(f"--depth-range: expected MIN,MAX mm with {back:g} (the prism's back plane) < MIN "
                              f"< MAX, got {zmin:g},{zmax:g}")
        depth_range = (zmin, zmax)
    views = config.views if config.views is not None else default_views(rig)
    if len(views) != 2:
        raise ConfigError(f"--views: expected two face indices I,J, got {list(views)}")
    n = rig.prism.faces
    for v in views:
        if not 0 <= int(v) < n:
            raise ConfigError(f"--views: expected face indices in 0..{n - 1}, got {list(views)}")
    if int(views[0]) == int(views[1]):
        raise ConfigError(f"--views: expected two different faces, got {list(views)}")
    if config.roi is not None:
        x, y, w, h = config.roi
        if w <= 0 or h <= 0 or x < 0 or y < 0:
            raise ConfigError(f"--roi: expected x,y,w,h with x, y >= 0 and w, h > 0, got {list(config.roi)}")
    if config.min_confidence is not None and not 0.0 <= config.min_confidence <= 1.0:
        raise ConfigError(f"--min-confidence: expected a number in [0, 1] (0 keeps every match), "
                          f"got {config.min_confidence!r}")
    if config.max_gap_mm is not None and not config.max_gap_mm > 0:
        raise ConfigError(f"max_gap_mm: expected a positive number, got {config.max_gap_mm!r}")
    resolved = DepthConfig(**{**asdict(config), "views": (int(views[0]), int(views[1])),
                              "method": config.method.lower(), "depth_range": depth_range})
    return img, resolved


# --------------------------------------------------------------------------- stages
Stage = Callable[[DepthResult], None]
#: ordered registry of pipeline stages: name -> function(state)
STAGES: dict[str, Stage] = {}


def register_stage(name: str) -> Callable[[Stage], Stage]:
    def deco(fn: Stage) -> Stage:
        STAGES[name] = fn
        return fn

    return deco


@register_stage("cameras")
def _stage_cameras(st: DepthResult) -> None:
    from prismstereo.cameras import calibrate_rig

    if st.views:  # prepared once for many frames (prepare_depth)
        return
    st.views = calibrate_rig(st.rig, method=st.config.calibration)


def common_view(pair: Any, depth_min_mm: float, depth_max_mm: float, *, n_depths: int = 12
                ) -> tuple[np.ndarray, tuple[int, int]]:
    """Where the two rectified views of a pair overlap for world depths in a range, and its disparities.

    The ray of every valid rectified-left pixel is followed to ``n_depths`` world depths between the
    bounds (geometric steps); a sample counts where its point projects into the valid region of the
    rectified right image (thesis Eq. 7.22: d = f λ / Z along the rectified axis).

    Returns
    -------
    mask : (h, w) bool
        Left pixels that see a point of the right view at some depth in the range.
    (min_disp, max_disp) : ints
        Floor / ceil of the disparities of those samples: the search range clipped to the common view.

    Raises
    ------
    GeometryError
        If no sample is seen by both views: the views do not overlap at these depths.
    """
    vl, vr = (np.asarray(m, dtype=bool) for m in pair.valid_masks())
    ys, xs = np.nonzero(vl)
    mask = np.zeros(vl.shape, dtype=bool)
    if ys.size == 0:
        raise GeometryError("expected a rectified left view with valid pixels, got none")
    px = np.stack([xs, ys], axis=1).astype(np.float64)
    K = np.asarray(pair.K, dtype=np.float64)
    R = np.asarray(pair.R_left, dtype=np.float64)
    C = np.asarray(pair.C_left, dtype=np.float64)
    rays = np.concatenate([px, np.ones((px.shape[0], 1))], axis=1) @ np.linalg.inv(K).T @ R  # world dirs
    seen = np.zeros(ys.size, dtype=bool)
    lo, hi = np.inf, -np.inf
    for z in np.geomspace(depth_min_mm, depth_max_mm, n_depths):
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (z - C[2]) / rays[:, 2]
        X = C + np.where(s > 0, s, np.nan)[:, None] * rays
        xr = np.asarray(pair.project(X, "right"), dtype=np.float64)
        ok = np.all(np.isfinite(xr), axis=1)
        ci = np.rint(np.where(ok, xr[:, 0], -1)).astype(np.int64)
        ri = np.rint(np.where(ok, xr[:, 1], -1)).astype(np.int64)
        ok &= (ci >= 0) & (ci < vr.shape[1]) & (ri >= 0) & (ri < vr.shape[0])
        ok[ok] &= vr[ri[ok], ci[ok]]
        if ok.any():
            d = px[ok, 0] - xr[ok, 0]
            lo, hi = min(lo, float(d.min())), max(hi, float(d.max()))
        seen |= ok
    if not seen.any():
        raise GeometryError(f"expected faces {pair.left_face} and {pair.right_face} to see a common part of the "
                            f"scene at {depth_min_mm:g}–{depth_max_mm:g} mm, got views that do not overlap "
                            "(choose other --views or --depth-range)")
    mask[ys[seen], xs[seen]] = True
    return mask, (max(0, int(np.floor(lo))), int(np.ceil(hi)))


@register_stage("rectify")
def _stage_rectify(st: DepthResult) -> None:
    try:
        from prismstereo.rectify import rectify_pair
    except ImportError:  # the package may not re-export it
        from prismstereo.rectify.rectification import rectify_pair

    if st.pair is not None:  # geometry prepared once for many frames (prepare_depth): only warp the capture
        left, right = st.pair.rectify_images(st.image)
        st.left, st.right = np.asarray(left), np.asarray(right)
        return
    assert st.config.views is not None
    by_face = {v.face: v for v in st.views}
    a, b = st.config.views
    st.pair = rectify_pair(st.rig, by_face[a], by_face[b])
    left, right = st.pair.rectify_images(st.image)
    st.left, st.right = np.asarray(left), np.asarray(right)
    width = st.left.shape[1]
    if st.config.depth_range is None:
        from prismstereo.depth.search_range import auto_search_range

        found = auto_search_range(st.pair, st.rig.prism.back_distance, st.left, st.right)
        st.warnings.extend(found.warnings)
        zmin, zmax = found.depth_mm
        common, _ = common_view(st.pair, zmin, zmax)
        lo, hi = found.disparity_px
        st.depth_range_source = found.source
    else:
        zmin, zmax = st.config.depth_range
        common, (lo, hi) = common_view(st.pair, zmin, zmax)
    st.depth_range = (zmin, zmax)
    hi = min(hi, width - 1)
    lo = min(lo, hi)
    st.disparity_range = (lo, hi)
    h = st.left.shape[0]
    mask = np.zeros((h, width), dtype=bool)
    if st.config.roi is not None:
        x, y, w_, h_ = st.config.roi
        if x >= width or y >= h:
            raise ConfigError(f"--roi: expected a region inside the {width}×{h} rectified left view, "
                              f"got {list(st.config.roi)}")
        mask[y:y + h_, x:x + w_] = True
    else:
        mask[:] = True
    st.roi_mask = mask & common


def _roi_box(mask: np.ndarray) -> tuple[int, int, int, int]:
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    if rows.size == 0:
        raise GeometryError("expected a non-empty region of the rectified left view to match, got none")
    return int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1


@register_stage("match")
def _stage_match(st: DepthResult) -> None:
    from prismstereo.matching import match

    assert st.left is not None and st.right is not None and st.roi_mask is not None
    lo, hi = st.disparity_range
    r0, r1, c0, c1 = _roi_box(st.roi_mask)
    # the right image must reach hi pixels to the left of the region
    ca = max(0, c0 - hi)
    left = st.left[r0:r1, ca:c1]
    right = st.right[r0:r1, ca:c1]
    hi_eff = min(hi, left.shape[1] - 1)
    lo_eff = min(lo, hi_eff)
    params = dict(st.config.matcher_params)
    res = match(left, right, max_disp=hi_eff, min_disp=lo_eff, method=st.config.method, **params)
    raw = res.disparity_raw if res.disparity_raw is not None else np.where(res.valid, res.disparity, np.nan)
    h, w = st.left.shape[:2]
    disp = np.full((h, w), np.nan, dtype=np.float32)
    dense = np.full((h, w), np.nan, dtype=np.float32)
    disp[r0:r1, ca:c1] = raw
    dense[r0:r1, ca:c1] = res.disparity
    out = ~st.roi_mask
    disp[out] = np.nan
    dense[out] = np.nan
    # a match must land inside the right view's valid region
    vr = np.asarray(st.pair.valid_masks()[1], dtype=bool)
    st.disparity_filled = dense
    src = dense if st.config.use_filled else disp
    ys, xs = np.nonzero(np.isfinite(src))
    xr = np.rint(xs - src[ys, xs]).astype(np.int64)
    inside = (xr >= 0) & (xr < w)
    inside[inside] &= vr[ys[inside], xr[inside]]
    bad = np.zeros((h, w), dtype=bool)
    bad[ys[~inside], xs[~inside]] = True
    src = src.copy()
    src[bad] = np.nan
    st.disparity = src
    st.match_timings = dict(res.timings)
    st.stage_counts["matched"] = int(np.isfinite(src).sum())
    st.raw_disparity = disp


def _real_pixels(st: DepthResult, ys: np.ndarray, xs: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    left_px = np.stack([xs, ys], axis=1).astype(np.float64)
    right_px = np.stack([xs - d, ys], axis=1).astype(np.float64)
    return st.pair.rectified_to_real(left_px, "left"), st.pair.rectified_to_real(right_px, "right")


def triangulate_matches(st: DepthResult, method: str, ys: np.ndarray, xs: np.ndarray, d: np.ndarray,
                        *, views: list[Any] | None = None) -> Triangulation:
    """Triangulate rectified-left matches (x, y) ↔ (x − d, y) of a finished run with ``method``.

    ``views`` overrides the virtual cameras used by ``midpoint`` and ``dlt`` (e.g. the thesis's
    construction while the rectification used the fitted model).
    """
    n = ys.size
    if method == "q":
        # thesis Eq. 7.23 on the listed (x, y, d), then from the rectified left frame to the world
        Q = np.asarray(st.pair.Q, dtype=np.float64)
        hom = np.stack([xs.astype(np.float64), ys.astype(np.float64), d, np.ones(n)], axis=1) @ Q.T
        with np.errstate(divide="ignore", invalid="ignore"):
            pts_rect = hom[:, :3] / hom[:, 3:4]
        pts = rectified_to_world(pts_rect, st.pair.R_left, st.pair.C_left)
        ok = np.all(np.isfinite(pts), axis=1) & (d > 0)
        return Triangulation(np.where(ok[:, None], pts, np.nan), np.full(n, np.nan), ok)
    pl, pr = _real_pixels(st, ys, xs, d)
    fl, fr = st.faces
    if method == "exact":
        return triangulate_exact(st.rig, pl, pr, faces=(fl, fr))
    by_face = {v.face: v for v in (views if views is not None else st.views)}
    cam_l, cam_r = by_face[fl].camera, by_face[fr].camera
    finite = np.all(np.isfinite(pl), axis=1) & np.all(np.isfinite(pr), axis=1)
    pl0, pr0 = np.where(finite[:, None], pl, 0.0), np.where(finite[:, None], pr, 0.0)
    if method == "midpoint":
        ol, dl = cam_l.unproject(pl0)
        orr, dr = cam_r.unproject(pr0)
        tri = triangulate_midpoint(ol, dl, orr, dr)
        ok = tri.valid & finite
        return Triangulation(np.where(ok[:, None], tri.points, np.nan), np.where(ok, tri.gaps, np.nan), ok)
    if method == "dlt":
        ul = cam_l.undistort_pixels(pl0) @ cam_l.K[:2, :2].T + cam_l.K[:2, 2]
        ur = cam_r.undistort_pixels(pr0) @ cam_r.K[:2, :2].T + cam_r.K[:2, 2]
        pts = triangulate_dlt(cam_l.P, cam_r.P, ul, ur)
        ok = finite & np.all(np.isfinite(pts), axis=1)
        return Triangulation(np.where(ok[:, None], pts, np.nan), np.full(n, np.nan), ok)
    raise ConfigError(f"triangulation: expected one of {', '.join(TRIANGULATIONS)}, got {method!r}")


@register_stage("refine")
def _stage_refine(st: DepthResult) -> None:
    from prismstereo.depth.confidence import confident_matches

    assert st.left is not None and st.right is not None and st.disparity is not None
    if not st.config.refine:
        st.confidence = np.where(np.isfinite(st.disparity), np.float32(0.0), np.float32(np.nan))
        return
    vl, vr = st.pair.valid_masks()
    st.disparity, st.confidence = confident_matches(
        st.left, st.right, st.disparity, radius=st.config.refine_radius, min_texture=st.config.refine_min_texture,
        min_confidence=st.config.min_confidence, valid_left=vl, valid_right=vr)
    st.stage_counts["refined"] = int(np.isfinite(st.disparity).sum())


@register_stage("speckles")
def _stage_speckles(st: DepthResult) -> None:
    from prismstereo.depth.confidence import remove_speckles

    if st.config.speckle_fraction is None:
        return
    assert st.disparity is not None and st.roi_mask is not None
    size = max(20, int(st.config.speckle_fraction * int(st.roi_mask.sum())))
    st.disparity = remove_speckles(st.disparity, max_size=size)
    st.stage_counts["despeckled"] = int(np.isfinite(st.disparity).sum())


@register_stage("triangulate")
def _stage_triangulate(st: DepthResult) -> None:
    assert st.disparity is not None and st.left is not None
    h, w = st.disparity.shape
    ys, xs = np.nonzero(np.isfinite(st.disparity))
    d = st.disparity[ys, xs].astype(np.float64)
    tri = triangulate_matches(st, st.config.triangulation, ys, xs, d)
    ok = tri.valid.copy()
    if st.config.max_gap_mm is not None:
        ok &= ~(tri.gaps > st.config.max_gap_mm)
    ok &= tri.points[:, 2] > st.rig.prism.back_distance
    points = np.full((h, w, 3), np.nan)
    gaps = np.full((h, w), np.nan, dtype=np.float32)
    points[ys[ok], xs[ok]] = tri.points[ok]
    gaps[ys[ok], xs[ok]] = tri.gaps[ok]
    valid = np.zeros((h, w), dtype=bool)
    valid[ys[ok], xs[ok]] = True
    st.points, st.gaps, st.valid = points, gaps, valid
    st.depth = np.where(valid, points[..., 2], np.nan).astype(np.float32)
    if st.confidence is not None:
        st.confidence = np.where(valid, st.confidence, np.float32(np.nan)).astype(np.float32)


@register_stage("diagnose")
def _stage_diagnose(st: DepthResult) -> None:
    from prismstereo.depth.search_range import depth_warnings

    c = st.counts()
    st.warnings.extend(depth_warnings(
        points=c["points"], region_pixels=c["region_pixels"], matched=c.get("matched", 0),
        confident=c.get("refined"), disparity=st.raw_disparity, valid=None,
        disparity_range=st.disparity_range, depth_range=st.depth_range))


def _progress(total: int) -> Any:
    if not sys.stderr.isatty():
        return None
    try:
        from tqdm import tqdm
    except ImportError:  # pragma: no cover
        return None
    return tqdm(total=total, desc="depth", unit="stage", leave=False)


def run_depth(rig: Rig, image: Any, *, config: DepthConfig | None = None,
              progress: bool | None = None) -> DepthResult:
    """Recover depth from one prism capture.

    Parameters
    ----------
    rig : Rig
    image : (H, W) or (H, W, 3) array
        The capture (RGB); its size must be the rig camera's.
    config : DepthConfig, optional
    progress : bool, optional
        Show a progress bar per stage; default: only when stderr is a terminal.

    Returns
    -------
    DepthResult

    Raises
    ------
    ImageError, ConfigError, GeometryError, MatchingError
        Bad input, found before any heavy work where possible.
    """
    t0 = time.perf_counter()
    img, cfg = validate_inputs(rig, image, config or DepthConfig())
    st = DepthResult(config=cfg, rig=rig, image=img)
    st.timings["validate"] = time.perf_counter() - t0
    return _run_stages(st, t0, progress)


def _run_stages(st: DepthResult, t0: float, progress: bool | None) -> DepthResult:
    bar = _progress(len(STAGES)) if progress is not False else None
    try:
        for name, stage in STAGES.items():
            if bar is not None:
                bar.set_description(f"depth: {name}")
            t = time.perf_counter()
            stage(st)
            st.timings[name] = time.perf_counter() - t
            log.info("stage %s: %.2f s", name, st.timings[name])
            if bar is not None:
                bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    st.timings["total"] = time.perf_counter() - t0
    for line in st.warnings:
        log.warning("%s", line)
    return st


# --------------------------------------------------------------------------- one set-up, many frames
@dataclass(frozen=True, eq=False)
class DepthSetup:
    """The per-rig part of a depth run, computed once and shared by every frame of a sequence (batch).

    Attributes
    ----------
    rig : Rig
    config : DepthConfig
        Resolved (views filled in).
    views : list of VirtualView
        The virtual cameras (stage ``cameras``).
    pair : RectifiedPair
        Rectification of the chosen pair, with its remap tables (stage ``rectify``).
    roi_mask : (h, w) bool
        Pixels matched in the rectified left view: region of interest ∩ common view in the depth range.
    disparity_range : (min, max)
        Integer disparity search range.
    timings : dict
        Seconds spent on the set-up stages.
    depth_range : (min, max)
        Depths searched, mm.
    depth_range_source : str
        ``"given"`` (the configuration's) or ``"rig"``: without a configured range a sequence is searched over
        every depth at which the views share a field, since one frame's content says nothing of the next's.
    """

    rig: Rig
    config: DepthConfig
    views: list[Any]
    pair: Any
    roi_mask: np.ndarray
    disparity_range: tuple[int, int]
    timings: dict[str, float] = field(default_factory=dict)
    depth_range: tuple[float, float] = (0.0, 0.0)
    depth_range_source: str = "given"


def prepare_depth(rig: Rig, *, config: DepthConfig | None = None) -> DepthSetup:
    """Run the stages of :func:`run_depth` that depend only on the rig and the configuration.

    The virtual cameras, the rectification maps, the common view and the disparity range are the same
    for every capture of a rig; :func:`run_depth_frame` then does the per-capture work.
    ``run_depth_frame(prepare_depth(rig, config=c), image)`` gives the same arrays as
    ``run_depth(rig, image, config=c)``.

    Raises
    ------
    ConfigError, GeometryError
        As :func:`run_depth`, before any per-frame work.
    """
    # the configuration checks of validate_inputs do not look at the pixels: a blank capture stands in
    blank = np.zeros((rig.camera.height, rig.camera.width, 3), dtype=np.uint8)
    _, cfg = validate_inputs(rig, blank, config or DepthConfig())
    st = DepthResult(config=cfg, rig=rig, image=blank)
    timings = {}
    for name in ("cameras", "rectify"):
        t = time.perf_counter()
        STAGES[name](st)
        timings[name] = time.perf_counter() - t
    assert st.roi_mask is not None
    # the blank stand-in cannot narrow the range by matching: the rig's whole range is searched, and the
    # "not a capture" warning the blank image raised says nothing about the frames to come
    source = "given" if cfg.depth_range is not None else "rig"
    return DepthSetup(rig=rig, config=st.config, views=list(st.views), pair=st.pair, roi_mask=st.roi_mask,
                      disparity_range=st.disparity_range, timings=timings, depth_range=st.depth_range,
                      depth_range_source=source)


def run_depth_frame(setup: DepthSetup, image: Any, *, progress: bool | None = False) -> DepthResult:
    """Recover depth from one capture with a prepared set-up (:func:`prepare_depth`).

    Parameters
    ----------
    setup : DepthSetup
    image : (H, W) or (H, W, 3) array
        The capture (RGB); its size must be the rig camera's.
    progress : bool, optional
        Show a progress bar per stage (default: no).

    Returns
    -------
    DepthResult
        As :func:`run_depth`; the set-up stages cost (almost) nothing in its timings.

    Raises
    ------
    ImageError
        If the capture does not fit the rig.
    """
    t0 = time.perf_counter()
    img = validate_image(setup.rig, image)
    st = DepthResult(config=setup.config, rig=setup.rig, image=img, views=list(setup.views), pair=setup.pair,
                     roi_mask=setup.roi_mask, disparity_range=setup.disparity_range,
                     depth_range=setup.depth_range, depth_range_source=setup.depth_range_source)
    st.timings["validate"] = time.perf_counter() - t0
    return _run_stages(st, t0, progress)
