"""Refining a prism's pose from feature matches between the sub-images of ordinary captures (self-calibration).

Every face of the prism shows the scene from its own virtual viewpoint, so one capture of a textured scene
holds stereo matches. For each pair of faces the features of the two sub-images are detected and matched
(OpenCV SIFT, Lowe's ratio test), and the matches are checked against a fundamental matrix (RANSAC on the
lens-undistorted pixels: over one face the prism's views are close to pinhole cameras, so this test does not
depend on the current, possibly wrong, prism pose). The prism's pose then minimises how far apart the exact
refracted rays of the matched pixels pass (:func:`~prismstereo.optics.trace_rays` through the posed prism):
the residual of a match is the length of the common perpendicular of its two rays, seen from the camera as
an angle in pixels (f · distance / range), so it is the row misalignment a rectification by that rig would
leave. scipy's ``least_squares`` (trust-region reflective, soft-L1 loss) fits it; the Jacobian has one
column per prism parameter (two to five), so it is dense and finite differences are cheap.

Observability: two matched rays meet wherever the scene point is, so matches fix the relative orientation
of the views up to what a change of depth can absorb (the epipolar geometry), never the scale:

- the **rotation** about the optical axis turns the views' baselines and gives row errors of ~7 px per
  degree at the image corners of the thesis bi-prism: well observed;
- the **tilt** changes the two faces' deviations differently (the prism's deviation grows away from the
  symmetric passage); the part that bends the rows is observed from matches spread over the field, a tilt
  about the baseline's own axis only moves both views alike and is weakly observed;
- the **decenter** moves the rays by less than 0.05 px per mm: not observed (held by a prior);
- the **apex distance**, **refractive index** and **corner angle** set the baseline and the views'
  convergence, i.e. the depth scale: a scene without known sizes cannot observe them, so they are never
  fitted here (calibrate them once with a checkerboard, ``calibrate-prism --board``).

Parameters that the matches observe weakly are held near the input rig's values by Gaussian priors
(:data:`PRIOR_STD`); the report gives each parameter's standard deviation from the data alone and says
which ones the scene observed.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from itertools import combinations

import cv2
import numpy as np
from scipy.optimize import least_squares

from prismstereo.calibration.dense import dense_pair_matches
from prismstereo.calibration.prism import PARAMETERS, free_items, prism_values, with_prism_values
from prismstereo.config import Rig
from prismstereo.depth.apex_band import apex_band_real
from prismstereo.errors import ConfigError, GeometryError, ImageError
from prismstereo.io.images import as_image
from prismstereo.optics import face_map, rays_from_pixels, trace_pixels, trace_rays
from prismstereo.optics.distortion import undistort_points

log = logging.getLogger(__name__)

__all__ = ["FREE_GROUPS", "FaceMatches", "SceneCalibration", "calibrate_from_scene", "match_faces",
           "match_features", "parse_scene_free", "sift_features"]

#: parameter groups the scene can be asked to refine (the scale parameters are not among them)
FREE_GROUPS = {"rotation": ("rotation",), "tilt": ("tilt_x", "tilt_y"), "decenter": ("decenter_x", "decenter_y")}
DEFAULT_FREE = ("rotation", "tilt")
#: std of the priors that hold weakly observed parameters near the input rig's values (degrees, mm)
PRIOR_STD = {"tilt_x": 2.0, "tilt_y": 2.0, "decenter_x": 1.0, "decenter_y": 1.0}
#: a parameter counts as observed by the scene when its data-only std is below this share of its prior std
OBSERVED_SHARE = 0.5
#: Lowe's ratio test
RATIO = 0.75
#: RANSAC threshold of the fundamental-matrix test, px (lens-undistorted)
RANSAC_PX = 1.5
#: features per face sub-image
MAX_FEATURES = 4000
#: band (px) along the prism's edges left out of the sub-images: a misaligned prism moves the edges
EDGE_BAND_PX = 12
#: matches kept per face pair for the fit (spread evenly; more only slow the fit)
MAX_FIT_MATCHES = 1500
#: fewest RANSAC-consistent matches (all pairs together) to fit anything
MIN_MATCHES = 60
#: the matches must spread over at least this share of the image height (a tilt and a rotation need lever)
MIN_SPREAD = 0.25
#: std limit (with priors) above which the fit is ill-conditioned
STD_LIMIT = {"rotation": 0.05, "tilt_x": 1.5, "tilt_y": 1.5, "decenter_x": 1.0, "decenter_y": 1.0}
#: ``dense="auto"``: optical-flow correspondences (:mod:`prismstereo.calibration.dense`) are added to a face
#: pair whose SIFT matches are fewer than this
DENSE_BELOW = 400
DENSE_MODES = ("auto", "always", "never")


@dataclass(frozen=True)
class FaceMatches:
    """RANSAC-consistent feature matches between two faces' sub-images of one capture.

    Attributes
    ----------
    face_a, face_b : int
    pixels_a, pixels_b : (N, 2) float64  real-image pixels of the matched features.
    capture : int  index of the capture.
    candidates : int  matches that passed the ratio test (before RANSAC), plus the optical-flow ones tried.
    dense : int  how many of the matches are optical-flow correspondences (:mod:`prismstereo.calibration.dense`).
    """

    face_a: int
    face_b: int
    pixels_a: np.ndarray
    pixels_b: np.ndarray
    capture: int = 0
    candidates: int = 0
    dense: int = 0

    def __len__(self) -> int:
        return int(self.pixels_a.shape[0])


@dataclass(frozen=True)
class SceneCalibration:
    """Result of :func:`calibrate_from_scene`.

    Attributes
    ----------
    rig : Rig  the input rig with the refined prism pose.
    estimates, initial : dict  fitted and starting value of every free parameter (deg, mm).
    std : dict  std of each estimate with the priors; ``std_data``: from the matches alone (inf: unobserved).
    observed : dict  whether the scene observed each parameter (``std_data`` < :data:`OBSERVED_SHARE` × prior).
    held : tuple of str  the parameters the scene did not observe, held at their input values (std: the prior's).
    matches : list of FaceMatches  the matches used.
    residual_before, residual_after : dict  p50/p95/rms of |ray residual| (px) under the input and refined rigs.
    seconds, cpu_seconds : float
    evaluations : int
    """

    rig: Rig
    estimates: dict[str, float]
    initial: dict[str, float]
    std: dict[str, float]
    std_data: dict[str, float]
    observed: dict[str, bool]
    matches: list[FaceMatches]
    residual_before: dict[str, float]
    residual_after: dict[str, float]
    seconds: float
    cpu_seconds: float
    evaluations: int
    notes: tuple[str, ...] = field(default=())
    held: tuple[str, ...] = field(default=())

    @property
    def n_matches(self) -> int:
        return sum(len(m) for m in self.matches)

    def summary(self) -> str:
        lines = [f"{'parameter':<12} {'initial':>9} {'fitted':>9} {'std':>8} {'std data':>9}  observed"]
        for k, v in self.estimates.items():
            lines.append(f"{k:<12} {self.initial[k]:>9.4f} {v:>9.4f} {self.std[k]:>8.4f} {self.std_data[k]:>9.4f}  "
                         f"{'yes' if self.observed[k] else 'no (held at its input value)'}  {PARAMETERS[k][0]}")
        pairs = ", ".join(f"{m.face_a}-{m.face_b}: {len(m)}/{m.candidates}" for m in self.matches)
        b, a = self.residual_before, self.residual_after
        lines.append(f"matches used (RANSAC-consistent/ratio test) per face pair: {pairs}")
        lines.append(f"ray residual px p50/p95: before {b['p50']:.3f}/{b['p95']:.3f}, after {a['p50']:.3f}/"
                     f"{a['p95']:.3f}; {self.evaluations} evaluations, {self.seconds:.1f} s ({self.cpu_seconds:.1f} "
                     "CPU s)")
        lines += list(self.notes)
        return "\n".join(lines)

    def report(self) -> dict[str, object]:
        return {
            "estimates": self.estimates, "initial": self.initial, "std": self.std, "std_data": self.std_data,
            "observed": self.observed, "held": list(self.held),
            "units": {k: PARAMETERS[k][0] for k in self.estimates},
            "matches": [{"faces": [m.face_a, m.face_b], "capture": m.capture, "used": len(m),
                         "ratio_test": m.candidates, "optical_flow": m.dense} for m in self.matches],
            "n_matches": self.n_matches, "residual_px": {"before": self.residual_before, "after": self.residual_after},
            "seconds": self.seconds, "cpu_seconds": self.cpu_seconds, "evaluations": self.evaluations,
            "notes": list(self.notes), "rig": self.rig.to_dict(),
            "not_fitted": {"apex_distance": "sets the depth scale: not observable from matches",
                           "refractive_index": "sets the depth scale: not observable from matches",
                           "corner_angle": "sets the depth scale: not observable from matches"},
        }


def parse_scene_free(text: str | Sequence[str] | None) -> tuple[str, ...]:
    """``"rotation,tilt"`` → the parameter names it frees (rotation, tilt, decenter only)."""
    out: list[str] = []
    for item in free_items(text, DEFAULT_FREE):
        if item in ("apex_distance", "refractive_index", "corner_angle"):
            raise ConfigError(f"free: {item} sets the depth scale, which feature matches cannot observe; calibrate "
                              "it with a checkerboard (calibrate_prism with a board) and fit rotation, tilt, decenter "
                              "here")
        names = FREE_GROUPS.get(item, (item,) if item in STD_LIMIT else ())
        if not names:
            raise ConfigError(f"free: expected a comma list of {', '.join(FREE_GROUPS)}, got {item!r}")
        out += [p for p in names if p not in out]
    if not out:
        raise ConfigError("free: expected at least one parameter to fit, got none")
    return tuple(out)


# --------------------------------------------------------------------------- features
def sift_features(gray: np.ndarray, mask: np.ndarray, *, max_features: int = MAX_FEATURES
                  ) -> tuple[np.ndarray, np.ndarray | None]:
    """SIFT keypoints ((N, 2) float64 pixels) and descriptors ((N, 128) float32 or None) inside ``mask``."""
    sift = cv2.SIFT_create(nfeatures=int(max_features))  # type: ignore[attr-defined]
    kps, desc = sift.detectAndCompute(gray, mask.astype(np.uint8) * 255)
    pts = np.array([k.pt for k in kps], dtype=np.float64).reshape(-1, 2)
    return pts, desc


def match_features(desc_a: np.ndarray | None, desc_b: np.ndarray | None, *, ratio: float = RATIO
                   ) -> np.ndarray:
    """(M, 2) int indices (into a, into b) of mutual nearest neighbours that pass Lowe's ratio test."""
    if desc_a is None or desc_b is None or len(desc_a) < 2 or len(desc_b) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    bf = cv2.BFMatcher(cv2.NORM_L2)
    ab = bf.knnMatch(desc_a, desc_b, k=2)
    ba = bf.match(desc_b, desc_a)
    back = np.full(len(desc_b), -1, dtype=np.int64)
    for m in ba:
        back[m.queryIdx] = m.trainIdx
    out = [(m[0].queryIdx, m[0].trainIdx) for m in ab
           if len(m) == 2 and m[0].distance < ratio * m[1].distance and back[m[0].trainIdx] == m[0].queryIdx]
    return np.array(out, dtype=np.int64).reshape(-1, 2)


def consistent_matches(pts_a: np.ndarray, pts_b: np.ndarray, *, threshold_px: float = RANSAC_PX,
                       seed: int = 0) -> np.ndarray:
    """(N,) bool: matches consistent with one fundamental matrix (OpenCV USAC MAGSAC++), ``pts`` in px."""
    if pts_a.shape[0] < 8:
        return np.zeros(pts_a.shape[0], dtype=bool)
    cv2.setRNGSeed(seed)
    _, inl = cv2.findFundamentalMat(pts_a.astype(np.float64), pts_b.astype(np.float64), cv2.USAC_MAGSAC,
                                    float(threshold_px), 0.9999, 20000)
    if inl is None:
        return np.zeros(pts_a.shape[0], dtype=bool)
    return inl.ravel().astype(bool)


def _undistorted_px(rig: Rig, px: np.ndarray) -> np.ndarray:
    """Pixels of an ideal (distortion-free) camera with the rig's K that see along the same rays."""
    cam = rig.camera
    if not cam.has_distortion:
        return px
    K = cam.K
    xy = (px - K[:2, 2]) / np.array([K[0, 0], K[1, 1]])
    und = undistort_points(xy, cam.distortion)
    return und * np.array([K[0, 0], K[1, 1]]) + K[:2, 2]


def _face_masks(rig: Rig, band_px: int) -> list[np.ndarray]:
    """Each face's pixels less ``band_px`` around its edges and, where the camera gives its f-number and focus
    distance, less the apex band where the lens sees through two faces (:mod:`prismstereo.depth.apex_band`)."""
    fm = face_map(rig)
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (2 * band_px + 1, 2 * band_px + 1))
    masks = [cv2.erode((fm == k).astype(np.uint8), kernel) > 0 for k in range(rig.prism.faces)]
    band = apex_band_real(rig)
    return masks if band is None else [m & ~band for m in masks]


def match_faces(
    image: np.ndarray, rig: Rig, *, capture: int = 0, ratio: float = RATIO, ransac_px: float = RANSAC_PX,
    max_features: int = MAX_FEATURES, band_px: int = EDGE_BAND_PX, pairs: Sequence[tuple[int, int]] | None = None,
    dense: str = "auto", dense_below: int = DENSE_BELOW,
) -> list[FaceMatches]:
    """Feature matches between every pair of faces' sub-images of one capture.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) capture of the rig's sensor size.
    rig : Rig  gives the sub-images (face map) and the lens model for the RANSAC test.
    pairs : face pairs to match (default every pair).
    dense : ``"auto"`` (default), ``"always"`` or ``"never"``
        Add the optical-flow correspondences of :func:`~prismstereo.calibration.dense.dense_pair_matches`
        to a pair whose SIFT matches are fewer than ``dense_below`` (``"auto"``), to every pair, or never.
        The two sets are tested against one fundamental matrix together.

    Returns
    -------
    list of FaceMatches, one per pair (possibly empty).
    """
    if dense not in DENSE_MODES:
        raise ConfigError(f"dense: expected one of {', '.join(DENSE_MODES)}, got {dense!r}")
    gray = as_image(image, channels=1)
    if gray.shape != (rig.camera.height, rig.camera.width):
        raise ImageError(f"expected captures of the rig's sensor size {rig.camera.width}×{rig.camera.height}, "
                         f"got {gray.shape[1]}×{gray.shape[0]}")
    masks = _face_masks(rig, band_px)
    feats = [sift_features(gray, m, max_features=max_features) for m in masks]
    out = []
    for a, b in (pairs if pairs is not None else combinations(range(rig.prism.faces), 2)):
        idx = match_features(feats[a][1], feats[b][1], ratio=ratio)
        pa, pb = feats[a][0][idx[:, 0]], feats[b][0][idx[:, 1]]
        ok = consistent_matches(_undistorted_px(rig, pa), _undistorted_px(rig, pb), threshold_px=ransac_px)
        log.debug("faces %d-%d: %d features / %d, %d ratio-test matches, %d consistent", a, b, len(feats[a][0]),
                  len(feats[b][0]), idx.shape[0], int(ok.sum()))
        n_sparse, n_dense, cand = int(ok.sum()), 0, int(idx.shape[0])
        if dense == "always" or (dense == "auto" and n_sparse < dense_below):
            da, db = dense_pair_matches(image, rig, faces=(a, b), band_px=band_px)
            keep = masks[a][_px_index(da, masks[a].shape)] & masks[b][_px_index(db, masks[b].shape)]
            pa, pb = np.concatenate([pa, da[keep]]), np.concatenate([pb, db[keep]])
            ok = consistent_matches(_undistorted_px(rig, pa), _undistorted_px(rig, pb), threshold_px=ransac_px)
            n_dense = int(ok[idx.shape[0]:].sum())
            cand += int(keep.sum())
            log.debug("faces %d-%d: %d SIFT + %d dense consistent matches", a, b, int(ok[:idx.shape[0]].sum()),
                      n_dense)
        out.append(FaceMatches(face_a=a, face_b=b, pixels_a=pa[ok], pixels_b=pb[ok], capture=capture,
                               candidates=cand, dense=n_dense))
    return out


def _px_index(px: np.ndarray, shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Row and column indices of the pixels ``px`` (rounded, clipped to ``shape``)."""
    j = np.rint(px).astype(np.int64)
    return np.clip(j[:, 1], 0, shape[0] - 1), np.clip(j[:, 0], 0, shape[1] - 1)


def _spread_subset(px: np.ndarray, n: int) -> np.ndarray:
    """Indices of at most ``n`` points spread evenly over the image (one per cell of a coarse grid first)."""
    if px.shape[0] <= n:
        return np.arange(px.shape[0])
    cell = max(4.0, float(np.sqrt(np.ptp(px[:, 0]) * np.ptp(px[:, 1]) / n)))
    key = np.floor(px[:, 0] / cell) * 1e6 + np.floor(px[:, 1] / cell)
    order = np.lexsort((np.arange(px.shape[0]), key))
    first = np.ones(order.size, dtype=bool)
    first[1:] = key[order[1:]] != key[order[:-1]]
    chosen = order[first]
    if chosen.size >= n:
        return np.sort(chosen[np.linspace(0, chosen.size - 1, n).astype(int)])
    rest = np.setdiff1d(np.arange(px.shape[0]), chosen)
    extra = rest[np.linspace(0, rest.size - 1, n - chosen.size).astype(int)]
    return np.sort(np.concatenate([chosen, extra]))


# --------------------------------------------------------------------------- ray residuals
def ray_residuals(rig: Rig, dirs_a: np.ndarray, dirs_b: np.ndarray, face_a: np.ndarray, face_b: np.ndarray,
                  *, normals: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Signed miss distance of matched rays through the prism, as an angle in pixels.

    Parameters
    ----------
    dirs_a, dirs_b : (N, 3) camera-frame ray directions of the matched pixels (lens already undone).
    face_a, face_b : (N,) int  faces they pass.
    normals : (N, 3), optional  orientation of the common perpendicular (its sign is taken from them, so the
        residual is a smooth function of the prism's pose); default the perpendicular of these rays.

    Returns
    -------
    residual : (N,) f · (o_b − o_a) · n / range_a, px (NaN where a ray does not pass its face).
    normals : (N, 3) the oriented common perpendiculars.
    """
    n_pts = dirs_a.shape[0]
    oa = np.full((n_pts, 3), np.nan)
    da = np.full((n_pts, 3), np.nan)
    ob, db = oa.copy(), da.copy()
    for k in np.unique(np.concatenate([face_a, face_b])):
        for sel, dirs, o, d in ((face_a == k, dirs_a, oa, da), (face_b == k, dirs_b, ob, db)):
            if sel.any():
                bun = trace_rays(rig, dirs[sel], face=int(k), bounded=False)
                o[sel], d[sel] = bun.origins, bun.directions
    cross = np.cross(da, db)
    nrm = cross / np.linalg.norm(cross, axis=1, keepdims=True)
    if normals is not None:
        nrm = nrm * np.sign(np.sum(nrm * normals, axis=1, keepdims=True))
    w = ob - oa
    # range along ray a of the closest approach (the usual two-line formula)
    ab = np.sum(da * db, axis=1)
    denom = np.maximum(1.0 - ab**2, 1e-12)
    t_a = (np.sum(w * da, axis=1) - ab * np.sum(w * db, axis=1)) / denom
    rng = np.maximum(np.abs(t_a), 50.0)
    return rig.camera.focal_px * np.sum(w * nrm, axis=1) / rng, nrm


def _stats(r: np.ndarray) -> dict[str, float]:
    a = np.abs(r[np.isfinite(r)])
    if a.size == 0:
        return {"p50": float("nan"), "p95": float("nan"), "rms": float("nan")}
    return {"p50": float(np.median(a)), "p95": float(np.percentile(a, 95)), "rms": float(np.sqrt(np.mean(a**2)))}


# --------------------------------------------------------------------------- fit
def calibrate_from_scene(
    rig: Rig,
    captures: Sequence[np.ndarray],
    *,
    free: Sequence[str] | str | None = None,
    loss_scale_px: float = 0.5,
    min_matches: int = MIN_MATCHES,
    max_fit_matches: int = MAX_FIT_MATCHES,
    matches: Sequence[FaceMatches] | None = None,
    dense: str = "auto",
) -> SceneCalibration:
    """Refine the prism's rotation and tilt (``free``) from feature matches in ordinary captures.

    A parameter with a prior (:data:`PRIOR_STD`) that the matches do not observe (its data-only std at least
    :data:`OBSERVED_SHARE` of the prior's) is held at its input value and the others are fitted again without
    it: its std is then the prior's (how far the prism may be off that value), and the report says so
    (``held``, ``notes``); :func:`~prismstereo.calibration.scene_uncertainty.unobserved_depth_error` turns it
    into a depth error.

    Parameters
    ----------
    rig : Rig
        The calibrated camera (held) and the current prism (the starting point; its apex distance,
        refractive index and corner angle are held: they set the depth scale, see the module notes).
    captures : sequence of (H, W) or (H, W, 3) captures of textured scenes through the prism.
    free : groups of :data:`FREE_GROUPS` to fit (default rotation, tilt).
    loss_scale_px : soft-L1 scale of the ray residuals (px).
    min_matches : fewest consistent matches to fit.
    max_fit_matches : matches kept per face pair and capture (spread over the image).
    matches : precomputed :func:`match_faces` results (``captures`` is then only used for nothing else).
    dense : ``"auto"``, ``"always"`` or ``"never"``
        Optical-flow correspondences where SIFT finds few (``dense`` of :func:`match_faces`).

    Returns
    -------
    SceneCalibration

    Raises
    ------
    ImageError
        Too few consistent matches or matches bunched in a small part of the image (too little texture).
    GeometryError
        The fit is ill-conditioned (a fitted parameter's std above :data:`STD_LIMIT`), or the refined prism
        shows a matched feature through another face.
    """
    t0, c0 = time.perf_counter(), time.process_time()
    free_params = parse_scene_free(free)
    if dense not in DENSE_MODES:
        raise ConfigError(f"dense: expected one of {', '.join(DENSE_MODES)}, got {dense!r}")
    if matches is None:
        if not captures:
            raise ImageError("expected at least one capture of a textured scene, got none")
        found = [m for i, img in enumerate(captures) for m in match_faces(img, rig, capture=i, dense=dense)]
    else:
        found = list(matches)
    used = []
    for m in found:
        keep = _spread_subset(m.pixels_a, max_fit_matches)
        n_dense = int(np.sum(keep >= len(m) - m.dense))
        used.append(dataclasses.replace(m, pixels_a=m.pixels_a[keep], pixels_b=m.pixels_b[keep], dense=n_dense))
    used = [m for m in used if len(m) >= 8]
    total = sum(len(m) for m in used)
    cand = sum(m.candidates for m in found)
    if total < min_matches:
        raise ImageError(f"expected at least {min_matches} consistent feature matches between the sub-images, got "
                         f"{total} (of {cand} candidates): the scene has too little texture; point the camera at a "
                         "textured scene that fills the common view, or calibrate with a checkerboard")
    pa = np.concatenate([m.pixels_a for m in used])
    pb = np.concatenate([m.pixels_b for m in used])
    fa = np.concatenate([np.full(len(m), m.face_a) for m in used])
    fb = np.concatenate([np.full(len(m), m.face_b) for m in used])
    spread = float(np.ptp(np.concatenate([pa[:, 1], pb[:, 1]]))) / rig.camera.height
    if spread < MIN_SPREAD:
        raise ImageError(f"expected feature matches spread over at least {100 * MIN_SPREAD:.0f} % of the image "
                         f"height, got {100 * spread:.0f} %: too little texture to observe the prism's rotation; "
                         "use a capture whose texture fills the common view")
    cam = rig.camera
    dist = cam.distortion if cam.has_distortion else None
    dirs_a = rays_from_pixels(pa, cam.K, dist)
    dirs_b = rays_from_pixels(pb, cam.K, dist)
    init = prism_values(rig)
    r0, normals = ray_residuals(rig, dirs_a, dirs_b, fa, fb)

    def fit(params: tuple[str, ...]) -> tuple[Rig, np.ndarray, np.ndarray, np.ndarray, int]:
        """Fit ``params`` (the others at their input values): the rig, the residuals, the std with the
        priors and from the data alone, the evaluations."""
        prior = [k for k in params if k in PRIOR_STD]

        def unpack(x: np.ndarray) -> Rig:
            values = dict(init)
            for i, k in enumerate(params):
                values[k] = init[k] + x[i]
            return with_prism_values(rig, values)

        def residuals(x: np.ndarray) -> np.ndarray:
            try:
                r_rig = unpack(x)
            except ConfigError:
                return np.full(total + len(prior), 1e3)
            r, _ = ray_residuals(r_rig, dirs_a, dirs_b, fa, fb, normals=normals)
            pri = [x[params.index(k)] / PRIOR_STD[k] * loss_scale_px for k in prior]
            return np.concatenate([np.nan_to_num(r, nan=1e3), np.asarray(pri)])

        # a misaligned prism leaves systematic residuals, not outliers: plain least squares first, then the
        # robust loss against the mismatches that passed RANSAC
        s1 = least_squares(residuals, np.zeros(len(params)), method="trf", x_scale=1.0, diff_step=1e-4,
                           max_nfev=50)
        sol = least_squares(residuals, s1.x, method="trf", loss="soft_l1", f_scale=loss_scale_px, x_scale=1.0,
                            diff_step=1e-4, max_nfev=50)
        fitted_rig = unpack(sol.x)
        r_fit, _ = ray_residuals(fitted_rig, dirs_a, dirs_b, fa, fb, normals=normals)
        # covariance from the Jacobian of the plain residuals (robust scale of the final residuals)
        J = np.asarray(sol.jac)
        sigma = max(1.4826 * float(np.median(np.abs(r_fit[np.isfinite(r_fit)]))), 1e-3)
        return fitted_rig, r_fit, _std(J, sigma), _std(J[:total], sigma), int(s1.nfev + sol.nfev)

    fitted, r1, std_all, std_data, nfev = fit(free_params)
    sdata = {k: float(std_data[i]) for i, k in enumerate(free_params)}
    std = {k: float(std_all[i]) for i, k in enumerate(free_params)}
    observed = {k: k not in PRIOR_STD or sdata[k] < OBSERVED_SHARE * PRIOR_STD[k] for k in free_params}
    held = tuple(k for k in free_params if not observed[k])
    fitted_params = tuple(k for k in free_params if observed[k])
    if held and fitted_params:
        # what the scene cannot tell stays where the user put it; the rest is fitted without it
        fitted, r1, std_all, _, n2 = fit(fitted_params)
        nfev += n2
        std = {k: float(std_all[fitted_params.index(k)]) if k in fitted_params else float(PRIOR_STD[k])
               for k in free_params}
    elif held:
        fitted, r1 = rig, r0
        std = {k: float(PRIOR_STD[k]) for k in free_params}
    estimates = {k: float(prism_values(fitted)[k]) for k in free_params}
    bad = [k for k in fitted_params if not np.isfinite(std[k]) or std[k] > STD_LIMIT[k]]
    if bad:
        detail = ", ".join(f"{k} ± {std[k]:.3g} {PARAMETERS[k][0]}".strip() for k in bad)
        raise GeometryError(f"expected a well-conditioned self-calibration, got {detail} from {total} matches; use "
                            "captures whose texture fills the common view, or calibrate with a checkerboard")
    for face, px in ((fa, pa), (fb, pb)):
        seen = trace_pixels(fitted, px).face == face
        if seen.mean() < 0.98:
            raise GeometryError(f"expected the refined prism to show every matched feature through the face it was "
                                f"found in, got {int((~seen).sum())} of {seen.size} elsewhere; the fit is "
                                "ill-conditioned (check the camera calibration, or fit only free=rotation)")
    notes = tuple(f"{k}: not observed by this scene (data-only std {sdata[k]:.3g} {PARAMETERS[k][0]}), held at "
                  f"its input value {init[k]:g} (± {PRIOR_STD[k]:g} assumed)" for k in held)
    dt, dc = time.perf_counter() - t0, time.process_time() - c0
    log.info("self-calibration: %d matches (%d optical flow), ray residual p95 %.3f -> %.3f px, %.1f s", total,
             sum(m.dense for m in used), _stats(r0)["p95"], _stats(r1)["p95"], dt)
    return SceneCalibration(
        rig=fitted, estimates=estimates, initial={k: float(init[k]) for k in free_params}, std=std, std_data=sdata,
        observed=observed, matches=used, residual_before=_stats(r0), residual_after=_stats(r1), seconds=dt,
        cpu_seconds=dc, evaluations=nfev, notes=notes, held=held)


def _std(J: np.ndarray, sigma: float) -> np.ndarray:
    try:
        cov = np.linalg.inv(J.T @ J) * sigma**2
    except np.linalg.LinAlgError:
        return np.full(J.shape[1], np.inf)
    d = np.diag(cov)
    return np.where(d >= 0, np.sqrt(np.abs(d)), np.inf)
