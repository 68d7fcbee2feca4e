"""Mean-shift colour segmentation of the reference image (thesis §5.1, Comaniciu & Meer 2002).

The joint spatial-range mean shift filter (spatial radius ``hs``, range radius ``hr``, thesis Eqs. 5.1-5.4)
is OpenCV's ``pyrMeanShiftFiltering`` run in CIELab (a perceptually uniform space, as §5.1 asks).
The converged modes are then delineated into clusters: 4-connected pixels whose modes are closer than
``hr`` in the range domain are grouped (union-find, numba), and regions smaller than ``M`` pixels are
merged into their most similar neighbour (the optional last step of the §5.1 procedure).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt
from numba import njit, prange

from prismstereo.checks import check_fields
from prismstereo.errors import ImageError
from prismstereo.io.images import as_image

log = logging.getLogger(__name__)

__all__ = ["SegmentationParams", "mean_shift_segment", "relabel_consecutive", "segment_adjacency",
           "split_segments"]


@dataclass(frozen=True)
class SegmentationParams:
    """Parameters of the mean-shift segmentation (thesis §5.1).

    Attributes
    ----------
    hs : int
        Spatial bandwidth ``h_s`` of the joint-domain kernel, pixels.
    hr : float
        Range bandwidth ``h_r`` in 8-bit CIELab units (OpenCV scaling: L in 0..255).
    min_region : int
        Minimum region size ``M``, pixels; smaller regions are merged into their closest neighbour.
    max_level : int
        Pyramid levels of OpenCV's mean shift filter (0 = the plain, full-resolution filter).
    max_region : int
        Optional cap on the size of a region (0 = none): larger regions are split along a grid of this
        area. Segment-based stereo assumes one plane per segment, which is safer for compact segments.
    depth_tau : float
        With an initial disparity map given, neighbours differing by this much (px) are kept apart
        (0 = colour only, as in the thesis).
    clahe : float
        Clip limit of a contrast-limited histogram equalisation of L* before the mean shift (0 = none), so
        that dark, low-contrast areas are segmented as finely as bright ones.
    """

    hs: int = 5
    hr: float = 4.0
    min_region: int = 20
    max_level: int = 0
    max_region: int = 0
    depth_tau: float = 0.0
    clahe: float = 0.0

    def __post_init__(self) -> None:
        check_fields(self, {"hs": (1, 100), "hr": (None, 255.0), "min_region": (1, None), "max_level": (0, 8),
                            "max_region": (0, None), "depth_tau": (0.0, None), "clahe": (0.0, 100.0)},
                     positive=("hr",))


def _to_lab8(image: npt.NDArray[np.generic]) -> npt.NDArray[np.uint8]:
    img = as_image(image, channels=3)  # the one coercion rule (docs/conventions.md)
    return np.ascontiguousarray(cv2.cvtColor(img, cv2.COLOR_RGB2Lab))


@njit(cache=True)
def _find(parent: npt.NDArray[np.int32], i: int) -> int:
    root = i
    while parent[root] != root:
        root = parent[root]
    while parent[i] != root:
        nxt = parent[i]
        parent[i] = root
        i = nxt
    return root


@njit(cache=True)
def _union(parent: npt.NDArray[np.int32], a: int, b: int) -> None:
    ra = _find(parent, a)
    rb = _find(parent, b)
    if ra != rb:
        if ra < rb:
            parent[rb] = ra
        else:
            parent[ra] = rb


@njit(cache=True, parallel=True, nogil=True)
def _mean_shift_filter(lab: npt.NDArray[np.uint8], sp: float, sr: float) -> npt.NDArray[np.uint8]:
    """OpenCV's ``pyrMeanShiftFiltering`` at ``maxLevel=0`` and its default stop (5 iterations, ε = 1), to the
    bit, on parallel rows (OpenCV's runs on one core): each pixel's joint spatial-range mean shift (Comaniciu
    and Meer 2002) from its own position and colour, over the (2 sp + 1)² window of the source image, the
    colours within ``sr`` (squared distance <= round(sr²)); returns (H, W, 3) uint8, the colours reached."""
    h, w, _ = lab.shape
    out = np.empty_like(lab)
    spf = np.float32(max(np.float32(sp), np.float32(1.0)))
    isr2 = int(np.rint(sr * sr))
    for i in prange(h):
        for j in range(w):
            x0 = j
            y0 = i
            c0 = np.int64(lab[i, j, 0])
            c1 = np.int64(lab[i, j, 1])
            c2 = np.int64(lab[i, j, 2])
            for _ in range(5):
                # the window bounds round in float32, as OpenCV's
                minx = max(int(np.rint(np.float32(x0) - spf)), 0)
                miny = max(int(np.rint(np.float32(y0) - spf)), 0)
                maxx = min(int(np.rint(np.float32(x0) + spf)), w - 1)
                maxy = min(int(np.rint(np.float32(y0) + spf)), h - 1)
                count = 0
                s0 = np.int64(0)
                s1 = np.int64(0)
                s2 = np.int64(0)
                sx = 0
                sy = 0
                for y in range(miny, maxy + 1):
                    rc = 0
                    for x in range(minx, maxx + 1):
                        t0 = np.int64(lab[y, x, 0])
                        t1 = np.int64(lab[y, x, 1])
                        t2 = np.int64(lab[y, x, 2])
                        if (t0 - c0) * (t0 - c0) + (t1 - c1) * (t1 - c1) + (t2 - c2) * (t2 - c2) <= isr2:
                            s0 += t0
                            s1 += t1
                            s2 += t2
                            sx += x
                            rc += 1
                    count += rc
                    sy += y * rc
                if count == 0:
                    break
                ic = 1.0 / count
                x1 = int(np.rint(sx * ic))
                y1 = int(np.rint(sy * ic))
                n0 = np.int64(np.rint(s0 * ic))
                n1 = np.int64(np.rint(s1 * ic))
                n2 = np.int64(np.rint(s2 * ic))
                stop = (x0 == x1 and y0 == y1) or (abs(x1 - x0) + abs(y1 - y0) + (n0 - c0) * (n0 - c0)
                                                    + (n1 - c1) * (n1 - c1) + (n2 - c2) * (n2 - c2) <= 1.0)
                x0 = x1
                y0 = y1
                c0 = n0
                c1 = n1
                c2 = n2
                if stop:
                    break
            out[i, j, 0] = c0
            out[i, j, 1] = c1
            out[i, j, 2] = c2
    return out


@njit(cache=True, nogil=True)
def _label_modes(filt: npt.NDArray[np.float32], hr2: float) -> npt.NDArray[np.int32]:
    """Union 4-neighbours whose filtered colours (modes) are closer than hr; returns root per pixel."""
    h, w, _ = filt.shape
    return _label_modes_depth(filt, hr2, np.zeros((h, w), np.float32), np.inf)


@njit(cache=True, nogil=True)
def _label_modes_depth(filt: npt.NDArray[np.float32], hr2: float, disp: npt.NDArray[np.float32],
                       tau: float) -> npt.NDArray[np.int32]:
    """As :func:`_label_modes`, but neighbours whose disparities differ by ``tau`` or more stay apart."""
    h, w, c = filt.shape
    parent = np.arange(h * w).astype(np.int32)
    for y in range(h):
        for x in range(w):
            i = y * w + x
            if x + 1 < w and abs(disp[y, x] - disp[y, x + 1]) < tau:
                d = 0.0
                for k in range(c):
                    t = filt[y, x, k] - filt[y, x + 1, k]
                    d += t * t
                if d < hr2:
                    _union(parent, i, i + 1)
            if y + 1 < h and abs(disp[y, x] - disp[y + 1, x]) < tau:
                d = 0.0
                for k in range(c):
                    t = filt[y, x, k] - filt[y + 1, x, k]
                    d += t * t
                if d < hr2:
                    _union(parent, i, i + w)
    out = np.empty(h * w, dtype=np.int32)
    for i in range(h * w):
        out[i] = _find(parent, i)
    return out


@njit(cache=True, nogil=True)
def _compact(roots: npt.NDArray[np.int32]) -> tuple[npt.NDArray[np.int32], int]:
    n = roots.shape[0]
    remap = np.full(n, -1, dtype=np.int32)
    out = np.empty(n, dtype=np.int32)
    k = 0
    for i in range(n):
        r = roots[i]
        if remap[r] < 0:
            remap[r] = k
            k += 1
        out[i] = remap[r]
    return out, k


@njit(cache=True, nogil=True)
def _merge_small(labels: npt.NDArray[np.int32], nlab: int, lab: npt.NDArray[np.float32], h: int, w: int,
                 min_region: int) -> tuple[npt.NDArray[np.int32], int]:
    """Merge regions smaller than ``min_region`` into their neighbour of closest mean colour."""
    c = lab.shape[1]
    for _it in range(50):
        size = np.zeros(nlab, dtype=np.int64)
        mean = np.zeros((nlab, c), dtype=np.float64)
        for i in range(h * w):
            size[labels[i]] += 1
            for k in range(c):
                mean[labels[i], k] += lab[i, k]
        nsmall = 0
        for r in range(nlab):
            if size[r] > 0:
                for k in range(c):
                    mean[r, k] /= size[r]
            if size[r] < min_region:
                nsmall += 1
        if nsmall == 0:
            break
        best = np.full(nlab, -1, dtype=np.int32)
        bestd = np.full(nlab, np.inf)
        for y in range(h):
            for x in range(w):
                i = y * w + x
                for dd in range(2):
                    if dd == 0:
                        if x + 1 >= w:
                            continue
                        j = i + 1
                    else:
                        if y + 1 >= h:
                            continue
                        j = i + w
                    a = labels[i]
                    b = labels[j]
                    if a == b:
                        continue
                    dist = 0.0
                    for k in range(c):
                        t = mean[a, k] - mean[b, k]
                        dist += t * t
                    if size[a] < min_region and dist < bestd[a]:
                        bestd[a] = dist
                        best[a] = b
                    if size[b] < min_region and dist < bestd[b]:
                        bestd[b] = dist
                        best[b] = a
        parent = np.arange(nlab).astype(np.int32)
        merged = 0
        for r in range(nlab):
            if best[r] >= 0:
                _union(parent, r, best[r])
                merged += 1
        if merged == 0:
            break
        roots = np.empty(nlab, dtype=np.int32)
        for r in range(nlab):
            roots[r] = _find(parent, r)
        for i in range(h * w):
            labels[i] = roots[labels[i]]
        labels, nlab = _compact(labels)
    return labels, nlab


def relabel_consecutive(labels: npt.NDArray[np.integer]) -> npt.NDArray[np.int32]:
    """Renumber a label map to 0..K-1 (order of first appearance in raster order). Shape preserved."""
    lab = np.asarray(labels)
    out, _ = _compact(np.ascontiguousarray(lab.reshape(-1).astype(np.int32)))
    return out.reshape(lab.shape)


def _split_large(labels: npt.NDArray[np.int32], max_region: int) -> npt.NDArray[np.int32]:
    h, w = labels.shape
    side = max(4, int(np.sqrt(max_region)))
    yy, xx = np.mgrid[0:h, 0:w]
    cell = (yy // side) * ((w + side - 1) // side) + (xx // side)
    sizes = np.bincount(labels.ravel())
    big = sizes[labels] > max_region
    key = np.where(big, labels.astype(np.int64) * (cell.max() + 1) + cell, -1 - labels.astype(np.int64))
    _, inv = np.unique(key.ravel(), return_inverse=True)
    # a grid cell may cut a region into disconnected pieces: relabel by connectivity
    comp = _label_modes(inv.reshape(h, w, 1).astype(np.float32), 0.25)
    out, _ = _compact(comp)
    return out.reshape(h, w)


def split_segments(labels: npt.NDArray[np.integer], image: npt.NDArray[np.generic],
                   selected: npt.NDArray[np.bool_], *, min_region: int = 20) -> npt.NDArray[np.int32]:
    """Split each selected segment into quarters at its centroid (connected pieces), others unchanged.

    Parameters
    ----------
    labels : (H, W) int label map 0..K-1.
    image : (H, W, 3) RGB or (H, W) grey reference image (colour of the small-piece merge).
    selected : (K,) bool segments to split.
    min_region : int, keyword-only
        Pieces smaller than this are merged into their closest-colour neighbour (as ``M`` of §5.1).

    Returns
    -------
    (H, W) int32 labels 0..K'-1, every segment 4-connected.
    """
    lab = np.asarray(labels).astype(np.int64)
    h, w = lab.shape
    k = int(lab.max()) + 1
    sel = np.asarray(selected, bool)
    yy, xx = np.mgrid[0:h, 0:w]
    n = np.maximum(np.bincount(lab.ravel(), minlength=k), 1)
    cx = np.bincount(lab.ravel(), weights=xx.ravel(), minlength=k) / n
    cy = np.bincount(lab.ravel(), weights=yy.ravel(), minlength=k) / n
    quad = (yy >= cy[lab]).astype(np.int64) * 2 + (xx >= cx[lab])
    key = np.where(sel[lab], lab * 4 + quad, lab * 4)
    # only equal keys are joined: the keys themselves serve while float32 holds them exactly (no sort)
    inv = key if 4 * k < 2 ** 24 else np.unique(key.ravel(), return_inverse=True)[1]
    comp = _label_modes(inv.reshape(h, w, 1).astype(np.float32), 0.25)
    out, nlab = _compact(comp)
    if min_region > 1:
        labf = _to_lab8(image).reshape(-1, 3).astype(np.float32)
        out, nlab = _merge_small(out, nlab, labf, h, w, int(min_region))
    return out.reshape(h, w)


def mean_shift_segment(image: npt.NDArray[np.generic], *, params: SegmentationParams | None = None,
                       disparity: npt.NDArray[np.floating] | None = None) -> npt.NDArray[np.int32]:
    """Segment an image by joint spatial-range mean shift (thesis §5.1).

    Parameters
    ----------
    image : (H, W, 3) uint8 RGB or (H, W) grey array
        The reference (left) image.
    params : SegmentationParams, keyword-only
        ``hs``, ``hr``, ``M`` (min_region) ...; defaults tuned for Middlebury-sized images.
    disparity : (H, W) float, keyword-only, optional
        A dense initial disparity map. When given and ``params.depth_tau > 0``, 4-neighbours whose
        (median-filtered) disparities differ by ``depth_tau`` or more are never grouped, and the small-region
        merge weighs disparity too, so that segments do not straddle depth edges the initial map shows
        (an extension of §5.1: the thesis assumes depth edges coincide with colour edges).

    Returns
    -------
    labels : (H, W) int32
        Segment index per pixel, 0..K-1, every segment 4-connected and (when the image allows)
        at least ``M`` pixels.
    """
    p = params or SegmentationParams()
    lab = _to_lab8(image)
    h, w = lab.shape[:2]
    if p.clahe > 0:
        lab = lab.copy()
        lab[:, :, 0] = cv2.createCLAHE(clipLimit=float(p.clahe), tileGridSize=(8, 8)).apply(
            np.ascontiguousarray(lab[:, :, 0]))
    filt: npt.NDArray[np.generic]
    if p.max_level == 0 and lab.size:
        filt = _mean_shift_filter(np.ascontiguousarray(lab), float(p.hs), float(p.hr))
    else:
        filt = cv2.pyrMeanShiftFiltering(lab, sp=float(p.hs), sr=float(p.hr), maxLevel=int(p.max_level))
    labf = lab.reshape(-1, 3).astype(np.float32)
    if disparity is not None and p.depth_tau > 0:
        dm = np.asarray(disparity, dtype=np.float32)
        if dm.shape != (h, w):
            raise ImageError(f"expected a disparity map of shape {(h, w)}, got {dm.shape}")
        dm = np.asarray(cv2.medianBlur(np.nan_to_num(dm, nan=0.0).astype(np.float32), 5), dtype=np.float32)
        roots = _label_modes_depth(filt.astype(np.float32), float(p.hr) ** 2, dm, float(p.depth_tau))
        scale = float(p.hr) / float(p.depth_tau)
        labf = np.concatenate([labf, (dm.reshape(-1, 1) * scale).astype(np.float32)], axis=1)
    else:
        roots = _label_modes(filt.astype(np.float32), float(p.hr) ** 2)
    labels, nlab = _compact(roots)
    if p.min_region > 1:
        labels, nlab = _merge_small(labels, nlab, labf, h, w, int(p.min_region))
    out = labels.reshape(h, w)
    if p.max_region > 0:
        out = _split_large(out, int(p.max_region))
        flat, nlab = _merge_small(out.reshape(-1).copy(), int(out.max()) + 1, labf, h, w, int(p.min_region))
        out = flat.reshape(h, w)
    log.debug("mean shift: %d segments", int(out.max()) + 1)
    return out


def segment_adjacency(labels: npt.NDArray[np.integer], image: npt.NDArray[np.generic] | None = None,
                      ) -> tuple[npt.NDArray[np.int32], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Adjacent segment pairs (thesis Eq. 6.11) with boundary length and mean colour contrast.

    Parameters
    ----------
    labels : (H, W) int
        Label map, 0..K-1.
    image : (H, W, 3) or (H, W), optional
        If given, the mean squared colour difference across each shared boundary is returned.

    Returns
    -------
    pairs : (P, 2) int32
        Unique pairs ``(i, j)`` with ``i < j`` of 4-adjacent segments.
    length : (P,) float64
        Number of 4-neighbour pixel pairs on the shared boundary.
    contrast : (P,) float64
        Mean of ``|I_p - I_q|^2`` over those pixel pairs (zeros when no image is given).
    """
    lab = np.asarray(labels).astype(np.int64)
    k = int(lab.max()) + 1
    img = None
    if image is not None:
        img = np.asarray(image, dtype=np.float64)
        if img.ndim == 2:
            img = img[:, :, None]
    keys_l, diffs_l = [], []
    for a, b, da in ((lab[:, :-1], lab[:, 1:], 1), (lab[:-1, :], lab[1:, :], 0)):
        m = a != b
        lo = np.minimum(a, b)[m]
        hi = np.maximum(a, b)[m]
        keys_l.append(lo * k + hi)
        if img is not None:
            if da == 1:
                diff = ((img[:, :-1] - img[:, 1:]) ** 2).sum(axis=2)
            else:
                diff = ((img[:-1, :] - img[1:, :]) ** 2).sum(axis=2)
            diffs_l.append(diff[m])
    keys = np.concatenate(keys_l)
    uniq, inv = np.unique(keys, return_inverse=True)
    length = np.bincount(inv, minlength=uniq.size).astype(np.float64)
    if img is not None:
        sums = np.bincount(inv, weights=np.concatenate(diffs_l), minlength=uniq.size)
        contrast = sums / np.maximum(length, 1)
    else:
        contrast = np.zeros(uniq.size)
    pairs = np.stack([uniq // k, uniq % k], axis=1).astype(np.int32)
    return pairs, length, contrast
