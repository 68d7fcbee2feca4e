"""Sub-pixel disparity refinement for depth: windowed Gauss–Newton on the rectified pair.

Depth error grows as ``ΔZ / Z = Δd / d``: at the thesis rig's ~80 px disparity at 1.5 m, 0.25 % depth error
is 0.2 px of disparity, finer than integer or parabola-fitted winners give. This step refines each valid
disparity continuously (Lucas–Kanade along the epipolar line): it minimises, over a ``(2r+1)²`` window,

    E(d) = Σ ( L(x, y) − R(x − d, y) )²   (window means removed)

with R sampled bilinearly, by Gauss–Newton steps ``Δd = −Σ r·J / Σ J²`` (``r = L − R(x − d)``, ``J = ∂r/∂d =
R_x(x − d)``), the whole window of each pixel shifted by that pixel's d (a parallel numba kernel over pixels,
accumulating window sums). Means are removed per window (zero-mean SSD), so an offset between the two faces'
brightness does not bias d. The update is bounded to ±``max_shift`` px around the matcher's disparity; pixels
without texture (small Σ J²) keep the matcher's value and get no confidence. The returned confidence (ZNCC of
the final windows) lets the pipeline drop matches the refinement could not confirm.
"""

from __future__ import annotations

import cv2
import numpy as np
from numba import njit, prange

__all__ = ["refine_disparity"]


@njit(cache=True, inline="always")
def _sample(img: np.ndarray, y: int, xf: float) -> float:  # pragma: no cover - numba
    """Linear interpolation along row ``y`` at column ``xf``, edge-replicated (cv2 BORDER_REPLICATE)."""
    w = img.shape[1]
    x0 = int(np.floor(xf))
    a = xf - x0
    xa = min(max(x0, 0), w - 1)
    xb = min(max(x0 + 1, 0), w - 1)
    return (1.0 - a) * img[y, xa] + a * img[y, xb]


@njit(cache=True, parallel=True, fastmath=True)
def _refine_kernel(L: np.ndarray, R: np.ndarray, Rx: np.ndarray, ys: np.ndarray, xs: np.ndarray, d0: np.ndarray,
                   radius: int, iterations: int, max_shift: float,
                   min_texture: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - numba
    """Gauss–Newton per pixel (module docstring); window sums instead of stored windows.

    With zero-mean windows ``Lz``, ``Rz = R - mean R``, ``Jz = J - mean J`` over ``m`` pixels:
    ``Σ r·Jz = Σ Lz·J - (Σ R·J - m·mean R·mean J)`` and ``Σ Jz² = Σ J² - m·mean J²`` (``Σ Lz = 0``).
    Returns the refined disparities, the final ZNCC and whether the pixel may keep its refinement.
    """
    n = ys.size
    m = (2 * radius + 1) ** 2
    d_out = np.empty(n, dtype=np.float32)
    zncc = np.empty(n, dtype=np.float32)
    keep = np.zeros(n, dtype=np.bool_)
    for i in prange(n):
        y, x = ys[i], xs[i]
        init = float(d0[y, x])
        lmean = 0.0
        for dy in range(-radius, radius + 1):
            for dx in range(-radius, radius + 1):
                lmean += L[y + dy, x + dx]
        lmean /= m
        d = init
        textured = True
        w = R.shape[1]
        for _ in range(iterations):
            sr = 0.0
            sj = 0.0
            slj = 0.0
            srj = 0.0
            sjj = 0.0
            # every window pixel is shifted by the same d: one pair of taps for the whole window, and
            # contiguous reads when the window stays inside the row (else the edge-replicating sampler)
            xf0 = x - d
            b0 = int(np.floor(xf0))
            fa = xf0 - b0
            fb = 1.0 - fa
            inner = b0 - radius >= 0 and b0 + radius + 1 <= w - 1
            for dy in range(-radius, radius + 1):
                for dx in range(-radius, radius + 1):
                    if inner:
                        xa = b0 + dx
                        rv = fb * R[y + dy, xa] + fa * R[y + dy, xa + 1]
                        jv = fb * Rx[y + dy, xa] + fa * Rx[y + dy, xa + 1]
                    else:
                        xf = x + dx - d
                        rv = _sample(R, y + dy, xf)
                        jv = _sample(Rx, y + dy, xf)
                    lz = L[y + dy, x + dx] - lmean
                    sr += rv
                    sj += jv
                    slj += lz * jv
                    srj += rv * jv
                    sjj += jv * jv
            num = slj - (srj - sr * sj / m)
            den = sjj - sj * sj / m
            textured = den > min_texture * m
            step = num / den if textured else 0.0
            step = min(max(step, -0.5), 0.5)
            d = min(max(d - step, init - max_shift), init + max_shift)
        sr = 0.0
        srr = 0.0
        slr = 0.0
        sll = 0.0
        for dy in range(-radius, radius + 1):
            for dx in range(-radius, radius + 1):
                rv = _sample(R, y + dy, x + dx - d)
                lz = L[y + dy, x + dx] - lmean
                sr += rv
                srr += rv * rv
                slr += lz * rv
                sll += lz * lz
        var_r = srr - sr * sr / m
        den = np.sqrt(sll * var_r)
        zncc[i] = slr / den if den > 0.0 else np.nan
        d_out[i] = d
        keep[i] = textured and np.isfinite(d) and abs(d - init) < max_shift - 1e-3
    return d_out, zncc, keep


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
    d, zncc, keep = _refine_kernel(L, R, Rx, ys.astype(np.int64), xs.astype(np.int64), d0, int(radius),
                                   int(iterations), float(max_shift), float(min_texture))
    if valid_right is not None:
        bad_r = cv2.dilate((~np.asarray(valid_right, dtype=bool)).astype(np.uint8), np.ones((k, k), np.uint8)) > 0
        xr = np.rint(xs - d).astype(np.int64)
        inside = (xr >= 0) & (xr < w)
        hit = np.ones(ys.size, dtype=bool)
        hit[inside] = bad_r[ys[inside], xr[inside]]
        keep &= ~hit
    out[ys[keep], xs[keep]] = d[keep]
    conf[ys[keep], xs[keep]] = zncc[keep]
    return out, conf
