"""The plane-label pipeline shared by the two-view ``coop`` and the global multi-view method.

Both methods build the same state, segments with candidate disparity planes (:class:`PlaneLabels`), from their
own front end (initial maps, segmentation, plane fits: thesis §5.1-§6.1 for two views, §7.1.2 for several),
and then run one sequence of named steps (:data:`STEP_NAMES`) on it:

``optimise``      cooperative optimisation of the plane labels (Eqs. 6.18-6.25 / 7.15-7.18)
``refit``         segments sharing a plane refitted together, offered as candidates, the optimisation resumed
``bpasw_planes``  planes fitted to the cross-checked BPASW map (and their merged clusters, group refits) offered
``sweep``         planes of a global sweep offered to the segments of highest slanted-window cost
``group_moves``   sweep candidates and planes across segment boundaries moved over whole regions at once
``fine``          finer segments along plane boundaries may take a neighbour's plane where the evidence agrees
``boundary``      pixels near boundaries take a nearby segment's plane where the BPASW cost clearly prefers it
``occlusion``     pixels whose match reliably sees a farther surface take the background plane
``curved``        segments whose evidence shows a curved surface take the quadric fitted to it
``median``        colour-weighted median that only overrides disparities it moves by more than 1 px
``fallback``      segments that failed the plane support test take the local matcher's map

A segment keeps a move of ``sweep`` and ``group_moves`` only where its own data term is lower under the new
plane (:func:`unsupported_moves`): the smoothness term and the neighbours' energies may propose a move, the
segment's own pixels must support it.

Each step is configured by one small frozen dataclass (:class:`StepParams` holds one of each) whose
constructor validates it, so a bad value fails before any image is read. What differs between the two
methods (the evidence each step reads: one pair, or all views fused on the unit grid) is behind
:class:`Evidence`, which each method implements once.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol, TypeVar

import numpy as np
import numpy.typing as npt
from numba import njit

from prismstereo.errors import ConfigError
from prismstereo.matching.coop.cooperative import (
    CoopMemo,
    CoopParams,
    SegmentGraph,
    expand_planes,
    interpolated_cost,
    neighbour_plane_candidates,
    slope_level,
)
from prismstereo.matching.coop.refine import (
    DataTerm,
    boundary_pixel_planes,
    bpasw_candidate_rounds,
    refine_fine_segments,
)
from prismstereo.matching.local.selection import weighted_median_filter
from prismstereo.matching.segments.planes import PlaneParams, SegmentIndex, curved_segment_surfaces, render_planes
from prismstereo.matching.segments.segmentation import SegmentationParams

__all__ = ["STEP_NAMES", "BoundaryParams", "BpaswPlanesParams", "CurvedParams", "Evidence", "FallbackParams",
           "FineParams", "GroupMovesParams", "MedianParams", "OcclusionParams", "PlaneLabels", "RefitParams",
           "StepParams", "SweepParams", "coerce_params", "run_steps", "unsupported_moves"]

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
I32 = npt.NDArray[np.int32]
I64 = npt.NDArray[np.int64]
B = npt.NDArray[np.bool_]

STEP_NAMES = ("optimise", "refit", "bpasw_planes", "sweep", "group_moves", "fine", "boundary", "occlusion",
              "curved", "median", "fallback")


def _need(ok: bool, what: str, value: object) -> None:
    """Raise :class:`ConfigError` unless ``ok``; implementation helper with no thesis equation of its own."""
    if not ok:
        raise ConfigError(f"expected {what}, got {value!r}")


@dataclass(frozen=True, kw_only=True)
class RefitParams:
    """``refit``: rounds of joint refitting of the segments that share a plane (0 = off)."""

    rounds: int = 1

    def __post_init__(self) -> None:
        """Validate the fields; implementation helper with no thesis equation of its own."""
        _need(isinstance(self.rounds, int) and self.rounds >= 0, "refit.rounds an integer >= 0", self.rounds)


@dataclass(frozen=True, kw_only=True)
class BpaswPlanesParams:
    """``bpasw_planes``: 1 = planes fitted per segment to the cross-checked BPASW map, 2 = also their merged
    clusters, 3 = also planes refitted over groups of segments sharing a plane (0 = off)."""

    rounds: int = 3

    def __post_init__(self) -> None:
        """Validate the fields; implementation helper with no thesis equation of its own."""
        _need(isinstance(self.rounds, int) and 0 <= self.rounds <= 3, "bpasw_planes.rounds in 0..3", self.rounds)


@dataclass(frozen=True, kw_only=True)
class SweepParams:
    """``sweep``: the ``frac`` of the segments (of at least ``min_px`` pixels) whose plane has the highest mean
    slanted-window cost (sampled every ``step`` px, window every ``dilation`` px) are offered the ``keep``
    cheapest planes of a sweep over the whole range x the vertical slopes ``slopes``; with ``row_box`` >= 0 the
    data term on their pixels is the pixel cost boxed along the row only (radius ``row_box``); ``neighbours``
    lets segments take their neighbours' candidates. With ``data_check`` a segment keeps its move only where its
    own data term supports it (:func:`unsupported_moves`, over at least ``check_cover`` of its pixels).
    ``frac`` 0 = off."""

    frac: float = 0.5
    slopes: tuple[float, ...] = (-1.0, -0.5, 0.0, 0.5, 1.0)
    keep: int = 2
    min_px: int = 20
    step: int = 4
    dilation: int = 3
    row_box: int = 1
    neighbours: bool = False
    data_check: bool = True
    check_cover: float = 0.5

    def __post_init__(self) -> None:
        """Validate the fields; implementation helper with no thesis equation of its own."""
        _need(0.0 <= float(self.frac) <= 1.0, "sweep.frac in [0, 1]", self.frac)
        _need(len(self.slopes) > 0, "sweep.slopes non-empty", self.slopes)
        _need(self.keep >= 1 and self.min_px >= 1 and self.step >= 1 and self.dilation >= 1,
              "sweep.keep, min_px, step, dilation >= 1", (self.keep, self.min_px, self.step, self.dilation))
        _need(self.row_box >= -1, "sweep.row_box >= -1 (-1 = off)", self.row_box)
        _need(0.0 <= self.check_cover <= 1.0, "sweep.check_cover in [0, 1]", self.check_cover)
        object.__setattr__(self, "slopes", tuple(float(b) for b in self.slopes))


@dataclass(frozen=True, kw_only=True)
class GroupMovesParams:
    """``group_moves``: sweep candidates and planes held across a segment boundary may move a connected region
    of segments at once (:func:`~prismstereo.matching.coop.cooperative.expand_planes`); with ``data_check`` a
    segment keeps a move of this step only where its own data term supports it (:func:`unsupported_moves`,
    over at least ``check_cover`` of its pixels)."""

    enabled: bool = True
    data_check: bool = True
    check_cover: float = 0.5

    def __post_init__(self) -> None:
        """Validate the fields; implementation helper with no thesis equation of its own."""
        _need(0.0 <= self.check_cover <= 1.0, "group_moves.check_cover in [0, 1]", self.check_cover)


@dataclass(frozen=True, kw_only=True)
class FineParams:
    """``fine``: one level per ``(hr, min_region)`` of ``levels``, each a mean shift of that range radius inside
    the previous level's segments; fine segments touching another plane resume the optimisation and keep a move
    only when at least ``check`` more of their evidence pixels lie within 1 px of the new plane than of the old
    (0: not fewer, the evidence only vetoes; None = keep every move). ``levels`` empty = off."""

    levels: tuple[tuple[float, int], ...] = ((3.0, 10),)
    check: int | None = 0

    def __post_init__(self) -> None:
        """Validate the fields; implementation helper with no thesis equation of its own."""
        lv = tuple((float(h), int(m)) for h, m in self.levels)
        _need(all(h > 0 and m >= 1 for h, m in lv), "fine.levels of (hr > 0, min_region >= 1)", self.levels)
        _need(self.check is None or (isinstance(self.check, int) and self.check >= 0), "fine.check >= 0 or None",
              self.check)
        object.__setattr__(self, "levels", lv)


@dataclass(frozen=True, kw_only=True)
class BoundaryParams:
    """``boundary``: a pixel may take the plane of a segment within ``radius`` px (its planes fitted to the
    BPASW map and to the initial map too with ``bplanes`` 1 / 2) where the BPASW aggregated cost is lower than
    its own plane's by more than ``margin`` and the plane lies within ``tol`` px of the reliable BPASW map;
    ``agree`` 1: the initial map must agree there too, 2: only for moves to a larger disparity. ``radius`` 0 =
    off."""

    radius: int = 5
    margin: float = 5.0
    tol: float = 1.0
    agree: int = 0
    bplanes: int = 2

    def __post_init__(self) -> None:
        """Validate the fields; implementation helper with no thesis equation of its own."""
        _need(self.radius >= 0 and self.tol >= 0 and self.agree in (0, 1, 2) and self.bplanes in (0, 1, 2),
              "boundary.radius >= 0, tol >= 0, agree and bplanes in 0..2",
              (self.radius, self.tol, self.agree, self.bplanes))


@dataclass(frozen=True, kw_only=True)
class OcclusionParams:
    """``occlusion``: a pixel whose match reliably sees a surface farther by more than ``tol`` px takes the
    background plane; one whose own BPASW match is reliable at a smaller disparity takes instead the plane
    within ``rematch_radius`` px closest to it (0 = never)."""

    enabled: bool = True
    tol: float = 1.0
    rematch_radius: int = 5

    def __post_init__(self) -> None:
        """Validate the fields; implementation helper with no thesis equation of its own."""
        _need(self.tol >= 0 and self.rematch_radius >= 0, "occlusion.tol, rematch_radius >= 0",
              (self.tol, self.rematch_radius))


@dataclass(frozen=True, kw_only=True)
class MedianParams:
    """``median``: radius of the colour-weighted median that only overrides disparities it moves by more than
    1 px, so subpixel plane disparities are kept (0 = off)."""

    radius: int = 4

    def __post_init__(self) -> None:
        """Validate the fields; implementation helper with no thesis equation of its own."""
        _need(self.radius >= 0, "median.radius >= 0", self.radius)


@dataclass(frozen=True, kw_only=True)
class FallbackParams:
    """``fallback``: the segments that failed the plane support test take the local matcher's map, and so do the
    segments whose final disparity nothing of their own supports:

    * sparse: segments of at least ``min_share`` of the image whose evidence covers less than ``min_coverage`` of
      their pixels (their plane is extrapolated over most of the segment), unless ``min_coverage`` of them lie
      within ``coverage_reach`` px (a square window) of an evidence pixel that agrees with their map within
      ``tol`` (scattered evidence the plane agrees with: it is interpolated there, not extrapolated; 0 = off);
    * bare: segments of at least ``bare_share`` of the image whose evidence covers less than ``bare_coverage`` of
      them (their plane comes from the neighbours and the smoothness term alone; ``bare_coverage`` 0 = off);
    * contradicted: segments of at least ``against_pixels`` whose evidence covers at least ``against_coverage``
      of them and agrees within ``tol`` px with less than ``max_agreement`` of it (the optimisation moved them
      against nearly all of their evidence; ``max_agreement`` 0 = off).

    Sizes are shares of the image, so the rules mean the same at any resolution. ``candidates`` are the maps such a
    segment may take (``"bpasw"``: the local matcher's, ``"sgm"``: the ``sgm`` matcher's, ``"plane"``: its own final
    map): it takes the first unless another's evidence (the pixels its matcher's left-right check keeps; for
    ``plane`` the evidence pixels within ``tol`` of it) covers a larger share of the segment's replaced pixels by
    more than ``margin``; then the best-covered one. With both ``bpasw`` and ``sgm`` among them, a segment whose
    BPASW cost is flat (median peak ratio of its replaced pixels below ``flat_ratio``,
    :mod:`~prismstereo.matching.coop.flatcost`) takes ``sgm``'s map when ``sgm``'s check keeps at least
    ``flat_min_support`` of those pixels and no less than BPASW's share minus ``flat_support_margin``
    (``flat_ratio`` 0 = off). When the views differ by a systematic brightness offset of at least
    ``radiometry_offset`` grey levels that the pair's own compensation leaves in place
    (:class:`~prismstereo.matching.coop.radiometry.RadiometryParams` ``min_offset``), the ``bpasw`` map a
    segment takes is that of the offset-compensated pair (one more BPASW volume); the evidence of the choice
    (the checks, the peak ratio) stays that of the pair the front end matched (0 = off). With both ``bpasw``
    and ``sgm`` among the candidates, an outvoted segment joins them too: one of at least ``outvoted_min_size``
    of the image where at least ``outvoted_share`` of its pixels have both matchers' checks holding, their maps
    within 1 px of each other and both more than ``outvoted_tol`` px from the segment's final map
    (:func:`~prismstereo.matching.coop.flatcost.outvoted_segments`; ``outvoted_tol`` 0 = off). With both
    among the candidates, a segment whose replaced pixels cover at least ``contradicted_min_size`` of the image
    takes ``sgm``'s map when on at least ``contradicted_share`` of them both matchers' checks hold and the two maps
    lie more than 1 px apart (:func:`~prismstereo.matching.coop.flatcost.contradicted_segments`;
    ``contradicted_share`` 0 = off)."""

    enabled: bool = True
    min_coverage: float = 0.4
    min_share: float = 0.03
    coverage_reach: int = 2
    bare_coverage: float = 0.05
    bare_share: float = 0.005
    max_agreement: float = 0.1
    against_coverage: float = 0.5
    against_pixels: int = 20
    tol: float = 1.0
    candidates: tuple[str, ...] = ("bpasw", "sgm")
    margin: float = 0.2
    flat_ratio: float = 0.07
    flat_min_support: float = 0.4
    flat_support_margin: float = 0.3
    radiometry_offset: float = 1.0
    outvoted_tol: float = 7.0
    outvoted_share: float = 0.05
    outvoted_min_size: float = 0.001
    contradicted_share: float = 0.4
    contradicted_min_size: float = 0.001

    def __post_init__(self) -> None:
        """Validate the fields; implementation helper with no thesis equation of its own."""
        _need(self.radiometry_offset >= 0, "fallback.radiometry_offset >= 0", self.radiometry_offset)
        _need(self.outvoted_tol >= 0 and 0.0 <= self.outvoted_share <= 1.0 and 0.0 <= self.outvoted_min_size <= 1.0,
              "fallback.outvoted_tol >= 0, outvoted_share and outvoted_min_size in [0, 1]",
              (self.outvoted_tol, self.outvoted_share, self.outvoted_min_size))
        _need(0.0 <= self.contradicted_share <= 1.0 and 0.0 <= self.contradicted_min_size <= 1.0,
              "fallback.contradicted_share and contradicted_min_size in [0, 1]",
              (self.contradicted_share, self.contradicted_min_size))
        _need(self.flat_ratio >= 0 and 0.0 <= self.flat_min_support <= 1.0 and 0.0 <= self.flat_support_margin <= 1.0,
              "fallback.flat_ratio >= 0, flat_min_support and flat_support_margin in [0, 1]",
              (self.flat_ratio, self.flat_min_support, self.flat_support_margin))
        object.__setattr__(self, "candidates", tuple(str(c) for c in self.candidates))
        _need(len(self.candidates) > 0 and set(self.candidates) <= {"plane", "bpasw", "sgm"}
              and len(set(self.candidates)) == len(self.candidates),
              "fallback.candidates distinct names among plane, bpasw, sgm", self.candidates)
        _need(0.0 <= self.margin <= 1.0, "fallback.margin in [0, 1]", self.margin)
        _need(all(0.0 <= v <= 1.0 for v in (self.min_coverage, self.bare_coverage, self.max_agreement,
                                             self.against_coverage))
              and 0.0 < self.min_share <= 1.0 and 0.0 < self.bare_share <= 1.0,
              "fallback.min_coverage, bare_coverage, max_agreement, against_coverage in [0, 1] and min_share, "
              "bare_share in (0, 1]", (self.min_coverage, self.bare_coverage, self.max_agreement,
                                       self.against_coverage, self.min_share, self.bare_share))
        _need(self.coverage_reach >= 0, "fallback.coverage_reach >= 0", self.coverage_reach)
        _need(self.against_pixels >= 1 and self.tol >= 0, "fallback.against_pixels >= 1 and tol >= 0",
              (self.against_pixels, self.tol))


@dataclass(frozen=True, kw_only=True)
class CurvedParams:
    """``curved``: a segment whose evidence (both cross-checked initial maps agree within ``tol``) bends away
    from its plane takes the quadric fitted to that evidence on its own-plane pixels
    (:func:`~prismstereo.matching.segments.planes.curved_segment_surfaces`: at least ``min_evidence`` inliers
    covering ``min_coverage`` of the segment, RMS at most ``max_rms_ratio`` of the plane's, a curved part of at
    least ``min_amplitude`` px, ``iterations`` inlier rounds, a pixel moved by at most ``max_shift`` px)."""

    enabled: bool = True
    min_evidence: int = 100
    min_coverage: float = 0.3
    tol: float = 1.0
    max_rms_ratio: float = 0.6
    min_amplitude: float = 0.3
    iterations: int = 3
    max_shift: float = 1.0

    def __post_init__(self) -> None:
        """Validate the fields; implementation helper with no thesis equation of its own."""
        _need(self.min_evidence >= 6 and 0.0 <= self.min_coverage <= 1.0 and self.tol > 0
              and 0.0 < self.max_rms_ratio <= 1.0 and self.min_amplitude >= 0 and self.iterations >= 0
              and self.max_shift >= 0,
              "curved.min_evidence >= 6, min_coverage in [0, 1], tol > 0, max_rms_ratio in (0, 1], "
              "min_amplitude, iterations, max_shift >= 0",
              (self.min_evidence, self.min_coverage, self.tol, self.max_rms_ratio, self.min_amplitude,
               self.iterations, self.max_shift))


P = TypeVar("P")


def coerce_params(cls: type[P], value: object, name: str, base: P | None = None) -> P:
    """``value`` as a ``cls``: None -> ``base`` (default: ``cls()``), a mapping -> ``base`` with those fields
    replaced (nested step mappings too, as the CLI's ``-p`` JSON gives them); anything else is a
    :class:`~prismstereo.errors.ConfigError`.

    Implementation helper (configuration) with no thesis equation of its own.
    """
    if value is None:
        return cls() if base is None else base
    if isinstance(value, cls):
        return value
    if isinstance(value, Mapping):
        kw = dict(value)
        hints = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
        unknown = sorted(set(kw) - set(hints))
        _need(not unknown, f"{name} fields among {', '.join(hints)}", unknown)
        for k, v in kw.items():
            sub = _STEP_TYPES.get(k) if cls is StepParams else None
            if sub is not None:
                kw[k] = coerce_params(sub, v, f"{name}.{k}", None if base is None else getattr(base, k))
            elif isinstance(v, list):
                kw[k] = tuple(tuple(x) if isinstance(x, list) else x for x in v)
        try:
            return cls(**kw) if base is None else dataclasses.replace(base, **kw)  # type: ignore[type-var]
        except (TypeError, ValueError) as exc:
            if isinstance(exc, ConfigError):
                raise
            raise ConfigError(f"expected valid {name} parameters, got {value!r} ({exc})") from None
    raise ConfigError(f"expected {name} as a {cls.__name__} or a mapping, got {value!r}")


@dataclass(frozen=True, kw_only=True)
class StepParams:
    """One parameter set per step of :data:`STEP_NAMES` (``optimise`` reads the method's ``CoopParams``)."""

    refit: RefitParams = field(default_factory=RefitParams)
    bpasw_planes: BpaswPlanesParams = field(default_factory=BpaswPlanesParams)
    sweep: SweepParams = field(default_factory=SweepParams)
    group_moves: GroupMovesParams = field(default_factory=GroupMovesParams)
    fine: FineParams = field(default_factory=FineParams)
    boundary: BoundaryParams = field(default_factory=BoundaryParams)
    occlusion: OcclusionParams = field(default_factory=OcclusionParams)
    median: MedianParams = field(default_factory=MedianParams)
    fallback: FallbackParams = field(default_factory=FallbackParams)
    curved: CurvedParams = field(default_factory=CurvedParams)

    def __post_init__(self) -> None:
        """Coerce every field to its step parameters (:func:`coerce_params`); implementation helper with no thesis
        equation."""
        for f in dataclasses.fields(self):
            object.__setattr__(self, f.name, coerce_params(_STEP_TYPES[f.name], getattr(self, f.name),
                                                           f"steps.{f.name}"))

    def without(self, *names: str) -> StepParams:
        """These steps switched off (``optimise`` cannot be).

        Implementation helper (configuration) with no thesis equation of its own.
        """
        off: dict[str, Any] = {"refit": RefitParams(rounds=0), "bpasw_planes": BpaswPlanesParams(rounds=0),
                               "sweep": dataclasses.replace(self.sweep, frac=0.0),
                               "group_moves": GroupMovesParams(enabled=False), "fine": FineParams(levels=()),
                               "boundary": dataclasses.replace(self.boundary, radius=0),
                               "occlusion": dataclasses.replace(self.occlusion, enabled=False),
                               "median": MedianParams(radius=0), "fallback": FallbackParams(enabled=False),
                               "curved": dataclasses.replace(self.curved, enabled=False)}
        bad = sorted(set(names) - set(off))
        _need(not bad, f"steps among {', '.join(off)}", bad)
        return dataclasses.replace(self, **{n: off[n] for n in names})


_STEP_TYPES: dict[str, type] = {"refit": RefitParams, "bpasw_planes": BpaswPlanesParams, "sweep": SweepParams,
                                "group_moves": GroupMovesParams, "fine": FineParams, "boundary": BoundaryParams,
                                "occlusion": OcclusionParams, "median": MedianParams,
                                "fallback": FallbackParams, "curved": CurvedParams}


@dataclass(frozen=True)
class PlaneLabels:
    """The state the steps pass on.

    Attributes
    ----------
    labels : (H, W) int32          segments (the finest level after ``fine``).
    index : SegmentIndex           their pixels.
    graph : SegmentGraph           adjacency and smoothness weights of the segments the optimiser works on.
    assign : (K,) int32            plane per segment, into ``planes``.
    planes : (L, 3) float64        plane set ``(a, b, c)``, ``d = a x + b y + c``.
    own : (K, 2) int64             each segment's own fitted plane and merged-cluster plane (-1 none).
    parent : (K,) int64            segment of the front end each segment lies in.
    pairs : (P, 2) int32           adjacent segment pairs of the front end's segments (for merging).
    bfit_ids : (K,) int64 or None  each segment's plane fitted to the BPASW map (after ``bpasw_planes``).
    sweep_ids : (K, m) int64       each segment's sweep candidates (after ``sweep``; m = 0 before).
    disparity : (H, W) float32 or None   the map, from ``boundary`` on.
    info : dict                    energies, counts.
    """

    labels: I32
    index: SegmentIndex
    graph: SegmentGraph
    assign: I32
    planes: F64
    own: I64
    parent: I64
    pairs: I32
    bfit_ids: I64 | None = None
    sweep_ids: I64 | None = None
    disparity: F32 | None = None
    info: dict[str, float] = field(default_factory=dict)

    def render(self) -> F32:
        """The (H, W) float32 disparity of the segments' planes ``d = a x + b y + c`` (thesis Eq. 6.1)."""
        return np.asarray(render_planes(self.index, self.planes, self.assign), np.float32)


class Evidence(Protocol):
    """What a method gives the steps: its data term and the evidence each step reads."""

    image: npt.NDArray[np.uint8]      # (H, W, 3) reference image
    data: F32                         # data-term volume of the optimiser (the sweep step may replace pixels)
    check_data: F32                   # the data term moves are checked against (``data`` before the sweep's)
    reliable: B                       # data-term reliability mask of the optimiser
    coop: CoopParams
    segmentation: SegmentationParams
    plane_params: PlaneParams
    min_disp: int
    max_disp: int
    slopes: tuple[float, ...] | None  # the data volume's vertical slopes (None: one unsheared volume)
    memo: CoopMemo                    # the optimiser's data terms, remembered from one call to the next

    def optimise(self, s: PlaneLabels, assign: I32, planes: F64, own: I64, *,
                 neighbour_own_planes: bool = False) -> tuple[I32, F64, dict[str, float]]: ...

    def refit(self, s: PlaneLabels, assign: I32, planes: F64) -> tuple[F64, I64] | None: ...

    def bpasw_map(self) -> tuple[F32, B] | None: ...

    def sweep(self, s: PlaneLabels, p: SweepParams) -> tuple[F64, I64]: ...

    def row_box(self, selected: B, p: SweepParams) -> None: ...

    def fine_evidence(self, tol: float) -> tuple[B, F32] | None: ...

    def segments(self, params: SegmentationParams) -> I32: ...  # mean_shift_segment(image, params=params)

    def boundary_evidence(self, tol: float) -> tuple[F32, F32, B, B] | None: ...

    def occlusion(self, s: PlaneLabels, final: F32, p: OcclusionParams) -> F32: ...

    def fallback(self, s: PlaneLabels, final: F32, p: FallbackParams) -> F32: ...


def _merge(s: PlaneLabels, info: Mapping[str, float]) -> dict[str, float]:
    """The step's ``info`` merged into ``s.info``, keeping the first ``energy_before``; implementation helper, no thesis
    equation."""
    return {**s.info, **info, "energy_before": s.info.get("energy_before", info.get("energy_before", 0.0))}


def step_optimise(s: PlaneLabels, ev: Evidence, p: StepParams) -> PlaneLabels:
    """The cooperative optimisation of thesis §6.2: segment-wise minimisation of Eq. 6.19 over the energy of
    Eqs. 6.18-6.25."""
    assign, planes, info = ev.optimise(s, s.assign, s.planes, s.own)
    return dataclasses.replace(s, assign=assign, planes=planes, info=_merge(s, info))


def step_refit(s: PlaneLabels, ev: Evidence, p: StepParams) -> PlaneLabels:
    """Refit one plane per group of segments sharing a plane (the robust fit of thesis Eqs. 6.1-6.10, as after the
    merging of §6.1.3), then resume the cooperative optimisation (§6.2, Eq. 6.19)."""
    for _ in range(p.refit.rounds):
        refit = ev.refit(s, s.assign, s.planes)
        if refit is None:
            break
        planes, group_ids = refit
        own2 = s.own.copy()
        own2[:, 1] = group_ids
        assign, planes, info = ev.optimise(s, s.assign, planes, own2)
        s = dataclasses.replace(s, assign=assign, planes=planes, info=_merge(s, info))
    return s


def step_bpasw_planes(s: PlaneLabels, ev: Evidence, p: StepParams) -> PlaneLabels:
    """Add candidate planes fitted (thesis §6.1, Eqs. 6.1-6.10) to the cross-checked (Eq. 6.7) BPASW map of §5.2 and
    resume the cooperative optimisation (Eq. 6.19)."""
    bm = ev.bpasw_map()
    if bm is None or p.bpasw_planes.rounds <= 0:
        return s

    def optimise(a: I32, pl: F64, own: I64) -> tuple[I32, F64, dict[str, float]]:
        """The cooperative optimisation of thesis §6.2 (Eq. 6.19) on ``s``; implementation helper (closure)."""
        return ev.optimise(s, a, pl, own)

    assign, planes, info, bfit_ids = bpasw_candidate_rounds(s.assign, s.planes, s.own, s.index, s.pairs, bm[0],
                                                            bm[1], optimise, planes=ev.plane_params,
                                                            rounds=p.bpasw_planes.rounds)
    return dataclasses.replace(s, assign=assign, planes=planes, bfit_ids=bfit_ids,
                               info=s.info if info is None else _merge(s, info))


def unsupported_moves(index: SegmentIndex, before: F64, after: F64, data: F32, *, min_disp: int,
                      slopes: tuple[float, ...] | None, trunc: float, min_cover: float) -> I64:
    """The segments whose move from plane ``before[j]`` to ``after[j]`` their own data term does not support.

    The data term of a segment under a plane is the mean truncated pixel cost (Eq. 6.21) over the pixels both
    planes send inside the search range and the right view; a move is supported when that mean is lower under
    the new plane and such pixels are at least ``min_cover`` of the segment (a plane that leaves the view or
    the range has no evidence for it).

    Parameters
    ----------
    index : SegmentIndex of K segments.
    before, after : (K, 3) float64, each segment's plane before and after the move.
    data : (H, W, D) or (S, H, W, D) float32, the data term's pixel cost (one volume per slope of ``slopes``).

    Returns
    -------
    (M,) int64, the moved segments the data term does not support.
    """
    moved = np.flatnonzero((before != after).any(axis=1))
    if moved.size == 0:
        return moved
    h, w = index.shape
    vol = data if data.ndim == 4 else data[None]
    flat = vol.reshape(vol.shape[0], h * w, vol.shape[3])
    lens = index.starts[moved + 1] - index.starts[moved]
    lv = np.zeros(1) if slopes is None else np.asarray(slopes, np.float64)
    n, gain = _move_gains(index.order, index.starts, moved, w, np.ascontiguousarray(before, np.float64),
                          np.ascontiguousarray(after, np.float64), flat, float(min_disp), lv, float(trunc))
    return moved[(n < min_cover * lens) | ~(gain > 0)]


@njit(cache=True, nogil=True)
def _pixel_cost(flat: F32, lev: int, p: int, d: float, x: float, min_disp: float, trunc: float
                ) -> tuple[float, bool]:
    """Truncated, linearly interpolated pixel cost at disparity ``d`` and whether ``d`` lies in the range and
    the right view.

    One pixel's ``c_data(x, y, d)`` of the data term, thesis Eq. 6.21.
    """
    k = d - min_disp
    ok = k >= -0.5 and k <= flat.shape[2] - 0.5 and x - d >= -0.5
    return interpolated_cost(flat, lev, p, k, trunc), ok


@njit(cache=True, nogil=True)
def _move_gains(order: I64, starts: I64, moved: I64, w: int, before: F64, after: F64, flat: F32,
                min_disp: float, lv: F64, trunc: float) -> tuple[F64, F64]:
    """Per moved segment, its pixels both planes send in range and the summed cost drop (pixel order).

    The change of the data term (thesis Eq. 6.21) of each moved segment.
    """
    n = np.zeros(moved.size)
    gain = np.zeros(moved.size)
    for m in range(moved.size):
        j = moved[m]
        b0, b1, b2 = before[j, 0], before[j, 1], before[j, 2]
        a0, a1, a2 = after[j, 0], after[j, 1], after[j, 2]
        lb = slope_level(lv, b1)
        la = slope_level(lv, a1)
        for t in range(starts[j], starts[j + 1]):
            p = order[t]
            x = float(p % w)
            y = float(p // w)
            c0, ok0 = _pixel_cost(flat, lb, p, b0 * x + b1 * y + b2, x, min_disp, trunc)
            c1, ok1 = _pixel_cost(flat, la, p, a0 * x + a1 * y + a2, x, min_disp, trunc)
            if ok0 and ok1:
                n[m] += 1.0
                gain[m] += c0 - c1
            else:
                gain[m] += 0.0
    return n, gain


def _checked(s: PlaneLabels, assign: I32, planes: F64, ev: Evidence, on: bool, min_cover: float
             ) -> tuple[I32, dict[str, float]]:
    """``assign`` with the moves from ``s`` that the segments' own data term does not support undone.

    A check of the moves against the data term of thesis Eq. 6.21; no equation of its own (an addition to the thesis).
    """
    if not on:
        return assign, {}
    undo = unsupported_moves(s.index, s.planes[s.assign], planes[assign], ev.check_data, min_disp=ev.min_disp,
                             slopes=ev.slopes, trunc=ev.coop.data_trunc, min_cover=min_cover)
    out = assign.copy()
    out[undo] = s.assign[undo]
    return out, {"undone": float(undo.size)}


def step_sweep(s: PlaneLabels, ev: Evidence, p: StepParams) -> PlaneLabels:
    """Segment sweep over slanted planes: an addition to the thesis with no equation of its own; its planes become
    candidates of the cooperative minimisation of Eq. 6.19 (§6.2)."""
    sp = p.sweep
    if sp.frac <= 0:
        return s
    planes, ids = ev.sweep(s, sp)
    if (ids >= 0).any() and sp.row_box >= 0:
        # the selected segments' pixels: pixel cost boxed along the row only (a square box favours
        # fronto-parallel planes on surfaces slanted in y)
        ev.row_box((ids[:, 0] >= 0)[s.labels], sp)
    assign = s.assign
    info = dict(s.info)
    k = assign.shape[0]
    for col in range(0, ids.shape[1], 2):
        own6 = np.full((k, 2), -1, np.int64)
        own6[:, :min(2, ids.shape[1] - col)] = ids[:, col:col + 2]
        if (own6 >= 0).any():
            assign, planes, info2 = ev.optimise(s, assign, planes, own6, neighbour_own_planes=sp.neighbours)
            info = {**info, **info2, "energy_before": info.get("energy_before", 0.0)}
    info["sweep_segments"] = float((ids[:, 0] >= 0).sum())
    assign, chk = _checked(s, assign, planes, ev, sp.data_check, sp.check_cover)
    info.update({f"sweep_{k}": v for k, v in chk.items()})
    return dataclasses.replace(s, assign=assign, planes=planes, sweep_ids=ids, info=info)


def step_group_moves(s: PlaneLabels, ev: Evidence, p: StepParams) -> PlaneLabels:
    """Group moves (a plane taken over whole regions at once, accepted when the total energy of thesis Eq. 6.18 falls):
    an addition to the thesis, then the cooperative optimisation of §6.2 (Eq. 6.19)."""
    if not p.group_moves.enabled:
        return s
    k = s.assign.shape[0]
    sw = s.sweep_ids if s.sweep_ids is not None else np.full((k, 0), -1, np.int64)
    # sweep candidates and the planes across each segment's boundary, moved over whole regions
    cands = np.concatenate([sw, neighbour_plane_candidates(s.graph, s.assign)], axis=1)
    assign, ginfo = expand_planes(s.assign, s.planes, s.index, s.graph, ev.data, ev.reliable, cands,
                                  min_disp=ev.min_disp, params=ev.coop, slopes=ev.slopes, memo=ev.memo)
    assign, planes, info = ev.optimise(s, assign, s.planes, s.own)
    gp = p.group_moves
    assign, chk = _checked(s, assign, planes, ev, gp.data_check, gp.check_cover)
    return dataclasses.replace(s, assign=assign, planes=planes,
                               info={**_merge(s, info), **ginfo, **{f"group_{k}": v for k, v in chk.items()}})


def step_fine(s: PlaneLabels, ev: Evidence, p: StepParams) -> PlaneLabels:
    """Finer mean-shift segments (thesis §5.1) along plane boundaries resume the cooperative optimisation (Eq. 6.19): an
    addition to §6.2 with no equation of its own."""
    if not p.fine.levels:
        return s
    evid = ev.fine_evidence(p.boundary.tol)
    if evid is None:
        return s

    evidence, reference = evid
    for hr, min_region in p.fine.levels:
        seg = dataclasses.replace(ev.segmentation, hr=float(hr), min_region=int(min_region))
        data = DataTerm(ev.data, ev.reliable, min_disp=ev.min_disp, slopes=ev.slopes)
        fs = refine_fine_segments(ev.image, s.labels, s.assign, s.planes, data, evidence, reference,
                                  segmentation=seg, coop=ev.coop, check=p.fine.check, fine=ev.segments(seg))
        s = dataclasses.replace(s, labels=fs.labels, index=fs.index, assign=fs.assign, planes=fs.planes,
                                own=s.own[fs.parent], parent=s.parent[fs.parent],
                                bfit_ids=None if s.bfit_ids is None else s.bfit_ids[fs.parent],
                                sweep_ids=None if s.sweep_ids is None else s.sweep_ids[fs.parent],
                                info=_merge(s, fs.info))
    return s


def step_boundary(s: PlaneLabels, ev: Evidence, p: StepParams) -> PlaneLabels:
    """Per-pixel choice among neighbouring planes near segment boundaries: post-processing beyond the thesis, no thesis
    equation; without evidence it renders the planes (Eq. 6.1)."""
    bp = p.boundary
    evid = ev.boundary_evidence(bp.tol) if bp.radius > 0 else None
    if evid is None:
        return dataclasses.replace(s, disparity=s.render())
    cost, bdisp, brel, bagree = evid
    extra = []
    if bp.bplanes and s.bfit_ids is not None:
        extra.append(s.bfit_ids)
    if bp.bplanes > 1:
        extra.append(s.own[:, 0])
    k = s.own.shape[0]
    bown = np.ascontiguousarray(np.stack(extra, axis=1) if extra else np.full((k, 1), -1), dtype=np.int32)
    rel = bagree if bp.agree == 1 else brel
    final = boundary_pixel_planes(np.ascontiguousarray(s.labels, dtype=np.int32), s.assign.astype(np.int32),
                                  s.planes, cost, int(ev.min_disp), int(bp.radius), float(bp.margin),
                                  np.ascontiguousarray(rel), bdisp, float(bp.tol),
                                  np.ascontiguousarray(bagree if bp.agree else rel), bown)
    return dataclasses.replace(s, disparity=np.asarray(final, np.float32))


def step_occlusion(s: PlaneLabels, ev: Evidence, p: StepParams) -> PlaneLabels:
    """Occluded pixels take the background plane (:class:`OcclusionParams`): post-processing beyond the thesis with no
    equation of its own."""
    if not p.occlusion.enabled:
        return s
    assert s.disparity is not None
    return dataclasses.replace(s, disparity=np.asarray(ev.occlusion(s, s.disparity, p.occlusion), np.float32))


def step_median(s: PlaneLabels, ev: Evidence, p: StepParams) -> PlaneLabels:
    """Weighted median filter of the final map: post-processing beyond the thesis with no equation of its own."""
    if p.median.radius <= 0:
        return s
    assert s.disparity is not None
    final = s.disparity
    wm = weighted_median_filter(final, ev.image, radius=p.median.radius)
    # the median works on integer bins: keep the subpixel plane disparity where it agrees within 1 px
    return dataclasses.replace(s, disparity=np.where(np.abs(wm - final) <= 1.0, final, wm).astype(np.float32))


def step_fallback(s: PlaneLabels, ev: Evidence, p: StepParams) -> PlaneLabels:
    """Segments without support of their own take the local matcher's map (:class:`FallbackParams`): post-processing
    beyond the thesis with no equation of its own."""
    if not p.fallback.enabled:
        return s
    assert s.disparity is not None
    return dataclasses.replace(s, disparity=np.asarray(ev.fallback(s, s.disparity, p.fallback), np.float32))


def step_curved(s: PlaneLabels, ev: Evidence, p: StepParams) -> PlaneLabels:
    """Curved surfaces for segments off their plane: an extension of the planar model of thesis Eq. 6.1 with no equation
    of its own."""
    cp = p.curved
    if not cp.enabled:
        return s
    assert s.disparity is not None
    fine = ev.fine_evidence(cp.tol)
    bnd = ev.boundary_evidence(cp.tol)
    if fine is None or bnd is None:
        return s
    agree, initial = fine
    reference = 0.5 * (initial + bnd[1])
    # only pixels still on their segment's plane: the boundary and occlusion steps chose the others pixel by pixel
    planar = np.abs(s.disparity - s.render()) <= 1e-3
    out, curved = curved_segment_surfaces(s.labels, s.disparity, planar, agree, reference,
                                          min_evidence=cp.min_evidence, min_coverage=cp.min_coverage, tol=cp.tol,
                                          max_rms_ratio=cp.max_rms_ratio, min_amplitude=cp.min_amplitude,
                                          iterations=cp.iterations, max_shift=cp.max_shift)
    return dataclasses.replace(s, disparity=out, info={**s.info, "curved_segments": float(curved.sum())})


STEPS: dict[str, Callable[[PlaneLabels, Evidence, StepParams], PlaneLabels]] = {
    "optimise": step_optimise, "refit": step_refit, "bpasw_planes": step_bpasw_planes, "sweep": step_sweep,
    "group_moves": step_group_moves, "fine": step_fine, "boundary": step_boundary, "occlusion": step_occlusion,
    "curved": step_curved, "median": step_median, "fallback": step_fallback}


def run_steps(state: PlaneLabels, evidence: Evidence, params: StepParams, *,
              snapshot: Callable[[str, PlaneLabels], None] | None = None) -> PlaneLabels:
    """Run :data:`STEP_NAMES` in order on ``state``; ``snapshot(name, state)`` after each. Returns the final
    state, whose ``disparity`` (H, W) float32 is clipped to the method's range.

    Implementation helper (step driver) with no thesis equation of its own.
    """
    for name in STEP_NAMES:
        state = STEPS[name](state, evidence, params)
        if snapshot is not None:
            snapshot(name, state)
    assert state.disparity is not None
    return dataclasses.replace(state, disparity=np.clip(state.disparity, evidence.min_disp,
                                                        evidence.max_disp).astype(np.float32))
