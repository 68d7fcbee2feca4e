"""Predicted depth resolution of a rig, per depth: baseline, disparity, common field, expected error.

The model (docs/design.md): the pair of faces the depth command matches by default
(:func:`~prismstereo.depth.pipeline.default_views`) is rectified like the pipeline does (common rotation with
r1 along the baseline, thesis Eq. 3.36; the real camera's focal length f in pixels). A point X at world depth Z
in the middle of the common field has rectified depth z = r3·(X − C_left) and disparity d = f·B / z. A
disparity error δd moves the triangulated point along the left ray by |∂X/∂d|·δd = |X − C_left| / d · δd, so

    |δZ| / Z = (Z − C_left,z) · z / (Z · f · B) · |δd|

and the expected (median) relative depth error is this with |δd| the median absolute disparity error of the
matcher: :data:`~prismstereo.design.precision.DISPARITY_PRECISION`, measured on rendered captures
(``benchmarks/bench_design.py``), not assumed.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from prismstereo.config import Rig
from prismstereo.depth.pipeline import default_views
from prismstereo.design.geometry import (
    FieldAtDepth,
    GlassSize,
    RigSample,
    SubImage,
    common_field,
    glass_size,
    sample_rig,
)
from prismstereo.design.precision import DEFAULT_PRESET, disparity_precision_of
from prismstereo.errors import ConfigError, GeometryError
from prismstereo.rectify import rectifying_rotation

__all__ = ["DepthPrediction", "Prediction", "predict", "predict_sample"]


@dataclass(frozen=True)
class DepthPrediction:
    """The prediction at one world depth.

    Attributes
    ----------
    depth_mm : float
    baseline_mm : float
        Distance between the two virtual camera centres.
    disparity_px : float
        True disparity f·B/z of the middle of the common field (before any offset of the rectified views).
    field_share : float
        Share of each view's sampled pixels that the other view sees too (the smaller of the two).
    field_width_mm, field_height_mm, field_area_mm2 : float
        Extent and area of the common field on the plane at this depth.
    relative_error : float
        Expected median |δZ| / Z (a fraction).
    error_mm : float
        Expected median |δZ|, mm.
    """

    depth_mm: float
    baseline_mm: float
    disparity_px: float
    field_share: float
    field_width_mm: float
    field_height_mm: float
    field_area_mm2: float
    relative_error: float
    error_mm: float

    def to_dict(self) -> dict[str, float]:
        return {k: float(getattr(self, k)) for k in self.__dataclass_fields__}


@dataclass(frozen=True)
class Prediction:
    """What a rig will measure over a set of depths (:func:`predict`).

    Attributes
    ----------
    rig : Rig
    views : (left, right) faces of the predicted pair (left = smaller coordinate along the baseline).
    disparity_precision : float
        Median absolute disparity error assumed, px.
    preset : str or None
        The matcher preset the precision was measured for (None when given as a number).
    depths : tuple of DepthPrediction
    sub_images : tuple of SubImage
        What the sensor sees through each face.
    glass : GlassSize
    lost_share : float
        Share of the sensor whose rays do not cross the glass.
    """

    rig: Rig
    views: tuple[int, int]
    disparity_precision: float
    preset: str | None
    depths: tuple[DepthPrediction, ...]
    sub_images: tuple[SubImage, ...]
    glass: GlassSize
    lost_share: float

    def at(self, depth_mm: float) -> DepthPrediction:
        """The prediction at the sampled depth nearest ``depth_mm``."""
        return min(self.depths, key=lambda p: abs(p.depth_mm - depth_mm))

    @property
    def worst_error(self) -> float:
        """Largest expected relative error over the depths."""
        return max(p.relative_error for p in self.depths)

    @property
    def min_field_share(self) -> float:
        return min(p.field_share for p in self.depths)

    @property
    def width_spread(self) -> float:
        """max / min − 1 of the sub-images' widths (0 = all equally wide)."""
        w = [s.width_px for s in self.sub_images]
        return float(max(w) / min(w) - 1.0) if min(w) > 0 else float("inf")

    def to_dict(self) -> dict[str, Any]:
        return {"views": list(self.views), "disparity_precision_px": self.disparity_precision,
                "preset": self.preset, "per_depth": [p.to_dict() for p in self.depths],
                "sub_images": [s.to_dict() for s in self.sub_images], "sub_image_width_spread": self.width_spread,
                "glass": self.glass.to_dict(), "lost_share": self.lost_share}


def _pair(rig: Rig, views: tuple[int, int] | None) -> tuple[int, int]:
    a, b = default_views(rig) if views is None else (int(views[0]), int(views[1]))
    n = rig.prism.faces
    if not (0 <= a < n and 0 <= b < n) or a == b:
        raise ConfigError(f"views: expected two different faces in [0, {n - 1}], got {(a, b)}")
    return a, b


def depth_prediction(sample: RigSample, field: FieldAtDepth, left: int, right: int, R: np.ndarray,
                     precision: float) -> DepthPrediction:
    """The prediction at one depth from a traced sample, the shared field there and the rectifying rotation."""
    C_l, C_r = sample.centres[left], sample.centres[right]
    B = float(np.linalg.norm(C_r - C_l))
    f = sample.rig.camera.focal_px
    Z = field.depth_mm
    X = field.centroid if np.all(np.isfinite(field.centroid)) else np.array([0.0, 0.0, Z])
    z = float(R[2] @ (X - C_l))
    d = f * B / z
    rel = (Z - float(C_l[2])) * z / (Z * f * B) * precision
    return DepthPrediction(depth_mm=Z, baseline_mm=B, disparity_px=d, field_share=field.share,
                           field_width_mm=field.width_mm, field_height_mm=field.height_mm,
                           field_area_mm2=field.area_mm2, relative_error=rel, error_mm=rel * Z)


def predict_sample(sample: RigSample, depths: Sequence[float] | np.ndarray, *, precision: float,
                   preset: str | None = None,
                   views: tuple[int, int] | None = None) -> tuple[Prediction, tuple[FieldAtDepth, ...]]:
    """:func:`predict` on an already traced :class:`~prismstereo.design.geometry.RigSample`; also the fields."""
    rig = sample.rig
    a, b = _pair(rig, views)
    if not (np.all(np.isfinite(sample.centres[a])) and np.all(np.isfinite(sample.centres[b]))):
        raise GeometryError(f"expected faces {a} and {b} to be seen by the camera, got a face no pixel looks through "
                            f"(corner_angle {rig.prism.corner_angle:g}°, apex_distance {rig.prism.apex_distance:g} mm)")
    R, swapped = rectifying_rotation(sample.centres[a], sample.centres[b])
    left, right = (b, a) if swapped else (a, b)
    fields = tuple(common_field(sample, left, right, float(z)) for z in depths)
    preds = tuple(depth_prediction(sample, fd, left, right, R, precision) for fd in fields)
    return Prediction(rig=rig, views=(left, right), disparity_precision=precision, preset=preset, depths=preds,
                      sub_images=sample.sub_images(), glass=glass_size(rig.prism, sample.rays),
                      lost_share=sample.lost_share), fields


def predict(rig: Rig, *, depths: Sequence[float] | np.ndarray, disparity_precision: float | str = DEFAULT_PRESET,
            views: tuple[int, int] | None = None, step: float = 8.0) -> Prediction:
    """Predicted depth resolution and common field of ``rig`` at world depths ``depths`` (mm).

    Parameters
    ----------
    rig : Rig
    depths : sequence of float
        World depths, mm, beyond the prism's back plane.
    disparity_precision : float or str
        Median absolute disparity error, px, or a preset name (``fast``, ``balanced``, ``accurate``) whose
        measured value (:data:`~prismstereo.design.precision.DISPARITY_PRECISION`) is used.
    views : (i, j), optional
        The pair of faces; default the depth command's (:func:`~prismstereo.depth.pipeline.default_views`).
    step : float
        Grid step of the traced sensor pixels, px.

    Returns
    -------
    Prediction
        Per depth the baseline, disparity, common field and expected error (module docstring), the sub-image
        sizes and the glass's dimensions.
    """
    zs = [float(z) for z in depths]
    if not zs or any(not np.isfinite(z) or z <= rig.prism.back_distance for z in zs):
        raise ConfigError(f"depths: expected world depths beyond the back plane ({rig.prism.back_distance:g} mm), "
                          f"got {zs}")
    precision, preset = disparity_precision_of(disparity_precision)
    pred, _ = predict_sample(sample_rig(rig, step=step), zs, precision=precision, preset=preset, views=views)
    return pred
