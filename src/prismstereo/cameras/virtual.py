"""Virtual cameras of a prism rig: three models behind one interface.

- ``thesis``: the geometric construction of thesis §3.2.1 and §4.1.2 — the optical centre is the average
  of midpoints of the common perpendiculars of back-extended exit rays (Appendix A), the optical axis is
  the refracted ray of the image centre, the intrinsics are the real camera's.
- ``fit``: a pinhole (K, R, C) with OpenCV 5-term distortion fitted by least squares to exactly traced
  rays of the face's image region, so that it reprojects 3D points where the real optics put them.
- ``exact``: the generalised camera: for any real pixel the exact ray (origin, direction) through the
  prism, and :func:`~prismstereo.optics.project_exact` for the inverse.

Refraction through a prism is not a central projection (the exit rays of one face do not meet in one
point), so ``thesis`` and ``fit`` are approximations whose error is reported, and ``exact`` is the
reference they are measured against.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from prismstereo.cameras.faces import face_pixels, thesis_camera, unseen_face_message
from prismstereo.cameras.overlap import MODEL_FRACTION, working_depth_range
from prismstereo.cameras.pinhole import PinholeCamera
from prismstereo.config import Rig, rig_from_dict
from prismstereo.errors import ConfigError, GeometryError
from prismstereo.io.jsonio import write_json
from prismstereo.optics import RayBundle, project_exact, trace_pixels

log = logging.getLogger(__name__)

METHODS = ("thesis", "fit")
#: a fixed range for callers that want one (the models default to the rig's working range,
#: :func:`~prismstereo.cameras.overlap.working_depth_range`)
DEPTH_RANGE_MM = (500.0, 3000.0)


@dataclass(frozen=True)
class VirtualView:
    """One virtual camera of a rig: which face, which model, and how well it reprojects."""

    face: int
    name: str
    method: str
    camera: PinholeCamera
    rms_px: float
    max_px: float

    def project(self, points_in_world: np.ndarray) -> np.ndarray:
        """(..., 3) world points → (..., 2) real-image pixels predicted by this model."""
        return self.camera.project(points_in_world)

    def to_dict(self) -> dict[str, Any]:
        return {"face": self.face, "name": self.name, **self.camera.to_dict(),
                "rms_px": self.rms_px, "max_px": self.max_px}


class ExactCamera:
    """The exact generalised camera of a rig: every pixel's true ray through the prism."""

    def __init__(self, rig: Rig) -> None:
        self.rig = rig

    def rays_from_pixels(self, pixels: np.ndarray) -> RayBundle:
        """(..., 2) real pixels → their rays after the prism (see :class:`~prismstereo.optics.RayBundle`)."""
        return trace_pixels(self.rig, pixels)

    def project(self, points_in_world: np.ndarray, face: int) -> tuple[np.ndarray, np.ndarray]:
        """(N, 3) world points → ((N, 2) real pixels seeing them through ``face``, (N,) valid)."""
        return project_exact(self.rig, points_in_world, face=face)


def sample_points(
    rig: Rig, face: int, *, n: int = 2000, depth_range: tuple[float, float] = DEPTH_RANGE_MM, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Random 3D points seen through ``face`` at world depths in ``depth_range`` with their exact pixels.

    Returns
    -------
    pixels : (M, 2) real pixels (uniform over the face's image region), M ≤ n.
    points : (M, 3) world points on those pixels' exact rays, mm.
    """
    rng = np.random.default_rng(seed)
    w, h = rig.camera.width, rig.camera.height
    px = rng.uniform([0, 0], [w - 1, h - 1], size=(4 * n, 2))
    b = trace_pixels(rig, px)
    keep = np.flatnonzero(b.face == face)[:n]
    if keep.size < 8:
        raise GeometryError(unseen_face_message(rig, face, int(keep.size)))
    z = rng.uniform(depth_range[0], depth_range[1], size=keep.size)
    pts = _points_at_depth(b, keep, z)
    return px[keep], pts


def _points_at_depth(b: RayBundle, idx: np.ndarray, z: np.ndarray) -> np.ndarray:
    o, d = b.origins[idx], b.directions[idx]
    s = (z - o[:, 2]) / d[:, 2]
    return o + s[:, None] * d


def reprojection_error(
    camera: PinholeCamera, rig: Rig, face: int, *, n: int = 2000, seed: int = 1,
    depth_range: tuple[float, float] | None = None,
) -> tuple[float, float]:
    """RMS and max reprojection error (px) of a model against exact refraction.

    Points at world depths in ``depth_range`` (default the rig's working range,
    :func:`~prismstereo.cameras.overlap.working_depth_range`) seen through ``face`` are projected with the
    model and compared with the real pixel that sees them.
    """
    if depth_range is None:
        depth_range = _model_depth_range(rig)
    px, pts = sample_points(rig, face, n=n, depth_range=depth_range, seed=seed)
    err = np.linalg.norm(camera.project(pts) - px, axis=1)
    return float(np.sqrt(np.mean(err**2))), float(np.max(err))


def _model_depth_range(rig: Rig) -> tuple[float, float]:
    """The models' depth range (:mod:`prismstereo.cameras.overlap`), or :data:`DEPTH_RANGE_MM` for a rig whose
    views never overlap."""
    try:
        return working_depth_range(rig, near_fraction=MODEL_FRACTION)
    except GeometryError as exc:
        log.info("no working depth range (%s): models fitted over %g–%g mm", exc, *DEPTH_RANGE_MM)
        return DEPTH_RANGE_MM


def fit_camera(
    rig: Rig,
    face: int,
    *,
    distortion: bool = True,
    depth_range: tuple[float, float] | None = None,
    step: float = 16.0,
    n_depths: int = 6,
) -> PinholeCamera:
    """A pinhole camera (+ optional 5-term distortion) fitted to the exact rays of ``face``.

    The exact rays of a grid of pixels over the face's image region are sampled at ``n_depths`` world
    depths spanning ``depth_range`` (default the depths at which the rig's views share a field,
    :mod:`prismstereo.cameras.overlap`); K (fx, fy, cx, cy), the rotation, the optical centre and, if
    ``distortion``, (k1, k2, p1, p2, k3) minimise the reprojection error of those points to their pixels
    (Levenberg–Marquardt, started from the thesis construction).

    Over a face's narrow field of view a rotation about the camera's Y (or X) axis and a shift of the
    principal point are nearly interchangeable, and the least-squares optimum uses both: the fitted R is
    not the physical optical axis of the thesis construction (for the thesis bi-prism it turns the right
    view by +2.1° with cx ≈ 1014 px, where the thesis's axis is −3.2° with cx = 511.5). Pinning R to the
    physical axis and fitting only K, C and distortion about doubles the reprojection error on the thesis
    bi-prism (docs/EXPERIMENTS.md), so the free fit is kept; the model is judged by how it reprojects.
    """
    if depth_range is None:
        depth_range = _model_depth_range(rig)
    init = thesis_camera(rig, face)
    px = face_pixels(rig, face, step=step)
    b = trace_pixels(rig, px)
    z = np.geomspace(depth_range[0], depth_range[1], n_depths)
    pts = np.concatenate([_points_at_depth(b, np.arange(px.shape[0]), np.full(px.shape[0], zi)) for zi in z])
    target = np.tile(px, (n_depths, 1))
    ok = np.all(np.isfinite(pts), axis=1)
    pts, target = pts[ok], target[ok]
    f0 = rig.camera.focal_px
    rvec0 = Rotation.from_matrix(init.R).as_rotvec()
    x0 = np.concatenate([[init.K[0, 0] / f0, init.K[1, 1] / f0, init.K[0, 2] / f0, init.K[1, 2] / f0],
                         rvec0, init.C / 100.0, np.zeros(5 if distortion else 0)])

    def unpack(x: np.ndarray) -> PinholeCamera:
        K = np.array([[x[0] * f0, 0.0, x[2] * f0], [0.0, x[1] * f0, x[3] * f0], [0.0, 0.0, 1.0]])
        R = Rotation.from_rotvec(x[4:7]).as_matrix()
        return PinholeCamera(K=K, R=R, C=x[7:10] * 100.0, dist=x[10:])

    def residuals(x: np.ndarray) -> np.ndarray:
        r = unpack(x).project(pts) - target
        return np.nan_to_num(r, nan=1e6).ravel()

    sol = least_squares(residuals, x0, method="lm", x_scale="jac", max_nfev=400)
    cam = unpack(sol.x)
    log.debug("fit face %d: cost %.4g after %d evaluations", face, sol.cost, sol.nfev)
    return cam


def virtual_view(rig: Rig, face: int, *, method: str = "fit",
                 depth_range: tuple[float, float] | None = None) -> VirtualView:
    """Build one virtual camera with the chosen model and measure its reprojection error (both over
    ``depth_range``, default the rig's working range)."""
    if method not in METHODS:
        raise ConfigError(f"expected a virtual camera method in {METHODS}, got {method!r}")
    if depth_range is None:
        depth_range = _model_depth_range(rig)
    cam = thesis_camera(rig, face) if method == "thesis" else fit_camera(rig, face, depth_range=depth_range)
    rms, mx = reprojection_error(cam, rig, face, depth_range=depth_range)
    return VirtualView(face=face, name=rig.view_name(face), method=method, camera=cam, rms_px=rms, max_px=mx)


def calibrate_rig(rig: Rig, *, method: str = "fit") -> list[VirtualView]:
    """All virtual cameras of a rig (one per face) with the chosen model (``thesis`` or ``fit``)."""
    if method not in METHODS:
        raise ConfigError(f"expected a virtual camera method in {METHODS}, got {method!r}")
    depth_range = _model_depth_range(rig)
    return [virtual_view(rig, k, method=method, depth_range=depth_range) for k in range(rig.prism.faces)]


def write_cameras_json(path: str | os.PathLike[str], rig: Rig, views: list[VirtualView], *, method: str) -> None:
    """Write cameras.json (docs/formats.md)."""
    write_json(path, {"method": method, "rig": rig.to_dict(), "views": [v.to_dict() for v in views]})


def read_cameras_json(data: dict[str, Any]) -> tuple[Rig, list[VirtualView]]:
    """Parse the mapping of a cameras.json file back into a rig and its views."""
    try:
        rig = rig_from_dict(data["rig"])
        method = str(data["method"])
        views = [
            VirtualView(face=int(v["face"]), name=str(v["name"]), method=method,
                        camera=PinholeCamera.from_dict(v), rms_px=float(v["rms_px"]), max_px=float(v["max_px"]))
            for v in data["views"]
        ]
    except (KeyError, TypeError) as exc:
        raise ConfigError(f"expected a cameras.json with method, rig and views, got a missing {exc}") from None
    return rig, views


def rotation_degrees(R: np.ndarray) -> tuple[float, float, float]:
    """Rotation of a camera relative to the real camera as (about X, about Y, about Z) degrees (XYZ)."""
    ang = Rotation.from_matrix(np.asarray(R).T).as_euler("xyz", degrees=True)
    return float(ang[0]), float(ang[1]), float(ang[2])


def cameras_table(rig: Rig, views: list[VirtualView]) -> str:
    """A short text table of the views: centre (mm), rotation (degrees), reprojection error (px)."""
    lines = [f"{'view':<7} {'face':>4} {'C x':>9} {'C y':>9} {'C z':>9} {'rot x':>7} {'rot y':>7} "
             f"{'rot z':>7} {'fx':>8} {'rms px':>7} {'max px':>7}"]
    for v in views:
        c = v.camera.C
        rx, ry, rz = rotation_degrees(v.camera.R)
        lines.append(f"{v.name:<7} {v.face:>4} {c[0]:>9.3f} {c[1]:>9.3f} {c[2]:>9.3f} {rx:>7.3f} {ry:>7.3f} "
                     f"{rz:>7.3f} {v.camera.K[0, 0]:>8.1f} {v.rms_px:>7.3f} {v.max_px:>7.3f}")
    return "\n".join(lines)
