"""Epipolar-line figures before and after rectification (thesis Figs. 3.11–3.14, 4.13, 4.15–4.16).

A few points are picked on one view; for each, its epipolar curve in the other view(s) is drawn: the
exact ray of the point's real pixel is sampled over a depth range and every sample is projected exactly
through the other face (:func:`~prismstereo.optics.project_exact`), so the curve is the true epipolar
curve of the prism (a pinhole model would draw it straight). After rectification the same samples are
mapped into the rectified images, where they must run along one image row.
"""

from __future__ import annotations

import cv2
import numpy as np

from prismstereo.config import Rig
from prismstereo.optics import project_exact, trace_pixels
from prismstereo.rectify.rectification import RectifiedPair, RectifiedViews
from prismstereo.rectify.regions import ViewRegion, view_regions
from prismstereo.rectify.verify import true_correspondences

__all__ = ["epipolar_after", "epipolar_after_views", "epipolar_before", "epipolar_curves", "pick_points"]

_COLOURS = [(255, 64, 64), (64, 220, 64), (64, 160, 255), (255, 200, 0), (230, 64, 230), (0, 230, 230)]


def with_title(image: np.ndarray, title: str) -> np.ndarray:
    """``image`` (RGB uint8) with a white band on top carrying ``title`` (black text)."""
    img = _rgb_u8(image)
    scale = float(np.clip(img.shape[1] / 1600.0, 0.4, 0.8))
    (_, th), base = cv2.getTextSize(title, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
    band = np.full((th + base + 10, img.shape[1], 3), 255, np.uint8)
    cv2.putText(band, title, (6, th + 5), cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), 1, cv2.LINE_AA)
    return np.concatenate([band, img], axis=0)


def _rgb_u8(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image)
    if img.dtype != np.uint8:
        img = np.clip(np.nan_to_num(img.astype(np.float64)), 0, 255).astype(np.uint8)
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    return np.ascontiguousarray(img[:, :, :3].copy())


def pick_points(rig: Rig, face_a: int, face_b: int, *, n: int = 3, depth_mm: float = 1500.0,
                regions: list[ViewRegion] | None = None, seed: int = 3) -> np.ndarray:
    """(n, 2) real pixels of ``face_a`` spread over rows whose points at ``depth_mm`` are also seen
    through ``face_b`` (falls back to the common view's nearest depths when none at ``depth_mm``)."""
    try:
        corr = true_correspondences(rig, face_a, face_b, n=600, depth_range=(depth_mm, depth_mm * 1.001),
                                    regions=regions, seed=seed)
    except Exception:  # noqa: BLE001 - no common view at that depth: take any depth
        corr = true_correspondences(rig, face_a, face_b, n=2000,
                                    depth_range=(rig.prism.back_distance + 30.0, 5000.0), regions=regions,
                                    seed=seed)
    px = corr.pixels_a
    order = np.argsort(px[:, 1])
    picks = order[(np.linspace(0.15, 0.85, n) * (order.size - 1)).astype(int)] if order.size >= n else order
    return px[picks]


def epipolar_curves(rig: Rig, pixels: np.ndarray, face_b: int, *, depth_range: tuple[float, float] = (300.0, 8000.0),
                    samples: int = 200) -> list[np.ndarray]:
    """Exact epipolar curves in face b of real pixels (seen through their own face).

    Returns
    -------
    list of (M_i, 2) real pixels of face b, one per input pixel (samples whose projection fails are
    dropped).
    """
    b = trace_pixels(rig, np.asarray(pixels, dtype=np.float64))
    lo = max(depth_range[0], rig.prism.back_distance + 5.0)
    z = np.geomspace(lo, depth_range[1], samples)
    out = []
    for i in range(b.origins.shape[0]):
        X = b.origins[i] + ((z - b.origins[i, 2]) / b.directions[i, 2])[:, None] * b.directions[i]
        px, ok = project_exact(rig, X, face=face_b)
        px = px[ok]
        inside = (px[:, 0] >= 0) & (px[:, 0] <= rig.camera.width - 1) & (px[:, 1] >= 0) & (
            px[:, 1] <= rig.camera.height - 1)
        out.append(px[inside])
    return out


def _draw(img: np.ndarray, points: np.ndarray, curves: list[np.ndarray], *, offset_b: tuple[float, float] = (0, 0)
          ) -> None:
    for i, (p, c) in enumerate(zip(points, curves, strict=True)):
        col = _COLOURS[i % len(_COLOURS)]
        if np.all(np.isfinite(p)):
            cv2.circle(img, (int(round(p[0])), int(round(p[1]))), 7, col, 2, cv2.LINE_AA)
        c = c[np.all(np.isfinite(c), axis=1)] + np.asarray(offset_b)
        if c.shape[0] >= 2:
            cv2.polylines(img, [np.rint(c).astype(np.int32).reshape(-1, 1, 2)], False, col, 2, cv2.LINE_AA)


def epipolar_before(capture: np.ndarray, rig: Rig, points: np.ndarray, faces_b: list[int], *,
                    regions: list[ViewRegion] | None = None) -> np.ndarray:
    """The real capture with ``points`` (real pixels of one face) and their exact epipolar curves in the
    other faces ``faces_b`` (thesis Figs. 3.11(a), 4.13(a–d)). Returns an RGB uint8 image."""
    img = _rgb_u8(capture)
    regions = view_regions(rig) if regions is None else regions
    for r in regions:
        cnts, _ = cv2.findContours(r.mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        cv2.drawContours(img, cnts, -1, (128, 128, 128), 1)
    for fb in faces_b:
        _draw(img, points, epipolar_curves(rig, points, fb))
    return img


def epipolar_after(left: np.ndarray, right: np.ndarray, pair: RectifiedPair, points_left_real: np.ndarray,
                   *, gap: int = 8) -> np.ndarray:
    """Rectified left | right side by side, the points on the left and their epipolar curves mapped into
    the right image (horizontal when the rectification is right; thesis Figs. 3.11(b)–3.14(b))."""
    L, Rr = _rgb_u8(left), _rgb_u8(right)
    h, w = L.shape[:2]
    canvas = np.zeros((h, 2 * w + gap, 3), dtype=np.uint8)
    canvas[:, :w], canvas[:, w + gap:] = L, Rr
    pts = pair.real_to_rectified(points_left_real, "left")
    curves = [pair.real_to_rectified(c, "right") if c.size else c
              for c in epipolar_curves(pair.rig, points_left_real, pair.right_face)]
    for i, p in enumerate(pts):
        if np.isfinite(p[1]):
            y = int(round(p[1]))
            cv2.line(canvas, (0, y), (canvas.shape[1] - 1, y), (90, 90, 90), 1)
            _ = i
    _draw(canvas, pts, curves, offset_b=(w + gap, 0))
    return canvas


def epipolar_after_views(images: list[np.ndarray], rv: RectifiedViews, points_ref_real: np.ndarray, *,
                         gap: int = 8) -> np.ndarray:
    """All rectified views side by side (shared orientation), the points on the reference view and their
    epipolar curves mapped into every other view (thesis Figs. 4.13(e–g), 4.16)."""
    tiles = [_rgb_u8(im) for im in images]
    h, w = tiles[0].shape[:2]
    canvas = np.zeros((h, len(tiles) * (w + gap) - gap, 3), dtype=np.uint8)
    for k, t in enumerate(tiles):
        canvas[:, k * (w + gap): k * (w + gap) + w] = t
    ref = rv.reference
    kr = rv.index(ref)
    pts = rv.real_to_rectified(points_ref_real, ref) + np.array([kr * (w + gap), 0.0])
    for i, p in enumerate(pts):
        if np.all(np.isfinite(p)):
            cv2.circle(canvas, (int(round(p[0])), int(round(p[1]))), 7, _COLOURS[i % len(_COLOURS)], 2,
                       cv2.LINE_AA)
    for k, face in enumerate(rv.faces):
        if face == ref:
            continue
        curves = [rv.real_to_rectified(c, face) if c.size else c
                  for c in epipolar_curves(rv.rig, points_ref_real, face)]
        _draw(canvas, np.full_like(pts, np.nan), curves, offset_b=(k * (w + gap), 0))
    return canvas
