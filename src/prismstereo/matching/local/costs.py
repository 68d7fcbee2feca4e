"""Pixel-wise and windowed matching costs as float32 cost volumes (thesis §2.6, §5.2.2).

Every function returns a ``float32`` array of shape ``(H, W, D)`` with ``D = max_disp - min_disp + 1``;
slice ``[..., i]`` holds the cost of disparity ``d = min_disp + i`` where ``d = x_left - x_right``, i.e.
left pixel ``(x, y)`` is compared with right pixel ``(x - d, y)``. Lower is better for every cost (NCC is
returned as ``1 - ZNCC``).

Where ``x - d`` falls outside the right image the cost is a large *finite* value: the worst cost the
measure can take (:func:`invalid_cost_value`), so that box or adaptive aggregation near the left border
stays finite and a winner-take-all never prefers an impossible match over a possible one.

Images are ``uint8`` or float (0..255 scale), ``H×W`` gray or ``H×W×3`` RGB. Windowed costs use box
filters (``cv2.blur``, an integral-image-equivalent running sum), never per-pixel window loops.
"""

from __future__ import annotations

import cv2
import numpy as np
from numba import njit, prange

from prismstereo.errors import MatchingError
from prismstereo.io.images import to_gray
from prismstereo.matching.local.aggregation import SegmentBand

__all__ = [
    "census_transform",
    "cost_ad",
    "cost_census",
    "cost_gradient",
    "cost_ncc",
    "cost_s_ad",
    "cost_s_ad_census",
    "cost_sad_window",
    "cost_ssd",
    "image_gradients",
    "to_float",
    "to_gray",
]


def to_float(image: np.ndarray) -> np.ndarray:
    """``image`` as contiguous float32, ``H×W`` or ``H×W×C`` (values kept on the 0..255 scale)."""
    return np.ascontiguousarray(image, dtype=np.float32)


def _channels(image: np.ndarray) -> np.ndarray:
    img = to_float(image)
    return img if img.ndim == 3 else img[:, :, None]


def _ndisp(max_disp: int, min_disp: int) -> int:
    return int(max_disp) - int(min_disp) + 1


def _shifted_abs_diff(left: np.ndarray, right: np.ndarray, min_disp: int, ndisp: int,
                      invalid: float) -> np.ndarray:
    """Mean over channels of ``|left(y, x) - right(y, x - d)|``, vectorised per disparity slice.

    Slices are built contiguous in a (D, H, W) array from channel-first images, then transposed once.
    """
    h, w, c = left.shape
    lc = np.ascontiguousarray(left.transpose(2, 0, 1))
    rc = np.ascontiguousarray(right.transpose(2, 0, 1))
    vol = np.full((ndisp, h, w), np.float32(invalid), dtype=np.float32)
    tmp = np.empty((h, w), dtype=np.float32)
    for i in range(ndisp):  # loop over disparities, not pixels
        d = min_disp + i
        if d >= w:
            break
        acc = vol[i, :, d:]
        np.subtract(lc[0, :, d:], rc[0, :, : w - d], out=acc)
        np.abs(acc, out=acc)
        t = tmp[:, d:]
        for k in range(1, c):
            np.subtract(lc[k, :, d:], rc[k, :, : w - d], out=t)
            np.abs(t, out=t)
            acc += t
        if c > 1:
            acc *= np.float32(1.0 / c)
    return np.ascontiguousarray(vol.transpose(1, 2, 0))


def cost_ad(left: np.ndarray, right: np.ndarray, *, max_disp: int, min_disp: int = 0,
            truncation: float | None = None) -> np.ndarray:
    """Absolute intensity difference, averaged over colour channels (thesis §2.6).

    Parameters
    ----------
    left, right : ndarray, (H, W) or (H, W, 3)
        Rectified images, 0..255 scale.
    max_disp, min_disp : int
        Inclusive disparity range in pixels.
    truncation : float, optional
        Clip the cost at this value (truncated AD); also the out-of-range cost when given.

    Returns
    -------
    ndarray, float32, (H, W, max_disp - min_disp + 1)
        ``|I_l(x, y) - I_r(x - d, y)|``; 255 (or ``truncation``) where ``x - d`` is outside the image.
    """
    invalid = 255.0 if truncation is None else float(truncation)
    vol = _shifted_abs_diff(_channels(left), _channels(right), int(min_disp), _ndisp(max_disp, min_disp),
                            float(invalid))
    if truncation is not None:
        np.minimum(vol, np.float32(truncation), out=vol)
    return vol


def image_gradients(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Central-difference gradients ``(∇x I, ∇y I)`` of the gray image, float32 ``H×W`` each."""
    g = to_gray(image)
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=1, borderType=cv2.BORDER_REPLICATE) * np.float32(0.5)
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=1, borderType=cv2.BORDER_REPLICATE) * np.float32(0.5)
    return gx, gy


def cost_gradient(left: np.ndarray, right: np.ndarray, *, max_disp: int, min_disp: int = 0,
                  truncation: float | None = None) -> np.ndarray:
    """Gradient dissimilarity ``|∇x I_l - ∇x I_r| + |∇y I_l - ∇y I_r|`` (second term of thesis Eq. 5.6).

    Returns a float32 ``(H, W, D)`` volume; out-of-range entries get 255 (or ``truncation``).
    """
    lx, ly = image_gradients(left)
    rx, ry = image_gradients(right)
    lg = np.stack([lx, ly], axis=2)
    rg = np.stack([rx, ry], axis=2)
    invalid = 255.0 if truncation is None else float(truncation)
    # _shifted_abs_diff averages over channels; the measure is the sum of the two terms
    vol = _shifted_abs_diff(lg, rg, int(min_disp), _ndisp(max_disp, min_disp), float(invalid / 2.0))
    vol *= np.float32(2.0)
    if truncation is not None:
        np.minimum(vol, np.float32(truncation), out=vol)
    return vol


def cost_s_ad(left: np.ndarray, right: np.ndarray, *, max_disp: int, min_disp: int = 0,
              omega: float = 0.5, tau_color: float | None = None,
              tau_gradient: float | None = None) -> np.ndarray:
    """The thesis's self-adaptation dissimilarity S_AD (thesis Eq. 5.6).

    ``S_AD = (1 - ω) |I_l(x, y) - I_r(x - d, y)| + ω (|∇x I_l - ∇x I_r| + |∇y I_l - ∇y I_r|)``.
    The thesis writes ``I'(x + d, y)``; with this project's convention ``d = x_left - x_right`` the right
    pixel is ``x - d``. Optional truncations ``tau_color`` / ``tau_gradient`` clip each term (the
    truncated form makes aggregation robust at occlusions; ``None`` gives the literal equation).

    Returns
    -------
    ndarray, float32, (H, W, D)
    """
    if not 0.0 <= omega <= 1.0:
        raise MatchingError(f"expected 0 <= omega <= 1, got {omega}")
    ad = cost_ad(left, right, max_disp=max_disp, min_disp=min_disp, truncation=tau_color)
    gr = cost_gradient(left, right, max_disp=max_disp, min_disp=min_disp, truncation=tau_gradient)
    ad *= np.float32(1.0 - omega)
    ad += np.float32(omega) * gr
    return ad


def _box_volume(vol: np.ndarray, radius: int) -> np.ndarray:
    """Mean over a (2r+1)² window of every disparity slice (running sums; reflected border)."""
    if radius <= 0:
        return vol
    k = (2 * radius + 1, 2 * radius + 1)
    out = np.empty_like(vol)
    for i in range(vol.shape[2]):  # loop over disparities, not pixels
        out[:, :, i] = cv2.blur(np.ascontiguousarray(vol[:, :, i]), k, borderType=cv2.BORDER_REFLECT_101)
    return out


def cost_sad_window(left: np.ndarray, right: np.ndarray, *, max_disp: int, min_disp: int = 0,
                    radius: int = 3) -> np.ndarray:
    """Windowed sum (reported as window mean) of absolute differences, SAD (thesis §2.6, Table 5.1).

    Gray images. Returns float32 ``(H, W, D)``; out-of-range matches cost 255 per pixel.
    """
    return _box_volume(cost_ad(to_gray(left), to_gray(right), max_disp=max_disp, min_disp=min_disp), radius)


def cost_ssd(left: np.ndarray, right: np.ndarray, *, max_disp: int, min_disp: int = 0,
             radius: int = 3) -> np.ndarray:
    """Windowed sum (as window mean) of squared differences, SSD (thesis §2.6).

    Gray images. Returns float32 ``(H, W, D)``; out-of-range matches cost 255² per pixel.
    """
    ad = cost_ad(to_gray(left), to_gray(right), max_disp=max_disp, min_disp=min_disp)
    np.square(ad, out=ad)
    return _box_volume(ad, radius)


def cost_ncc(left: np.ndarray, right: np.ndarray, *, max_disp: int, min_disp: int = 0,
             radius: int = 3, eps: float = 1e-2) -> np.ndarray:
    """Zero-mean normalised cross-correlation as a cost ``1 - ZNCC`` in [0, 2] (thesis §2.6).

    Window means, variances and the cross term are box filters of the gray images and of their products
    (one ``cv2.blur`` per disparity). ``eps`` (grey levels²) regularises flat windows, whose cost tends
    to 1. Out-of-range matches cost 2.

    Returns
    -------
    ndarray, float32, (H, W, D)
    """
    lg = to_gray(left).astype(np.float64)
    rg = to_gray(right).astype(np.float64)
    h, w = lg.shape
    k = (2 * radius + 1, 2 * radius + 1)
    border = cv2.BORDER_REFLECT_101

    def blur(a: np.ndarray) -> np.ndarray:
        return cv2.blur(a, k, borderType=border)

    ml = blur(lg)
    vl = np.maximum(blur(lg * lg) - ml * ml, 0.0) + eps
    nd = _ndisp(max_disp, min_disp)
    out = np.full((h, w, nd), 2.0, dtype=np.float32)
    for i in range(nd):  # loop over disparities, not pixels
        d = min_disp + i
        if d >= w:
            continue
        rs = np.empty_like(rg)
        rs[:, d:] = rg[:, : w - d]
        rs[:, :d] = rg[:, :1]
        # statistics of the shifted image computed on it (consistent borders with the cross term)
        mrs = blur(rs)
        vrs = np.maximum(blur(rs * rs) - mrs * mrs, 0.0) + eps
        cross = blur(lg * rs) - ml * mrs
        zncc = np.clip(cross / np.sqrt(vl * vrs), -1.0, 1.0)
        out[:, d:, i] = (1.0 - zncc[:, d:]).astype(np.float32)
    return out


# ----------------------------------------------------------------------------------------- census
def _census(gray: np.ndarray, ry: int, rx: int) -> np.ndarray:
    """Census codes, one vectorised compare per window offset (replicated border)."""
    h, w = gray.shape
    pad = np.pad(gray, ((ry, ry), (rx, rx)), mode="edge")
    code = np.zeros((h, w), dtype=np.uint64)
    for dy in range(-ry, ry + 1):  # loop over window offsets, not pixels
        for dx in range(-rx, rx + 1):
            if dy == 0 and dx == 0:
                continue
            nb = pad[ry + dy: ry + dy + h, rx + dx: rx + dx + w]
            code = (code << np.uint64(1)) | (nb < gray).astype(np.uint64)
    return code


def _hamming_volume(cl: np.ndarray, cr: np.ndarray, min_disp: int, ndisp: int,
                    invalid: float) -> np.ndarray:
    h, w = cl.shape
    out = np.full((h, w, ndisp), np.float32(invalid), dtype=np.float32)
    for i in range(ndisp):  # loop over disparities, not pixels
        d = min_disp + i
        if d >= w:
            break
        out[:, d:, i] = np.bitwise_count(cl[:, d:] ^ cr[:, : w - d])
    return out


def census_transform(image: np.ndarray, *, window: tuple[int, int] = (7, 9)) -> np.ndarray:
    """Census transform (Zabih–Woodfill): one bit per window pixel darker than the centre.

    Parameters
    ----------
    image : ndarray, (H, W) or (H, W, 3)
    window : (int, int)
        Odd window ``(height, width)``; at most 64 pixels (the bits fit a uint64).

    Returns
    -------
    ndarray, uint64, (H, W)
    """
    wh, ww = int(window[0]), int(window[1])
    if wh % 2 == 0 or ww % 2 == 0 or wh < 1 or ww < 1 or wh * ww - 1 > 64:
        raise MatchingError(f"expected an odd census window with at most 65 pixels, got {window}")
    return _census(to_gray(image), wh // 2, ww // 2)


def cost_census(left: np.ndarray, right: np.ndarray, *, max_disp: int, min_disp: int = 0,
                window: tuple[int, int] = (7, 9)) -> np.ndarray:
    """Hamming distance between census codes (the per-pixel term of SHD, thesis Table 5.1).

    Returns a float32 ``(H, W, D)`` volume of bit counts; out-of-range entries get the number of bits.
    """
    cl = census_transform(left, window=window)
    cr = census_transform(right, window=window)
    nbits = window[0] * window[1] - 1
    return _hamming_volume(cl, cr, int(min_disp), _ndisp(max_disp, min_disp), float(nbits))


@njit(cache=True, inline="always")
def popcount64(v: np.uint64) -> int:  # pragma: no cover - numba
    """Number of set bits of a uint64 (a census Hamming distance, in numba kernels): the SWAR count, branch-free
    so that the loops calling it vectorise."""
    v = v - ((v >> np.uint64(1)) & np.uint64(0x5555555555555555))
    v = (v & np.uint64(0x3333333333333333)) + ((v >> np.uint64(2)) & np.uint64(0x3333333333333333))
    v = (v + (v >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return int((v * np.uint64(0x0101010101010101)) >> np.uint64(56))


@njit(cache=True, parallel=True, nogil=True)
def _s_ad_census_kernel(lc: np.ndarray, rc: np.ndarray, lg: np.ndarray, rg: np.ndarray, cl: np.ndarray,
                        cr: np.ndarray, min_disp: int, nd: int, inv_c: np.float32, bad_c: np.float32,
                        tau_c: np.float32, clip_c: bool, bad_g: np.float32, tau_g: np.float32, clip_g: bool,
                        w_ad: np.float32, w_gr: np.float32, w_cen: np.float32, bad_cen: np.float32,
                        use_census: bool, keep: np.ndarray, seg: int) -> np.ndarray:  # pragma: no cover - numba
    """:func:`cost_s_ad` (+ ``w_cen`` × :func:`cost_census`) per entry, float32 operations in numpy's order;
    only the slices ``keep[y, x // seg, 0] … keep[y, x // seg, 1]`` (inclusive) of pixel ``(y, x)``, the others
    0 (compiled without fastmath: an entry does not depend on the slices computed beside it)."""
    h, w, c = lc.shape
    out = np.empty((h, w, nd), np.float32)
    two = np.float32(2.0)
    half = np.float32(0.5)
    zero = np.float32(0.0)
    for y in prange(h):
        for x in range(w):
            s = x // seg
            lo = max(keep[y, s, 0], 0)
            hi = min(keep[y, s, 1], nd - 1)
            for i in range(min(lo, nd)):
                out[y, x, i] = zero
            for i in range(max(hi + 1, lo), nd):
                out[y, x, i] = zero
            for i in range(lo, hi + 1):
                xr = x - (min_disp + i)
                if xr >= 0:
                    ad = abs(lc[y, x, 0] - rc[y, xr, 0])
                    for k in range(1, c):
                        ad = ad + abs(lc[y, x, k] - rc[y, xr, k])
                    if c > 1:
                        ad = ad * inv_c
                    g = abs(lg[y, x, 0] - rg[y, xr, 0]) + abs(lg[y, x, 1] - rg[y, xr, 1])
                    g = g * half
                else:
                    ad = bad_c
                    g = bad_g
                if clip_c:
                    ad = min(ad, tau_c)
                g = g * two
                if clip_g:
                    g = min(g, tau_g)
                v = ad * w_ad
                v = v + w_gr * g
                if use_census:
                    cen = np.float32(popcount64(cl[y, x] ^ cr[y, xr])) if xr >= 0 else bad_cen
                    v = v + w_cen * cen
                out[y, x, i] = v
    return out


def cost_s_ad_census(left: np.ndarray, right: np.ndarray, *, max_disp: int, min_disp: int = 0,
                     omega: float = 0.5, tau_color: float | None = None, tau_gradient: float | None = None,
                     census_weight: float = 0.0, window: tuple[int, int] = (7, 9),
                     band: SegmentBand | None = None) -> np.ndarray:
    """``cost_s_ad(...) + census_weight * cost_census(...)`` (thesis Eq. 5.6 plus a census term) in one
    parallel pass, equal to composing the two functions bit for bit.

    Parameters as :func:`cost_s_ad` and :func:`cost_census`; ``census_weight <= 0`` leaves the census out.
    ``band``: only its entries are computed (the same values), the others are 0.

    Returns
    -------
    ndarray, float32, (H, W, D)
    """
    if not 0.0 <= omega <= 1.0:
        raise MatchingError(f"expected 0 <= omega <= 1, got {omega}")
    lc, rc = _channels(left), _channels(right)
    nd = _ndisp(max_disp, min_disp)
    if int(min_disp) < 0 or nd < 1 or lc.shape != rc.shape or nd + int(min_disp) > lc.shape[1]:
        # the composed functions' own checks and messages for the unusual ranges
        vol = cost_s_ad(left, right, max_disp=max_disp, min_disp=min_disp, omega=omega, tau_color=tau_color,
                        tau_gradient=tau_gradient)
        if census_weight > 0:
            vol += np.float32(census_weight) * cost_census(left, right, max_disp=max_disp, min_disp=min_disp,
                                                           window=window)
        if band is not None:
            h, w, nd_v = vol.shape
            b = np.repeat(band.check(h, w), band.segment, axis=1)[:, :w]
            idx = np.arange(nd_v)[None, None, :]
            vol[(idx < b[:, :, :1]) | (idx > b[:, :, 1:])] = 0.0
        return vol
    lx, ly = image_gradients(left)
    rx, ry = image_gradients(right)
    use_census = census_weight > 0
    if use_census:
        cl = census_transform(left, window=window)
        cr = census_transform(right, window=window)
    else:
        cl = cr = np.zeros((1, 1), np.uint64)
    bad_c = 255.0 if tau_color is None else float(tau_color)
    bad_g = 255.0 if tau_gradient is None else float(tau_gradient)
    f32 = np.float32
    h, w = lc.shape[:2]
    if band is None:  # every slice: one segment per row
        keep, seg = np.tile(np.array([0, nd - 1], np.int64), (h, 1, 1)), max(w, 1)
    else:
        keep, seg = band.check(h, w), int(band.segment)
    return _s_ad_census_kernel(lc, rc, np.ascontiguousarray(np.stack([lx, ly], axis=2)),
                               np.ascontiguousarray(np.stack([rx, ry], axis=2)), cl, cr, int(min_disp), nd,
                               f32(1.0 / lc.shape[2]), f32(bad_c), f32(0.0 if tau_color is None else tau_color),
                               tau_color is not None, f32(bad_g / 2.0),
                               f32(0.0 if tau_gradient is None else tau_gradient), tau_gradient is not None,
                               f32(1.0 - omega), f32(omega), f32(census_weight),
                               f32(int(window[0]) * int(window[1]) - 1), use_census, keep, seg)


def invalid_cost_value(kind: str) -> float:
    """The finite cost given to out-of-range matches by each measure (documentation helper)."""
    return {"ad": 255.0, "gradient": 255.0, "ssd": 255.0**2, "ncc": 2.0}[kind]
