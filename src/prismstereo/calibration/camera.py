"""Intrinsics and lens distortion of the bare camera from checkerboard photos (Zhang's method, OpenCV).

The photos are taken without the prism. Each is searched for the board (:func:`detect_board`); boards
that are missing, partial or blurred are rejected, then ``cv2.calibrateCamera`` estimates fx, fy, the
principal point and (k1, k2, p1, p2, k3). Views whose reprojection RMS is far above the others' (a
mis-detected board) are dropped and the calibration repeated once.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from prismstereo.calibration.boards import MAX_EDGE_WIDTH_PX, Board, detect_board
from prismstereo.config import CameraSpec
from prismstereo.errors import ImageError

log = logging.getLogger(__name__)

#: fewest good board views for a calibration with distortion
MIN_VIEWS = 5


@dataclass(frozen=True)
class CameraCalibration:
    """Result of :func:`calibrate_camera`.

    Attributes
    ----------
    camera : CameraSpec
        width, height, fx, fy, principal point and distortion.
    rms_px : float
        Overall reprojection RMS of the used views, px.
    per_view_rms : dict[str, float]
        Reprojection RMS per used view, px.
    rejected : dict[str, str]
        Views not used, with the reason.
    std : dict[str, float]
        Standard deviations of fx, fy, cx, cy, k1, k2, p1, p2, k3 from OpenCV's covariance.
    """

    camera: CameraSpec
    rms_px: float
    per_view_rms: dict[str, float]
    rejected: dict[str, str]
    std: dict[str, float] = field(default_factory=dict)

    def summary(self) -> str:
        c = self.camera
        lines = [f"{'view':<28} {'rms px':>7}"]
        lines += [f"{name:<28} {rms:>7.3f}" for name, rms in self.per_view_rms.items()]
        lines += [f"{name:<28} rejected: {why}" for name, why in self.rejected.items()]
        k = ", ".join(f"{v:.5f}" for v in c.distortion)
        lines.append(f"fx {c.fx:.2f} fy {c.fy:.2f} cx {c.center[0]:.2f} cy {c.center[1]:.2f} px, "
                     f"distortion [{k}], RMS {self.rms_px:.3f} px over {len(self.per_view_rms)} views")
        return "\n".join(lines)


def _view_rms(obj: np.ndarray, img: np.ndarray, rvec: np.ndarray, tvec: np.ndarray, K: np.ndarray,
              dist: np.ndarray) -> float:
    proj, _ = cv2.projectPoints(obj, rvec, tvec, K, dist)
    return float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - img) ** 2, axis=1))))


def calibrate_camera(
    images: Sequence[np.ndarray],
    board: Board,
    *,
    names: Sequence[str] | None = None,
    min_views: int = MIN_VIEWS,
    max_edge_width: float = MAX_EDGE_WIDTH_PX,
    outlier_factor: float = 3.0,
    fix_k3: bool = True,
) -> CameraCalibration:
    """Calibrate a camera from photos of a checkerboard (no prism).

    Parameters
    ----------
    images : sequence of (H, W) or (H, W, 3) uint8 arrays, all the same size.
    board : Board
    names : names of the images for the report (default ``view0`` …).
    min_views : int
        Fewest good views; fewer raise :class:`ImageError`.
    max_edge_width : float
        Sharpness threshold (px) of :func:`detect_board`.
    outlier_factor : float
        Views whose RMS exceeds ``outlier_factor`` × the median (and 0.5 px) are dropped, once.
    fix_k3 : bool
        Hold k3 at 0 (OpenCV's ``CALIB_FIX_K3``). Over the narrow field of a long lens (|x| ≲ 0.12 for the
        thesis camera) r⁶ is below 3e-6 and k3 is not identifiable: left free it trades against k2 to
        values in the thousands.

    Returns
    -------
    CameraCalibration

    Raises
    ------
    ImageError
        If the images differ in size or fewer than ``min_views`` show a usable board.
    """
    names = [f"view{i}" for i in range(len(images))] if names is None else list(names)
    if not images:
        raise ImageError("expected checkerboard photos, got none")
    shapes = {np.shape(im)[:2] for im in images}
    if len(shapes) != 1:
        raise ImageError(f"expected photos of one size, got sizes {sorted(shapes)}")
    h, w = shapes.pop()
    obj = board.object_points()
    used: dict[str, np.ndarray] = {}
    rejected: dict[str, str] = {}
    for name, img in zip(names, images, strict=True):
        det = detect_board(img, board, max_edge_width=max_edge_width)
        if det.corners is None:
            rejected[name] = det.reason
        else:
            used[name] = det.corners
    for _ in range(2):
        if len(used) < min_views:
            raise ImageError(
                f"expected at least {min_views} photos with a whole, sharp {board.cols}x{board.rows} board, got "
                f"{len(used)} of {len(images)}; take more photos (whole board, in focus, varied tilts)")
        objs = [obj.astype(np.float32)] * len(used)
        imgs = [c.astype(np.float32) for c in used.values()]
        rms, K, dist, rvecs, tvecs, std_int, _, _ = cv2.calibrateCameraExtended(  # type: ignore[call-overload]
            objs, imgs, (w, h), None, None, flags=cv2.CALIB_FIX_K3 if fix_k3 else 0)
        dist = dist.ravel()[:5]
        per = {n: _view_rms(obj, c, r, t, K, dist) for n, c, r, t in zip(used, used.values(), rvecs, tvecs,
                                                                          strict=True)}
        limit = max(0.5, outlier_factor * float(np.median(list(per.values()))))
        bad = [n for n, v in per.items() if v > limit]
        if not bad:
            break
        for n in bad:
            rejected[n] = f"reprojection RMS {per[n]:.2f} px > {limit:.2f} px (mis-detected board?)"
            del used[n]
    log.info("camera calibration: RMS %.3f px over %d views", rms, len(used))
    camera = CameraSpec(width=w, height=h, fx=float(K[0, 0]), fy=float(K[1, 1]),
                        principal_point=(float(K[0, 2]), float(K[1, 2])),
                        distortion=tuple(float(v) for v in dist))  # type: ignore[arg-type]
    s = np.asarray(std_int).ravel()
    std = dict(zip(("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"), (float(v) for v in s[:9]), strict=False))
    return CameraCalibration(camera=camera, rms_px=float(rms), per_view_rms=per, rejected=rejected, std=std)


def camera_toml(camera: CameraSpec) -> dict[str, object]:
    """The ``[camera]`` table of a calibrated camera, ready for tomli_w (docs/rig.md)."""
    cam: dict[str, object] = {"width": camera.width, "height": camera.height}
    if camera.focal_length is not None and camera.pixel_size is not None and camera.fx is None:
        cam |= {"focal_length": camera.focal_length, "pixel_size": camera.pixel_size}
    cam |= {"fx": camera.fx, "fy": camera.fy, "principal_point": list(camera.center),
            "distortion": list(camera.distortion)}
    return {"camera": cam}
