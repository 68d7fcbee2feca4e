"""Search the prisms that suit a camera and a job, ranked by predicted depth resolution and common field.

The search (docs/design.md) walks a grid of corner angles (every :data:`ANGLE_STEP`° up to the glass's
total-internal-reflection limit) × apex distances (``min_apex_distance`` … ``max_apex_distance``) × faces ×
glasses × face layouts, sizes the smallest glass that covers the sensor's field for each
(:func:`~prismstereo.design.geometry.size_prism`), and checks in this order:

1. ``tir``: every ray of the field crosses the glass (no total internal reflection);
2. ``size``: the glass's largest dimension is at most ``max_size``;
3. ``overlap``: the two views share at least ``min_field_share`` of each sub-image at every depth of the range
   (:data:`MIN_FIELD_SHARE` by default);
4. ``field``: a ``field`` W × H mm rectangle at the far depth lies in both views (when asked);
5. ``balance``: the sub-images' widths differ by at most ``max_width_spread`` (the thesis's tri-prism
   complaint, §8.2: "the acquired images using tri-prism are not of the same size");
6. ``accuracy``: the expected relative depth error at the far depth is at most ``accuracy`` (when asked).

The candidates that pass are ranked by their expected error (the worst over the range; ties by the common
field) or, when an accuracy is asked (and met), by the common field (the smallest share over the range); the
grid is then refined around the best few (:data:`ANGLE_STEP_FINE`°, :data:`APEX_STEP_FINE` mm). When no
candidate passes, :class:`~prismstereo.errors.GeometryError` names the constraint that removed the last ones
and what the best prism reaches there.

A tri-prism's sub-images are made equal in width by moving its apex off the optical axis (``decenter``)
toward its single face's side: the ``balanced`` layout (the centred one is searched as well).
"""

from __future__ import annotations

import functools
import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from prismstereo.cameras.faces import max_corner_angle
from prismstereo.config import CameraSpec, PrismSpec, Rig
from prismstereo.design.geometry import glass_size, sample_rig, sensor_pixels, size_prism
from prismstereo.design.glass import Glass, parse_glasses
from prismstereo.design.precision import DEFAULT_PRESET, disparity_precision_of
from prismstereo.design.predict import Prediction, predict_sample
from prismstereo.errors import ConfigError, GeometryError
from prismstereo.optics import trace_pixels

log = logging.getLogger(__name__)

__all__ = ["ANGLE_STEP", "ANGLE_STEP_FINE", "APEX_STEP_FINE", "CHECKS", "Candidate", "Design", "Request",
           "MIN_FIELD_SHARE", "assess", "search"]

#: corner angle step of the coarse grid, degrees
ANGLE_STEP = 0.5
#: corner angle step of the refinement around the best candidates, degrees
ANGLE_STEP_FINE = 0.1
#: apex distances of the coarse grid
APEX_COUNT = 15
#: apex distance step of the refinement, mm
APEX_STEP_FINE = 5.0
#: the checks in the order they are made (module docstring)
CHECKS = ("tir", "size", "overlap", "field", "balance", "accuracy")
#: default least share of each sub-image the pair's views must share over the range: a bi-prism's halves, and
#: the wedges of N >= 3 faces, two of which (one turned by 360°/N against the other) share at most about half
MIN_FIELD_SHARE = {2: 0.5, 3: 0.3}
#: depths of the range at which every candidate is predicted
N_DEPTHS = 7


@dataclass(frozen=True)
class Request:
    """The camera, the job and the constraints of a search (see :func:`search`)."""

    camera: CameraSpec
    near: float
    far: float
    field: tuple[float, float] | None = None
    accuracy: float | None = None
    faces: tuple[int, ...] = (2,)
    glasses: tuple[Glass, ...] = ()
    max_size: float = 100.0
    min_apex_distance: float = 50.0
    max_apex_distance: float = 400.0
    edge_thickness: float = 1.0
    min_field_share: float | None = None
    max_width_spread: float = 0.10
    precision: float = 0.0
    preset: str | None = DEFAULT_PRESET

    def __post_init__(self) -> None:
        if not (math.isfinite(self.near) and math.isfinite(self.far) and 0 < self.near < self.far):
            raise ConfigError(f"near, far: expected 0 < near < far (mm), got {self.near!r}, {self.far!r}")
        if self.field is not None and (len(self.field) != 2 or min(self.field) <= 0):
            raise ConfigError(f"field: expected a width and height > 0 mm, got {self.field!r}")
        if self.accuracy is not None and not 0 < self.accuracy < 1:
            raise ConfigError(f"accuracy: expected a relative depth error in (0, 1) (0.01 = 1 %), "
                              f"got {self.accuracy!r}")
        if not self.faces or any(int(n) != n or n < 2 for n in self.faces):
            raise ConfigError(f"faces: expected face counts >= 2 (2 = bi-prism), got {self.faces!r}")
        if not self.max_size > 0:
            raise ConfigError(f"max_size: expected a size > 0 mm, got {self.max_size!r}")
        if not 0 < self.min_apex_distance <= self.max_apex_distance:
            raise ConfigError(f"min_apex_distance: expected 0 < min_apex_distance <= max_apex_distance "
                              f"({self.max_apex_distance:g} mm), got {self.min_apex_distance!r}")
        if self.min_apex_distance >= self.near:
            raise ConfigError(f"min_apex_distance: expected the prism before the near depth ({self.near:g} mm), "
                              f"got {self.min_apex_distance:g} mm")
        if self.min_field_share is not None and not 0 < self.min_field_share <= 1:
            raise ConfigError(f"min_field_share: expected a share in (0, 1], got {self.min_field_share!r}")
        if not self.max_width_spread >= 0:
            raise ConfigError(f"max_width_spread: expected a share >= 0, got {self.max_width_spread!r}")

    def field_share_for(self, faces: int) -> float:
        """The ``overlap`` check's least shared share for a prism with this many faces."""
        if self.min_field_share is not None:
            return self.min_field_share
        return MIN_FIELD_SHARE[2] if faces == 2 else MIN_FIELD_SHARE[3]

    @property
    def depths(self) -> np.ndarray:
        return np.geomspace(self.near, self.far, N_DEPTHS)

    def to_dict(self) -> dict[str, Any]:
        cam = Rig(camera=self.camera, prism=PrismSpec(faces=2, corner_angle=1.0, refractive_index=1.5,
                                                      apex_distance=1.0, back_distance=2.0)).to_dict()["camera"]
        return {"camera": cam, "range_mm": [self.near, self.far],
                "field_mm": list(self.field) if self.field else None, "accuracy": self.accuracy,
                "faces": list(self.faces), "glasses": [{"name": g.name, "n_d": g.n_d, "abbe": g.abbe}
                                                        for g in self.glasses],
                "max_size_mm": self.max_size, "min_apex_distance_mm": self.min_apex_distance,
                "max_apex_distance_mm": self.max_apex_distance, "edge_thickness_mm": self.edge_thickness,
                "min_field_share": self.min_field_share, "max_width_spread": self.max_width_spread,
                "disparity_precision_px": self.precision, "preset": self.preset}


@dataclass(frozen=True)
class Candidate:
    """One prism looked at by the search.

    Attributes
    ----------
    rig : Rig or None
        The camera with the prism (None when no glass of this shape works: total internal reflection).
    faces, corner_angle, apex_distance, glass, layout : what was asked for.
    prediction : Prediction or None
        None when rejected before the prediction (``tir``, ``size``).
    rejected : str or None
        The first check it failed (:data:`CHECKS`), None if it passed them all.
    reason : str
        Why, in one line ("" when it passed).
    source : str
        ``search`` or ``given`` (a prism passed in ``include``).
    """

    faces: int
    corner_angle: float
    apex_distance: float
    glass: Glass
    layout: str
    rig: Rig | None
    prediction: Prediction | None
    rejected: str | None
    reason: str = ""
    source: str = "search"
    rank: int | None = field(default=None, compare=False)

    @property
    def feasible(self) -> bool:
        return self.rejected is None

    def error_at(self, depth_mm: float) -> float:
        return self.prediction.at(depth_mm).relative_error if self.prediction is not None else float("nan")

    def to_dict(self) -> dict[str, Any]:
        return {"rank": self.rank, "source": self.source, "faces": self.faces, "corner_angle": self.corner_angle,
                "apex_distance": self.apex_distance, "glass": self.glass.name, "refractive_index": self.glass.n_d,
                "layout": self.layout, "rejected": self.rejected, "reason": self.reason,
                "prism": self.rig.to_dict()["prism"] if self.rig is not None else None,
                "prediction": self.prediction.to_dict() if self.prediction is not None else None}


@dataclass(frozen=True)
class Design:
    """The result of :func:`search`: the request and every candidate, feasible ones first by rank."""

    request: Request
    candidates: tuple[Candidate, ...]
    seconds: float = 0.0
    cpu_seconds: float = 0.0

    @property
    def feasible(self) -> tuple[Candidate, ...]:
        return tuple(c for c in self.candidates if c.feasible)

    @property
    def best(self) -> Candidate:
        return self.feasible[0]

    def rejections(self) -> dict[str, int]:
        """How many candidates each check removed."""
        out = {k: 0 for k in CHECKS}
        for c in self.candidates:
            if c.rejected is not None:
                out[c.rejected] += 1
        return out

    def to_dict(self) -> dict[str, Any]:
        return {"request": self.request.to_dict(), "seconds": self.seconds, "cpu_seconds": self.cpu_seconds,
                "n_candidates": len(self.candidates),
                "n_feasible": len(self.feasible), "rejections": self.rejections(),
                "best": self.best.to_dict() if self.feasible else None,
                "candidates": [c.to_dict() for c in self.candidates]}


# --------------------------------------------------------------------------- one candidate
def _widths(rig: Rig, step: float = 16.0) -> np.ndarray:
    """(N,) bounding widths (px) of the faces' sub-images, traced through unbounded faces."""
    px = sensor_pixels(rig.camera, step)
    b = trace_pixels(rig, px, bounded=False)
    out = np.zeros(rig.prism.faces)
    for k in range(rig.prism.faces):
        sel = b.face == k
        if sel.any():
            out[k] = px[sel, 0].max() - px[sel, 0].min() + step
    return out


def _balanced_decenter(req: Request, faces: int, corner_angle: float, glass: Glass, apex: float) -> tuple[float, float]:
    """Decenter (dx, 0) mm that makes a rotation-0 tri-prism's sub-images equally wide.

    The sub-images meet where the faces' edges are seen, lines through the apex's image: the apex is placed at
    the image position x0 (px from the principal point) found by bisection on a prism at the reference
    distance :data:`_BALANCE_APEX_MM`, then dx = x0 · apex / f (x0 hardly changes with the apex distance).
    """
    x0 = _balanced_x0(req.camera, faces, round(corner_angle, 3), glass.n_d)
    return (x0 * apex / req.camera.focal_xy[0], 0.0)


#: apex distance of the bisection in :func:`_balanced_decenter`, mm
_BALANCE_APEX_MM = 200.0


@functools.lru_cache(maxsize=4096)
def _balanced_x0(cam: CameraSpec, faces: int, corner_angle: float, n_d: float) -> float:
    f = cam.focal_xy[0]
    apex = _BALANCE_APEX_MM
    base = PrismSpec(faces=faces, corner_angle=corner_angle, refractive_index=n_d, apex_distance=apex,
                     back_distance=apex + 50.0, height=49.0)
    lo, hi = -0.5 * cam.width, 0.5 * cam.width  # apex image position, px from the principal point

    def spread(x0: float) -> float:
        dx = x0 * apex / f
        w = _widths(Rig(camera=cam, prism=replace(base, decenter=(dx, 0.0))))
        return float(w[0] - max(w[1:]))

    for _ in range(12):
        mid = 0.5 * (lo + hi)
        if spread(mid) > 0:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def _layouts(req: Request, faces: int, corner_angle: float, glass: Glass, apex: float
             ) -> list[tuple[str, float, tuple[float, float]]]:
    """(name, rotation, decenter) of the face layouts searched for this shape."""
    if faces == 2:
        return [("centred", 0.0, (0.0, 0.0))]
    if faces % 2:
        return [("centred", 0.0, (0.0, 0.0)),
                ("balanced", 0.0, _balanced_decenter(req, faces, corner_angle, glass, apex))]
    return [("centred", 0.0, (0.0, 0.0)), ("diagonal", 180.0 / faces, (0.0, 0.0))]


def assess(req: Request, prism: PrismSpec, *, glass: Glass | None = None, layout: str = "given",
           source: str = "given", step: float = 16.0, screen: bool = False) -> Candidate:
    """Check one existing prism against the request (the checks of the module docstring) and predict it.

    ``step``: grid step of the traced pixels, px. ``screen``: predict only the near and far depths (the
    search's first pass; a candidate that passes is assessed again over the whole range).
    """
    g = glass if glass is not None else Glass(f"n={prism.refractive_index:g}", prism.refractive_index)
    rig = Rig(camera=req.camera, prism=prism, name="candidate")

    def cand(rejected: str | None, reason: str, pred: Prediction | None) -> Candidate:
        return Candidate(faces=prism.faces, corner_angle=prism.corner_angle, apex_distance=prism.apex_distance,
                         glass=g, layout=layout, rig=rig, prediction=pred, rejected=rejected, reason=reason,
                         source=source)

    sample = sample_rig(rig, step=step)
    if sample.lost_share > 0.002:
        unb = trace_pixels(rig, sample.pixels, bounded=False)
        if not unb.valid.all():
            return cand("tir", f"{100 * (1 - unb.valid.mean()):.1f} % of the field is totally internally reflected",
                        None)
        return cand("size", f"the glass does not cover the field: {100 * sample.lost_share:.1f} % of the sensor "
                            "sees past it", None)
    size = glass_size(prism, sample.rays)
    if size.largest > req.max_size:
        return cand("size", f"the glass is {size.largest:.1f} mm, more than max_size {req.max_size:g} mm", None)
    for k in range(prism.faces):
        if not np.all(np.isfinite(sample.centres[k])):
            return cand("overlap", f"face {k} is not seen by the camera", None)
    depths = np.array([req.near, req.far]) if screen else req.depths
    pred, fields = predict_sample(sample, depths, precision=req.precision, preset=req.preset)
    worst = min(pred.depths, key=lambda p: p.field_share)
    need = req.field_share_for(prism.faces)
    if worst.field_share < need:
        return cand("overlap", f"the views share {100 * worst.field_share:.0f} % of a sub-image at "
                               f"{worst.depth_mm:.0f} mm, less than min_field_share {100 * need:.0f} %", pred)
    if req.field is not None and not fields[-1].contains_rectangle(*req.field):
        far = pred.depths[-1]
        return cand("field", f"the common field at {far.depth_mm:.0f} mm is {far.field_width_mm:.0f} × "
                             f"{far.field_height_mm:.0f} mm, smaller than field {req.field[0]:g} × {req.field[1]:g} mm",
                    pred)
    if pred.width_spread > req.max_width_spread:
        return cand("balance", f"the sub-images differ by {100 * pred.width_spread:.0f} % in width, more than "
                               f"max_width_spread {100 * req.max_width_spread:.0f} %", pred)
    err = pred.depths[-1].relative_error
    if req.accuracy is not None and err > req.accuracy:
        return cand("accuracy", f"expected error {100 * err:.3f} % at {req.far:.0f} mm, more than accuracy "
                                f"{100 * req.accuracy:.3g} %", pred)
    return cand(None, "", pred)


def _candidate(req: Request, faces: int, alpha: float, apex: float, glass: Glass, step: float
               ) -> list[Candidate]:
    out = []
    if alpha >= max_corner_angle(glass.n_d):
        return [Candidate(faces=faces, corner_angle=alpha, apex_distance=apex, glass=glass, layout="centred", rig=None,
                          prediction=None, rejected="tir",
                          reason=f"corner angle {alpha:g}° reflects the axial ray totally for n = {glass.n_d:g}")]
    for name, rotation, decenter in _layouts(req, faces, alpha, glass, apex):
        prism, tir = size_prism(req.camera, faces=faces, corner_angle=alpha, refractive_index=glass.n_d,
                                apex_distance=apex, edge_thickness=req.edge_thickness, rotation=rotation,
                                decenter=decenter)
        if prism is None:
            out.append(Candidate(faces=faces, corner_angle=alpha, apex_distance=apex, glass=glass, layout=name,
                                 rig=None, prediction=None, rejected="tir",
                                 reason=f"{100 * tir:.1f} % of the field is totally internally reflected "
                                        f"(corner angle {alpha:g}°, n = {glass.n_d:g})"))
            continue
        c = assess(req, prism, glass=glass, layout=name, source="search", step=32.0, screen=True)
        if c.feasible:
            c = assess(req, prism, glass=glass, layout=name, source="search", step=step)
        out.append(c)
    return out


def _rank_key(req: Request, c: Candidate) -> tuple[float, float]:
    assert c.prediction is not None
    if req.accuracy is not None:
        return (-c.prediction.min_field_share, c.prediction.worst_error)
    return (c.prediction.worst_error, -c.prediction.min_field_share)


def _extreme(cands: Sequence[Candidate], value: Callable[[Prediction], float], *, largest: bool
             ) -> tuple[float, Candidate] | None:
    """The candidate whose prediction has the largest (or smallest) ``value``, with that value; None if none."""
    got = [(value(c.prediction), c) for c in cands if c.prediction is not None]
    if not got:
        return None
    return (max if largest else min)(got, key=lambda t: t[0])


def _no_solution(req: Request, cands: Sequence[Candidate]) -> GeometryError:
    stage = max((CHECKS.index(c.rejected) for c in cands if c.rejected is not None), default=0)
    name = CHECKS[stage]
    last = [c for c in cands if c.rejected == name]
    hint = {"tir": "use a smaller corner angle or a glass of higher index",
            "size": "raise max_size or lower min_apex_distance",
            "overlap": "lower min_field_share or widen the apex distances (min/max_apex_distance)",
            "field": "ask for a smaller field, or allow a larger glass (max_size) and apex distance",
            "balance": "raise max_width_spread",
            "accuracy": "relax accuracy, raise max_size or max_apex_distance"}[name]
    best = ""
    if name == "size":
        sizes = [(glass_size(c.rig.prism).largest, c) for c in last if c.rig is not None]
        if sizes:
            s, c = min(sizes, key=lambda t: t[0])
            best = f"; the smallest glass needed is {s:.1f} mm (α {c.corner_angle:g}°, apex {c.apex_distance:g} mm)"
    elif name == "overlap":
        hit = _extreme(last, lambda p: p.min_field_share, largest=True)
        if hit:
            s, c = hit
            best = f"; the best shares {100 * s:.0f} % (α {c.corner_angle:g}°, apex {c.apex_distance:g} mm)"
    elif name == "field":
        hit = _extreme(last, lambda p: p.depths[-1].field_area_mm2, largest=True)
        if hit:
            c = hit[1]
            assert c.prediction is not None
            p = c.prediction.depths[-1]
            best = (f"; the largest common field at {req.far:g} mm is {p.field_width_mm:.0f} × "
                    f"{p.field_height_mm:.0f} mm "
                    f"(α {c.corner_angle:g}°, apex {c.apex_distance:g} mm)")
    elif name == "balance":
        hit = _extreme(last, lambda p: p.width_spread, largest=False)
        if hit:
            best = f"; the most even differs by {100 * hit[0]:.0f} %"
    elif name == "accuracy":
        hit = _extreme(last, lambda p: p.depths[-1].relative_error, largest=False)
        if hit:
            e, c = hit
            best = (f"; the best reaches {100 * e:.3g} % (α {c.corner_angle:g}°, apex {c.apex_distance:g} mm, "
                    f"glass {c.glass.name})")
    what = {"tir": "total internal reflection", "size": f"max_size {req.max_size:g} mm",
            "overlap": f"min_field_share {100 * req.field_share_for(min(req.faces)):.0f} % over "
                       f"{req.near:g}-{req.far:g} mm",
            "field": f"field {req.field[0]:g} × {req.field[1]:g} mm at {req.far:g} mm" if req.field else "field",
            "balance": f"max_width_spread {100 * req.max_width_spread:.0f} %",
            "accuracy": f"accuracy {100 * (req.accuracy or 0):.3g} % at {req.far:g} mm"}[name]
    return GeometryError(f"expected a prism that meets every constraint, got none: {what} binds "
                         f"({len(last)} of {len(cands)} candidates fail it last{best}); {hint}")


def search(camera: CameraSpec, *, near: float, far: float, field: tuple[float, float] | None = None,
           accuracy: float | None = None, faces: Sequence[int] = (2,), glass: Any = "N-BK7",
           max_size: float = 100.0, min_apex_distance: float = 50.0, max_apex_distance: float = 400.0,
           edge_thickness: float = 1.0, min_field_share: float | None = None, max_width_spread: float = 0.10,
           disparity_precision: float | str = DEFAULT_PRESET, include: Sequence[PrismSpec] = (),
           keep: int = 12) -> Design:
    """Search and rank prisms for ``camera`` and the depth range ``near``–``far`` mm (module docstring).

    Parameters
    ----------
    camera : CameraSpec
    near, far : float
        The job's depth range, world Z, mm.
    field : (W, H) mm, optional
        Field the two views must share at ``far``.
    accuracy : float, optional
        Expected relative depth error wanted at ``far`` (0.001 = 0.1 %).
    faces : sequence of int
        Face counts to search (2 = bi-prism).
    glass : str, Glass or sequence
        Catalogue name(s) of :data:`~prismstereo.design.glass.GLASSES` or ``"n=…"``.
    max_size : float
        Largest dimension of the glass, mm.
    min_apex_distance, max_apex_distance : float
        Apex distances searched, mm (the minimum clears the lens).
    edge_thickness : float
        Glass behind the faces' base (a flat slab), mm.
    min_field_share : float, optional
        The ``overlap`` check; default :data:`MIN_FIELD_SHARE` (0.5 for a bi-prism, 0.3 for N >= 3 faces).
    max_width_spread : float
        The ``balance`` check.
    disparity_precision : float or str
        Median |δd| px or a preset (:data:`~prismstereo.design.precision.DISPARITY_PRECISION`).
    include : sequence of PrismSpec
        Existing prisms to assess and rank beside the searched ones (``source="given"``).
    keep : int
        Feasible candidates re-predicted on a finer pixel grid at the end.

    Returns
    -------
    Design

    Raises
    ------
    GeometryError
        No candidate passes every check; the message names the binding constraint.
    """
    t0, c0 = time.perf_counter(), time.process_time()
    precision, preset = disparity_precision_of(disparity_precision)
    req = Request(camera=camera, near=float(near), far=float(far), field=None if field is None else
                  (float(field[0]), float(field[1])), accuracy=None if accuracy is None else float(accuracy),
                  faces=tuple(int(n) for n in faces), glasses=parse_glasses(glass), max_size=float(max_size),
                  min_apex_distance=float(min_apex_distance), max_apex_distance=float(max_apex_distance),
                  edge_thickness=float(edge_thickness),
                  min_field_share=None if min_field_share is None else float(min_field_share),
                  max_width_spread=float(max_width_spread), precision=precision, preset=preset)

    apexes = np.unique(np.round(np.geomspace(req.min_apex_distance, req.max_apex_distance, APEX_COUNT), 0))
    cands: list[Candidate] = []
    seen: set[tuple[int, float, float, str]] = set()

    def run(n: int, alpha: float, apex: float, g: Glass) -> list[Candidate]:
        key = (n, round(alpha, 3), round(apex, 2), g.name)
        if key in seen or not req.min_apex_distance <= apex <= req.max_apex_distance or alpha <= 0:
            return []
        seen.add(key)
        got = _candidate(req, n, alpha, apex, g, 16.0)
        cands.extend(got)
        return got

    def share(got: list[Candidate]) -> float:
        return max((c.prediction.min_field_share for c in got if c.prediction is not None), default=-1.0)

    for n in req.faces:
        for g in req.glasses:
            limit = max_corner_angle(g.n_d)
            for apex in apexes:
                # the views' common field grows with the corner angle until they cross, then shrinks: once it
                # has peaked and fallen below min_field_share, larger angles only share less; the glass grows
                # with the corner angle and the apex distance: once too large, it is too large for the rest
                best = -1.0
                first = True
                too_big = False
                for alpha in np.arange(ANGLE_STEP, limit + ANGLE_STEP, ANGLE_STEP):
                    got = run(n, float(alpha), float(apex), g)
                    if got and all(c.rejected == "size" for c in got):
                        too_big = first
                        break
                    first = False
                    s = share(got)
                    if any(c.rejected == "tir" for c in got) and not any(c.rig is not None for c in got):
                        break
                    if s >= 0 and best >= 0 and s < best and s < req.field_share_for(n) and \
                            all(c.rejected in ("overlap", "field") or c.rejected is None for c in got):
                        break
                    best = max(best, s)
                if too_big:
                    break
    # refine around the best few of each face count
    for n in req.faces:
        ok = sorted((c for c in cands if c.feasible and c.faces == n), key=lambda c: _rank_key(req, c))
        for c in ok[:2]:
            for da in np.arange(-0.3, 0.31, ANGLE_STEP_FINE):
                for dz in np.arange(-2, 3) * APEX_STEP_FINE:
                    run(n, round(c.corner_angle + float(da), 2), round(c.apex_distance + float(dz), 1), c.glass)
    for p in include:
        cands.append(assess(req, p, source="given"))
    feasible = sorted((c for c in cands if c.feasible), key=lambda c: _rank_key(req, c))
    if not feasible:
        raise _no_solution(req, cands)
    # the best ones again on a finer grid of pixels, then the final order
    fine = []
    for c in feasible[:keep]:
        assert c.rig is not None
        again = assess(req, c.rig.prism, glass=c.glass, layout=c.layout, source=c.source, step=8.0)
        fine.append(again)
    final = sorted([c for c in fine if c.feasible], key=lambda c: _rank_key(req, c)) + \
        [c for c in feasible[keep:]]
    given = [c for c in feasible[keep:] if c.source == "given"]
    final = [c for c in final if c not in given] + given if given else final
    ranked = [replace(c, rank=i + 1) for i, c in enumerate(sorted(final, key=lambda c: _rank_key(req, c)))]
    rejected = [c for c in cands if not c.feasible] + [c for c in fine if not c.feasible]
    design = Design(request=req, candidates=tuple(ranked + rejected), seconds=time.perf_counter() - t0,
                    cpu_seconds=time.process_time() - c0)
    log.info("design search: %d candidates, %d feasible, %.1f s", len(design.candidates), len(ranked), design.seconds)
    return design
