"""The fast geometric model behind a design: how large the glass must be, what the sensor sees through each
face, where the virtual cameras are and what field the views share at a depth.

Everything here comes from exact ray tracing (:func:`~prismstereo.optics.trace_pixels`) of a sparse grid of
sensor pixels, so that a search can afford it for thousands of prisms:

- **Glass size.** The prism must cover the whole sensor's field: every pixel's ray has to enter a face
  below the base of the faces and leave through the back plane inside the glass. For a corner angle α the
  inradius r (axis to each face's base edge) is found by fixed-point iteration: rays traced through
  unbounded faces give the largest lateral extent of the entry and exit points along each face's direction,
  r = that · (1 + :data:`SIZE_MARGIN`) + :data:`SIZE_CLEARANCE_MM`, the face height h = r·tan α, the back
  plane at apex + h + edge thickness. A ray the unbounded faces still lose is totally internally reflected.
- **Sub-images.** The pixels of the grid that look through each face: their count (area), bounding width
  and height in pixels.
- **Virtual cameras.** The centre of a face's virtual camera is the mean of the midpoints of the common
  perpendiculars of pairs of its exit rays, back-extended (thesis Appendix A, as
  :func:`~prismstereo.cameras.thesis_camera`).
- **Common field at depth Z.** The points at world depth Z of one face's rays that fall inside the convex
  hull of the other face's points at Z (the hull of a face's footprint on the plane): their share of the
  face's rays, their extent in mm, the area of their hull and their centroid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from itertools import combinations

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from prismstereo.config import CameraSpec, PrismSpec, Rig
from prismstereo.errors import ConfigError
from prismstereo.optics import RayBundle, closest_points_between_lines, pixel_grid, trace_pixels
from prismstereo.simulate.render import dispersed_indices

__all__ = ["SIZE_CLEARANCE_MM", "SIZE_MARGIN", "FieldAtDepth", "GlassSize", "RigSample", "SubImage",
           "colour_spread_px", "common_field", "glass_size", "sample_rig", "sensor_pixels", "size_prism"]

#: relative margin on the glass's inradius beyond the last ray (mounting, chamfers)
SIZE_MARGIN = 0.05
#: absolute clearance on the glass's inradius beyond the last ray, mm
SIZE_CLEARANCE_MM = 1.0


@dataclass(frozen=True)
class SubImage:
    """What the sensor sees through one face: ``area_px`` pixels inside a ``width_px`` × ``height_px`` box."""

    face: int
    width_px: float
    height_px: float
    area_px: float

    def to_dict(self) -> dict[str, float]:
        return {"face": self.face, "width_px": self.width_px, "height_px": self.height_px, "area_px": self.area_px}


@dataclass(frozen=True)
class GlassSize:
    """Dimensions of the glass, mm.

    ``across_flats``: twice the inradius (bi-prism: its width across the faces); ``across_corners``: the
    base polygon's circumscribed diameter (N ≥ 3; the bi-prism's width); ``length``: a bi-prism's extent along
    its edge needed to cover the field (N ≥ 3: ``across_corners``); ``thickness``: apex to back plane;
    ``largest``: the largest of these, what ``max_size`` is compared with.
    """

    across_flats: float
    across_corners: float
    length: float
    thickness: float
    face_height: float

    @property
    def largest(self) -> float:
        return max(self.across_flats, self.across_corners, self.length, self.thickness)

    def to_dict(self) -> dict[str, float]:
        return {"across_flats_mm": self.across_flats, "across_corners_mm": self.across_corners,
                "length_mm": self.length, "thickness_mm": self.thickness, "face_height_mm": self.face_height,
                "largest_mm": self.largest}


def sensor_pixels(camera: CameraSpec, step: float) -> np.ndarray:
    """(M, 2) pixel centres of a grid with this step (cell centres) and the image border every ``step``."""
    w, h = camera.width, camera.height
    grid = pixel_grid(w, h, step=step).reshape(-1, 2) + (step - 1) / 2.0
    grid = grid[(grid[:, 0] <= w - 1) & (grid[:, 1] <= h - 1)]
    us = np.append(np.arange(0.0, w - 1, step), w - 1.0)
    vs = np.append(np.arange(0.0, h - 1, step), h - 1.0)
    border = np.concatenate([np.stack([us, np.zeros_like(us)], 1), np.stack([us, np.full_like(us, h - 1.0)], 1),
                             np.stack([np.zeros_like(vs), vs], 1), np.stack([np.full_like(vs, w - 1.0), vs], 1)])
    return np.concatenate([grid, border])


def _lateral(prism: PrismSpec, points: np.ndarray) -> np.ndarray:
    """(M,) largest p·u_k of points (M, 3) in the centred prism's frame (the lateral walls are at the inradius)."""
    q = points.copy()
    if prism.is_posed:
        M, apex = prism.pose()
        q = (q - apex) @ M + np.array([0.0, 0.0, prism.apex_distance])
    return np.max(q @ prism.face_directions().T, axis=1)


def glass_size(prism: PrismSpec, rays: RayBundle | None = None) -> GlassSize:
    """The glass's dimensions (mm); a bi-prism's length is the extent along its edge that ``rays`` cross
    (default: its across-flats width)."""
    r = prism.inradius
    n = prism.faces
    corners = 2.0 * r if n == 2 else 2.0 * r / math.cos(math.pi / n)
    length = corners
    if n == 2 and rays is not None:
        pts = np.concatenate([rays.entry_points[rays.valid], rays.origins[rays.valid]])
        edge_dir = np.array([-math.sin(math.radians(prism.rotation)), math.cos(math.radians(prism.rotation)), 0.0])
        along = np.abs((pts - np.array([prism.decenter[0], prism.decenter[1], 0.0])) @ edge_dir)
        length = 2.0 * (float(along.max()) * (1.0 + SIZE_MARGIN) + SIZE_CLEARANCE_MM) if along.size else corners
    return GlassSize(across_flats=2.0 * r, across_corners=corners, length=length,
                     thickness=prism.back_distance - prism.apex_distance, face_height=prism.face_height)


def size_prism(camera: CameraSpec, *, faces: int, corner_angle: float, refractive_index: float,
               apex_distance: float, edge_thickness: float = 1.0, rotation: float = 0.0,
               decenter: tuple[float, float] = (0.0, 0.0), step: float = 32.0) -> tuple[PrismSpec | None, float]:
    """The smallest prism of this shape whose glass covers the camera's whole field (module docstring).

    Returns
    -------
    prism : PrismSpec or None
        None when some ray of the field cannot cross the glass at all (total internal reflection).
    tir_share : float
        Share of the sampled sensor pixels whose rays are lost through any glass of this shape.
    """
    if not 0.0 < corner_angle < 90.0:
        raise ConfigError(f"corner_angle: expected degrees in (0, 90), got {corner_angle!r}")
    if edge_thickness < 0:
        raise ConfigError(f"edge_thickness: expected a thickness >= 0 mm, got {edge_thickness!r}")
    px = sensor_pixels(camera, step)
    t = math.tan(math.radians(corner_angle))
    f = camera.focal_xy
    cx, cy = camera.center
    tf = math.hypot(max(cx, camera.width - 1 - cx) / f[0], max(cy, camera.height - 1 - cy) / f[1])
    r = apex_distance * tf / max(1e-3, 1.0 - tf * t) + abs(decenter[0]) + abs(decenter[1])
    def build(radius: float) -> PrismSpec:
        h = radius * t
        return PrismSpec(faces=faces, corner_angle=corner_angle, refractive_index=refractive_index,
                         apex_distance=apex_distance, back_distance=apex_distance + h + max(edge_thickness, 1e-3),
                         height=h, rotation=rotation, decenter=decenter)

    for _ in range(8):
        b = trace_pixels(Rig(camera=camera, prism=build(r)), px, bounded=False)
        tir = float(1.0 - b.valid.mean())
        if tir > 0:
            return None, tir
        prism = build(r)
        need = max(float(_lateral(prism, b.entry_points).max()), float(_lateral(prism, b.origins).max()))
        new_r = need * (1.0 + SIZE_MARGIN) + SIZE_CLEARANCE_MM
        converged = abs(new_r - r) < 0.05
        r = new_r
        if converged:
            break
    return build(r), 0.0


@dataclass(frozen=True)
class RigSample:
    """Exact rays of a grid of sensor pixels through a rig, split by face (see the module docstring).

    Attributes
    ----------
    rig : Rig
    step : float
        Grid step, px.
    pixels : (M, 2) the sampled pixels.
    rays : RayBundle of the pixels (bounded: rays that miss the glass are invalid).
    centres : (N, 3) virtual camera centre of each face, mm (NaN for a face that is not seen).
    """

    rig: Rig
    step: float
    pixels: np.ndarray
    rays: RayBundle
    centres: np.ndarray

    @property
    def lost_share(self) -> float:
        """Share of the grid's pixels whose rays do not cross the glass (cut-off sub-images)."""
        return float(1.0 - self.rays.valid.mean())

    def sub_images(self) -> tuple[SubImage, ...]:
        out = []
        grid = self._grid_only()
        for k in range(self.rig.prism.faces):
            sel = grid & (self.rays.face == k)
            if not sel.any():
                out.append(SubImage(face=k, width_px=0.0, height_px=0.0, area_px=0.0))
                continue
            p = self.pixels[sel]
            w = min(float(p[:, 0].max() - p[:, 0].min()) + self.step, float(self.rig.camera.width))
            h = min(float(p[:, 1].max() - p[:, 1].min()) + self.step, float(self.rig.camera.height))
            out.append(SubImage(face=k, width_px=w, height_px=h, area_px=float(sel.sum()) * self.step ** 2))
        return tuple(out)

    def _grid_only(self) -> np.ndarray:
        """(M,) bool: the interior grid's pixels (not the border samples), which tile the sensor evenly."""
        s = self.step
        frac = (self.pixels - (s - 1) / 2.0) / s
        return np.all(np.abs(frac - np.round(frac)) < 1e-9, axis=1)

    def face_points(self, face: int, depth_mm: float) -> np.ndarray:
        """(M_k, 3) points at world depth ``depth_mm`` of the face's sampled rays."""
        sel = self.rays.face == face
        return self.rays.point_at_depth(float(depth_mm))[sel]


def sample_rig(rig: Rig, *, step: float = 16.0, n_centre_rays: int = 24) -> RigSample:
    """Trace a grid of ``step`` px (and the image border) through the rig and find each face's virtual centre."""
    px = sensor_pixels(rig.camera, step)
    b = trace_pixels(rig, px)
    centres = np.full((rig.prism.faces, 3), np.nan)
    rng = np.random.default_rng(0)
    for k in range(rig.prism.faces):
        idx = np.flatnonzero(b.face == k)
        if idx.size < 4:
            continue
        pick = rng.choice(idx, size=min(n_centre_rays, idx.size), replace=False)
        pairs = np.array(list(combinations(range(pick.size), 2)))
        o, d = b.origins[pick], b.directions[pick]
        mids, _ = closest_points_between_lines(o[pairs[:, 0]], d[pairs[:, 0]], o[pairs[:, 1]], d[pairs[:, 1]])
        centres[k] = np.nanmean(mids, axis=0)
    return RigSample(rig=rig, step=step, pixels=px, rays=b, centres=centres)


@dataclass(frozen=True)
class FieldAtDepth:
    """The field two faces' views share on the plane at world depth ``depth_mm``.

    ``share``: the smaller of the two shares of a face's sampled rays that the other face also sees;
    ``width_mm``, ``height_mm``: extent of the shared points; ``area_mm2``: area of their hull;
    ``centroid``: (3,) their mean, mm.
    """

    depth_mm: float
    share: float
    width_mm: float
    height_mm: float
    area_mm2: float
    centroid: np.ndarray
    hulls: tuple[np.ndarray | None, np.ndarray | None]

    def contains_rectangle(self, width_mm: float, height_mm: float, *, n: int = 16) -> bool:
        """True when a ``width_mm`` × ``height_mm`` rectangle centred on the shared points lies in both views."""
        if self.share <= 0 or any(h is None for h in self.hulls):
            return False
        t = np.linspace(-0.5, 0.5, n)
        ones = np.full(n, 0.5)
        edge = np.concatenate([np.stack([t, -ones], 1), np.stack([t, ones], 1), np.stack([-ones, t], 1),
                               np.stack([ones, t], 1)])
        pts = self.centroid[:2] + edge * np.array([width_mm, height_mm])
        return all(bool(np.all(_inside(h, pts))) for h in self.hulls if h is not None)


def _hull(points: np.ndarray) -> np.ndarray | None:
    """(F, 3) half-plane equations a·x + b·y + c <= 0 of the convex hull of (M, 2) points, or None."""
    if points.shape[0] < 3:
        return None
    try:
        return np.asarray(ConvexHull(points).equations)
    except QhullError:
        return None


def _inside(hull: np.ndarray, points: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """(M,) bool: the (M, 2) points lie inside the hull's half-planes."""
    return np.asarray(np.max(points @ hull[:, :2].T + hull[:, 2], axis=1) <= tol)


def common_field(sample: RigSample, face_a: int, face_b: int, depth_mm: float) -> FieldAtDepth:
    """The field faces ``face_a`` and ``face_b`` share at world depth ``depth_mm`` (module docstring)."""
    pa = sample.face_points(face_a, depth_mm)
    pb = sample.face_points(face_b, depth_mm)
    ha, hb = _hull(pa[:, :2]), _hull(pb[:, :2])
    empty = FieldAtDepth(depth_mm=float(depth_mm), share=0.0, width_mm=0.0, height_mm=0.0, area_mm2=0.0,
                         centroid=np.array([np.nan, np.nan, float(depth_mm)]), hulls=(ha, hb))
    if ha is None or hb is None:
        return empty
    in_b = _inside(hb, pa[:, :2])
    in_a = _inside(ha, pb[:, :2])
    share = float(min(in_b.mean(), in_a.mean()))
    common = np.concatenate([pa[in_b], pb[in_a]])
    if common.shape[0] < 3:
        return empty
    ext = np.ptp(common[:, :2], axis=0)
    try:
        area = float(ConvexHull(common[:, :2]).volume)
    except QhullError:
        area = 0.0
    return FieldAtDepth(depth_mm=float(depth_mm), share=share, width_mm=float(ext[0]), height_mm=float(ext[1]),
                        area_mm2=area, centroid=common.mean(axis=0), hulls=(ha, hb))


def colour_spread_px(rig: Rig, abbe: float | None, *, step: float = 32.0) -> float:
    """Largest angle (in pixels of focal length) between the exit rays of the same sensor pixel at 656.3 nm and
    486.1 nm (the glass's dispersion, indices from its Abbe number as the simulator's
    :func:`~prismstereo.simulate.render.dispersed_indices`); 0 for a glass without an Abbe number.

    A colour camera sees each face's red and blue images this far apart; the measured disparity precision
    holds for a monochrome (narrow-band) capture (docs/design.md, limits).
    """
    if abbe is None:
        return 0.0
    n_c, _, n_f = dispersed_indices(rig.prism.refractive_index, abbe)
    px = sensor_pixels(rig.camera, step)
    red = trace_pixels(rig.with_prism(refractive_index=n_c), px)
    blue = trace_pixels(rig.with_prism(refractive_index=n_f), px)
    ok = red.valid & blue.valid & (red.face == blue.face)
    if not ok.any():
        return 0.0
    cos = np.clip(np.einsum("ij,ij->i", red.directions[ok], blue.directions[ok]), -1.0, 1.0)
    return float(np.max(np.arccos(cos)) * rig.camera.focal_px)
