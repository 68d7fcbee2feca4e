"""Pinhole camera with OpenCV's 5-term distortion: x_cam = R (X − C), pixel ~ K x_cam (docs/conventions.md)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from prismstereo.optics.distortion import distort_points, undistort_points
from prismstereo.optics.refraction import normalize


def project_points(
    points_in_world: np.ndarray,
    K: np.ndarray,
    R: np.ndarray,
    C: np.ndarray,
    dist: np.ndarray | None = None,
) -> np.ndarray:
    """Project world points with a pinhole camera (thesis Eq. 3.35, P = K [R | −R C]).

    Parameters
    ----------
    points_in_world : (..., 3) array, mm.
    K : (3, 3) intrinsics; R : (3, 3) world-to-camera rotation; C : (3,) optical centre, mm.
    dist : (k1, k2, p1, p2, k3) or fewer terms, optional.

    Returns
    -------
    (..., 2) pixels (u, v); NaN for points at or behind the camera.
    """
    X = np.asarray(points_in_world, dtype=np.float64)
    xc = (X - np.asarray(C, dtype=np.float64)) @ np.asarray(R, dtype=np.float64).T
    with np.errstate(divide="ignore", invalid="ignore"):
        xy = xc[..., :2] / xc[..., 2:3]
    xy = np.where(xc[..., 2:3] > 0, xy, np.nan)
    if dist is not None and len(dist):
        xy = distort_points(xy, np.asarray(dist, dtype=np.float64))
    K = np.asarray(K, dtype=np.float64)
    u = K[0, 0] * xy[..., 0] + K[0, 1] * xy[..., 1] + K[0, 2]
    v = K[1, 1] * xy[..., 1] + K[1, 2]
    return np.stack([u, v], axis=-1)


@dataclass(frozen=True)
class PinholeCamera:
    """A (virtual) pinhole camera.

    Attributes
    ----------
    K : (3, 3) intrinsics (pixels of the real image).
    R : (3, 3) world-to-camera rotation.
    C : (3,) optical centre in the world frame, mm.
    dist : (0,) or (5,) OpenCV distortion (k1, k2, p1, p2, k3).
    """

    K: np.ndarray
    R: np.ndarray
    C: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self) -> None:
        for name in ("K", "R", "C", "dist"):
            object.__setattr__(self, name, np.asarray(getattr(self, name), dtype=np.float64))

    @property
    def P(self) -> np.ndarray:
        """3×4 projection matrix K [R | −R C] (ignores distortion)."""
        return self.K @ np.hstack([self.R, -(self.R @ self.C)[:, None]])

    @property
    def t(self) -> np.ndarray:
        """Translation −R C of the world-to-camera transform."""
        return -(self.R @ self.C)

    def project(self, points_in_world: np.ndarray) -> np.ndarray:
        """(..., 3) world points → (..., 2) pixels, with distortion."""
        return project_points(points_in_world, self.K, self.R, self.C, self.dist)

    def undistort_pixels(self, pixels: np.ndarray) -> np.ndarray:
        """(..., 2) distorted pixels → normalised undistorted coordinates (..., 2).

        Inverts the distortion with Newton's method (:func:`~prismstereo.optics.distortion.undistort_points`);
        NaN where the distortion folds back on itself, far outside the calibrated field.
        """
        px = np.asarray(pixels, dtype=np.float64)
        K = self.K
        y = (px[..., 1] - K[1, 2]) / K[1, 1]
        x = (px[..., 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
        target = np.stack([x, y], axis=-1)
        if not len(self.dist) or not np.any(self.dist):
            return target
        return undistort_points(target, self.dist)

    def unproject(self, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rays of pixels: origins (..., 3) = C and unit directions (..., 3) in the world frame."""
        xy = self.undistort_pixels(pixels)
        rays_cam = np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], axis=-1)
        dirs = normalize(rays_cam @ self.R)  # R^T x for row vectors
        return np.broadcast_to(self.C, dirs.shape).copy(), dirs

    def unproject_depth(self, pixels: np.ndarray, depth_z: np.ndarray) -> np.ndarray:
        """Points along the pixels' rays at camera-frame depth ``depth_z`` (mm): (..., 3) world."""
        xy = self.undistort_pixels(pixels)
        z = np.asarray(depth_z, dtype=np.float64)[..., None]
        xc = np.concatenate([xy * z, z], axis=-1)
        return xc @ self.R + self.C

    def to_dict(self) -> dict[str, object]:
        return {
            "K": self.K.tolist(),
            "R": self.R.tolist(),
            "C": self.C.tolist(),
            "P": self.P.tolist(),
            "dist": self.dist.tolist(),
        }

    @classmethod
    def from_dict(cls, data: dict[str, object]) -> PinholeCamera:
        return cls(K=np.array(data["K"]), R=np.array(data["R"]), C=np.array(data["C"]),
                   dist=np.array(data.get("dist", [])))


def rotation_from_axis(z_axis: np.ndarray) -> np.ndarray:
    """World-to-camera rotation whose optical axis (camera +Z) is ``z_axis`` (world frame).

    The smallest rotation taking the world +Z to ``z_axis`` is used, so for a bi-prism (axis in the XZ
    plane) it is the thesis's rotation about Y by β (thesis §3.2.1 step 6), and for rotated faces it
    stays as close as possible to the real camera's orientation.
    """
    z = np.asarray(z_axis, dtype=np.float64)
    z = z / np.linalg.norm(z)
    e = np.array([0.0, 0.0, 1.0])
    axis = np.cross(e, z)
    s = np.linalg.norm(axis)
    c = float(np.dot(e, z))
    if s < 1e-15:
        R_cw = np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    else:
        k = axis / s
        Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        R_cw = np.eye(3) + s * Kx + (1 - c) * (Kx @ Kx)
    return R_cw.T
