"""Conventional calibration baseline (thesis §3.3 Table 3.4, §4.3 Table 4.3): Zhang's method per virtual
camera against the geometric virtual cameras, on the thesis's correspondence-transfer metric.

The experiment, in simulation:

1. Checkerboards at ≥ 12 poses wholly visible through every face
   (:func:`~prismstereo.simulate.checkerboard_poses`) are rendered through the prism
   (:func:`~prismstereo.simulate.render_capture`); the corners of each sub-image are detected with
   ``cv2.findChessboardCorners`` + ``cv2.cornerSubPix`` (``source="render"``). Without rendering, the exact
   corner pixels (:func:`~prismstereo.optics.project_exact`) plus Gaussian noise can be used instead
   (``source="exact"``).
2. Each virtual camera is calibrated with ``cv2.calibrateCamera`` (Zhang [29]: K, 5 distortion terms), the
   pairs with ``cv2.stereoCalibrate`` (intrinsics fixed). The reference camera is placed in the world
   (real-camera) frame from the known board poses (average over poses), the others through the stereo
   extrinsics.
3. Metric (thesis Tables 3.3/4.2): for test pixels of one view, the corresponding pixel predicted in
   another view by each model against the exact correspondence (ray tracing):
   - bi-prism: back-project the left pixel to the known depth (world Z) with the model, project it into
     the right view with the model;
   - tri-prism: the bottom-view pixel at the intersection of the epipolar lines of the left and right
     points (Eq. 3.9 / Appendix B), lines built from each model's rays.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from prismstereo.cameras import PinholeCamera, calibrate_rig, fit_camera
from prismstereo.config import Rig
from prismstereo.errors import GeometryError
from prismstereo.optics import project_exact, trace_pixels
from prismstereo.rectify.regions import ViewRegion, split_capture, view_regions
from prismstereo.simulate import checkerboard_poses, render_capture

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Detections:
    """Checkerboard corners found per view.

    Attributes
    ----------
    object_points : list of (M, 3) float32, one per pose (board frame, mm).
    image_points : dict face -> list of (M, 2) float32 real-image pixels, or None where not detected.
    exact_points : dict face -> list of (M, 2) exact corner pixels (ray tracing).
    board_rotations, board_origins : per pose, board-to-world rotation (3, 3) and origin (3,).
    source : "render" or "exact".
    seconds : float
    """

    object_points: list[np.ndarray]
    image_points: dict[int, list[np.ndarray | None]]
    exact_points: dict[int, list[np.ndarray]]
    board_rotations: list[np.ndarray]
    board_origins: list[np.ndarray]
    source: str
    seconds: float

    def detection_error(self, face: int) -> float:
        """RMS (px) of detected corners against the exact ones."""
        d = [a - b for a, b in zip(self.image_points[face], self.exact_points[face], strict=True) if a is not None]
        if not d:
            return float("nan")
        e = np.concatenate(d)
        return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))

    def n_detected(self, face: int) -> int:
        return sum(p is not None for p in self.image_points[face])


def detect_corners(
    rig: Rig,
    faces: list[int],
    *,
    n_poses: int = 12,
    source: str = "render",
    noise_px: float = 0.2,
    supersample: int = 2,
    sensor_noise: float = 1.0,
    seed: int = 0,
    regions: list[ViewRegion] | None = None,
    distance_range: tuple[float, float] = (600.0, 1500.0),
) -> Detections:
    """Checkerboard corners of ``n_poses`` boards in each face's sub-image (step 1 of the module docstring)."""

    t0 = time.perf_counter()
    regions = view_regions(rig) if regions is None else regions
    poses = checkerboard_poses(rig, n_poses=n_poses, seed=seed, distance_range=distance_range)
    rng = np.random.default_rng(seed + 1)
    img_pts: dict[int, list[np.ndarray | None]] = {f: [] for f in faces}
    exact: dict[int, list[np.ndarray]] = {f: [] for f in faces}
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-3)
    for k, pose in enumerate(poses):
        truth = {}
        for f in faces:
            px, ok = project_exact(rig, pose.corners, face=f)
            if not ok.all():
                raise GeometryError(f"expected every corner of pose {k} to be seen through face {f}, got "
                                    f"{int((~ok).sum())} missing")
            truth[f] = px
            exact[f].append(px.astype(np.float32))
        if source == "exact":
            for f in faces:
                img_pts[f].append((truth[f] + rng.normal(0.0, noise_px, truth[f].shape)).astype(np.float32))
            continue
        cap = render_capture(rig, pose.scene, supersample=supersample, noise=sensor_noise, seed=seed + k)
        gray = cv2.cvtColor(cap.image, cv2.COLOR_RGB2GRAY)
        subs = {s.face: s for s in split_capture(gray, rig, regions=regions, fill=115)}
        for f in faces:
            s = subs[f]
            found, corners = cv2.findChessboardCorners(
                s.image, pose.pattern_size, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
            if not found:
                log.info("pose %d face %d: chessboard not found", k, f)
                img_pts[f].append(None)
                continue
            corners = cv2.cornerSubPix(s.image, corners, (5, 5), (-1, -1), crit).reshape(-1, 2)
            pts = corners + np.asarray(s.offset, dtype=np.float32)
            # the pattern is symmetric under a half turn: label the corners like the object points
            rev = pts[::-1]
            if np.mean(np.linalg.norm(rev - truth[f], axis=1)) < np.mean(np.linalg.norm(pts - truth[f], axis=1)):
                pts = rev
            img_pts[f].append(pts.astype(np.float32))
    return Detections(object_points=[p.object_points.astype(np.float32) for p in poses], image_points=img_pts,
                      exact_points=exact, board_rotations=[p.rotation for p in poses],
                      board_origins=[p.origin for p in poses], source=source,
                      seconds=time.perf_counter() - t0)


@dataclass(frozen=True)
class ZhangCalibration:
    """Zhang-calibrated virtual cameras in the world frame, with OpenCV's reprojection RMS per view."""

    cameras: dict[int, PinholeCamera]
    rms_px: dict[int, float]
    stereo_rms_px: dict[tuple[int, int], float]


def _common(det: Detections, faces: list[int]) -> list[int]:
    return [i for i in range(len(det.object_points)) if all(det.image_points[f][i] is not None for f in faces)]


#: OpenCV flags of the distortion models tried for Zhang's calibration
ZHANG_MODELS: dict[str, int] = {
    "k1,k2,p1,p2,k3": 0,
    "k1,k2": cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST,
    "none": cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST,
}


def zhang_calibration(rig: Rig, det: Detections, faces: list[int], *, flags: int = 0) -> ZhangCalibration:
    """Calibrate each view (``cv2.calibrateCamera`` with ``flags``, see :data:`ZHANG_MODELS`) and each view
    against ``faces[0]`` (``cv2.stereoCalibrate``, intrinsics fixed); place ``faces[0]`` in the world from
    the known board poses."""
    size = (rig.camera.width, rig.camera.height)
    intr: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    rms: dict[int, float] = {}
    ref = faces[0]
    ref_pose: tuple[np.ndarray, np.ndarray] | None = None
    for f in faces:
        idx = [i for i, p in enumerate(det.image_points[f]) if p is not None]
        if len(idx) < 3:
            raise GeometryError(f"expected the board in at least 3 poses of face {f}, got {len(idx)}")
        obj = [det.object_points[i] for i in idx]
        img = [np.asarray(det.image_points[f][i]) for i in idx]
        err, K, dist, rvecs, tvecs = cv2.calibrateCamera(obj, img, size, None, None,  # type: ignore[call-overload,arg-type]
                                                         flags=flags)
        intr[f] = (K, dist.ravel())
        rms[f] = float(err)
        if f == ref:
            Rs, Cs = [], []
            for i, rv, tv in zip(idx, rvecs, tvecs, strict=True):
                Rbc = cv2.Rodrigues(rv)[0]
                Rwc = det.board_rotations[i] @ Rbc.T  # camera-to-world
                Rs.append(Rwc)
                Cs.append(det.board_origins[i] - Rwc @ tv.ravel())
            Rwc_mean = Rotation.from_matrix(np.stack(Rs)).mean().as_matrix()
            ref_pose = (Rwc_mean.T, np.mean(Cs, axis=0))
    assert ref_pose is not None
    cams = {ref: PinholeCamera(K=intr[ref][0], R=ref_pose[0], C=ref_pose[1], dist=intr[ref][1])}
    srms: dict[tuple[int, int], float] = {}
    for f in faces[1:]:
        idx = _common(det, [ref, f])
        obj = [det.object_points[i] for i in idx]
        ia = [np.asarray(det.image_points[ref][i]) for i in idx]
        ib = [np.asarray(det.image_points[f][i]) for i in idx]
        out = cv2.stereoCalibrate(obj, ia, ib, intr[ref][0], intr[ref][1], intr[f][0], intr[f][1], size,
                                  flags=cv2.CALIB_FIX_INTRINSIC)
        err, R_ab, T_ab = float(out[0]), out[5], out[6].ravel()
        R_b = R_ab @ ref_pose[0]
        C_b = ref_pose[1] - R_b.T @ T_ab
        cams[f] = PinholeCamera(K=intr[f][0], R=R_b, C=C_b, dist=intr[f][1])
        srms[(ref, f)] = err
    return ZhangCalibration(cameras=cams, rms_px=rms, stereo_rms_px=srms)


# --------------------------------------------------------------------------- the thesis metric
def transfer_at_depth(cam_a: PinholeCamera, cam_b: PinholeCamera, pixels_a: np.ndarray, depth_z: np.ndarray
                      ) -> np.ndarray:
    """Bi-prism metric (thesis Table 3.4): pixels of view a → the point of the model ray at world depth Z →
    pixels predicted in view b. Shapes (N, 2), (N,) → (N, 2)."""
    o, d = cam_a.unproject(pixels_a)
    s = (np.asarray(depth_z, dtype=np.float64) - o[:, 2]) / d[:, 2]
    return cam_b.project(o + s[:, None] * d)


def _epipolar_line(cam_src: PinholeCamera, pixels: np.ndarray, cam_dst: PinholeCamera) -> np.ndarray:
    """Homogeneous epipolar lines (N, 3) in the destination's undistorted normalised image."""
    _, d = cam_src.unproject(pixels)
    e = cam_dst.R @ (cam_src.C - cam_dst.C)  # epipole (homogeneous, normalised coordinates)
    v = d @ cam_dst.R.T  # vanishing points of the rays
    return np.cross(np.broadcast_to(e, v.shape), v)


def transfer_epipolar(cam_l: PinholeCamera, cam_r: PinholeCamera, cam_b: PinholeCamera, pixels_l: np.ndarray,
                      pixels_r: np.ndarray) -> np.ndarray:
    """Tri-prism metric (thesis Table 4.3): the bottom-view pixel at the intersection of the epipolar lines
    of a left and a right pixel. (N, 2), (N, 2) → (N, 2) (distortion of the bottom model applied)."""
    x = np.cross(_epipolar_line(cam_l, pixels_l, cam_b), _epipolar_line(cam_r, pixels_r, cam_b))
    with np.errstate(divide="ignore", invalid="ignore"):
        xy = x[:, :2] / x[:, 2:3]
    xc = np.concatenate([xy, np.ones((xy.shape[0], 1))], axis=1)
    return cam_b.project(xc @ cam_b.R + cam_b.C)


def exact_correspondence(rig: Rig, face_a: int, face_b: int, pixels_a: np.ndarray, depth_z: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact correspondences of given pixels of face a at world depths: (points (N, 3), pixels_b (N, 2),
    valid (N,))."""
    b = trace_pixels(rig, np.asarray(pixels_a, dtype=np.float64))
    X = b.point_at_depth(np.asarray(depth_z, dtype=np.float64))
    pb, ok = project_exact(rig, X, face=face_b)
    ok &= b.face == face_a
    return X, pb, ok


# --------------------------------------------------------------------------- experiments (Tables 3.4, 4.3)
@dataclass(frozen=True)
class TransferExperiment:
    """Transfer errors of several camera models on the thesis's correspondence metric.

    Attributes
    ----------
    rig_name : str
    faces : dict role -> face ("left", "right"[, "bottom"])
    table_points : dict with the listed test points: "pixels" (role -> (8, 2)), "exact" (8, 2) and, per
        model, "pred" (8, 2) and "err" (8,)
    summary : dict model -> {"mean", "median", "p95", "max", "n"} over many common-view points
    zhang : dict with the calibration details (detections source, RMS, detection error)
    depth_mm : depth of the listed points; depth_range : of the summary points
    """

    rig_name: str
    faces: dict[str, int]
    table_points: dict[str, object]
    summary: dict[str, dict[str, float]]
    zhang: dict[str, object]
    depth_mm: float
    depth_range: tuple[float, float]


def _stats(e: np.ndarray) -> dict[str, float]:
    e = e[np.isfinite(e)]
    return {"mean": float(np.mean(e)), "median": float(np.median(e)), "p95": float(np.percentile(e, 95)),
            "max": float(np.max(e)), "n": float(e.size)}


def _models(rig: Rig, det: Detections, faces: list[int], *, fit_depth_range: tuple[float, float] | None = None
            ) -> tuple[dict[str, dict[int, PinholeCamera]], dict[str, object]]:

    models: dict[str, dict[int, PinholeCamera]] = {
        "geometric (thesis construction)": {v.face: v.camera for v in calibrate_rig(rig, method="thesis")},
        "geometric (fitted model)": {v.face: v.camera for v in calibrate_rig(rig, method="fit")},
    }
    if fit_depth_range is not None:
        lo, hi = fit_depth_range
        models[f"geometric (fitted at {lo:g}-{hi:g} mm)"] = {
            f: fit_camera(rig, f, depth_range=fit_depth_range) for f in faces}
    info: dict[str, object] = {"source": det.source, "poses": len(det.object_points),
                               "detected": {f: det.n_detected(f) for f in faces},
                               "detection_rms_px": {f: det.detection_error(f) for f in faces}, "models": {}}
    for name, flags in ZHANG_MODELS.items():
        z = zhang_calibration(rig, det, faces, flags=flags)
        models[f"Zhang ({name})"] = z.cameras
        info["models"][name] = {"rms_px": z.rms_px,  # type: ignore[index]
                                "stereo_rms_px": {f"{a}-{b}": v for (a, b), v in z.stereo_rms_px.items()}}
    return models, info


def _random_pixels(region: ViewRegion, n: int, rng: np.random.Generator) -> np.ndarray:
    ys, xs = np.nonzero(region.mask)
    i = rng.choice(xs.size, size=n)
    return np.stack([xs[i], ys[i]], axis=1).astype(np.float64)


def biprism_experiment(
    rig: Rig, table_pixels: np.ndarray, *, depth_mm: float = 1500.0, depth_range: tuple[float, float] = (800.0, 2500.0),
    n_poses: int = 12, source: str = "render", n_summary: int = 2000, seed: int = 0,
) -> TransferExperiment:
    """Thesis Table 3.4: left pixels → right pixels at the known depth, per model (module docstring)."""
    regions = view_regions(rig)
    left, right = 1, 0
    det = detect_corners(rig, [left, right], n_poses=n_poses, source=source, seed=seed, regions=regions)
    models, info = _models(rig, det, [left, right])
    tp = np.asarray(table_pixels, dtype=np.float64)
    _, exact_b, ok = exact_correspondence(rig, left, right, tp, np.full(tp.shape[0], depth_mm))
    table: dict[str, object] = {"pixels": {"left": tp}, "exact": np.where(ok[:, None], exact_b, np.nan)}
    rng = np.random.default_rng(seed + 7)
    pa = _random_pixels(regions[left], n_summary, rng)
    za = rng.uniform(*depth_range, size=n_summary)
    _, pb, okb = exact_correspondence(rig, left, right, pa, za)
    pa, za, pb = pa[okb], za[okb], pb[okb]
    summary = {}
    for name, cams in models.items():
        pred = transfer_at_depth(cams[left], cams[right], tp, np.full(tp.shape[0], depth_mm))
        table[name] = {"pred": pred, "err": np.linalg.norm(pred - table["exact"], axis=1)}  # type: ignore[operator]
        summary[name] = _stats(np.linalg.norm(transfer_at_depth(cams[left], cams[right], pa, za) - pb, axis=1))
    return TransferExperiment(rig_name=rig.name, faces={"left": left, "right": right}, table_points=table,
                              summary=summary, zhang=info, depth_mm=depth_mm, depth_range=depth_range)


def triprism_experiment(
    rig: Rig, *, faces: tuple[int, int, int] = (1, 2, 0), depth_mm: float = 1500.0,
    depth_range: tuple[float, float] = (800.0, 2500.0), n_table: int = 8, n_poses: int = 12,
    source: str = "render", n_summary: int = 3000, seed: int = 0,
    board_distance_range: tuple[float, float] = (600.0, 1500.0),
) -> TransferExperiment:
    """Thesis Table 4.3: (left, right) pixels → bottom pixel at the intersection of their epipolar lines."""
    regions = view_regions(rig)
    fl, fr, fb = faces
    det = detect_corners(rig, [fl, fr, fb], n_poses=n_poses, source=source, seed=seed, regions=regions,
                         distance_range=board_distance_range)
    models, info = _models(rig, det, [fl, fr, fb], fit_depth_range=depth_range)
    rng = np.random.default_rng(seed + 11)

    def triples(n: int, z: np.ndarray | float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        pl = _random_pixels(regions[fl], n, rng)
        zz = np.broadcast_to(np.asarray(z, dtype=np.float64), (n,))
        X, pr, okr = exact_correspondence(rig, fl, fr, pl, zz)
        pbt, okb = project_exact(rig, X, face=fb)
        ok = okr & okb
        for f, p in ((fr, pr), (fb, pbt)):
            u = np.rint(np.nan_to_num(p[:, 0], nan=-1)).astype(int)
            v = np.rint(np.nan_to_num(p[:, 1], nan=-1)).astype(int)
            inside = (u >= 0) & (u < rig.camera.width) & (v >= 0) & (v < rig.camera.height)
            ok &= inside
            ok[inside] &= regions[f].mask[v[inside], u[inside]]
        return pl[ok], pr[ok], pbt[ok]

    tl, tr, tb = triples(400, depth_mm)
    if tl.shape[0] < n_table:
        raise GeometryError(f"expected {n_table} points seen by all three faces at {depth_mm} mm, got {tl.shape[0]}")
    pick = np.argsort(tl[:, 0])[np.linspace(0, tl.shape[0] - 1, n_table).astype(int)]
    tl, tr, tb = tl[pick], tr[pick], tb[pick]
    sl, sr, sb = triples(n_summary, rng.uniform(*depth_range, size=n_summary))
    table: dict[str, object] = {"pixels": {"left": tl, "right": tr}, "exact": tb}
    summary = {}
    for name, cams in models.items():
        pred = transfer_epipolar(cams[fl], cams[fr], cams[fb], tl, tr)
        table[name] = {"pred": pred, "err": np.linalg.norm(pred - tb, axis=1)}
        summary[name] = _stats(np.linalg.norm(transfer_epipolar(cams[fl], cams[fr], cams[fb], sl, sr) - sb, axis=1))
    return TransferExperiment(rig_name=rig.name, faces={"left": fl, "right": fr, "bottom": fb}, table_points=table,
                              summary=summary, zhang=info, depth_mm=depth_mm, depth_range=depth_range)
