"""Dense correspondences between two faces' views for self-calibration, where sparse features are few.

SIFT with Lowe's ratio test needs distinctive features; on weak or repetitive texture it finds a few dozen
matches where the depth matcher, which knows the geometry, matches most of the view. The geometry is used
here too: the capture is rectified with the current (possibly misaligned) rig, so the two views differ by a
disparity along the rows plus the few pixels of row error a misalignment leaves, and

1. a global shift is found by normalised cross-correlation of the two rectified views at a quarter of the
   resolution (the centre of the left view's common region against the whole right view);
2. OpenCV's DIS optical flow (Kroeger et al. 2016), started from that shift, gives a dense 2-D displacement
   field from the left view to the right one;
3. at corners of the left view (Shi–Tomasi, so both components of the displacement are defined) the field
   seeds pyramidal Lucas–Kanade tracking to sub-pixel precision, kept where tracking back lands within
   :data:`FB_PX` of the start, agrees with the flow within :data:`FLOW_AGREE_PX` and the two windows
   correlate (ZNCC ≥ :data:`MIN_ZNCC`: sensor noise on a textureless surface makes corners too, which do not);
4. the rectified pixels are mapped back to real pixels through the rectification's own remap tables (the
   inverse of the warp applied, exact whatever the rig's error), and the fundamental-matrix test of
   :func:`~prismstereo.calibration.from_scene.consistent_matches` drops what is left of the mismatches.

The correspondences are those of the capture itself: a wrong rig only changes the warp they are found in.
"""

from __future__ import annotations

import logging

import cv2
import numpy as np

from prismstereo.cameras import calibrate_rig
from prismstereo.config import Rig
from prismstereo.depth.apex_band import apex_band_views
from prismstereo.errors import ConfigError
from prismstereo.io.images import as_image
from prismstereo.rectify import rectify_pair

log = logging.getLogger(__name__)

__all__ = ["FB_PX", "FLOW_AGREE_PX", "dense_pair_matches"]

#: forward–backward tracking error (px) above which a tracked corner is dropped
FB_PX = 0.3
#: largest difference (px) between the tracked position and the optical flow's
FLOW_AGREE_PX = 2.0
#: corners sought in the left view
MAX_CORNERS = 4000
#: smallest corner distance, px
MIN_CORNER_DISTANCE = 8
#: Shi–Tomasi quality level (share of the strongest corner's response)
CORNER_QUALITY = 0.003
#: Lucas–Kanade window, px
LK_WINDOW = 21
#: downsampling of the global-shift search
SHIFT_SCALE = 4
#: half-size (px) of the windows whose zero-mean normalised cross-correlation must reach :data:`MIN_ZNCC`
ZNCC_RADIUS = 6
#: two views of one surface correlate; two draws of sensor noise (a textureless scene's "corners") do not
MIN_ZNCC = 0.8


def _to_u8(gray: np.ndarray) -> np.ndarray:
    g = np.asarray(gray, dtype=np.float32)
    hi = float(np.percentile(g, 99.9)) if g.size else 1.0
    scale = 255.0 / hi if hi > 0 else 1.0
    return np.clip(g * scale, 0, 255).astype(np.uint8)


def _global_shift(left: np.ndarray, right: np.ndarray, valid_left: np.ndarray) -> tuple[float, float] | None:
    """(dx, dy) px such that right(x + dx, y + dy) ≈ left(x, y) over most of the view (NCC at 1/4 scale),
    None when the left view's region is too small."""
    s = SHIFT_SCALE
    ys, xs = np.nonzero(valid_left)
    if ys.size == 0:
        return None
    y0, y1, x0, x1 = ys.min(), ys.max(), xs.min(), xs.max()
    # the central half of the left region: the right view holds it at every disparity the rig allows
    cy0, cy1 = y0 + (y1 - y0) // 4, y1 - (y1 - y0) // 4
    cx0, cx1 = x0 + (x1 - x0) // 4, x1 - (x1 - x0) // 4
    if (cy1 - cy0) < 8 * s or (cx1 - cx0) < 8 * s:
        return None
    tmpl = cv2.resize(left[cy0:cy1, cx0:cx1], None, fx=1 / s, fy=1 / s, interpolation=cv2.INTER_AREA)
    search = cv2.resize(right, None, fx=1 / s, fy=1 / s, interpolation=cv2.INTER_AREA)
    if tmpl.shape[0] > search.shape[0] or tmpl.shape[1] > search.shape[1]:
        return None
    score = cv2.matchTemplate(search.astype(np.float32), tmpl.astype(np.float32), cv2.TM_CCOEFF_NORMED)
    _, _, _, (bx, by) = cv2.minMaxLoc(score)
    return float(bx * s - cx0), float(by * s - cy0)


def _zncc(left: np.ndarray, right: np.ndarray, p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
    """(N,) zero-mean normalised cross-correlation of the (2·ZNCC_RADIUS + 1)² windows of ``left`` at
    ``p0`` and ``right`` at ``p1`` (sub-pixel, bilinear)."""
    size = (2 * ZNCC_RADIUS + 1, 2 * ZNCC_RADIUS + 1)
    lf, rf = left.astype(np.float32), right.astype(np.float32)
    out = np.zeros(p0.shape[0])
    for i, (q0, q1) in enumerate(zip(p0, p1, strict=True)):
        wa = cv2.getRectSubPix(lf, size, (float(q0[0]), float(q0[1]))).ravel()
        wb = cv2.getRectSubPix(rf, size, (float(q1[0]), float(q1[1]))).ravel()
        wa, wb = wa - wa.mean(), wb - wb.mean()
        den = float(np.sqrt(np.dot(wa, wa) * np.dot(wb, wb)))
        out[i] = float(np.dot(wa, wb)) / den if den > 0 else 0.0
    return out


def dense_pair_matches(image: np.ndarray, rig: Rig, *, faces: tuple[int, int], band_px: int = 12,
                       max_corners: int = MAX_CORNERS) -> tuple[np.ndarray, np.ndarray]:
    """Correspondences between the views of two faces of one capture, from optical flow on the pair
    rectified by ``rig`` (module notes).

    Parameters
    ----------
    image : (H, W) or (H, W, 3) capture of the rig's sensor size.
    rig : Rig
        The current rig (it only sets the warp the matches are found in).
    faces : (int, int)
        The two faces (a, b).
    band_px : int
        Band along the edges of each rectified view left out (a misaligned prism moves the edges).
    max_corners : int
        Corners sought in the view of the left face.

    Returns
    -------
    pixels_a, pixels_b : (N, 2) float64
        Real-image pixels of face ``a`` and their matches in face ``b`` (not yet tested against a
        fundamental matrix).

    Raises
    ------
    ConfigError
        ``faces`` not two distinct faces of the rig.
    """
    a, b = (int(f) for f in faces)
    if a == b or not (0 <= a < rig.prism.faces and 0 <= b < rig.prism.faces):
        raise ConfigError(f"faces: expected two distinct faces of the {rig.prism.faces}-face prism, got {faces}")
    by_face = {v.face: v for v in calibrate_rig(rig, method="fit")}
    pair = rectify_pair(rig, by_face[a], by_face[b])
    gray = _to_u8(as_image(image, channels=1))
    left, right = (np.ascontiguousarray(v) for v in pair.rectify_images(gray))
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (2 * band_px + 1, 2 * band_px + 1))
    vl = cv2.erode(pair.valid_left.astype(np.uint8), kernel) > 0
    vr = cv2.erode(pair.valid_right.astype(np.uint8), kernel) > 0
    band = apex_band_views(rig, pair)
    if band is not None:
        vl &= ~band[0]
        vr &= ~band[1]
    empty = (np.zeros((0, 2)), np.zeros((0, 2)))
    shift = _global_shift(left, right, vl)
    if shift is None:
        return empty
    h, w = left.shape
    init = np.empty((h, w, 2), dtype=np.float32)
    init[..., 0], init[..., 1] = shift
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)  # type: ignore[attr-defined]
    flow = dis.calc(left, right, init)  # a flow of the right size and type is its initial value
    p0 = cv2.goodFeaturesToTrack(left, maxCorners=int(max_corners), qualityLevel=CORNER_QUALITY,
                                 minDistance=MIN_CORNER_DISTANCE, mask=vl.astype(np.uint8) * 255, blockSize=7)
    if p0 is None:
        return empty
    p0 = p0.reshape(-1, 2).astype(np.float32)
    ix = np.clip(np.rint(p0).astype(np.int64), 0, [w - 1, h - 1])
    guess = p0 + flow[ix[:, 1], ix[:, 0]]
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 40, 0.01)
    win, flags = (LK_WINDOW, LK_WINDOW), cv2.OPTFLOW_USE_INITIAL_FLOW
    p1, st1, _ = cv2.calcOpticalFlowPyrLK(left, right, p0.reshape(-1, 1, 2), guess.reshape(-1, 1, 2).copy(), None,
                                          None, winSize=win, maxLevel=2, criteria=crit, flags=flags)
    p1 = np.asarray(p1).reshape(-1, 2)
    back, st2, _ = cv2.calcOpticalFlowPyrLK(right, left, p1.reshape(-1, 1, 2), p0.reshape(-1, 1, 2).copy(), None,
                                            None, winSize=win, maxLevel=2, criteria=crit, flags=flags)
    back = np.asarray(back).reshape(-1, 2)
    ok = (np.asarray(st1).ravel() == 1) & (np.asarray(st2).ravel() == 1)
    ok &= np.linalg.norm(back - p0, axis=1) < FB_PX
    ok &= np.linalg.norm(p1 - guess, axis=1) < FLOW_AGREE_PX
    j = np.rint(p1).astype(np.int64)
    inside = (j[:, 0] >= 0) & (j[:, 0] < w) & (j[:, 1] >= 0) & (j[:, 1] < h)
    ok &= inside
    ok[inside] &= vr[j[inside, 1], j[inside, 0]]
    ok[ok] &= _zncc(left, right, p0[ok], p1[ok]) >= MIN_ZNCC
    pl = pair.rectified_to_real(p0[ok].astype(np.float64), "left")
    pr = pair.rectified_to_real(p1[ok].astype(np.float64), "right")
    fin = np.all(np.isfinite(pl), axis=1) & np.all(np.isfinite(pr), axis=1)
    pl, pr = pl[fin], pr[fin]
    log.debug("dense matches faces %d-%d: shift (%.1f, %.1f) px, %d corners, %d tracked", a, b, shift[0], shift[1],
              p0.shape[0], pl.shape[0])
    # the rectification's left view is the face with the smaller coordinate along the baseline
    return (pl, pr) if pair.left_face == a else (pr, pl)
