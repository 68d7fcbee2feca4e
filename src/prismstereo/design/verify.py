"""Measured depth and disparity errors of a rig on rendered captures: what ``design --verify`` and
``benchmarks/bench_design.py`` run.

At each depth Z a fronto-parallel textured plane is rendered through the rig (:func:`verify_scene`: seeded
multi-octave noise whose coarsest feature spans :data:`TEXTURE_PX` pixels at any depth, 2 × 2 supersampling,
Gaussian sensor noise of :data:`NOISE_GREY` grey levels, the glass's dispersion when its Abbe number is known),
the depth pipeline runs on the capture (:func:`~prismstereo.depth.pipeline.run_depth`, one preset) and its
output is compared with the exact ground truth:

- **depth error**: |Z − Z_gt| / Z_gt of every reconstructed point, Z_gt where the pixel's exact ray meets the
  plane (:func:`~prismstereo.evaluation.depth_metrics.ground_truth_for_run`);
- **disparity error**: at up to :data:`DISPARITY_SAMPLES` reconstructed pixels, the ground-truth point is
  projected exactly into the right face (:func:`~prismstereo.optics.project_exact`) and that real pixel is
  found in the rectified right view by inverting the view's remap table (Newton on its bilinear lookup, so
  it is where the matcher had to find it); the error is the refined disparity minus x_left − x_right.
- the **relation** between them: each sampled pixel's |δd| times the depth sensitivity
  (Z − C_left,z)·z/(Z·f·B) of the run's own rectified pair (:mod:`prismstereo.design.predict`) predicts its
  relative depth error; ``model_ratio`` is the median measured relative error over the median of these.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from prismstereo.config import Rig
from prismstereo.depth.pipeline import DepthConfig, DepthRun, run_depth
from prismstereo.depth.presets import apply_preset, get_preset
from prismstereo.design.precision import DEFAULT_PRESET, disparity_precision_of
from prismstereo.design.predict import Prediction, predict
from prismstereo.errors import ConfigError
from prismstereo.evaluation.depth_metrics import depth_accuracy, ground_truth_for_run
from prismstereo.optics import project_exact
from prismstereo.rectify import RectifiedPair
from prismstereo.simulate import NoiseTexture, Plane, Scene, render_capture

log = logging.getLogger(__name__)

__all__ = ["AGREEMENT", "DISPARITY_SAMPLES", "NOISE_GREY", "TEXTURE_PX", "Measurement", "VerifyRow",
           "measure_at_depth", "verify", "verify_scene"]

#: size of the coarsest texture feature on the sensor, px (the plane's texture scales with its depth)
TEXTURE_PX = 100.0
#: standard deviation of the rendered sensor noise, grey levels of 255
NOISE_GREY = 1.0
#: pixels at which the disparity error is measured
DISPARITY_SAMPLES = 20_000
#: the measured median error must lie within this share of the predicted one
AGREEMENT = 0.30


def verify_scene(rig: Rig, depth_mm: float, *, seed: int = 5, abbe: float | None = None,
                 noise: float = NOISE_GREY, texture_px: float = TEXTURE_PX) -> Scene:
    """A fronto-parallel textured plane at world depth ``depth_mm`` (module docstring)."""
    scale = texture_px * float(depth_mm) / rig.camera.focal_px
    return Scene(objects=(Plane(center=(0.0, 0.0, float(depth_mm)), name="plane",
                                texture=NoiseTexture(scale=scale, octaves=6, persistence=0.8, contrast=2.5,
                                                     seed=seed)),),
                 supersample=2, noise=noise, seed=seed, abbe=abbe, name=f"plane-{depth_mm:g}mm")


@dataclass(frozen=True)
class Measurement:
    """Errors of one run at one depth (module docstring); relative errors are fractions.

    ``median_rel``, ``p95_rel``, ``coverage``, ``n_points``: the depth map against ground truth;
    ``median_abs_disparity_px``, ``disparity_bias_px``: median |δd| and median δd of the sampled pixels;
    ``model_rel``: median over the sampled pixels of |δd| × their depth sensitivity; ``model_ratio`` =
    median_rel / model_rel; ``baseline_mm``: of the run's rectified pair; ``seconds``: render, depth.
    """

    depth_mm: float
    preset: str
    median_rel: float
    p95_rel: float
    coverage: float
    n_points: int
    median_abs_disparity_px: float
    disparity_bias_px: float
    model_rel: float
    model_ratio: float
    baseline_mm: float
    render_s: float
    depth_s: float

    def to_dict(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def _invert_map(pair: RectifiedPair, real_px: np.ndarray, side: str) -> np.ndarray:
    """Rectified pixels (N, 2) whose remap-table lookup gives ``real_px`` (Newton from the model's inverse)."""
    q = np.asarray(pair.real_to_rectified(real_px, side), dtype=np.float64)
    h = 0.5
    for _ in range(4):
        m = pair.rectified_to_real(q, side)
        mx = pair.rectified_to_real(q + [h, 0.0], side)
        my = pair.rectified_to_real(q + [0.0, h], side)
        J = np.stack([(mx - m) / h, (my - m) / h], axis=-1)  # (N, 2, 2): columns d/dx, d/dy
        r = real_px - m
        ok = np.isfinite(J).all(axis=(1, 2)) & np.isfinite(r).all(axis=1) & (np.abs(np.linalg.det(J)) > 1e-9)
        step = np.full_like(q, np.nan)
        step[ok] = np.linalg.solve(J[ok], r[ok][..., None])[..., 0]
        q = q + step
    return q


def sensitivity(pair: RectifiedPair, points: np.ndarray) -> np.ndarray:
    """(N,) relative depth error per pixel of disparity error of world points (N, 3) for a rectified pair:
    (Z − C_left,z) · z / (Z · f · B) (:mod:`prismstereo.design.predict`)."""
    z = (points - pair.C_left) @ pair.R[2]
    Z = points[:, 2]
    return np.asarray((Z - pair.C_left[2]) * z / (Z * pair.focal_px * pair.baseline_mm))


def disparity_errors(result: DepthRun, gt_points: np.ndarray, *, n: int = DISPARITY_SAMPLES, seed: int = 0
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Disparity errors δd (px) at up to ``n`` reconstructed pixels and those pixels' ground-truth points (M, 3)."""
    pair = result.pair
    if pair is None or result.disparity is None:
        raise ConfigError("expected a pair run (views I,J) to measure disparity errors, got an all-view run")
    ys, xs = np.nonzero(result.valid & np.isfinite(result.disparity) & np.isfinite(gt_points[..., 2]))
    if ys.size == 0:
        return np.zeros(0), np.zeros((0, 3))
    rng = np.random.default_rng(seed)
    pick = rng.choice(ys.size, size=min(n, ys.size), replace=False)
    ys, xs = ys[pick], xs[pick]
    X = gt_points[ys, xs]
    real_r, ok = project_exact(result.rig, X, face=pair.right_face)
    q = np.full((X.shape[0], 2), np.nan)
    if ok.any():
        q[ok] = _invert_map(pair, real_r[ok], "right")
    d_true = xs - q[:, 0]
    err = result.disparity[ys, xs].astype(np.float64) - d_true
    keep = np.isfinite(err)
    return err[keep], X[keep]


def measure_at_depth(rig: Rig, depth_mm: float, *, preset: str = DEFAULT_PRESET,
                     depth_range: tuple[float, float] | None = None, views: tuple[int, int] | None = None,
                     abbe: float | None = None, seed: int = 5) -> Measurement:
    """Render the plane at ``depth_mm``, run the depth pipeline with ``preset`` and measure its errors."""
    profile = get_preset(preset)
    scene = verify_scene(rig, depth_mm, seed=seed, abbe=abbe)
    t0 = time.perf_counter()
    cap = render_capture(rig, scene)
    t1 = time.perf_counter()
    rng = depth_range if depth_range is not None else (0.85 * depth_mm, 1.15 * depth_mm)
    res = run_depth(rig, cap.image, config=apply_preset(DepthConfig(depth_range=rng, views=views), profile))
    t2 = time.perf_counter()
    gt = ground_truth_for_run(res, scene=scene)
    acc = depth_accuracy(res.depth, res.valid, gt)
    err, X = disparity_errors(res, gt.points)
    assert res.pair is not None
    model = np.abs(err) * sensitivity(res.pair, X) if err.size else np.array([np.nan])
    model_rel = float(np.median(model))
    log.info("depth %.0f mm, %s: median %.4f %%, |δd| %.4f px", depth_mm, preset, 100 * acc["median_rel"],
             float(np.median(np.abs(err))) if err.size else float("nan"))
    return Measurement(depth_mm=float(depth_mm), preset=preset, median_rel=float(acc["median_rel"]),
                       p95_rel=float(acc["p95_rel"]), coverage=float(acc["coverage"]), n_points=int(acc["n_points"]),
                       median_abs_disparity_px=float(np.median(np.abs(err))) if err.size else float("nan"),
                       disparity_bias_px=float(np.median(err)) if err.size else float("nan"),
                       model_rel=model_rel, model_ratio=float(acc["median_rel"]) / model_rel,
                       baseline_mm=res.pair.baseline_mm, render_s=t1 - t0, depth_s=t2 - t1)


@dataclass(frozen=True)
class VerifyRow:
    """Predicted against measured median relative depth error at one depth."""

    depth_mm: float
    predicted_rel: float
    measured: Measurement

    @property
    def ratio(self) -> float:
        """measured / predicted."""
        return self.measured.median_rel / self.predicted_rel

    @property
    def agrees(self) -> bool:
        return bool(abs(self.ratio - 1.0) <= AGREEMENT)

    def to_dict(self) -> dict[str, Any]:
        return {"depth_mm": self.depth_mm, "predicted_rel": self.predicted_rel,
                "measured_rel": self.measured.median_rel, "ratio": self.ratio, "agrees": self.agrees,
                "measurement": self.measured.to_dict()}


def verify(rig: Rig, *, depths: Sequence[float] | np.ndarray, preset: str = DEFAULT_PRESET,
           views: tuple[int, int] | None = None,
           depth_range: tuple[float, float] | None = None, abbe: float | None = None,
           prediction: Prediction | None = None) -> tuple[VerifyRow, ...]:
    """Predicted (:func:`~prismstereo.design.predict.predict`) against measured (:func:`measure_at_depth`)
    median relative depth error at each of ``depths`` (mm), with the precision measured for ``preset``."""
    zs = [float(z) for z in depths]
    precision, _ = disparity_precision_of(preset)
    pred = prediction if prediction is not None else predict(rig, depths=zs, disparity_precision=precision, views=views)
    rows = []
    for z in zs:
        m = measure_at_depth(rig, z, preset=preset, depth_range=depth_range, views=views, abbe=abbe)
        p = pred.at(z)
        rel = p.relative_error * precision / pred.disparity_precision
        rows.append(VerifyRow(depth_mm=z, predicted_rel=rel, measured=m))
    return tuple(rows)
