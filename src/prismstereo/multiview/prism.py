"""Depth from ALL N views of a prism capture (tri-prism, N-face pyramid): plane sweep in the reference view.

Why a plane sweep, not per-pair rectification
---------------------------------------------
The virtual cameras of a tri-prism or an N-face pyramid sit on a circle around the optical axis, so the
baselines from the reference view to the others are NOT collinear: every pair has its own rectifying
rotation, its own rectified image of the reference, and disparities measured along different directions
with different baselines. Fusing per-pair costs would need every pair's volume warped back into one
reference frame, with one resampling per pair and a different disparity-to-depth law per pair (and, for
the exact geometry, a depth-dependent one, since the refraction is not a pinhole). Sweeping depth
hypotheses in the reference view instead puts every view's evidence on ONE axis — the depth along each
reference pixel's own exact ray — with no rectification at all:

1. each reference pixel (a real pixel of the reference face's sub-image) gets its exact refracted ray
   (:func:`~prismstereo.optics.trace_pixels`);
2. for every depth hypothesis ``Z_k`` (uniform in inverse depth, about one pixel of motion per step in the
   view that moves most) the ray's point at ``Z_k`` is projected into every other face with that face's
   fitted virtual camera (sub-pixel accurate, :func:`~prismstereo.cameras.calibrate_rig`) and the capture is
   sampled there (bilinear);
3. the per-view cost (truncated colour + gradient difference, box-aggregated per slice) is averaged over
   the views that see the point (inside their face's region), the winner is taken per pixel (thesis
   Eq. 5.15 over depth) and refined by a parabola;
4. the point is then **triangulated from all views that see it**: each view's own best depth near the
   joint winner gives its matched real pixel, whose EXACT refracted ray joins the reference ray in a
   least-squares intersection (the midpoint of several rays, thesis §7.2 generalised). The fitted camera is
   thus only used to search; the geometry of the result is exact refraction.

The same function with ``views=[j]`` is the single-pair baseline, so "all views vs the best pair" compares
like with like.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from prismstereo.cameras import calibrate_rig
from prismstereo.checks import check_fields
from prismstereo.config import DEFAULT_DEPTH_RANGE_MM, Rig
from prismstereo.errors import ConfigError, ImageError
from prismstereo.optics import trace_pixels
from prismstereo.progress import progress_bar
from prismstereo.rectify.regions import view_regions

log = logging.getLogger(__name__)

__all__ = ["AllViewsDepth", "SweepParams", "depth_all_views"]

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]


@dataclass(frozen=True, kw_only=True)
class SweepParams:
    """Parameters of the plane sweep.

    Attributes
    ----------
    n_depths : int or None
        Number of depth hypotheses; None = about one pixel of motion per step in the view that moves most.
    radius : int
        Box aggregation radius (pixels) of the per-view cost.
    tau_color, tau_grad : float
        Truncations of the mean absolute colour difference and of the gradient difference (0..255 scale).
    omega : float
        Weight of the gradient term (thesis Eq. 5.6's ω).
    uniqueness : float
        A pixel is kept when its second-best cost (outside ±2 hypotheses) exceeds the best by this fraction.
    min_views : int
        Fewest views besides the reference that must see the point.
    margin_px : int
        Margin dropped along the prism edges (see :func:`~prismstereo.rectify.regions.view_regions`).
    """

    n_depths: int | None = None
    radius: int = 4
    tau_color: float = 30.0
    tau_grad: float = 10.0
    omega: float = 0.5
    uniqueness: float = 0.05
    min_views: int = 1
    margin_px: int = 4

    def __post_init__(self) -> None:
        check_fields(self, {"n_depths": (2, 100_000), "radius": (0, 50), "tau_color": (None, 255.0),
                            "tau_grad": (None, 255.0), "omega": (0.0, 1.0), "uniqueness": (0.0, 1.0),
                            "min_views": (1, 64), "margin_px": (0, 10_000)}, positive=("tau_color", "tau_grad"))


@dataclass(frozen=True)
class AllViewsDepth:
    """Result of :func:`depth_all_views`, everything in the REAL capture's pixel grid.

    Attributes
    ----------
    reference : int
        Face whose sub-image is the reference view.
    views : tuple[int, ...]
        Other faces used.
    depth : (H, W) float32
        Z (mm, world = real camera frame) of the triangulated point of every valid reference pixel; NaN
        elsewhere (outside the reference face's region, or rejected).
    depth_sweep : (H, W) float32
        The sweep's winner depth along the reference ray, before the multi-ray triangulation.
    inverse_depth_index : (H, W) float32
        Sub-hypothesis index of the winner (the sweep's "disparity": ``1/Z`` is linear in it).
    valid : (H, W) bool
    counts : (H, W) uint8
        Number of views (the reference included) that see the point and were used to triangulate it.
    points : (N, 3) float64
        Triangulated points of the valid pixels, mm, world frame (row-major pixel order).
    colors : (N, 3) uint8
        Their reference colours.
    pixels : (N, 2) int
        Their real-image pixels (u, v).
    depths : (K,) float64
        The depth hypotheses, mm.
    timings : dict[str, float]
    region : (H, W) bool or None
        The reference face's region (the pixels that could get a depth).
    """

    reference: int
    views: tuple[int, ...]
    depth: F32
    depth_sweep: F32
    inverse_depth_index: F32
    valid: npt.NDArray[np.bool_]
    counts: npt.NDArray[np.uint8]
    points: F64
    colors: npt.NDArray[np.uint8]
    pixels: npt.NDArray[np.int64]
    depths: F64
    timings: dict[str, float] = field(default_factory=dict)
    region: npt.NDArray[np.bool_] | None = None


def _gray_grad(img: F32) -> tuple[F32, F32, F32]:
    g = (img[..., 0] * 0.299 + img[..., 1] * 0.587 + img[..., 2] * 0.114).astype(np.float32)
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3) / np.float32(4.0)
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3) / np.float32(4.0)
    return g, gx, gy


def _pixel_cost(ref: F32, rgx: F32, rgy: F32, warped: F32, wgx: F32, wgy: F32, p: SweepParams) -> F32:
    ad = np.minimum(np.abs(ref - warped).mean(axis=2), np.float32(p.tau_color))
    gd = np.minimum(np.abs(rgx - wgx) + np.abs(rgy - wgy), np.float32(p.tau_grad))
    return ((1.0 - p.omega) * ad + p.omega * gd).astype(np.float32)


def _box(a: F32, r: int) -> F32:
    if r <= 0:
        return a
    return np.asarray(cv2.blur(a, (2 * r + 1, 2 * r + 1), borderType=cv2.BORDER_REFLECT), dtype=np.float32)


def _sample(img: F32, uv: F32) -> F32:
    """Bilinear sample of ``img`` (H, W, C) at (h, w, 2) real pixels; outside -> 0."""
    return np.asarray(cv2.remap(img, uv[..., 0], uv[..., 1], interpolation=cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_CONSTANT, borderValue=0), dtype=np.float32)


def _inside(mask: npt.NDArray[np.bool_], uv: F32) -> npt.NDArray[np.bool_]:
    m = cv2.remap(mask.astype(np.uint8), uv[..., 0], uv[..., 1], interpolation=cv2.INTER_NEAREST,
                  borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return (m > 0) & np.isfinite(uv[..., 0])


def _multi_ray_point(origins: F64, dirs: F64, use: npt.NDArray[np.bool_]) -> F64:
    """Least-squares intersection of up to V rays per point: ``argmin_X Σ ||(I - d dᵀ)(X - o)||²``.

    origins, dirs: (V, N, 3); use: (V, N). Returns (N, 3), NaN where fewer than two rays are used.
    """
    d = dirs / np.linalg.norm(dirs, axis=-1, keepdims=True)
    eye = np.eye(3)
    proj = eye[None, None] - d[..., :, None] * d[..., None, :]  # V N 3 3
    w = use.astype(np.float64)[..., None, None]
    proj = np.where(np.isfinite(proj), proj, 0.0) * w
    o = np.where(np.isfinite(origins), origins, 0.0)
    a = proj.sum(axis=0)
    b = np.einsum("vnij,vnj->ni", proj, o)
    ok = use.sum(axis=0) >= 2
    out = np.full(b.shape, np.nan)
    if ok.any():
        out[ok] = np.linalg.solve(a[ok], b[ok][..., None])[..., 0]
    return out


def depth_all_views(rig: Rig, capture: Any, *, method: str = "sweep",
                    depth_range: tuple[float, float] = DEFAULT_DEPTH_RANGE_MM, reference: int | None = None,
                    views: Sequence[int] | None = None, params: SweepParams | None = None,
                    calibration: str = "fit") -> AllViewsDepth:
    """Depth of the reference view from every other view of a prism capture (thesis §7.1 and §7.2).

    Parameters
    ----------
    rig : Rig
        The rig that took ``capture`` (any number of faces ≥ 2).
    capture : (H, W, 3) or (H, W) image, or an object with an ``image`` attribute (a simulated Capture)
        The real camera's image, the rig's sensor size.
    method : {"sweep"}, keyword-only
        Plane sweep along the reference rays (module docstring; the only method).
    depth_range : (float, float), keyword-only
        Scene depths to search, mm (``0 < min < max``), world Z.
    reference : int, optional
        Reference face; default the face seen by the most pixels.
    views : sequence of int, optional
        The other faces to use; default all of them. ``views=[j]`` is the single pair (reference, j).
    params : SweepParams, optional
    calibration : {"fit", "thesis"}
        Virtual camera model used to project the hypotheses (the final points use exact rays).

    Returns
    -------
    AllViewsDepth

    Raises
    ------
    ConfigError, ImageError
    """
    if method != "sweep":
        raise ConfigError(f"expected method 'sweep' for all-view depth, got {method!r}")
    p = params or SweepParams()
    zmin, zmax = (float(v) for v in depth_range)
    if not (0.0 < zmin < zmax) or not math.isfinite(zmax):
        raise ConfigError(f"expected a depth range 0 < min < max (mm), got {depth_range}")
    img = np.asarray(getattr(capture, "image", capture))
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    cam_w, cam_h = rig.camera.width, rig.camera.height
    if img.ndim != 3 or img.shape[:2] != (cam_h, cam_w):
        raise ImageError(f"expected a capture of the rig's size {cam_w}×{cam_h}, got shape {img.shape}")
    nf = rig.prism.faces
    tm: dict[str, float] = {}
    t = time.perf_counter()
    regions = view_regions(rig, margin_px=p.margin_px)
    ref = int(np.argmax([r.area for r in regions])) if reference is None else int(reference)
    if not 0 <= ref < nf:
        raise ConfigError(f"expected a reference face in [0, {nf - 1}], got {reference}")
    others = tuple(int(v) for v in (views if views is not None else [k for k in range(nf) if k != ref]))
    if not others or any((not 0 <= v < nf) or v == ref for v in others) or len(set(others)) != len(others):
        raise ConfigError(f"expected other faces among {[k for k in range(nf) if k != ref]}, got {list(others)}")
    cams = {v.face: v for v in calibrate_rig(rig, method=calibration)}
    x0, y0, x1, y1 = regions[ref].bbox
    rmask = regions[ref].mask[y0:y1, x0:x1]
    uu, vv = np.meshgrid(np.arange(x0, x1, dtype=np.float64), np.arange(y0, y1, dtype=np.float64))
    rays = trace_pixels(rig, np.stack([uu, vv], axis=-1))
    rmask = rmask & rays.valid
    o_ref, d_ref = rays.origins, rays.directions
    imgf = img.astype(np.float32)
    ref_img = np.ascontiguousarray(imgf[y0:y1, x0:x1])
    _, rgx, rgy = _gray_grad(ref_img)
    full_g = _gray_grad(imgf)
    full_feat = np.ascontiguousarray(np.dstack([imgf, full_g[1], full_g[2]]))
    tm["setup"] = time.perf_counter() - t

    # depth hypotheses: uniform in 1/Z, ~1 px of motion per step in the view that moves most
    t = time.perf_counter()
    if p.n_depths is None:
        cy, cx = (np.array(np.nonzero(rmask)).mean(axis=1)).astype(int)
        od, dd = o_ref[cy, cx], d_ref[cy, cx]
        motion = 0.0
        for v in others:
            a = cams[v].project(od + dd * ((zmin - od[2]) / dd[2]))
            b = cams[v].project(od + dd * ((zmax - od[2]) / dd[2]))
            motion = max(motion, float(np.linalg.norm(a - b)))
        nk = int(np.clip(math.ceil(motion) + 1, 8, 1024))
    else:
        nk = int(p.n_depths)
        if nk < 3:
            raise ConfigError(f"expected n_depths >= 3, got {nk}")
    inv = np.linspace(1.0 / zmin, 1.0 / zmax, nk)
    depths = 1.0 / inv
    h, w = rmask.shape
    vol = np.empty((h, w, nk), np.float32)
    big = np.float32(1e6)

    def point_at(z: npt.NDArray[np.float64] | float) -> F64:
        s = (np.asarray(z) - o_ref[..., 2]) / d_ref[..., 2]
        return np.asarray(o_ref + s[..., None] * d_ref)

    def view_cost(v: int, pts: F64) -> tuple[F32, npt.NDArray[np.bool_], F32]:
        uv = cams[v].project(pts).astype(np.float32)
        seen = _inside(regions[v].mask, uv) & rmask
        f = _sample(full_feat, uv)
        c = _pixel_cost(ref_img, rgx, rgy, np.ascontiguousarray(f[..., :3]), f[..., 3], f[..., 4], p)
        c = np.where(seen, c, np.float32(0.0))
        agg = _box(c, p.radius)
        cnt = _box(seen.astype(np.float32), p.radius)
        out = np.where(cnt > 1e-3, agg / np.maximum(cnt, np.float32(1e-3)), np.float32(np.nan))
        return out.astype(np.float32), seen, uv

    # loop over depth hypotheses (planes), not pixels; a bar on a terminal only
    for k in progress_bar(range(nk), desc="all-view plane sweep", unit="plane", leave=False):
        pts = point_at(depths[k])
        acc = np.zeros((h, w), np.float32)
        n = np.zeros((h, w), np.float32)
        for v in others:
            c, seen, _ = view_cost(v, pts)
            ok = seen & np.isfinite(c)
            acc += np.where(ok, c, np.float32(0.0))
            n += ok
        vol[:, :, k] = np.where(n >= p.min_views, acc / np.maximum(n, 1.0), big)
    tm["sweep"] = time.perf_counter() - t

    t = time.perf_counter()
    kbest = np.argmin(vol, axis=2)
    c1 = np.take_along_axis(vol, kbest[..., None], 2)[..., 0]
    kk = np.arange(nk)[None, None, :]
    far = np.abs(kk - kbest[..., None]) > 2
    c2 = np.where(far, vol, np.inf).min(axis=2)
    interior = (kbest > 0) & (kbest < nk - 1)
    km = np.clip(kbest - 1, 0, nk - 1)
    kp = np.clip(kbest + 1, 0, nk - 1)
    cm = np.take_along_axis(vol, km[..., None], 2)[..., 0]
    cp = np.take_along_axis(vol, kp[..., None], 2)[..., 0]
    den = cm - 2 * c1 + cp
    off = np.where(interior & (den > 1e-6), np.clip((cm - cp) / (2 * np.maximum(den, 1e-6)), -0.5, 0.5), 0.0)
    kf = kbest + off
    valid = rmask & interior & (c1 < big) & (c2 > c1 * (1.0 + p.uniqueness))
    del vol
    inv_k = np.interp(kf, np.arange(nk), inv)
    z_sweep = np.where(valid, 1.0 / inv_k, np.nan)
    tm["select"] = time.perf_counter() - t

    # triangulate from all views that see the point: each view's own best depth near the joint winner
    t = time.perf_counter()
    offs = np.arange(-2, 3)
    per_view_uv = []
    per_view_ok = []
    for v in others:
        cs = []
        for o in offs:
            kq = np.clip(kf + o * 0.5, 0, nk - 1)
            zq = 1.0 / np.interp(kq, np.arange(nk), inv)
            c, _seen, _ = view_cost(v, point_at(zq))
            cs.append(np.where(np.isfinite(c), c, np.inf))
        cst = np.stack(cs, axis=-1)
        j = np.argmin(cst, axis=-1)
        jm, jp = np.clip(j - 1, 0, 4), np.clip(j + 1, 0, 4)
        a0 = np.take_along_axis(cst, j[..., None], 2)[..., 0]
        am = np.take_along_axis(cst, jm[..., None], 2)[..., 0]
        ap = np.take_along_axis(cst, jp[..., None], 2)[..., 0]
        inner = (j > 0) & (j < 4) & np.isfinite(am) & np.isfinite(ap)
        with np.errstate(invalid="ignore", divide="ignore"):
            dn = am - 2 * a0 + ap
            o2 = np.where(inner & (dn > 1e-6), np.clip((am - ap) / (2 * np.maximum(dn, 1e-6)), -0.5, 0.5),
                          0.0)
        kv = np.clip(kf + (j - 2 + o2) * 0.5, 0, nk - 1)
        zv = 1.0 / np.interp(kv, np.arange(nk), inv)
        uv = cams[v].project(point_at(zv))
        ok = valid & inner & _inside(regions[v].mask, uv.astype(np.float32))
        per_view_uv.append(uv)
        per_view_ok.append(ok)
    sel = np.flatnonzero(valid.ravel())
    origins = [o_ref.reshape(-1, 3)[sel]]
    dirs = [d_ref.reshape(-1, 3)[sel]]
    use = [np.ones(sel.size, bool)]
    for v, uv, ok in zip(others, per_view_uv, per_view_ok, strict=True):
        okf = ok.ravel()[sel]
        bundle = trace_pixels(rig, uv.reshape(-1, 2)[sel])
        okf &= bundle.valid & (bundle.face == v)
        origins.append(bundle.origins)
        dirs.append(bundle.directions)
        use.append(okf)
    use_a = np.stack(use)
    pts = _multi_ray_point(np.stack(origins), np.stack(dirs), use_a)
    # points seen by the reference only keep the sweep depth on the reference ray
    lone = ~np.isfinite(pts[:, 0])
    if lone.any():
        pts[lone] = point_at(z_sweep).reshape(-1, 3)[sel][lone]
    good = np.isfinite(pts).all(axis=1) & (pts[:, 2] > 0)
    sel, pts, use_a = sel[good], pts[good], use_a[:, good]
    depth = np.full(h * w, np.nan, np.float32)
    depth[sel] = pts[:, 2]
    cnt = np.zeros(h * w, np.uint8)
    cnt[sel] = use_a.sum(axis=0)
    tm["triangulate"] = time.perf_counter() - t

    def full(a: npt.NDArray[Any], fill: Any) -> npt.NDArray[Any]:
        out = np.full((cam_h, cam_w), fill, dtype=a.dtype)
        out[y0:y1, x0:x1] = a.reshape(h, w)
        return out

    valid_full = np.zeros((cam_h, cam_w), bool)
    vv_crop = np.zeros(h * w, bool)
    vv_crop[sel] = True
    valid_full[y0:y1, x0:x1] = vv_crop.reshape(h, w)
    ys, xs = np.divmod(sel, w)
    pix = np.stack([xs + x0, ys + y0], axis=1).astype(np.int64)
    colors = np.clip(np.rint(ref_img.reshape(-1, 3)[sel]), 0, 255).astype(np.uint8)
    log.info("all-view depth: reference face %d, views %s, %d hypotheses, %d points", ref, list(others), nk,
             sel.size)
    return AllViewsDepth(reference=ref, views=others, depth=full(depth, np.float32(np.nan)),
                         depth_sweep=full(z_sweep.astype(np.float32), np.float32(np.nan)),
                         inverse_depth_index=full(np.where(valid, kf, np.nan).astype(np.float32),
                                                  np.float32(np.nan)),
                         valid=valid_full, counts=full(cnt, np.uint8(0)), points=pts, colors=colors, pixels=pix,
                         depths=depths, timings=tm, region=regions[ref].mask.copy())
