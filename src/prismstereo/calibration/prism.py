"""The pose of a real prism from checkerboard captures taken through it (bundle adjustment).

Each capture shows the same board once per face. The board's inner corners are detected in every
sub-image (the board's 180° symmetry resolved by :func:`~prismstereo.calibration.boards.canonical_order`,
so that every view of a capture labels the corners alike), then one bundle adjustment refines every
board's pose (rotation vector, translation) together with the prism's rotation, tilt and decenter, the
camera's focal lengths, and optionally the prism's apex distance, refractive index and corner angle and the
camera's principal point and k1. The model is exact: a corner's predicted
pixel is the real pixel whose ray, refracted through the posed prism by the calibrated (distorting) lens,
passes through the corner (:func:`~prismstereo.optics.project_exact`). The solver is scipy's
``least_squares`` (trust-region reflective) with a sparse finite-difference Jacobian (a board's pose moves
only its own corners) and a Huber loss against mis-detected corners.

Observability: the rotation turns the two views' images in opposite directions (~4 px per degree for the
thesis bi-prism at 1 m) and is well determined; a tilt changes the deviation of the faces by different
amounts (a differential ~0.1–0.2 px per degree) and needs boards spread in position and depth. A
decenter moves the rays by less than 0.05 px per mm (a thin prism deviates every ray by an angle that
does not depend on where it crosses the face), so board corners hardly see it, and depth hardly depends
on it; it only moves the line between the sub-images. It is therefore held near the input rig's value
by a prior (``decenter_prior_mm``) and within ±3 mm of it, and its standard deviation is reported.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix
from scipy.spatial.transform import Rotation

from prismstereo.calibration.boards import MAX_EDGE_WIDTH_PX, Board, detect_board
from prismstereo.cameras.faces import thesis_camera
from prismstereo.config import Rig
from prismstereo.errors import ConfigError, GeometryError, ImageError
from prismstereo.io.images import as_image
from prismstereo.optics import face_map, project_exact, rays_from_pixels, trace_pixels, trace_rays

log = logging.getLogger(__name__)

#: prism parameters that can be fitted, with their units and the std (in those units) above which the
#: fit is called ill-conditioned
PARAMETERS: dict[str, tuple[str, float]] = {
    "rotation": ("deg", 0.2),
    "tilt_x": ("deg", 1.0),
    "tilt_y": ("deg", 1.0),
    "decenter_x": ("mm", 5.0),
    "decenter_y": ("mm", 5.0),
    "apex_distance": ("mm", 10.0),
    "refractive_index": ("", 0.02),
    "corner_angle": ("deg", 0.5),
    "fx": ("px", 100.0),
    "fy": ("px", 100.0),
    "cx": ("px", 100.0),
    "cy": ("px", 100.0),
    "k1": ("", 0.5),
}
_CAMERA_PARAMS = ("fx", "fy", "cx", "cy", "k1")
#: names accepted by ``free`` and what they free
FREE_GROUPS = {
    "rotation": ("rotation",),
    "tilt": ("tilt_x", "tilt_y"),
    "decenter": ("decenter_x", "decenter_y"),
    "apex_distance": ("apex_distance",),
    "refractive_index": ("refractive_index",),
    "corner_angle": ("corner_angle",),
    "focal": ("fx", "fy"),
    "principal_point": ("cx", "cy"),
    "k1": ("k1",),
}
DEFAULT_FREE = ("rotation", "tilt", "decenter", "focal")
#: search band (px) beyond the input rig's sub-image in which a board is looked for
SEARCH_BAND_PX = 48
#: corner noise (px) that the decenter prior is weighed against until the fit has measured it
PRIOR_NOISE_PX = 0.1
#: the decenter may move at most this far (mm) from the input rig's: beyond it a fit is using the decenter's
#: tiny effect to absorb some other error
DECENTER_BOUND_MM = 3.0


@dataclass(frozen=True)
class PrismCalibration:
    """Result of :func:`calibrate_prism`.

    Attributes
    ----------
    rig : Rig
        The input rig with the fitted prism parameters.
    estimates : dict[str, float]
        Fitted value of every free parameter (degrees, mm or unitless).
    std : dict[str, float]
        Standard deviation of each estimate (from the Gauss–Newton covariance, scaled by the residual).
    per_view_rms : dict[str, float]
        Reprojection RMS (px) per capture and face, keys ``"<capture>:<face>"``.
    rms_px : float
        Overall reprojection RMS, px.
    residuals : (M, 2) float64
        Final residual (predicted − detected) of every corner, px.
    observed : (M, 2) float64
        The detected corners, px.
    view_index : (M,) int
        Index into ``view_names`` of each corner.
    view_names : list of str
    seconds : float
    iterations : int
    """

    rig: Rig
    estimates: dict[str, float]
    std: dict[str, float]
    per_view_rms: dict[str, float]
    rms_px: float
    residuals: np.ndarray
    observed: np.ndarray
    view_index: np.ndarray
    view_names: list[str]
    seconds: float
    iterations: int
    initial: dict[str, float] = field(default_factory=dict)

    def summary(self) -> str:
        lines = [f"{'parameter':<18} {'initial':>10} {'fitted':>10} {'std':>9}"]
        for k, v in self.estimates.items():
            unit = PARAMETERS[k][0]
            lines.append(f"{k:<18} {self.initial.get(k, float('nan')):>10.4f} {v:>10.4f} "
                         f"{self.std[k]:>9.4f} {unit}")
        lines.append(f"{'view':<28} {'rms px':>7}")
        lines += [f"{k:<28} {v:>7.3f}" for k, v in self.per_view_rms.items()]
        lines.append(f"RMS {self.rms_px:.3f} px over {len(self.residuals)} corners, {self.iterations} "
                     f"evaluations, {self.seconds:.1f} s")
        return "\n".join(lines)

    def report(self) -> dict[str, object]:
        return {
            "estimates": self.estimates, "std": self.std, "initial": self.initial,
            "units": {k: PARAMETERS[k][0] for k in self.estimates},
            "rms_px": self.rms_px, "per_view_rms_px": self.per_view_rms, "n_corners": int(len(self.residuals)),
            "seconds": self.seconds, "evaluations": self.iterations, "rig": self.rig.to_dict(),
        }


def free_items(text: str | Sequence[str] | None, default: Sequence[str]) -> list[str]:
    """The names of a ``--free`` value: a comma list, a sequence of names, or None for ``default``."""
    if text is None:
        return list(default)
    if isinstance(text, str):
        return [t.strip() for t in text.split(",") if t.strip()]
    return list(text)


def parse_free(text: str | Sequence[str] | None) -> tuple[str, ...]:
    """``"rotation,tilt"`` → the parameter names it frees (see :data:`FREE_GROUPS`)."""
    out: list[str] = []
    for item in free_items(text, DEFAULT_FREE):
        if item not in FREE_GROUPS and item not in PARAMETERS:
            raise ConfigError(f"free: expected a comma list of {', '.join(FREE_GROUPS)}, got {item!r}")
        out += [p for p in FREE_GROUPS.get(item, (item,)) if p not in out]
    if not out:
        raise ConfigError("free: expected at least one parameter to fit, got none")
    return tuple(out)


def prism_values(rig: Rig) -> dict[str, float]:
    """The rig's fittable values by name (the keys of :data:`PARAMETERS`: prism pose and shape, mm and degrees;
    camera focal lengths, principal point and first distortion term, px)."""
    p, c = rig.prism, rig.camera
    fx, fy = c.focal_xy
    return {"rotation": p.rotation, "tilt_x": p.tilt[0], "tilt_y": p.tilt[1], "decenter_x": p.decenter[0],
            "decenter_y": p.decenter[1], "apex_distance": p.apex_distance,
            "refractive_index": p.refractive_index, "corner_angle": p.corner_angle,
            "fx": fx, "fy": fy, "cx": c.center[0], "cy": c.center[1], "k1": c.distortion[0]}


def with_prism_values(rig: Rig, values: dict[str, float]) -> Rig:
    """``rig`` with the values of :func:`prism_values` replaced by ``values`` (every key present); a new apex
    distance moves the back plane with it (the glass keeps its thickness)."""
    changes: dict[str, object] = {
        "rotation": values["rotation"], "tilt": (values["tilt_x"], values["tilt_y"]),
        "decenter": (values["decenter_x"], values["decenter_y"]), "refractive_index": values["refractive_index"],
        "corner_angle": values["corner_angle"],
    }
    cam = rig.camera
    if any(values[k] != v for k, v in prism_values(rig).items() if k in _CAMERA_PARAMS):
        cam = dataclasses.replace(cam, fx=values["fx"], fy=values["fy"], principal_point=(values["cx"], values["cy"]),
                                  distortion=(values["k1"],) + cam.distortion[1:])
        rig = dataclasses.replace(rig, camera=cam)
    if values["apex_distance"] != rig.prism.apex_distance:
        # the glass keeps its thickness: move the back plane with the apex
        shift = values["apex_distance"] - rig.prism.apex_distance
        changes |= {"apex_distance": values["apex_distance"], "back_distance": rig.prism.back_distance + shift}
    return rig.with_prism(**changes)


def detect_in_subimages(
    image: np.ndarray, rig: Rig, board: Board, *, faces: np.ndarray | None = None,
    band_px: int = SEARCH_BAND_PX, max_edge_width: float = MAX_EDGE_WIDTH_PX,
) -> list[np.ndarray | None]:
    """The board's corners in each face's sub-image of one capture ((M, 2) real pixels, or None).

    Each face is searched in its sub-image under ``rig`` widened by ``band_px`` (the real prism's line
    between the views may sit some pixels away from the input rig's); everything else is filled with the
    image's median grey. A board is credited to the face whose sub-image holds most of its corners.
    """
    gray = as_image(image, channels=1)
    if gray.shape != (rig.camera.height, rig.camera.width):
        raise ImageError(f"expected captures of the rig's sensor size {rig.camera.width}×{rig.camera.height}, "
                         f"got {gray.shape[1]}×{gray.shape[0]}")
    fm = face_map(rig) if faces is None else faces
    fill = int(np.median(gray))
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (2 * band_px + 1, 2 * band_px + 1))
    out: list[np.ndarray | None] = []
    for k in range(rig.prism.faces):
        mask = cv2.dilate((fm == k).astype(np.uint8), kernel) > 0
        ys, xs = np.nonzero(mask)
        if ys.size == 0:
            out.append(None)
            continue
        y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
        crop = np.where(mask[y0:y1, x0:x1], gray[y0:y1, x0:x1], fill).astype(np.uint8)
        det = detect_board(crop, board, max_edge_width=max_edge_width)
        if det.corners is None:
            out.append(None)
            continue
        c = det.corners + np.array([x0, y0], dtype=np.float64)
        ci = np.clip(np.rint(c).astype(int), 0, [rig.camera.width - 1, rig.camera.height - 1])
        out.append(c if np.mean(fm[ci[:, 1], ci[:, 0]] == k) > 0.5 else None)
    return out


def _initial_pose(rig: Rig, board: Board, corners: np.ndarray, face: int) -> np.ndarray:
    """Board pose (rotation vector, translation mm) in the world from one view (the thesis virtual camera)."""
    cam = thesis_camera(rig, face)
    obj = board.object_points()
    ok, rvec, tvec = cv2.solvePnP(obj, corners.reshape(-1, 1, 2), cam.K, np.asarray(rig.camera.distortion),
                                  flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        raise GeometryError("expected a board pose from its corners, got none (degenerate detection?)")
    R_b = Rotation.from_rotvec(rvec.ravel()).as_matrix()
    R_w = cam.R.T @ R_b
    t_w = cam.R.T @ tvec.ravel() + cam.C
    return np.concatenate([Rotation.from_matrix(R_w).as_rotvec(), t_w])


def calibrate_prism(
    rig: Rig,
    captures: Sequence[np.ndarray],
    board: Board,
    *,
    names: Sequence[str] | None = None,
    free: Sequence[str] | str | None = None,
    decenter_prior_mm: float = 1.0,
    loss_scale_px: float = 1.0,
    max_edge_width: float = MAX_EDGE_WIDTH_PX,
    min_captures: int = 3,
) -> PrismCalibration:
    """Fit the prism's pose (and optionally more) to checkerboard captures taken through it.

    Parameters
    ----------
    rig : Rig
        The camera (intrinsics and distortion from :func:`calibrate_camera`; held, except the camera
        parameters in ``free``) and the nominal prism (the starting point).
    captures : sequence of (H, W) or (H, W, 3) uint8 images of the board through the prism.
    board : Board
    names : names of the captures for the report.
    free : parameter groups to fit (default rotation, tilt, decenter, focal; see :data:`FREE_GROUPS`).
        ``focal`` refines the camera's fx, fy, ``principal_point`` its cx, cy, ``k1`` its first radial
        term: the two views of a board of known size pin the focal length to ~1 px, several times better
        than a bare-camera calibration over a long lens's narrow field, and a focal error otherwise leaks
        into the tilt (which changes the two views' scale differentially).
    decenter_prior_mm : float
        Std of the prior holding the decenter near the input rig's value (it is nearly unobservable from
        board corners; see the module notes). 0 removes the prior.
    loss_scale_px : float
        Huber scale of the corner residuals.
    min_captures : int

    Returns
    -------
    PrismCalibration

    Raises
    ------
    ImageError
        When a board is missing in a sub-image of some capture, or too few captures.
    GeometryError
        When the fit is ill-conditioned: a parameter's std above its limit in :data:`PARAMETERS`, a
        decenter at its ±:data:`DECENTER_BOUND_MM` bound, or a fitted prism that shows a detected corner
        through another face than the one it was found in.
    """
    t0 = time.perf_counter()
    free_params = parse_free(free)
    names = [f"capture{i}" for i in range(len(captures))] if names is None else list(names)
    if len(captures) < min_captures:
        raise ImageError(f"expected at least {min_captures} board captures through the prism, got {len(captures)}")
    n_faces = rig.prism.faces
    fm = face_map(rig)
    obs: list[list[np.ndarray]] = []
    for name, img in zip(names, captures, strict=True):
        found = detect_in_subimages(img, rig, board, faces=fm, max_edge_width=max_edge_width)
        missing = [k for k, c in enumerate(found) if c is None]
        if missing:
            raise ImageError(
                f"expected the whole {board.cols}x{board.rows} board in every sub-image, got none in face(s) "
                f"{', '.join(map(str, missing))} of {name}; retake it with the board seen whole through every face")
        obs.append([c for c in found if c is not None])

    n_cap, m = len(obs), board.n_corners
    obj = board.object_points()
    poses0 = np.stack([_initial_pose(rig, board, o[0], 0) for o in obs])
    init = prism_values(rig)
    scale = {"rotation": 1.0, "tilt_x": 1.0, "tilt_y": 1.0, "decenter_x": 1.0, "decenter_y": 1.0,
             "apex_distance": 1.0, "refractive_index": 0.01, "corner_angle": 0.1, "fx": 1.0, "fy": 1.0, "cx": 1.0,
             "cy": 1.0, "k1": 0.01}
    observed = np.stack([np.stack(o) for o in obs])  # (n_cap, n_faces, m, 2)
    # corner pixels grouped by face: (n_faces, n_cap·m, 2)
    obs_face = observed.transpose(1, 0, 2, 3).reshape(n_faces, n_cap * m, 2)
    n_p = len(free_params)
    prior = [k for k in ("decenter_x", "decenter_y") if k in free_params and decenter_prior_mm > 0]

    def unpack(x: np.ndarray) -> tuple[Rig, np.ndarray]:
        values = dict(init)
        for i, k in enumerate(free_params):
            values[k] = init[k] + x[i] * scale[k]
        return with_prism_values(rig, values), x[n_p:].reshape(n_cap, 6)

    def corners_world(poses: np.ndarray) -> np.ndarray:
        R = Rotation.from_rotvec(poses[:, :3]).as_matrix()  # (n_cap, 3, 3)
        return (np.einsum("cij,mj->cmi", R, obj) + poses[:, None, 3:]).reshape(-1, 3)

    # With the camera held, the rays of the detected corners (and of their ±h neighbours for the local
    # Jacobian) are computed once and each evaluation only traces them through the prism.
    h = 0.5
    steps = np.array([[0.0, 0.0], [h, 0.0], [-h, 0.0], [0.0, h], [0.0, -h]])
    camera_free = any(k in _CAMERA_PARAMS for k in free_params)

    def camera_rays(r_rig: Rig) -> list[np.ndarray]:
        cam = r_rig.camera
        dist = cam.distortion if cam.has_distortion else None
        return [rays_from_pixels(obs_face[k][None] + steps[:, None], cam.K, dist).reshape(-1, 3)
                for k in range(n_faces)]

    fixed_rays = camera_rays(rig)

    def project_near(r_rig: Rig, X: np.ndarray, k: int, rays: list[np.ndarray]) -> np.ndarray:
        """Pixel offsets from the detected corners to the predicted ones: one Newton step of
        :func:`project_exact` started at the detected pixel (exact to second order in the offset, ~1e-5 px
        at sub-pixel residuals; the reported residuals use the converged projection)."""
        b = trace_rays(r_rig, rays[k], face=k, bounded=False)
        o = b.origins.reshape(5, -1, 3)
        d = b.directions.reshape(5, -1, 3)
        with np.errstate(divide="ignore", invalid="ignore"):
            s_ = (X[None, :, 2] - o[..., 2]) / d[..., 2]
        off = o[..., :2] + s_[..., None] * d[..., :2] - X[None, :, :2]  # (5, N, 2)
        ju = (off[1] - off[2]) / (2 * h)
        jv = (off[3] - off[4]) / (2 * h)
        r = off[0]
        det = ju[:, 0] * jv[:, 1] - jv[:, 0] * ju[:, 1]
        with np.errstate(divide="ignore", invalid="ignore"):
            du = (jv[:, 1] * r[:, 0] - jv[:, 0] * r[:, 1]) / det
            dv = (-ju[:, 1] * r[:, 0] + ju[:, 0] * r[:, 1]) / det
        return -np.stack([du, dv], axis=1)

    def residuals(x: np.ndarray, exact: bool = False) -> np.ndarray:
        try:
            r_rig, poses = unpack(x)
        except ConfigError:
            return np.full(n_faces * n_cap * m * 2 + len(prior), 1e3)
        X = corners_world(poses)
        res = np.empty((n_faces, n_cap * m, 2))
        rays = camera_rays(r_rig) if camera_free else fixed_rays
        for k in range(n_faces):
            if exact:
                px, _ = project_exact(r_rig, X, face=k, tolerance_px=1e-9, initial_pixels=obs_face[k])
                res[k] = px - obs_face[k]
            else:
                res[k] = project_near(r_rig, X, k, rays)
        # (face, capture, corner) → (capture, face, corner) so that a board's rows are contiguous
        out = res.reshape(n_faces, n_cap, m, 2).transpose(1, 0, 2, 3)
        if not exact:
            out = out * weight
        pri = [x[free_params.index(k)] * scale[k] / decenter_prior_mm * noise_px[0] for k in prior]
        return np.concatenate([np.nan_to_num(out.ravel(), nan=1e3), np.asarray(pri)])

    n_res = n_cap * n_faces * m * 2
    x0 = np.concatenate([np.zeros(n_p), poses0.ravel()])
    # per view and axis weights of the corner residuals (set after the plain fit) and the corner noise
    # that the decenter prior is weighed against
    weight = np.ones((n_cap, n_faces, 1, 2))
    noise_px = [PRIOR_NOISE_PX]

    def sparsity(prism_free: bool) -> lil_matrix:
        S = lil_matrix((n_res + len(prior), x0.size), dtype=np.int8)
        rows = n_faces * m * 2
        for c in range(n_cap):
            S[c * rows:(c + 1) * rows, n_p + 6 * c:n_p + 6 * (c + 1)] = 1
        if prism_free:
            S[:n_res, :n_p] = 1
            for i, k in enumerate(prior):
                S[n_res + i, free_params.index(k)] = 1
        return S

    # 1. boards alone (prism at the input rig's pose), plain least squares: the residuals of a misaligned
    #    prism are systematic, not outliers, and a robust loss only slows the descent from far away
    zeros = np.zeros(n_p)
    s1 = least_squares(lambda xb: residuals(np.concatenate([zeros, xb])), x0[n_p:],
                       jac_sparsity=sparsity(False)[:, n_p:], x_scale="jac", method="trf", max_nfev=30)
    # 2. everything together, first plainly, then with the Huber loss against mis-detected corners
    lo = np.full(x0.size, -np.inf)
    hi = np.full(x0.size, np.inf)
    for i, k in enumerate(free_params):
        if k.startswith("decenter"):
            lo[i], hi[i] = -DECENTER_BOUND_MM / scale[k], DECENTER_BOUND_MM / scale[k]
    bounds = (lo, hi)
    s2 = least_squares(residuals, np.concatenate([zeros, s1.x]), jac_sparsity=sparsity(True), x_scale="jac",
                       method="trf", max_nfev=60, bounds=bounds)
    # 3. corner noise differs between views and axes (a board seen small, foreshortened or with its edges
    #    along the pixel rows is located less well): weigh each view's x and y residuals by the inverse of
    #    their RMS in the plain fit (variance components; the residuals of a view track its corner errors
    #    closely, as the boards' poses absorb little of them), relative to the median view's, at most 2×
    sigma = np.sqrt(np.mean(s2.fun[:n_res].reshape(n_cap, n_faces, m, 2) ** 2, axis=2, keepdims=True))
    ref = float(np.median(sigma))
    if np.isfinite(ref) and ref > 0:
        weight = ref / np.maximum(sigma, 0.5 * ref)
        noise_px[0] = ref
    sol = least_squares(residuals, s2.x, jac_sparsity=sparsity(True), loss="huber", f_scale=loss_scale_px,
                        x_scale="jac", method="trf", max_nfev=30, bounds=bounds)
    log.debug("prism calibration: costs %.4g -> %.4g -> %.4g (%d, %d, %d evaluations)", s1.cost, s2.cost,
              sol.cost, s1.nfev, s2.nfev, sol.nfev)
    fitted, _ = unpack(sol.x)
    res = residuals(sol.x, exact=True)[:n_res].reshape(n_cap, n_faces, m, 2)

    # covariance of the prism parameters (Gauss–Newton, scaled by the residual variance)
    J = sol.jac.toarray() if hasattr(sol.jac, "toarray") else np.asarray(sol.jac)
    dof = max(1, n_res - x0.size)
    var = float(np.sum((res * weight) ** 2)) / dof
    JTJ = J.T @ J
    try:
        cov = np.linalg.inv(JTJ) * var
        std_all = np.sqrt(np.maximum(np.diag(cov), 0.0))
    except np.linalg.LinAlgError:
        std_all = np.full(x0.size, np.inf)
    at_bound = [name for i, name in enumerate(free_params) if np.isfinite(lo[i])
                and min(sol.x[i] - lo[i], hi[i] - sol.x[i]) * scale[name] < 1e-3]
    if at_bound:
        raise GeometryError(
            f"expected a prism fit inside the ±{DECENTER_BOUND_MM:g} mm decenter bound, got {', '.join(at_bound)} "
            f"at it: the corners ask for more than a decenter can do (a camera calibration error?); "
            f"add focal to free or recalibrate the camera")
    # every corner must still be seen through the face it was found in
    for face in range(n_faces):
        seen = trace_pixels(fitted, obs_face[face]).face == face
        if seen.mean() < 0.98:
            raise GeometryError(
                f"expected the fitted prism to show each board through the face it was found in, got "
                f"{int((~seen).sum())} of {seen.size} corners of face {face} elsewhere; the fit is ill-conditioned "
                f"(check the camera calibration, or fit fewer parameters: free)")
    values = prism_values(fitted)
    estimates = {k: float(values[k]) for k in free_params}
    std = {k: float(std_all[i] * scale[k]) for i, k in enumerate(free_params)}
    bad = [k for k in free_params if not np.isfinite(std[k]) or std[k] > PARAMETERS[k][1]]
    if bad:
        detail = ", ".join(f"{k} ± {std[k]:.3g} {PARAMETERS[k][0]}".strip() for k in bad)
        raise GeometryError(
            f"expected a well-conditioned prism fit, got {detail}; add captures with the board at more depths "
            f"and positions, or fit fewer parameters (free)")
    view_names = [f"{n}:{k}" for n in names for k in range(n_faces)]
    per_view = {view_names[c * n_faces + k]: float(np.sqrt(np.mean(np.sum(res[c, k] ** 2, axis=1))))
                for c in range(n_cap) for k in range(n_faces)}
    flat = res.reshape(-1, 2)
    dt = time.perf_counter() - t0
    log.info("prism calibration: RMS %.3f px, %d evaluations, %.1f s", np.sqrt(np.mean(np.sum(flat**2, 1))),
             sol.nfev, dt)
    return PrismCalibration(
        rig=fitted, estimates=estimates, std=std, per_view_rms=per_view,
        rms_px=float(np.sqrt(np.mean(np.sum(flat**2, axis=1)))), residuals=flat,
        observed=observed.reshape(-1, 2), view_index=np.repeat(np.arange(n_cap * n_faces), m),
        view_names=view_names, seconds=dt, iterations=int(s1.nfev + s2.nfev + sol.nfev),
        initial={k: float(init[k]) for k in free_params},
    )
