"""Rectification of the virtual cameras of a prism rig (thesis §3.2.2, §4.1.3, §4.2; Eq. 3.36–3.37, 7.23).

A pair of virtual cameras (C_a, R_a), (C_b, R_b) is rectified by turning both to one common orientation

    R_rect = [r1ᵀ; r2ᵀ; r3ᵀ],  r1 = (C_right − C_left) / ‖C_right − C_left‖,  r2 ∝ z_ref × r1,  r3 = r1 × r2

(thesis Eq. 3.36 with r2 "as the real camera's Y": z_ref is the real camera's optical axis, so r2 is the
direction perpendicular to the baseline that is closest to the real camera's +Y; this generalises the
thesis's r2 = Y_w to baselines that are not along X_w). Each rectified camera is then
P = K_rect [R_rect | −R_rect C] (thesis Eq. 3.37–3.38 with a world-to-camera R) with one common K_rect
(the real camera's focal length in pixels, so the views keep about their native resolution).

Common view: a strongly deviating prism (a 20° bi-prism) sees its scene only over a narrow band of depths,
where every point has a large disparity (~1200–1700 px): with one K both rectified views would have to span
the two footprints and the disparity between them (1951 px wide for 377 px of view each). The right view's
principal point is then moved by a disparity offset d₀ (OpenCV's cx' ≠ cx, Q[3, 3] = d₀ / B): image
disparities x_left − x_right are the true ones minus d₀, the images shrink to the common view, and :attr:`Q`
and the remap tables account for it. d₀ is the smallest true disparity of the common view over the depths at
which the views overlap (:func:`~prismstereo.cameras.overlap.pair_depth_range`), less
:data:`OFFSET_PAD_PX`, and it is used only when it reaches :data:`OFFSET_MIN_PX` (a weak prism's pair keeps
d = f B / Z).
The sign of r1 is chosen so that r1 points along the real camera's +X (or +Y for a vertical baseline),
and the "left" camera is the one with the smaller coordinate along r1, so d = x_left − x_right ≥ 0 for
points in front of the cameras.

For N ≥ 3 views (thesis §4.1.3, §4.2) all views are turned to the real camera's orientation
(r1 = X_w, r2 = Y_w, r3 = Z_w, Eq. 4.31–4.32 / 4.35–4.36); pairs whose baseline is not horizontal in that
frame are also rectified pair by pair.

The remap tables give, for every rectified pixel, the REAL-image pixel to sample. Two constructions:

- ``"model"``: through the virtual camera model (``fit`` by default, with its distortion): the rectified
  ray is projected by the model. Exact inverse: :meth:`RectifiedPair.real_to_rectified`.
- ``"exact"``: through exact refraction: the rectified ray from the virtual centre is followed to a
  reference depth and the real pixel whose exact ray passes through that point is found
  (:func:`~prismstereo.optics.project_exact`). Exact for points at the reference depth, and it does not
  depend on how well a pinhole model fits the face.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from itertools import combinations
from typing import Any, Literal

import cv2
import numpy as np
from scipy.ndimage import map_coordinates

from prismstereo.cameras import VirtualView
from prismstereo.cameras.overlap import pair_depth_range
from prismstereo.config import Rig
from prismstereo.errors import ConfigError, GeometryError, ImageError
from prismstereo.optics import project_exact, trace_pixels
from prismstereo.optics.refraction import normalize
from prismstereo.rectify.regions import MARGIN_PX, ViewRegion, check_image_size, view_regions

log = logging.getLogger(__name__)

RemapKind = Literal["model", "exact"]
REMAPS = ("model", "exact")
#: reference depth (mm, world Z) of the ``exact`` remap
REFERENCE_DEPTH_MM = 1500.0
_MAP_STEP = 8  # px: the remap tables are solved on this grid and interpolated bilinearly
#: disparity kept below the common view's smallest one when the right view is offset, px
OFFSET_PAD_PX = 16
#: smallest disparity offset worth using, px (below it a pair keeps d = f B / Z)
OFFSET_MIN_PX = 64


# --------------------------------------------------------------------------- rotations
def rectifying_rotation(C_a: np.ndarray, C_b: np.ndarray) -> tuple[np.ndarray, bool]:
    """Common world-to-rectified rotation for two centres (thesis Eq. 3.36, generalised).

    Parameters
    ----------
    C_a, C_b : (3,) optical centres, mm, world frame.

    Returns
    -------
    R : (3, 3) rotation whose rows are r1 (along the baseline), r2, r3.
    swapped : bool
        True when ``b`` is the left camera (smaller coordinate along r1).

    Raises
    ------
    GeometryError
        If the centres coincide (no baseline).
    """
    base = np.asarray(C_b, dtype=np.float64) - np.asarray(C_a, dtype=np.float64)
    norm = float(np.linalg.norm(base))
    if not norm > 1e-9:
        raise GeometryError(f"expected two virtual cameras with distinct optical centres, got a baseline of "
                            f"{norm:.3g} mm")
    r1 = base / norm
    swapped = False
    if r1[0] < -1e-9 or (abs(r1[0]) <= 1e-9 and r1[1] < 0):
        r1, swapped = -r1, True
    z_ref = np.array([0.0, 0.0, 1.0])
    r2 = np.cross(z_ref, r1)
    if np.linalg.norm(r2) < 1e-9:
        raise GeometryError("expected a baseline not along the real optical axis, got one along +Z")
    r2 = r2 / np.linalg.norm(r2)
    r3 = np.cross(r1, r2)
    return np.stack([r1, r2, r3]), swapped


# --------------------------------------------------------------------------- per-view mapping
@dataclass(frozen=True, eq=False)
class _ViewMapper:
    """Maps between one view's real pixels and rectified pixels (common R, K)."""

    rig: Rig
    view: VirtualView
    R: np.ndarray
    C: np.ndarray
    remap: str
    reference_depth: float

    def real_to_rect_dirs(self, pixels: np.ndarray) -> np.ndarray:
        """(N, 2) real pixels → (N, 3) unit ray directions in the rectified frame."""
        px = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
        if self.remap == "model":
            xy = self.view.camera.undistort_pixels(px)
            d_cam = np.concatenate([xy, np.ones((xy.shape[0], 1))], axis=1)
            d_world = d_cam @ self.view.camera.R  # R_view^T d
        else:
            b = trace_pixels(self.rig, px, face=self.view.face, bounded=False)
            X = b.point_at_depth(self.reference_depth)
            d_world = X - self.C
        return normalize(d_world @ self.R.T)

    def rect_dirs_to_real(self, dirs_rect: np.ndarray) -> np.ndarray:
        """(N, 3) rectified-frame directions → (N, 2) real pixels (NaN where none)."""
        d_world = dirs_rect @ self.R
        if self.remap == "model":
            return self.view.camera.project(self.C + d_world)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (self.reference_depth - self.C[2]) / d_world[:, 2]
        X = self.C + np.where(s > 0, s, np.nan)[:, None] * d_world
        px, _ = project_exact(self.rig, X, face=self.view.face)
        return px


def _rect_pixels_to_dirs(pixels: np.ndarray, K: np.ndarray) -> np.ndarray:
    px = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    hom = np.concatenate([px, np.ones((px.shape[0], 1))], axis=1)
    return hom @ np.linalg.inv(K).T


def _dirs_to_rect_pixels(dirs: np.ndarray, K: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        h = dirs @ K.T
        px = h[:, :2] / h[:, 2:3]
    return np.where(dirs[:, 2:3] > 1e-12, px, np.nan)


def _build_map(mapper: _ViewMapper, K: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(H, W, 2) float32 remap table: rectified pixel → real pixel."""
    # The map is smooth: solved on a grid of _MAP_STEP px and interpolated bilinearly (error ≪ 0.01 px).
    w, h = size
    step = _MAP_STEP
    gx = np.arange(0, w - 1 + step, step, dtype=np.float64)
    gy = np.arange(0, h - 1 + step, step, dtype=np.float64)
    xs, ys = np.meshgrid(gx, gy)
    dirs = _rect_pixels_to_dirs(np.stack([xs, ys], axis=-1), K)
    coarse = mapper.rect_dirs_to_real(dirs).reshape(gy.size, gx.size, 2).astype(np.float32)
    fx, fy = np.meshgrid(np.arange(w, dtype=np.float32) / step, np.arange(h, dtype=np.float32) / step)
    return cv2.remap(coarse, fx, fy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def _valid_from_map(map_xy: np.ndarray, region: np.ndarray) -> np.ndarray:
    """(H, W) bool: rectified pixels whose real pixel lies inside ``region`` (nearest-pixel test)."""
    hr, wr = region.shape
    u = np.rint(np.nan_to_num(map_xy[..., 0], nan=-1.0)).astype(np.int64)
    v = np.rint(np.nan_to_num(map_xy[..., 1], nan=-1.0)).astype(np.int64)
    inside = (u >= 0) & (u < wr) & (v >= 0) & (v < hr)
    ok = np.zeros(u.shape, dtype=bool)
    ok[inside] = region[v[inside], u[inside]]
    return ok


def _roundtrip_valid(mapper: _ViewMapper, map_xy: np.ndarray, K: np.ndarray, valid: np.ndarray,
                     *, tol_px: float = 0.5) -> np.ndarray:
    """Drop rectified pixels whose real pixel does not map back to them (a distortion polynomial that
    folds over far outside the region it was fitted on can send far-away rays into the face's region)."""
    # checked on a grid of ``step`` px (folds are wide regions); a failing grid pixel drops its cell
    step = 4
    sub = valid[::step, ::step]
    ys, xs = np.nonzero(sub)
    if ys.size == 0:
        return valid
    ys, xs = ys * step, xs * step
    back = _dirs_to_rect_pixels(mapper.real_to_rect_dirs(map_xy[ys, xs].astype(np.float64)), K)
    bad_pts = ~(np.hypot(back[:, 0] - xs, back[:, 1] - ys) <= tol_px)
    if not bad_pts.any():
        return valid
    bad = np.zeros(sub.shape, dtype=np.uint8)
    bad[ys[bad_pts] // step, xs[bad_pts] // step] = 1
    grown = np.asarray(cv2.dilate(bad, np.ones((3, 3), np.uint8)))
    full = np.kron(grown, np.ones((step, step), np.uint8))[: valid.shape[0], : valid.shape[1]].astype(bool)
    return valid & ~full


def _footprint(mapper: _ViewMapper, region: ViewRegion, f: float) -> np.ndarray:
    """(M, 2) rectified pixels (K with f, principal point 0) of the region's outline and a coarse grid."""
    contours, _ = cv2.findContours(region.mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    pts = [c.reshape(-1, 2).astype(np.float64) for c in contours]
    ys, xs = np.nonzero(region.mask[::16, ::16])
    pts.append(np.stack([xs * 16.0, ys * 16.0], axis=1))
    px = np.concatenate(pts)
    K0 = np.array([[f, 0.0, 0.0], [0.0, f, 0.0], [0.0, 0.0, 1.0]])
    rect = _dirs_to_rect_pixels(mapper.real_to_rect_dirs(px), K0)
    return rect[np.all(np.isfinite(rect), axis=1)]


def _common_K(footprints: list[np.ndarray], f: float, size: tuple[int, int] | None
              ) -> tuple[np.ndarray, tuple[int, int]]:
    allpts = np.concatenate(footprints)
    lo = np.floor(allpts.min(axis=0))
    hi = np.ceil(allpts.max(axis=0))
    if size is None:
        w, h = int(hi[0] - lo[0]) + 1, int(hi[1] - lo[1]) + 1
        cx, cy = -lo[0], -lo[1]
    else:
        w, h = int(size[0]), int(size[1])
        if w <= 0 or h <= 0:
            raise ConfigError(f"expected a positive rectified size (w, h), got {size}")
        mid = (lo + hi) / 2.0
        cx, cy = (w - 1) / 2.0 - mid[0], (h - 1) / 2.0 - mid[1]
    K = np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
    return K, (w, h)


def _check_remap(remap: str) -> None:
    if remap not in REMAPS:
        raise ConfigError(f"expected a remap construction in {REMAPS}, got {remap!r}")


def _check_views(rig: Rig, views: list[VirtualView]) -> None:
    for v in views:
        if not 0 <= v.face < rig.prism.faces:
            raise GeometryError(f"expected a face index in [0, {rig.prism.faces - 1}], got {v.face}")


def _sample_map(map_xy: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    px = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    coords = [px[:, 1], px[:, 0]]
    out = np.stack([map_coordinates(map_xy[..., c].astype(np.float64), coords, order=1, mode="constant",
                                    cval=np.nan) for c in (0, 1)], axis=1)
    return out


def _remap_image(image: np.ndarray, map_xy: np.ndarray, valid: np.ndarray, fill: float) -> np.ndarray:
    img = np.asarray(image)
    src = img.astype(np.float32) if img.dtype not in (np.uint8, np.uint16, np.float32) else img
    # the (h, w, 2) table as one two-channel map: the same samples as two one-channel maps, without copying
    # the strided x and y planes out of it on every call
    out = cv2.remap(src, map_xy, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    if out.ndim == 2 and img.ndim == 3:
        out = out[:, :, None]
    if np.isnan(fill) and not np.issubdtype(out.dtype, np.floating):
        out = out.astype(np.float32)
    out[~valid] = fill
    return out


# --------------------------------------------------------------------------- pair
@dataclass(frozen=True, eq=False)
class RectifiedPair:
    """A rectified pair of virtual cameras: common K and rotation, remap tables, Q.

    Attributes
    ----------
    left_face, right_face : int
        Faces of the left and right rectified cameras (left = smaller coordinate along the baseline).
    K : (3, 3) common rectified intrinsics (square pixels, focal length of the real camera).
    R : (3, 3) common world-to-rectified rotation (thesis Eq. 3.36–3.37).
    C_left, C_right : (3,) optical centres, mm, world frame.
    size : (w, h) of the rectified images.
    map_left, map_right : (h, w, 2) float32
        For every rectified pixel, the real-image pixel (u, v) to sample (``cv2.remap`` tables).
    valid_left, valid_right : (h, w) bool
        Rectified pixels whose real pixel lies in the face's region (margin dropped).
    method : str
        Virtual camera model the pair was built from (``fit`` or ``thesis``).
    remap : str
        ``model`` or ``exact`` (see the module docstring).
    reference_depth_mm : float
        Reference depth of the ``exact`` remap (world Z, mm).
    view_left, view_right : VirtualView
    rig : Rig
    disparity_offset : float
        d₀, px: the right view's principal point is cx + d₀, so the true disparity of an image match is
        x_left − x_right + d₀ (module docstring; 0 for most rigs).
    """

    left_face: int
    right_face: int
    K: np.ndarray
    R: np.ndarray
    C_left: np.ndarray
    C_right: np.ndarray
    size: tuple[int, int]
    map_left: np.ndarray
    map_right: np.ndarray
    valid_left: np.ndarray
    valid_right: np.ndarray
    method: str
    remap: str
    reference_depth_mm: float
    view_left: VirtualView = field(repr=False)
    view_right: VirtualView = field(repr=False)
    rig: Rig = field(repr=False)
    disparity_offset: float = 0.0

    # ---- geometry
    @property
    def K_left(self) -> np.ndarray:
        """Intrinsics of the left rectified view (:attr:`K`)."""
        return self.K

    @property
    def K_right(self) -> np.ndarray:
        """Intrinsics of the right rectified view: :attr:`K` with cx moved by :attr:`disparity_offset`."""
        K = self.K.copy()
        K[0, 2] += self.disparity_offset
        return K

    @property
    def R_left(self) -> np.ndarray:
        """World-to-rectified rotation of the left camera (the common rotation)."""
        return self.R

    @property
    def R_right(self) -> np.ndarray:
        """World-to-rectified rotation of the right camera (the common rotation)."""
        return self.R

    @property
    def baseline_mm(self) -> float:
        return float(np.linalg.norm(self.C_right - self.C_left))

    @property
    def focal_px(self) -> float:
        return float(self.K[0, 0])

    @property
    def P_left(self) -> np.ndarray:
        """3×4 K [R | −R C_left] (thesis Eq. 3.38)."""
        return self.K @ np.hstack([self.R, -(self.R @ self.C_left)[:, None]])

    @property
    def P_right(self) -> np.ndarray:
        """3×4 K_right [R | −R C_right] (thesis Eq. 3.38)."""
        return self.K_right @ np.hstack([self.R, -(self.R @ self.C_right)[:, None]])

    @property
    def Q(self) -> np.ndarray:
        """4×4 reprojection matrix (thesis Eq. 7.23, OpenCV convention).

        ``Q @ [x, y, d, 1]`` is the homogeneous 3D point in the rectified LEFT camera frame (mm) for a
        left rectified pixel (x, y) with disparity d = x_left − x_right: X = (x − c_x) B / d,
        Y = (y − c_y) B / d, Z = f B / d, with d the true disparity (image disparity + :attr:`disparity_offset`,
        which Q[3, 3] = d₀ / B adds). See :meth:`left_to_world`.
        """
        f, cx, cy, B = self.K[0, 0], self.K[0, 2], self.K[1, 2], self.baseline_mm
        return np.array([[1.0, 0.0, 0.0, -cx], [0.0, 1.0, 0.0, -cy], [0.0, 0.0, 0.0, f],
                         [0.0, 0.0, 1.0 / B, self.disparity_offset / B]])

    def left_to_world(self, points: np.ndarray) -> np.ndarray:
        """(..., 3) points in the rectified left camera frame → world frame (mm)."""
        return np.asarray(points, dtype=np.float64) @ self.R + self.C_left

    def world_to_left(self, points: np.ndarray) -> np.ndarray:
        """(..., 3) world points → rectified left camera frame (mm)."""
        return (np.asarray(points, dtype=np.float64) - self.C_left) @ self.R.T

    def reproject(self, pixels: np.ndarray, disparity: np.ndarray) -> np.ndarray:
        """World points (N, 3) of left rectified pixels (N, 2) with disparities (N,), through :attr:`Q`."""
        px = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
        d = np.asarray(disparity, dtype=np.float64).reshape(-1)
        hom = np.stack([px[:, 0], px[:, 1], d, np.ones_like(d)], axis=1) @ self.Q.T
        with np.errstate(divide="ignore", invalid="ignore"):
            pts = hom[:, :3] / hom[:, 3:4]
        return self.left_to_world(pts)

    def project(self, points: np.ndarray, side: str = "left") -> np.ndarray:
        """(N, 3) world points → (N, 2) rectified pixels of one side (pinhole, no distortion)."""
        P = self.P_left if self._side(side) == "left" else self.P_right
        X = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        h = X @ P[:, :3].T + P[:, 3]
        with np.errstate(divide="ignore", invalid="ignore"):
            return h[:, :2] / h[:, 2:3]

    # ---- pixels
    @staticmethod
    def _side(side: str) -> str:
        if side not in ("left", "right"):
            raise ConfigError(f"expected side 'left' or 'right', got {side!r}")
        return side

    def _mapper(self, side: str) -> _ViewMapper:
        left = self._side(side) == "left"
        return _ViewMapper(rig=self.rig, view=self.view_left if left else self.view_right, R=self.R,
                           C=self.C_left if left else self.C_right, remap=self.remap,
                           reference_depth=self.reference_depth_mm)

    def rectified_to_real(self, pixels: np.ndarray, side: str = "left") -> np.ndarray:
        """(N, 2) rectified pixels → (N, 2) real-image pixels, by bilinear lookup in the remap table."""
        m = self.map_left if self._side(side) == "left" else self.map_right
        return _sample_map(m, pixels)

    def real_to_rectified(self, pixels: np.ndarray, side: str = "left") -> np.ndarray:
        """(N, 2) real-image pixels of the side's face → (N, 2) rectified pixels (inverse of the remap)."""
        dirs = self._mapper(side).real_to_rect_dirs(pixels)
        return _dirs_to_rect_pixels(dirs, self.K if self._side(side) == "left" else self.K_right)

    def valid_masks(self) -> tuple[np.ndarray, np.ndarray]:
        """(h, w) bool masks of the left and right rectified images."""
        return self.valid_left, self.valid_right

    def rectify_images(self, capture: np.ndarray, *, fill: float = 0) -> tuple[np.ndarray, np.ndarray]:
        """Warp a real capture into the rectified left and right images (``cv2.remap``, bilinear).

        Parameters
        ----------
        capture : (H, W) or (H, W, C) real image of the rig's sensor size.
        fill : value of pixels outside the face's region (use ``np.nan`` for a float NaN mask).

        Returns
        -------
        left, right : (h, w[, C]) arrays, the capture's dtype (float32 when ``fill`` is NaN).
        """
        check_image_size(capture, self.rig)
        if np.asarray(capture).dtype == bool:
            raise ImageError("expected a numeric image, got a boolean array")
        return (_remap_image(capture, self.map_left, self.valid_left, fill),
                _remap_image(capture, self.map_right, self.valid_right, fill))

    def view_dict(self, side: str) -> dict[str, Any]:
        left = self._side(side) == "left"
        v = self.view_left if left else self.view_right
        C = self.C_left if left else self.C_right
        return {"face": v.face, "name": v.name, "side": side, "K": self.K if left else self.K_right, "R": self.R,
                "C": C,
                "P": self.P_left if left else self.P_right}

    def to_json(self) -> dict[str, Any]:
        """The content of rectification.json (docs/formats.md)."""
        return {
            "method": self.method, "remap": self.remap, "reference_depth_mm": self.reference_depth_mm,
            "size": list(self.size), "left_face": self.left_face, "right_face": self.right_face,
            "views": [self.view_dict("left"), self.view_dict("right")],
            "baseline_mm": self.baseline_mm, "Q": self.Q, "disparity_offset": self.disparity_offset,
        }


def _views_overlap(fa: np.ndarray, fb: np.ndarray, left_is_a: bool) -> bool:
    """Whether two rectified footprints (same K, R) can see a common point in front of both."""
    fl, fr = (fa, fb) if left_is_a else (fb, fa)
    y_overlap = min(fl[:, 1].max(), fr[:, 1].max()) - max(fl[:, 1].min(), fr[:, 1].min())
    # d = x_left − x_right > 0 in front: some left x must exceed some right x
    return bool(y_overlap > 0 and fl[:, 0].max() > fr[:, 0].min())


def rectify_pair(
    rig: Rig,
    view_a: VirtualView,
    view_b: VirtualView,
    *,
    size: tuple[int, int] | None = None,
    remap: RemapKind = "model",
    margin_px: int = MARGIN_PX,
    reference_depth_mm: float = REFERENCE_DEPTH_MM,
    regions: list[ViewRegion] | None = None,
    depth_range: tuple[float, float] | None = None,
) -> RectifiedPair:
    """Rectify two virtual cameras of a rig (thesis §3.2.2, Eq. 3.36–3.38; Q of Eq. 7.23).

    Parameters
    ----------
    rig : Rig
    view_a, view_b : VirtualView
        The two virtual cameras (from :func:`~prismstereo.cameras.calibrate_rig`, ``fit`` or ``thesis``);
        their order does not matter: the left one is the one with the smaller coordinate along the
        baseline direction (which points along the real camera's +X).
    size : (w, h), optional
        Rectified image size. By default the union of both views' footprints at the real camera's focal
        length, so the common view keeps about the native resolution.
    remap : ``"model"`` or ``"exact"``
        How rectified pixels map to real pixels (module docstring).
    margin_px : int
        Band dropped along the prism edges (:func:`view_regions`).
    reference_depth_mm : float
        Depth (world Z) at which the ``exact`` remap is exact.
    regions : list of ViewRegion, optional
        Precomputed :func:`view_regions`.
    depth_range : (near, far) mm, optional
        Depths at which the scene may lie, for the common view and the disparity offset (module docstring);
        default the depths at which the two views overlap (:func:`~prismstereo.cameras.overlap.pair_depth_range`).
        Used only when ``size`` is None.

    Returns
    -------
    RectifiedPair

    Raises
    ------
    GeometryError
        If both views have the same centre, or if they cannot see a common point.
    """
    _check_remap(remap)
    _check_views(rig, [view_a, view_b])
    if view_a.face == view_b.face:
        raise GeometryError(f"expected two different faces, got face {view_a.face} twice")
    R, swapped = rectifying_rotation(view_a.camera.C, view_b.camera.C)
    left, right = (view_b, view_a) if swapped else (view_a, view_b)
    regions = view_regions(rig, margin_px=margin_px) if regions is None else regions
    f = rig.camera.focal_px
    mappers = [_ViewMapper(rig=rig, view=v, R=R, C=v.camera.C, remap=remap, reference_depth=reference_depth_mm)
               for v in (left, right)]
    feet = [_footprint(m, regions[v.face], f) for m, v in zip(mappers, (left, right), strict=True)]
    if not _views_overlap(feet[0], feet[1], True):
        raise GeometryError(f"expected faces {left.face} and {right.face} to see a common part of the scene, got "
                            "views that do not overlap")
    offset = 0.0
    if size is None:
        if depth_range is None:
            try:
                depth_range = pair_depth_range(rig, left.face, right.face, depth_step_cap=False)
            except GeometryError as exc:  # too few pixels to measure the overlap: keep one principal point
                log.info("no overlap range for faces %d and %d (%s): no disparity offset", left.face, right.face, exc)
        if depth_range is not None:
            offset = _disparity_offset(mappers, feet, f, depth_range)
    K, wh = _common_K([feet[0], feet[1] + np.array([offset, 0.0])], f, size)
    K_right = K.copy()
    K_right[0, 2] += offset
    maps = [_build_map(m, k, wh) for m, k in zip(mappers, (K, K_right), strict=True)]
    valid = [_roundtrip_valid(m, mp, k, _valid_from_map(mp, regions[v.face].mask))
             for m, mp, k, v in zip(mappers, maps, (K, K_right), (left, right), strict=True)]
    log.info("rectified faces %d (left) and %d (right): %dx%d, baseline %.2f mm, disparity offset %.0f px", left.face,
             right.face, *wh, float(np.linalg.norm(right.camera.C - left.camera.C)), offset)
    return RectifiedPair(left_face=left.face, right_face=right.face, K=K, R=R, C_left=left.camera.C.copy(),
                         C_right=right.camera.C.copy(), size=wh, map_left=maps[0], map_right=maps[1],
                         valid_left=valid[0], valid_right=valid[1], method=left.method, remap=remap,
                         reference_depth_mm=float(reference_depth_mm), view_left=left, view_right=right, rig=rig,
                         disparity_offset=float(offset))


def _disparity_offset(mappers: list[_ViewMapper], feet: list[np.ndarray], f: float,
                      depth_range: tuple[float, float], *, n_depths: int = 8) -> float:
    """d₀ (px, see the module docstring) for two footprints (K with focal f, principal point 0), or 0."""
    left, right = mappers
    K0 = np.array([[f, 0.0, 0.0], [0.0, f, 0.0], [0.0, 0.0, 1.0]])
    d_world = _rect_pixels_to_dirs(feet[0], K0) @ left.R
    fr = feet[1]
    lo_r, hi_r = fr.min(axis=0), fr.max(axis=0)
    d_min = np.inf
    for z in np.geomspace(depth_range[0], depth_range[1], n_depths):
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (z - left.C[2]) / d_world[:, 2]
            X = left.C + np.where(s > 0, s, np.nan)[:, None] * d_world
            xr = _dirs_to_rect_pixels((X - right.C) @ right.R.T, K0)
        ok = np.all(np.isfinite(xr), axis=1) & np.all((xr >= lo_r) & (xr <= hi_r), axis=1)
        if ok.any():
            d_min = min(d_min, float(np.min(feet[0][ok, 0] - xr[ok, 0])))
    if not np.isfinite(d_min):
        return 0.0
    offset = float(np.floor(d_min)) - OFFSET_PAD_PX
    return offset if offset >= OFFSET_MIN_PX else 0.0


def _seen_by_right(pair: RectifiedPair, px: np.ndarray, depths_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Follow left rectified pixels (N, 2) to world depths (D,) and look them up in the right view.

    Returns ok (D, N) bool, the point lands in the right view's valid region (thesis Eq. 7.22), and the
    image disparities x_left − x_right (D, N), px.
    """
    vr = np.asarray(pair.valid_right, dtype=bool)
    K = np.asarray(pair.K, dtype=np.float64)
    R = np.asarray(pair.R_left, dtype=np.float64)
    C = np.asarray(pair.C_left, dtype=np.float64)
    rays = np.concatenate([px, np.ones((px.shape[0], 1))], axis=1) @ np.linalg.inv(K).T @ R  # world dirs
    ok = np.zeros((len(depths_mm), px.shape[0]), dtype=bool)
    disp = np.full((len(depths_mm), px.shape[0]), np.nan)
    for i, z in enumerate(depths_mm):
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (z - C[2]) / rays[:, 2]
        X = C + np.where(s > 0, s, np.nan)[:, None] * rays
        xr = np.asarray(pair.project(X, "right"), dtype=np.float64)
        good = np.all(np.isfinite(xr), axis=1)
        ci = np.rint(np.where(good, xr[:, 0], -1)).astype(np.int64)
        ri = np.rint(np.where(good, xr[:, 1], -1)).astype(np.int64)
        good &= (ci >= 0) & (ci < vr.shape[1]) & (ri >= 0) & (ri < vr.shape[0])
        good[good] &= vr[ri[good], ci[good]]
        ok[i] = good
        disp[i] = px[:, 0] - xr[:, 0]
    return ok, disp


def view_overlap(pair: RectifiedPair, depths_mm: np.ndarray, *, stride: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Shared fraction of the rectified left view and the median disparity at each world depth.

    Every ``stride``-th valid left pixel is followed along its ray to each depth and projected into the
    rectified right view (thesis Eq. 7.22), as in :func:`common_view`.

    Returns
    -------
    fraction : (D,) float  share of the sampled left pixels whose point lands in the right view's valid region.
    disparity : (D,) float  median disparity x_left − x_right of those samples, px (NaN where none).
    """
    vl = np.asarray(pair.valid_left, dtype=bool)
    ys, xs = np.nonzero(vl[::stride, ::stride])
    if ys.size == 0:
        raise GeometryError("expected a rectified left view with valid pixels, got none")
    px = np.stack([xs * stride, ys * stride], axis=1).astype(np.float64)
    ok, d = _seen_by_right(pair, px, np.asarray(depths_mm, dtype=np.float64))
    frac = ok.mean(axis=1)
    disp = np.array([float(np.median(di[oi])) if oi.any() else np.nan for oi, di in zip(ok, d, strict=True)])
    return frac, disp


#: grid step of :func:`common_view`'s first pass, px (its cells are resolved pixel by pixel only where they
#: straddle an edge of the common view or of the left view's valid region)
_COMMON_VIEW_STEP = 4


def common_view(pair: RectifiedPair, depth_min_mm: float, depth_max_mm: float, *, n_depths: int = 12
                ) -> tuple[np.ndarray, tuple[int, int]]:
    """Where the two rectified views of a pair overlap for world depths in a range, and its disparities.

    The ray of every valid rectified-left pixel is followed to ``n_depths`` world depths between the
    bounds (geometric steps); a sample counts where its point projects into the valid region of the
    rectified right image (thesis Eq. 7.22: d = f λ / Z along the rectified axis).

    The pixels are visited on a grid of ``_COMMON_VIEW_STEP`` px first: a grid cell whose corners agree
    (all seen or none, at one depth) inside the valid left region takes its corners' answer, and only the
    cells that straddle an edge are followed pixel by pixel (the regions are smooth and far wider than a
    cell; the disparity is affine across a cell to far below a pixel, so its extremes are at corners).

    Returns
    -------
    mask : (h, w) bool
        Left pixels that see a point of the right view at some depth in the range.
    (min_disp, max_disp) : ints
        Floor / ceil of the disparities of those samples (``min_disp >= 0``): the search range clipped to
        the common view.

    Raises
    ------
    GeometryError
        If no sample is seen by both views: the views do not overlap at these depths.
    """
    vl = np.asarray(pair.valid_left, dtype=bool)
    if not vl.any():
        raise GeometryError("expected a rectified left view with valid pixels, got none")
    h, w = vl.shape
    step = _COMMON_VIEW_STEP
    gy = np.unique(np.append(np.arange(0, h, step), h - 1))
    gx = np.unique(np.append(np.arange(0, w, step), w - 1))
    # cell of each pixel (cells span grid line i to i + 1, both included; the last line closes the last cell)
    cy = np.minimum(np.searchsorted(gy, np.arange(h), side="right") - 1, max(gy.size - 2, 0))
    cx = np.minimum(np.searchsorted(gx, np.arange(w), side="right") - 1, max(gx.size - 2, 0))
    # valid-left pixels per cell (integral image over the closed cell): a cell is uniform when all or none are
    ii = np.zeros((h + 1, w + 1), dtype=np.int64)
    ii[1:, 1:] = np.cumsum(np.cumsum(vl, axis=0), axis=1)
    y0, y1 = gy[:-1], gy[1:] + 1
    x0, x1 = gx[:-1], gx[1:] + 1
    count = ii[y1][:, x1] - ii[y0][:, x1] - ii[y1][:, x0] + ii[y0][:, x0]
    area = (y1 - y0)[:, None] * (x1 - x0)[None, :]
    uniform = (count == 0) | (count == area)
    if gy.size < 2 or gx.size < 2:  # a one-pixel-wide view: no cells, every pixel is followed
        uniform = np.zeros((max(gy.size - 1, 1), max(gx.size - 1, 1)), dtype=bool)
        cy, cx = np.zeros(h, dtype=np.int64), np.zeros(w, dtype=np.int64)
    depths = np.geomspace(depth_min_mm, depth_max_mm, n_depths)
    gyy, gxx = np.meshgrid(gy, gx, indexing="ij")
    grid_px = np.stack([gxx.ravel(), gyy.ravel()], axis=1).astype(np.float64)
    grid_ok, grid_d = _seen_by_right(pair, grid_px, depths)
    grid_ok &= vl[gyy.ravel(), gxx.ravel()][None, :]
    mask = np.zeros((h, w), dtype=bool)
    lo, hi = np.inf, -np.inf
    for i in range(depths.size):
        ok = grid_ok[i].reshape(gy.size, gx.size)
        if gy.size >= 2 and gx.size >= 2:
            corners = (ok[:-1, :-1].astype(np.int8) + ok[1:, :-1] + ok[:-1, 1:] + ok[1:, 1:])
            all_seen, pure = corners == 4, uniform & ((corners == 0) | (corners == 4))
        else:
            all_seen = pure = np.zeros_like(uniform)
        seen = all_seen[cy][:, cx] & vl
        ys, xs = np.nonzero(~pure[cy][:, cx] & vl)
        if ys.size:
            px = np.stack([xs, ys], axis=1).astype(np.float64)
            ok_px, d_px = _seen_by_right(pair, px, depths[i:i + 1])
            seen[ys, xs] = ok_px[0]
            if ok_px[0].any():
                d = d_px[0, ok_px[0]]
                lo, hi = min(lo, float(d.min())), max(hi, float(d.max()))
        if grid_ok[i].any():
            d = grid_d[i, grid_ok[i]]
            lo, hi = min(lo, float(d.min())), max(hi, float(d.max()))
        mask |= seen
    if not mask.any():
        raise GeometryError(f"expected faces {pair.left_face} and {pair.right_face} to see a common part of the "
                            f"scene at {depth_min_mm:g}–{depth_max_mm:g} mm, got views that do not overlap "
                            "(choose other views or depth_range)")
    return mask, (max(0, int(np.floor(lo))), int(np.ceil(hi)))


def disparity_range(pair: RectifiedPair, depth_min_mm: float, depth_max_mm: float) -> tuple[int, int]:
    """Disparity search range (px) for scene depths (world Z, mm) in [depth_min_mm, depth_max_mm].

    The disparities of :func:`common_view`: those of the left pixels whose point, somewhere in the depth
    range, is seen by the right view (thesis Eq. 7.22); image disparities, i.e. the true ones less the pair's
    :attr:`~RectifiedPair.disparity_offset`.

    Returns
    -------
    (min_disp, max_disp) : ints, floor and ceil of the range, min_disp ≥ 0.

    Raises
    ------
    ConfigError
        If the range is not ``0 < min < max``.
    GeometryError
        If the views do not overlap at these depths.
    """
    if not 0 < depth_min_mm < depth_max_mm:
        raise ConfigError(f"expected 0 < depth_min < depth_max (mm), got {depth_min_mm}, {depth_max_mm}")
    return common_view(pair, depth_min_mm, depth_max_mm)[1]


# --------------------------------------------------------------------------- N views
@dataclass(frozen=True, eq=False)
class RectifiedViews:
    """N virtual cameras turned to one shared orientation (thesis §4.1.3, §4.2, Eq. 4.31–4.32, 4.35–4.36).

    Attributes
    ----------
    faces : tuple of int
    K : (3, 3) common intrinsics; R : (3, 3) shared world-to-rectified rotation (the real camera's
        orientation, r1 = X_w, r2 = Y_w).
    centres : (N, 3) optical centres, mm.
    size : (w, h); maps : tuple of (h, w, 2) float32; valid : tuple of (h, w) bool.
    reference : int
        Face of the reference view.
    pairs : tuple of RectifiedPair
        Per-pair rectifications of the pairs whose baseline is not horizontal in the shared frame.
    horizontal_pairs : tuple of (left_face, right_face)
        Pairs already row-aligned in the shared frame (baseline within ``tolerance_deg`` of X_w and
        perpendicular to the optical axis).
    """

    faces: tuple[int, ...]
    K: np.ndarray
    R: np.ndarray
    centres: np.ndarray
    size: tuple[int, int]
    maps: tuple[np.ndarray, ...]
    valid: tuple[np.ndarray, ...]
    reference: int
    method: str
    remap: str
    pairs: tuple[RectifiedPair, ...]
    horizontal_pairs: tuple[tuple[int, int], ...]
    views: tuple[VirtualView, ...] = field(repr=False)
    rig: Rig = field(repr=False)

    def index(self, face: int) -> int:
        if face not in self.faces:
            raise GeometryError(f"expected one of faces {self.faces}, got {face}")
        return self.faces.index(face)

    def P(self, face: int) -> np.ndarray:
        """3×4 K [R | −R C] of a view."""
        C = self.centres[self.index(face)]
        return self.K @ np.hstack([self.R, -(self.R @ C)[:, None]])

    def baseline_direction(self, face_a: int, face_b: int) -> float:
        """Angle (degrees, from +x toward +y) of the image displacement from view a to view b in the shared
        frame for points far away: the direction of the projected baseline C_a − C_b."""
        b = self.R @ (self.centres[self.index(face_a)] - self.centres[self.index(face_b)])
        return float(np.degrees(np.arctan2(b[1], b[0])))

    def rectify_images(self, capture: np.ndarray, *, fill: float = 0) -> list[np.ndarray]:
        """Warp a capture into every view's rectified image (``cv2.remap``, bilinear)."""
        check_image_size(capture, self.rig)
        return [_remap_image(capture, m, v, fill) for m, v in zip(self.maps, self.valid, strict=True)]

    def real_to_rectified(self, pixels: np.ndarray, face: int) -> np.ndarray:
        """(N, 2) real pixels of ``face`` → (N, 2) pixels of its rectified view."""
        i = self.index(face)
        m = _ViewMapper(rig=self.rig, view=self.views[i], R=self.R, C=self.centres[i], remap=self.remap,
                        reference_depth=REFERENCE_DEPTH_MM)
        return _dirs_to_rect_pixels(m.real_to_rect_dirs(pixels), self.K)

    def rectified_to_real(self, pixels: np.ndarray, face: int) -> np.ndarray:
        """(N, 2) rectified pixels of ``face`` → (N, 2) real pixels (bilinear lookup in the map)."""
        return _sample_map(self.maps[self.index(face)], pixels)

    def pair(self, face_a: int, face_b: int) -> RectifiedPair:
        """The per-pair rectification of two views (computed on demand when not in :attr:`pairs`)."""
        for p in self.pairs:
            if {p.left_face, p.right_face} == {face_a, face_b}:
                return p
        return rectify_pair(self.rig, self.views[self.index(face_a)], self.views[self.index(face_b)],
                            remap=self.remap)  # type: ignore[arg-type]

    def to_json(self) -> dict[str, Any]:
        views = [{"face": f, "name": v.name, "K": self.K, "R": self.R, "C": C, "P": self.P(f)}
                 for f, v, C in zip(self.faces, self.views, self.centres, strict=True)]
        return {"method": self.method, "remap": self.remap, "size": list(self.size), "reference": self.reference,
                "views": views, "horizontal_pairs": [list(p) for p in self.horizontal_pairs],
                "pairs": [p.to_json() for p in self.pairs]}


def rectify_views(
    rig: Rig,
    views: list[VirtualView],
    *,
    reference: int | None = None,
    remap: RemapKind = "model",
    margin_px: int = MARGIN_PX,
    tolerance_deg: float = 0.5,
    pairs: bool = True,
    size: tuple[int, int] | None = None,
) -> RectifiedViews:
    """Rectify N ≥ 2 virtual cameras to the shared orientation of thesis §4.1.3/§4.2.

    All views are turned to the real camera's orientation (r1 = X_w, r2 = Y_w, r3 = Z_w; thesis
    Eq. 4.31–4.32 for the tri-prism, 4.35–4.36 for the N-face prism) with one common K, so that pairs
    whose baseline is along X_w are row-aligned. Pairs whose baseline is not horizontal (beyond
    ``tolerance_deg``, or with a component along the optical axis that tilts the epipolar lines by more than
    that) are also rectified pair by pair (:func:`rectify_pair`) when ``pairs`` is True.

    Parameters
    ----------
    rig : Rig
    views : list of VirtualView (≥ 2, distinct faces)
    reference : int, optional
        Face of the reference view; default the leftmost (smallest centre x) view.
    remap, margin_px, size : see :func:`rectify_pair`.
    tolerance_deg : float
    pairs : bool

    Returns
    -------
    RectifiedViews
    """
    _check_remap(remap)
    _check_views(rig, views)
    if len(views) < 2 or len({v.face for v in views}) != len(views):
        raise GeometryError(f"expected at least two distinct faces, got {[v.face for v in views]}")
    regions = view_regions(rig, margin_px=margin_px)
    R = np.eye(3)
    f = rig.camera.focal_px
    mappers = [_ViewMapper(rig=rig, view=v, R=R, C=v.camera.C, remap=remap, reference_depth=REFERENCE_DEPTH_MM)
               for v in views]
    feet = [_footprint(m, regions[v.face], f) for m, v in zip(mappers, views, strict=True)]
    K, wh = _common_K(feet, f, size)
    maps = tuple(_build_map(m, K, wh) for m in mappers)
    valid = tuple(_roundtrip_valid(m, mp, K, _valid_from_map(mp, regions[v.face].mask))
                  for m, mp, v in zip(mappers, maps, views, strict=True))
    centres = np.stack([v.camera.C for v in views])
    faces = tuple(v.face for v in views)
    if reference is None:
        reference = faces[int(np.argmin(centres[:, 0]))]
    elif reference not in faces:
        raise GeometryError(f"expected the reference to be one of faces {faces}, got {reference}")
    horizontal: list[tuple[int, int]] = []
    per_pair: list[RectifiedPair] = []
    tol = np.radians(tolerance_deg)
    for i, j in combinations(range(len(views)), 2):
        b = centres[j] - centres[i]
        a, bb = (i, j) if b[0] >= 0 else (j, i)
        horiz_angle = abs(np.arctan2(b[1], abs(b[0]))) if abs(b[0]) > 0 else np.pi / 2
        tilt = abs(np.arctan2(b[2], np.hypot(b[0], b[1])))
        if horiz_angle <= tol and tilt <= tol:
            horizontal.append((faces[a], faces[bb]))
        elif pairs:
            try:
                per_pair.append(rectify_pair(rig, views[i], views[j], remap=remap, margin_px=margin_px,
                                             regions=regions))
            except GeometryError as exc:
                log.info("faces %d and %d not rectified as a pair: %s", faces[i], faces[j], exc)
    return RectifiedViews(faces=faces, K=K, R=R, centres=centres, size=wh, maps=maps, valid=valid,
                          reference=int(reference), method=views[0].method, remap=remap, pairs=tuple(per_pair),
                          horizontal_pairs=tuple(horizontal), views=tuple(views), rig=rig)
