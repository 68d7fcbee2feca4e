"""Sub-pixel disparity refinement for depth: windowed Gauss–Newton on the rectified pair.

Depth error grows as ``ΔZ / Z = Δd / d``: at the thesis rig's ~80 px disparity at 1.5 m, 0.25 % depth error
is 0.2 px of disparity, finer than integer or parabola-fitted winners give. This step refines each valid
disparity continuously (Lucas–Kanade along the epipolar line): it minimises, over a ``(2r+1)²`` window,

    E(d) = Σ ( L(x, y) − R(x − d, y) )²   (window means removed)

with R sampled bilinearly, by Gauss–Newton steps ``Δd = −Σ r·J / Σ J²`` (``r = L − R(x − d)``,
``J = ∂r/∂d = R_x(x − d)``), the whole window of each pixel shifted by that pixel's d (vectorised over
pixels). Means are removed per window (zero-mean SSD), so an offset between the two faces' brightness
does not bias d. The update is bounded to ±``max_shift`` px around the matcher's disparity; pixels
without texture (small Σ J²) keep the matcher's value and get no confidence. The returned confidence
(ZNCC of the final windows) lets the pipeline drop matches the refinement could not confirm.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["refine_disparity"]


def _gray(img: np.ndarray) -> np.ndarray:
    a = np.asarray(img)
    if a.ndim == 3:
        a = cv2.cvtColor(a.astype(np.float32), cv2.COLOR_RGB2GRAY)
    return a.astype(np.float32)


def refine_disparity(
    left: np.ndarray,
    right: np.ndarray,
    disparity: np.ndarray,
    *,
    radius: int = 3,
    iterations: int = 6,
    max_shift: float = 1.0,
    min_texture: float = 1.0,
    valid_left: np.ndarray | None = None,
    valid_right: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Refine a disparity map to sub-pixel precision (module docstring).

    Parameters
    ----------
    left, right : (H, W) or (H, W, 3) arrays
        The rectified pair (uint8 or float, 0..255).
    disparity : (H, W) float array
        Initial disparity of ``left`` (``d = x_left − x_right``), NaN = invalid (left untouched).
    radius : int
        Half-size of the square window.
    iterations : int
        Gauss–Newton iterations.
    max_shift : float
        Largest allowed change from the initial disparity, px.
    min_texture : float
        Minimum mean squared horizontal gradient (grey levels²/px²) in the window to refine.
    valid_left, valid_right : (H, W) bool, optional
        Valid regions of the rectified images; windows touching invalid pixels are not refined.

    Returns
    -------
    disparity : (H, W) float32
        Refined disparity; the input value where it could not be refined, NaN where the input was NaN.
    confidence : (H, W) float32
        Zero-mean normalised cross-correlation of the two windows at the refined disparity, in [−1, 1];
        NaN where the pixel was not refined (border, no texture, invalid region, or the update hit the
        ±``max_shift`` bound, i.e. the matcher's disparity was more than a pixel off).
    """
    L = _gray(left)
    R = _gray(right)
    d0 = np.asarray(disparity, dtype=np.float32)
    h, w = d0.shape
    out = d0.copy()
    conf = np.full(d0.shape, np.nan, dtype=np.float32)
    finite = np.isfinite(d0)
    k = 2 * radius + 1
    ok = finite.copy()
    if valid_left is not None:
        bad = cv2.dilate((~np.asarray(valid_left, dtype=bool)).astype(np.uint8), np.ones((k, k), np.uint8)) > 0
        ok &= ~bad
    # keep windows inside the image
    ok[:radius] = ok[h - radius:] = False
    ok[:, :radius] = ok[:, w - radius:] = False
    ys, xs = np.nonzero(ok)
    if ys.size == 0:
        return out, conf
    Rx = cv2.Sobel(R, cv2.CV_32F, 1, 0, ksize=3, scale=1.0 / 8.0)
    oy, ox = np.mgrid[-radius:radius + 1, -radius:radius + 1]
    ox = ox.ravel().astype(np.float32)
    oy = oy.ravel().astype(np.int64)
    bad_r = None
    if valid_right is not None:
        bad_r = cv2.dilate((~np.asarray(valid_right, dtype=bool)).astype(np.uint8), np.ones((k, k), np.uint8)) > 0
    chunk = max(1, min(30_000, 2_000_000 // ox.size))  # cv2.remap needs < 32767 rows
    for c0 in range(0, ys.size, chunk):
        y, x = ys[c0:c0 + chunk], xs[c0:c0 + chunk]
        init = d0[y, x].astype(np.float32)
        d = init.copy()
        Lw = L[y[:, None] + oy[None, :], x[:, None] + ox.astype(np.int64)[None, :]]
        Lw = Lw - Lw.mean(axis=1, keepdims=True)
        Ym = (y[:, None] + oy[None, :]).astype(np.float32)
        textured = np.ones(y.size, dtype=bool)
        for _ in range(iterations):
            Xm = (x[:, None].astype(np.float32) + ox[None, :]) - d[:, None]
            Rw = cv2.remap(R, Xm, Ym, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            J = cv2.remap(Rx, Xm, Ym, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            r = Lw - (Rw - Rw.mean(axis=1, keepdims=True))
            Jz = J - J.mean(axis=1, keepdims=True)
            num = np.einsum("nm,nm->n", r, Jz)
            den = np.einsum("nm,nm->n", Jz, Jz)
            textured = den > min_texture * ox.size
            with np.errstate(divide="ignore", invalid="ignore"):
                step = np.where(textured, num / den, 0.0).astype(np.float32)
            # r = L − R(x − d): dr/dd = +R_x, so the Gauss–Newton step is −Σ r J / Σ J²
            d = np.clip(d - np.clip(step, -0.5, 0.5), init - max_shift, init + max_shift)
        # final correlation of the windows
        Xm = (x[:, None].astype(np.float32) + ox[None, :]) - d[:, None]
        Rw = cv2.remap(R, Xm, Ym, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        Rz = Rw - Rw.mean(axis=1, keepdims=True)
        with np.errstate(divide="ignore", invalid="ignore"):
            zncc = np.einsum("nm,nm->n", Lw, Rz) / np.sqrt(np.einsum("nm,nm->n", Lw, Lw) *
                                                             np.einsum("nm,nm->n", Rz, Rz))
        keep = textured & np.isfinite(d) & (np.abs(d - init) < max_shift - 1e-3)
        if bad_r is not None:
            xr = np.rint(x - d).astype(np.int64)
            inside = (xr >= 0) & (xr < w)
            hit = np.ones(y.size, dtype=bool)
            hit[inside] = bad_r[y[inside], xr[inside]]
            keep &= ~hit
        out[y[keep], x[keep]] = d[keep]
        conf[y[keep], x[keep]] = zncc[keep]
    return out, conf
