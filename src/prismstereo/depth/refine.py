"""Sub-pixel disparity refinement for depth: windowed Gauss–Newton on the rectified pair.

Depth error grows as ``ΔZ / Z = Δd / d``: at the thesis rig's ~80 px disparity at 1.5 m, 0.25 % depth error
is 0.2 px of disparity, finer than integer or parabola-fitted winners give. This step refines each valid
disparity continuously (Lucas–Kanade along the epipolar line): it minimises, over a ``(2r+1)²`` window,

    E(d) = Σ ( L(x, y) − R(x − d, y + δy) )²   (window means removed)

where δy is the row offset of the exact epipolar curve at the pixel (the views of a prism are not exact
pinholes, so a match lies off the left pixel's row by a known amount: :mod:`prismstereo.rectify.epipolar`;
0 without it), with R sampled bilinearly, by Gauss–Newton steps ``Δd = −Σ r·J / Σ J²`` (``r = L − R``,
``J = ∂r/∂d = R_x``, both at (x − d, y + δy)), the whole window of each pixel shifted by that pixel's d (a
parallel numba kernel over pixels, accumulating window sums). Means are removed per window (zero-mean SSD),
so an offset between the two faces' brightness does not bias d. The update is bounded to ±``max_shift`` px
around the matcher's disparity; pixels without texture (small Σ J²) keep the matcher's value and get no
confidence. The returned confidence (ZNCC of the final windows) lets the pipeline drop matches the
refinement could not confirm. Both views may first be
low-passed along their rows (``prefilter``): linear sampling damps fine texture by an amount that depends on
the sub-pixel phase and so biases d on it; texture already damped leaves it less to damp.
"""

from __future__ import annotations

import cv2
import numba
import numpy as np
from numba import njit, prange

__all__ = ["REFINE_KERNELS", "refine_disparity"]


@njit(cache=True, inline="always")
def _sample(img: np.ndarray, y: int, xf: float, fy: float) -> float:  # pragma: no cover - numba
    """Bilinear interpolation at column ``xf`` between rows ``y`` and ``y + 1`` (weight ``fy`` on ``y + 1``),
    edge-replicated (cv2 BORDER_REPLICATE)."""
    h, w = img.shape
    x0 = int(np.floor(xf))
    a = xf - x0
    xa = min(max(x0, 0), w - 1)
    xb = min(max(x0 + 1, 0), w - 1)
    ya = min(max(y, 0), h - 1)
    v = (1.0 - a) * img[ya, xa] + a * img[ya, xb]
    if fy == 0.0:
        return v
    yb = min(max(y + 1, 0), h - 1)
    return (1.0 - fy) * v + fy * ((1.0 - a) * img[yb, xa] + a * img[yb, xb])


@njit(cache=True, inline="always")
def _strip(img: np.ndarray, T: np.ndarray, D: np.ndarray | None, y0: int, k: int, c0: int, c1: int,
           pad: int) -> None:  # pragma: no cover - numba
    """The rows ``y0`` … ``y0 + k − 1`` of ``img`` (clamped to the image) at the columns ``c0`` … ``c1 − 1``
    (inside it), column-major and ``pad`` columns on: ``T[(c + pad)·k + j] = img[y0 + j, c]``; with ``D``, the
    difference to the next row there too (``img[y0 + j + 1, c] − T[…]``, both rows clamped: 0 past the
    image's edge). A window of columns is then one contiguous run of ``T``, and its next column ``k``
    elements further on. Unsigned indices (no test for negative ones)."""
    h, w = img.shape
    flat = img.ravel()
    rows = np.empty(k + 1, dtype=np.uint64)
    for j in range(k + 1):
        rows[j] = np.uint64(min(max(y0 + j, 0), h - 1) * w)
    uk = np.uint64(k)
    up = np.uint64(pad)
    for c in range(c0, c1):
        # a column's k values are consecutive in T: stores in order, loads from k + 1 row streams
        uc = np.uint64(c)
        o = (uc + up) * uk
        # np.float64, not float(): numba's float() keeps a float32, and the row difference must not round
        # (in float64 strips; a float32 strip rounds it once, on the store)
        v = np.float64(flat[rows[0] + uc])
        for j in range(k):
            uj = np.uint64(j)
            T[o + uj] = v
            nxt = np.float64(flat[rows[j + 1] + uc])
            if D is not None:
                D[o + uj] = nxt - v
            v = nxt


@njit(cache=True, inline="always")
def _window_sums32(TL: np.ndarray, TR: np.ndarray, TD: np.ndarray, TJ: np.ndarray, TE: np.ndarray, ul: int,
                   ur: int, uk: int, m: int, lmean: float, fy: float, out: np.ndarray,
                   j: int) -> None:  # pragma: no cover - numba
    """Window sums of the two integer taps ``a`` and ``b = a + 1`` of R and Rx against the left window less
    its mean ``lz`` into ``out[j]``: Σ Ra, Σ Rb, Σ Ja, Σ Jb, Σ lz·Ja, Σ lz·Jb, Σ Ra·Ja, Σ Ra·Jb, Σ Rb·Ja,
    Σ Rb·Jb, Σ Ja², Σ Ja·Jb, Σ Jb², Σ Ra², Σ Ra·Rb, Σ Rb², Σ lz·Ra, Σ lz·Rb, from column-major float32 strips
    (:func:`_strip`): the left window is ``TL[ul:ul + m]``, tap a of R ``TR[ur:ur + m] + fy·TD[ur:ur + m]``
    (linear between two rows), Rx alike from ``TJ``, ``TE``, and tap b the same ``uk`` further on. Flat loops
    over the window, so that they vectorise; unsigned offsets (numba then skips its test for negative
    indices, which keeps the loads contiguous).

    In float32 arithmetic (twice the SIMD lanes of float64), the left window less its mean and R's taps less
    R's value at the window's centre: every sum the kernel uses enters through a difference that does not
    change when R moves by a constant (``Σ R·J − Σ R·Σ J / m``, ``Σ R² − (Σ R)² / m``, ``Σ lz·R`` with
    ``Σ lz = 0``), so the terms stay of the size of the texture instead of the grey level (100–250), and
    the float32 rounding with them (≈ 1e-7 of the texture's terms, not of the brightness's)."""
    c = np.float32(lmean)
    # the left window less its exact mean: Σ lz = 0 is what lets the kernel leave R's mean out of Σ lz·R
    # and Σ lz·J, and float32(lmean) is up to 1e-5 grey levels off it (times Σ R of the window)
    e = np.float32(lmean - np.float64(c))
    f = np.float32(fy)
    ua = np.uint64(ur)
    ub = np.uint64(ur + uk)
    u0 = np.uint64(ul)
    # R less its own value at the window's centre (tap a): the two views' brightness may differ by several
    # grey levels, and R less the left mean would keep that offset in every term of Σ R²
    cr = TR[ua + np.uint64(m // 2)]
    # three loops of at most 7 sums each: one loop of 18 sums spills its accumulators to the stack (16 ymm
    # registers on AVX2); the window's strips are in L1, so reading them three times costs less
    sja = sjb = slja = sljb = sjaja = sjajb = sjbjb = np.float32(0.0)
    for q in range(m):
        uq = np.uint64(q)
        ja = TJ[ua + uq] + f * TE[ua + uq]
        jb = TJ[ub + uq] + f * TE[ub + uq]
        z = (TL[u0 + uq] - c) - e
        sja += ja
        sjb += jb
        slja += z * ja
        sljb += z * jb
        sjaja += ja * ja
        sjajb += ja * jb
        sjbjb += jb * jb
    sra = srb = srara = srarb = srbrb = slra = slrb = np.float32(0.0)
    for q in range(m):
        uq = np.uint64(q)
        a = TR[ua + uq] + f * TD[ua + uq] - cr
        b = TR[ub + uq] + f * TD[ub + uq] - cr
        z = (TL[u0 + uq] - c) - e
        sra += a
        srb += b
        srara += a * a
        srarb += a * b
        srbrb += b * b
        slra += z * a
        slrb += z * b
    sraja = srajb = srbja = srbjb = np.float32(0.0)
    for q in range(m):
        uq = np.uint64(q)
        a = TR[ua + uq] + f * TD[ua + uq] - cr
        b = TR[ub + uq] + f * TD[ub + uq] - cr
        ja = TJ[ua + uq] + f * TE[ua + uq]
        jb = TJ[ub + uq] + f * TE[ub + uq]
        sraja += a * ja
        srajb += a * jb
        srbja += b * ja
        srbjb += b * jb
    o = out[j]
    o[0] = sra
    o[1] = srb
    o[2] = sja
    o[3] = sjb
    o[4] = slja
    o[5] = sljb
    o[6] = sraja
    o[7] = srajb
    o[8] = srbja
    o[9] = srbjb
    o[10] = sjaja
    o[11] = sjajb
    o[12] = sjbjb
    o[13] = srara
    o[14] = srarb
    o[15] = srbrb
    o[16] = slra
    o[17] = slrb


@njit(cache=True, parallel=True, fastmath=True, nogil=True)
def _refine_kernel(L: np.ndarray, R: np.ndarray, Rx: np.ndarray, ys: np.ndarray, xs: np.ndarray, d0: np.ndarray,
                   oys: np.ndarray, fys: np.ndarray, radius: int, iterations: int, max_shift: float,
                   min_texture: float, threads: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover
    """Gauss–Newton per pixel (module docstring); window sums instead of stored windows.

    With zero-mean windows ``Lz``, ``Rz = R - mean R``, ``Jz = J - mean J`` over ``m`` pixels:
    ``Σ r·Jz = Σ Lz·J - (Σ R·J - m·mean R·mean J)`` and ``Σ Jz² = Σ J² - m·mean J²`` (``Σ Lz = 0``).
    Every window pixel is shifted by the same d, so its samples are ``R = fb·Ra + fa·Rb`` (and J alike)
    with one pair of integer taps and one fraction for the whole window: each sum is a polynomial in
    ``fa`` whose coefficients are sums over the integer taps (:func:`_window_sums32`). These are computed
    once per integer position ``b0`` the iterations visit (mostly one or two) instead of once per iteration.
    The right window's rows are moved by the pixel's row offset ``oys[i] + fys[i]`` (integer part, fraction
    in [0, 1)), sampled linearly between two rows.

    The pixels (``ys`` ascending) are taken a row and an integer row offset at a time: the left window's rows
    and the right window's rows with their differences to the next row are copied once into column-major
    strips (:func:`_strip`) that every pixel of the row reads its windows from, and each Gauss–Newton
    iteration runs over all these pixels before the next (their updates are independent, so the processor
    overlaps them instead of waiting on one pixel's chain of dependent steps).
    Returns the refined disparities, the final ZNCC and whether the pixel may keep its refinement.
    """
    n = ys.size
    h, w = R.shape
    k = 2 * radius + 1
    m = k * k
    d_out = np.empty(n, dtype=np.float32)
    zncc = np.empty(n, dtype=np.float32)
    keep = np.zeros(n, dtype=np.bool_)
    starts = np.searchsorted(ys, np.arange(h + 1))
    reach = int(np.ceil(max_shift)) + 1
    # rows in turn over the threads (row y on thread y % nt): the rows' pixels differ in number, and
    # prange's static blocks of consecutive rows leave a thread idle (the later passes' pixels cluster); ``threads``
    # given (numba.get_num_threads() inside the kernel would keep it out of the cache)
    nt = max(1, min(threads, h))
    for t in prange(nt):
        for y in range(t, h, nt):
            i0, i1 = starts[y], starts[y + 1]
            if i0 == i1:
                continue
            TL = np.empty(w * k, dtype=np.float32)
            TR = np.empty(w * k, dtype=np.float32)
            TD = np.empty(w * k, dtype=np.float32)
            TJ = np.empty(w * k, dtype=np.float32)
            TE = np.empty(w * k, dtype=np.float32)
            S = np.empty((i1 - i0, 18), dtype=np.float64)
            lms = np.empty(i1 - i0, dtype=np.float64)
            slls = np.empty(i1 - i0, dtype=np.float64)
            ds = np.empty(i1 - i0, dtype=np.float64)
            cached = np.empty(i1 - i0, dtype=np.int64)
            textured = np.ones(i1 - i0, dtype=np.bool_)
            sel = np.empty(i1 - i0, dtype=np.int64)
            lo, hi = w, 0
            oy_lo, oy_hi = oys[i0], oys[i0]
            for i in range(i0, i1):
                lo = min(lo, xs[i])
                hi = max(hi, xs[i])
                oy_lo = min(oy_lo, oys[i])
                oy_hi = max(oy_hi, oys[i])
            _strip(L, TL, None, y - radius, k, max(lo - radius, 0), min(hi + radius + 1, w), 0)
            for oy in range(oy_lo, oy_hi + 1):
                # this offset's pixels, and the columns their taps may reach
                npx = 0
                c0, c1 = w, 0
                for i in range(i0, i1):
                    if oys[i] == oy:
                        sel[npx] = i
                        npx += 1
                        b = int(np.floor(xs[i] - float(d0[y, xs[i]])))
                        c0 = min(c0, b - reach - radius)
                        c1 = max(c1, b + reach + radius + 2)
                if npx == 0:
                    continue
                _strip(R, TR, TD, y + oy - radius, k, max(c0, 0), min(c1, w), 0)
                _strip(Rx, TJ, TE, y + oy - radius, k, max(c0, 0), min(c1, w), 0)
                for j in range(npx):
                    i = sel[j]
                    x = xs[i]
                    ul = (x - radius) * k
                    sl = 0.0
                    sl2 = 0.0
                    for q in range(m):
                        lv = np.float64(TL[np.uint64(ul) + np.uint64(q)])
                        sl += lv
                        sl2 += lv * lv
                    lmean = sl / m
                    lms[j] = lmean
                    slls[j] = max(sl2 - sl * lmean, 0.0)
                    d = float(d0[y, x])
                    ds[j] = d
                    b0 = int(np.floor(x - d))
                    cached[j] = -1
                    if b0 - radius >= 0 and b0 + radius + 1 <= w - 1:
                        _window_sums32(TL, TR, TD, TJ, TE, ul, (b0 - radius) * k, k, m, lmean, fys[i], S, j)
                        cached[j] = b0
                for _ in range(iterations):
                    for j in range(npx):
                        i = sel[j]
                        x = xs[i]
                        fy = fys[i]
                        d = ds[j]
                        init = float(d0[y, x])
                        xf0 = x - d
                        b0 = int(np.floor(xf0))
                        fa = xf0 - b0
                        fb = 1.0 - fa
                        if b0 - radius >= 0 and b0 + radius + 1 <= w - 1:
                            if b0 != cached[j]:
                                _window_sums32(TL, TR, TD, TJ, TE, (x - radius) * k, (b0 - radius) * k, k, m, lms[j],
                                               fy, S, j)
                                cached[j] = b0
                            Sj = S[j]
                            sr = fb * Sj[0] + fa * Sj[1]
                            sj = fb * Sj[2] + fa * Sj[3]
                            slj = fb * Sj[4] + fa * Sj[5]
                            srj = fb * fb * Sj[6] + fb * fa * (Sj[7] + Sj[8]) + fa * fa * Sj[9]
                            sjj = fb * fb * Sj[10] + 2.0 * fb * fa * Sj[11] + fa * fa * Sj[12]
                        else:
                            # the window leaves the row: the edge-replicating sampler, pixel by pixel
                            lmean = lms[j]
                            sr = sj = slj = srj = sjj = 0.0
                            for dy in range(-radius, radius + 1):
                                for dx in range(-radius, radius + 1):
                                    xf = x + dx - d
                                    rv = _sample(R, y + dy + oy, xf, fy)
                                    jv = _sample(Rx, y + dy + oy, xf, fy)
                                    lz = L[y + dy, x + dx] - lmean
                                    sr += rv
                                    sj += jv
                                    slj += lz * jv
                                    srj += rv * jv
                                    sjj += jv * jv
                        num = slj - (srj - sr * sj / m)
                        den = sjj - sj * sj / m
                        tex = den > min_texture * m
                        textured[j] = tex
                        step = num / den if tex else 0.0
                        step = min(max(step, -0.5), 0.5)
                        ds[j] = min(max(d - step, init - max_shift), init + max_shift)
                for j in range(npx):
                    i = sel[j]
                    x = xs[i]
                    fy = fys[i]
                    d = ds[j]
                    init = float(d0[y, x])
                    lmean = lms[j]
                    xf0 = x - d
                    b0 = int(np.floor(xf0))
                    fa = xf0 - b0
                    fb = 1.0 - fa
                    if b0 - radius >= 0 and b0 + radius + 1 <= w - 1:
                        if b0 != cached[j]:
                            _window_sums32(TL, TR, TD, TJ, TE, (x - radius) * k, (b0 - radius) * k, k, m, lmean, fy,
                                           S, j)
                        Sj = S[j]
                        sr = fb * Sj[0] + fa * Sj[1]
                        srr = fb * fb * Sj[13] + 2.0 * fb * fa * Sj[14] + fa * fa * Sj[15]
                        slr = fb * Sj[16] + fa * Sj[17]
                    else:
                        sr = srr = slr = 0.0
                        for dy in range(-radius, radius + 1):
                            for dx in range(-radius, radius + 1):
                                rv = _sample(R, y + dy + oy, x + dx - d, fy)
                                lz = L[y + dy, x + dx] - lmean
                                sr += rv
                                srr += rv * rv
                                slr += lz * rv
                    var_r = srr - sr * sr / m
                    den = np.sqrt(slls[j] * var_r)
                    zncc[i] = slr / den if den > 0.0 else np.nan
                    d_out[i] = d
                    keep[i] = textured[j] and np.isfinite(d) and abs(d - init) < max_shift - 1e-3
    return d_out, zncc, keep


@njit(cache=True, inline="always")
def _weight_strip(V: np.ndarray, T: np.ndarray, y0: int, k: int, c0: int, c1: int, pad: int, near: int,
                  near_min: int, far: int, far_min: int) -> None:  # pragma: no cover - numba
    """Which window pixels a view holds, column-major as :func:`_strip` (1.0 or 0.0): at row ``y0 + j`` and
    column ``c``, ``V`` at the row ``near`` rows on is at least ``near_min`` and, with ``far_min`` > 0, ``V``
    at the row ``far`` rows on at least ``far_min``, each row inside the image."""
    h = V.shape[0]
    for c in range(c0, c1):
        o = (c + pad) * k
        for j in range(k):
            yn = y0 + j + near
            ok = 0 <= yn < h and V[min(max(yn, 0), h - 1), c] >= near_min
            if far_min > 0:
                yf = y0 + j + far
                ok = ok and 0 <= yf < h and V[min(max(yf, 0), h - 1), c] >= far_min
            T[np.uint64(o + j)] = 1.0 if ok else 0.0


@njit(cache=True, inline="always")
def _masked_window_sums(TL: np.ndarray, WL: np.ndarray, TR: np.ndarray, TD: np.ndarray, TJ: np.ndarray,
                        TE: np.ndarray, WR: np.ndarray, ul: int, ur: int, uk: int, m: int, fy: float,
                        out: np.ndarray) -> None:  # pragma: no cover - numba
    """The sums of :func:`_window_sums32` (in float64) over the window pixels that count, on the raw left
    window, into ``out``: m, Σ L, Σ L², then Σ Ra, Σ Rb, Σ Ja, Σ Jb, Σ L·Ja, Σ L·Jb, Σ Ra·Ja, Σ Ra·Jb,
    Σ Rb·Ja, Σ Rb·Jb, Σ Ja², Σ Ja·Jb, Σ Jb², Σ Ra², Σ Ra·Rb, Σ Rb², Σ L·Ra, Σ L·Rb. A window pixel counts
    when the left view holds it (``WL``) and the right view both its taps (``WR`` at tap a and at tap b,
    ``uk`` further on): each term is weighted by that (1.0 or 0.0); the strips' columns off the image hold
    0 in ``WL`` / ``WR`` and finite values in the others."""
    sm = sl = sll = 0.0
    sra = srb = sja = sjb = slja = sljb = 0.0
    sraja = srajb = srbja = srbjb = sjaja = sjajb = sjbjb = 0.0
    srara = srarb = srbrb = slra = slrb = 0.0
    ua = np.uint64(ur)
    ub = np.uint64(ur + uk)
    u0 = np.uint64(ul)
    for q in range(m):
        uq = np.uint64(q)
        a = TR[ua + uq] + fy * TD[ua + uq]
        b = TR[ub + uq] + fy * TD[ub + uq]
        ja = TJ[ua + uq] + fy * TE[ua + uq]
        jb = TJ[ub + uq] + fy * TE[ub + uq]
        lv = TL[u0 + uq]
        v = WL[u0 + uq] * WR[ua + uq] * WR[ub + uq]
        wa = v * a
        wb = v * b
        wja = v * ja
        wjb = v * jb
        wl = v * lv
        sm += v
        sl += wl
        sll += wl * lv
        sra += wa
        srb += wb
        sja += wja
        sjb += wjb
        slja += wl * ja
        sljb += wl * jb
        sraja += wa * ja
        srajb += wa * jb
        srbja += wb * ja
        srbjb += wb * jb
        sjaja += wja * ja
        sjajb += wja * jb
        sjbjb += wjb * jb
        srara += wa * a
        srarb += wa * b
        srbrb += wb * b
        slra += wl * a
        slrb += wl * b
    out[0] = sm
    out[1] = sl
    out[2] = sll
    out[3] = sra
    out[4] = srb
    out[5] = sja
    out[6] = sjb
    out[7] = slja
    out[8] = sljb
    out[9] = sraja
    out[10] = srajb
    out[11] = srbja
    out[12] = srbjb
    out[13] = sjaja
    out[14] = sjajb
    out[15] = sjbjb
    out[16] = srara
    out[17] = srarb
    out[18] = srbrb
    out[19] = slra
    out[20] = slrb


@njit(cache=True, inline="always")
def _cut_sums(TL: np.ndarray, WL: np.ndarray, TR: np.ndarray, TD: np.ndarray, TJ: np.ndarray, TE: np.ndarray,
              WR: np.ndarray, x: int, b0: int, radius: int, pad: int, w: int, fy: float,
              S: np.ndarray) -> None:  # pragma: no cover - numba
    """:func:`_masked_window_sums` of the window at ``x`` with taps from ``b0`` into ``S`` (strips ``pad``
    columns on); taps whose columns all lie past the strips' padding (so off the image): all 0."""
    k = 2 * radius + 1
    if b0 - radius < -pad or b0 + radius + 1 >= w + pad:
        S[:] = 0.0
    else:
        _masked_window_sums(TL, WL, TR, TD, TJ, TE, WR, (x - radius + pad) * k, (b0 - radius + pad) * k, k, k * k,
                            fy, S)


@njit(cache=True, parallel=True, fastmath=True, nogil=True)
def _refine_cut_kernel(L: np.ndarray, R: np.ndarray, Rx: np.ndarray, VL: np.ndarray, VR: np.ndarray,
                       ys: np.ndarray, xs: np.ndarray, d0: np.ndarray, oys: np.ndarray, fys: np.ndarray,
                       radius: int, iterations: int, max_shift: float, min_texture: float,
                       min_pixels: int, threads: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover
    """Gauss–Newton of the pixels whose windows are cut by an edge: the sums run over the window's pixels
    that lie in both views (re-selected at each tap position, since the right taps move with d); the means,
    the texture test and the ZNCC are those of these pixels. Fewer than ``min_pixels`` of them: not
    refined. The sums come from :func:`_masked_window_sums`, once per integer tap position visited (as in
    :func:`_refine_kernel`).

    A window pixel counts when it lies inside the image and the left view (``VL`` ≠ 0) and both its right taps
    inside the right view: ``VR`` is 2 inside it, 1 on its outermost pixels, 0 outside; of the rows ``yr`` and
    ``yr + 1`` (weight ``fy`` on ``yr + 1``) the nearer one must be inside (2), the other one, weighted less
    than half, in the view (≥ 1; not read when ``fy`` is 0). With the taps at ``b0 + dx`` the set is the same
    for every fraction. The pixels (``ys`` ascending, ``xs`` ascending along a row) are taken a run of nearby
    pixels of a row at a time with strips as in :func:`_refine_kernel` over the run's columns, ``k + 1``
    columns of padding on each side (the windows may leave the image), and the right view's weights per
    integer row offset and kind of fraction (0, below one half, above).
    """
    n = ys.size
    h, w = R.shape
    k = 2 * radius + 1
    pad = k + 1
    wp = w + 2 * pad
    d_out = np.empty(n, dtype=np.float32)
    zncc = np.empty(n, dtype=np.float32)
    keep = np.zeros(n, dtype=np.bool_)
    starts = np.searchsorted(ys, np.arange(h + 1))
    reach = int(np.ceil(max_shift)) + 1
    gap = 2 * (k + reach)
    # rows in turn over the threads, as in _refine_kernel
    nt = max(1, min(threads, h))
    for t in prange(nt):
        for y in range(t, h, nt):
            i0, i1 = starts[y], starts[y + 1]
            if i0 == i1:
                continue
            TL = np.empty(wp * k, dtype=np.float64)
            WL = np.empty(wp * k, dtype=np.float64)
            TR = np.empty(wp * k, dtype=np.float64)
            TD = np.empty(wp * k, dtype=np.float64)
            TJ = np.empty(wp * k, dtype=np.float64)
            TE = np.empty(wp * k, dtype=np.float64)
            WR = np.empty(wp * k, dtype=np.float64)
            # the padding: finite values, weight 0
            for q in range(pad * k):
                TL[q] = WL[q] = TR[q] = TD[q] = TJ[q] = TE[q] = WR[q] = 0.0
            for q in range((w + pad) * k, wp * k):
                TL[q] = WL[q] = TR[q] = TD[q] = TJ[q] = TE[q] = WR[q] = 0.0
            S = np.empty(21, dtype=np.float64)
            g0 = i0
            while g0 < i1:
                # a run of the row's pixels whose windows lie close together: the strips are built over its
                # columns only (the cut windows of a row are few, at the views' edges)
                g1 = g0 + 1
                while g1 < i1 and xs[g1] - xs[g1 - 1] <= gap:
                    g1 += 1
                lo, hi = w, 0
                oy_lo, oy_hi = oys[g0], oys[g0]
                for i in range(g0, g1):
                    lo = min(lo, xs[i])
                    hi = max(hi, xs[i])
                    oy_lo = min(oy_lo, oys[i])
                    oy_hi = max(oy_hi, oys[i])
                cl0, cl1 = max(lo - radius, 0), min(hi + radius + 1, w)
                _strip(L, TL, None, y - radius, k, cl0, cl1, pad)
                _weight_strip(VL, WL, y - radius, k, cl0, cl1, pad, 0, 1, 0, 0)
                for oy in range(oy_lo, oy_hi + 1):
                    c0, c1 = w, 0
                    for i in range(g0, g1):
                        if oys[i] == oy:
                            b = int(np.floor(xs[i] - float(d0[y, xs[i]])))
                            c0 = min(c0, b - reach - radius)
                            c1 = max(c1, b + reach + radius + 2)
                    c0, c1 = max(c0, 0), min(c1, w)
                    if c1 <= c0:
                        c0 = c1 = 0  # every tap off the image: weights 0 from the padding
                    _strip(R, TR, TD, y + oy - radius, k, c0, c1, pad)
                    _strip(Rx, TJ, TE, y + oy - radius, k, c0, c1, pad)
                    for kind in range(3):
                        # the rows the right view must hold: fy 0 reads one, below one half the nearer is the first
                        near = 1 if kind == 2 else 0
                        _weight_strip(VR, WR, y + oy - radius, k, c0, c1, pad, near, 2, 1 - near, 0 if kind == 0 else 1)
                        for i in range(g0, g1):
                            fy = fys[i]
                            if oys[i] != oy or (0 if fy == 0.0 else 1 if fy < 0.5 else 2) != kind:
                                continue
                            x = xs[i]
                            init = float(d0[y, x])
                            d = init
                            textured = True
                            cached = int(np.floor(x - d))
                            _cut_sums(TL, WL, TR, TD, TJ, TE, WR, x, cached, radius, pad, w, fy, S)
                            refined = True
                            for _ in range(iterations):
                                xf0 = x - d
                                b0 = int(np.floor(xf0))
                                if b0 != cached:
                                    _cut_sums(TL, WL, TR, TD, TJ, TE, WR, x, b0, radius, pad, w, fy, S)
                                    cached = b0
                                m = S[0]
                                if m < min_pixels:
                                    refined = False
                                    break
                                fa = xf0 - b0
                                fb = 1.0 - fa
                                sl = S[1]
                                sr = fb * S[3] + fa * S[4]
                                sj = fb * S[5] + fa * S[6]
                                slj = fb * S[7] + fa * S[8]
                                srj = fb * fb * S[9] + fb * fa * (S[10] + S[11]) + fa * fa * S[12]
                                sjj = fb * fb * S[13] + 2.0 * fb * fa * S[14] + fa * fa * S[15]
                                num = (slj - sl * sj / m) - (srj - sr * sj / m)
                                den = sjj - sj * sj / m
                                textured = den > min_texture * m
                                step = num / den if textured else 0.0
                                step = min(max(step, -0.5), 0.5)
                                d = min(max(d - step, init - max_shift), init + max_shift)
                            z = np.nan
                            kept = False
                            if refined:
                                xf0 = x - d
                                b0 = int(np.floor(xf0))
                                if b0 != cached:
                                    _cut_sums(TL, WL, TR, TD, TJ, TE, WR, x, b0, radius, pad, w, fy, S)
                                m = S[0]
                                if m >= min_pixels:
                                    fa = xf0 - b0
                                    fb = 1.0 - fa
                                    sl = S[1]
                                    sr = fb * S[3] + fa * S[4]
                                    srr = fb * fb * S[16] + 2.0 * fb * fa * S[17] + fa * fa * S[18]
                                    slr = fb * S[19] + fa * S[20]
                                    den = np.sqrt(max(S[2] - sl * sl / m, 0.0) * max(srr - sr * sr / m, 0.0))
                                    z = (slr - sl * sr / m) / den if den > 0.0 else np.nan
                                    kept = textured and np.isfinite(d) and abs(d - init) < max_shift - 1e-3
                            d_out[i] = d
                            zncc[i] = z
                            keep[i] = kept
                g0 = g1
    return d_out, zncc, keep


def _inner(valid: np.ndarray) -> np.ndarray:
    """``valid`` without its outermost pixels (those next to an invalid one; the image's edge does not count)."""
    return cv2.erode(valid.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0


@njit(cache=True, inline="always")
def _row_split(v: float) -> tuple[int, float]:  # pragma: no cover - numba
    """A row offset (float64) → integer part and fraction in [0, 1); 0 where not finite."""
    if not np.isfinite(v):
        v = 0.0
    b = np.floor(v)
    return int(b), v - b


@njit(cache=True)
def _select_pixels(d0: np.ndarray, static: np.ndarray, vl: np.ndarray, whole_r: np.ndarray, offs: np.ndarray,
                   has_offs: bool, cut_mode: bool) -> tuple[np.ndarray, ...]:  # pragma: no cover - numba
    """The pixels :func:`refine_disparity` refines, in row-major order, with their row offsets split
    (:func:`_row_split`): those whose whole window is refined (finite, ``static``: inside the image and off
    the left view's edge, and with ``cut_mode`` whose right window stays in ``whole_r`` at the matcher's
    disparity on both rows it reads) and, with ``cut_mode``, the cut ones (finite, in ``vl``, not whole).
    Returns ys, xs, oy, fy of the whole ones, then of the cut ones."""
    h, w = d0.shape
    kind = np.zeros((h, w), dtype=np.uint8)
    n_whole = 0
    n_cut = 0
    for y in range(h):
        for x in range(w):
            v = d0[y, x]
            if not np.isfinite(v):
                continue
            whole = static[y, x]
            if whole and cut_mode:
                oy, fy = _row_split(float(offs[y, x]) if has_offs else 0.0)
                xr = np.rint(float(x) - float(v))
                yr0 = y + oy
                yr1 = yr0 + (1 if fy > 0.0 else 0)
                if 0.0 <= xr < w and yr0 >= 0 and yr1 < h:
                    xi = int(xr)
                    whole = whole_r[yr0, xi] and whole_r[yr1, xi]
                else:
                    whole = False
            if whole:
                kind[y, x] = 1
                n_whole += 1
            elif cut_mode and vl[y, x]:
                kind[y, x] = 2
                n_cut += 1
    ys = np.empty(n_whole, dtype=np.int64)
    xs = np.empty(n_whole, dtype=np.int64)
    oys = np.zeros(n_whole, dtype=np.int64)
    fys = np.zeros(n_whole, dtype=np.float64)
    cys = np.empty(n_cut, dtype=np.int64)
    cxs = np.empty(n_cut, dtype=np.int64)
    coys = np.zeros(n_cut, dtype=np.int64)
    cfys = np.zeros(n_cut, dtype=np.float64)
    i = 0
    j = 0
    for y in range(h):
        for x in range(w):
            k = kind[y, x]
            if k == 0:
                continue
            oy, fy = _row_split(float(offs[y, x]) if has_offs else 0.0)
            if k == 1:
                ys[i] = y
                xs[i] = x
                oys[i] = oy
                fys[i] = fy
                i += 1
            else:
                cys[j] = y
                cxs[j] = x
                coys[j] = oy
                cfys[j] = fy
                j += 1
    return ys, xs, oys, fys, cys, cxs, coys, cfys


@njit(cache=True)
def _scatter(out: np.ndarray, conf: np.ndarray, ys: np.ndarray, xs: np.ndarray, d: np.ndarray, zncc: np.ndarray,
             keep: np.ndarray, allowed: np.ndarray, check: bool) -> None:  # pragma: no cover - numba
    """Write the kept refinements into ``out`` and ``conf``; with ``check`` only those whose match
    ``rint(x − d)`` lies inside the row and in ``allowed``."""
    w = out.shape[1]
    for i in range(ys.size):
        if not keep[i]:
            continue
        if check:
            xr = np.rint(float(xs[i]) - float(d[i]))
            if not (0.0 <= xr < w) or not allowed[ys[i], int(xr)]:
                continue
        out[ys[i], xs[i]] = d[i]
        conf[ys[i], xs[i]] = zncc[i]


def _gray(img: np.ndarray) -> np.ndarray:
    a = np.asarray(img)
    if a.ndim == 3:
        a = cv2.cvtColor(a.astype(np.float32), cv2.COLOR_RGB2GRAY)
    return np.ascontiguousarray(a, dtype=np.float32)


def _low_pass(img: np.ndarray, valid: np.ndarray | None, sigma: float) -> np.ndarray:
    """Gaussian low-pass of a grey view along its rows inside ``valid`` (what lies beyond it does not bleed
    in; the pixels whose kernel it cuts are left as they are, those just outside get the blur of the inside).

    Sampling R between pixels (linear interpolation) damps its fine texture by an amount that depends on
    the sub-pixel phase, which pulls the estimate towards some phases ("pixel locking"); damping that
    texture in both views beforehand leaves the interpolation less to damp. Along rows only: the
    estimate is horizontal, and a vertical blur would mix rows across horizontal depth edges."""
    r = int(np.ceil(3.0 * sigma))
    kx = cv2.getGaussianKernel(2 * r + 1, sigma, cv2.CV_32F)
    ky = np.ones((1, 1), dtype=np.float32)

    def blur(a: np.ndarray) -> np.ndarray:
        return np.asarray(cv2.sepFilter2D(a, cv2.CV_32F, kx, ky, borderType=cv2.BORDER_REPLICATE))

    if valid is None:
        return blur(img)
    v = valid.astype(np.float32)
    num = blur(img * v)
    den = blur(v)
    # a kernel cut by the region's edge would shift the texture (its weights are one-sided): those pixels
    # stay as they are; the pixels just outside get the blur from the inside (the gradient at the edge
    # reads them, and the fill or a blended rim would otherwise)
    return _low_pass_select(img, num, den, valid)


_CUT_BELOW = np.float32(1.0 - 1e-3)
_DEN_ABOVE = np.float32(1e-3)
_DEN_FLOOR = np.float32(1e-6)


@njit(cache=True)
def _low_pass_select(img: np.ndarray, num: np.ndarray, den: np.ndarray,
                     valid: np.ndarray) -> np.ndarray:  # pragma: no cover - numba
    """:func:`_low_pass`' result from the blurred ``img · valid`` (``num``) and ``valid`` (``den``): the
    image where the kernel is cut inside ``valid`` or ``den`` is (almost) 0, else ``num / den`` (float32
    arithmetic and float32 thresholds, as numpy's on these arrays)."""
    h, w = img.shape
    out = np.empty((h, w), dtype=np.float32)
    for y in range(h):
        for x in range(w):
            dd = den[y, x]
            if (valid[y, x] and dd < _CUT_BELOW) or not dd > _DEN_ABOVE:
                out[y, x] = img[y, x]
            else:
                out[y, x] = num[y, x] / max(dd, _DEN_FLOOR)
    return out


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
    min_pixels: int | None = None,
    row_offset: np.ndarray | None = None,
    prefilter: float | None = None,
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
        Valid regions of the rectified images.
    min_pixels : int or None
        None: windows that leave the image or touch an invalid pixel (left, or right around the match) are
        not refined. An int: such a window is cut to its pixels inside the image and both views (the right
        ones at the current disparity) and refined on them if there are at least ``min_pixels``; the means,
        the texture test and the confidence are then those of the cut window. Windows inside everything
        are refined the same way either way.
    row_offset : (H, W) float array, optional
        Row of the match in ``right`` less the row of the left pixel (the epipolar curve of views that are
        not exact pinholes, :meth:`~prismstereo.rectify.epipolar.EpipolarTable.row_offset`): the right window of
        each pixel is sampled on the rows moved by its offset, linearly between two rows. None: on the
        left pixel's rows (offset 0 everywhere, the same result).
    prefilter : float or None
        Standard deviation (px) of a Gaussian low-pass along the rows of both views (each within its valid
        region less its outermost pixels) before refining: less bias from the linear interpolation on
        fine texture; None or 0: none.

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
    d0 = np.ascontiguousarray(disparity, dtype=np.float32)
    h, w = d0.shape
    out = d0.copy()
    conf = np.full(d0.shape, np.nan, dtype=np.float32)
    k = 2 * radius + 1
    offs = None if row_offset is None else np.ascontiguousarray(row_offset)
    vl = np.ones((h, w), dtype=bool) if valid_left is None else np.asarray(valid_left, dtype=bool)
    vr = np.ones((h, w), dtype=bool) if valid_right is None else np.asarray(valid_right, dtype=bool)
    # window content: with cut windows, not the outermost pixel of a view's valid region either (its
    # intensity is off: the remap blends it with what lies beyond the region)
    vl_in, vr_in = (vl, vr) if min_pixels is None else (_inner(vl), _inner(vr))
    if prefilter is not None and prefilter > 0.0:
        # over the region without its outermost ring too, which would spread into the windows
        # (with cut windows that is vl_in / vr_in already)
        L = _low_pass(L, None if valid_left is None else vl_in if min_pixels is not None else _inner(vl),
                      float(prefilter))
        R = _low_pass(R, None if valid_right is None else vr_in if min_pixels is not None else _inner(vr),
                      float(prefilter))
    # the pixels whose whole window may be refined: off the left view's edge, the window inside the image
    static = np.zeros((h, w), dtype=bool)
    static[radius:h - radius, radius:w - radius] = True
    if valid_left is not None:
        static &= cv2.dilate((~vl_in).astype(np.uint8), np.ones((k, k), np.uint8)) == 0
    cut_mode = min_pixels is not None
    whole_r = np.zeros((1, 1), dtype=bool)
    if cut_mode:
        # the whole window must stay in the right view for every disparity the update may reach (taps
        # included), else it is a cut window
        reach = radius + int(np.ceil(max_shift)) + 2
        whole_r = cv2.erode(vr_in.astype(np.uint8), np.ones((k, 2 * reach + 1), np.uint8),
                            borderType=cv2.BORDER_CONSTANT, borderValue=0) > 0
    ys, xs, oy, fy, cys, cxs, coy, cfy = _select_pixels(
        d0, static, vl, whole_r, np.zeros((1, 1), dtype=np.float32) if offs is None else offs, offs is not None,
        cut_mode)
    Rx = cv2.Sobel(R, cv2.CV_32F, 1, 0, ksize=3, scale=1.0 / 8.0)
    if ys.size:
        d, zncc, keep = _refine_kernel(L, R, Rx, ys, xs, d0, oy, fy, int(radius), int(iterations),
                                       float(max_shift), float(min_texture), numba.get_num_threads())
        check = valid_right is not None and min_pixels is None
        # the match must not land next to the right view's edge (its window would read beyond it)
        allowed = (cv2.dilate((~vr).astype(np.uint8), np.ones((k, k), np.uint8)) == 0 if check
                   else np.zeros((1, 1), dtype=bool))
        _scatter(out, conf, ys, xs, d, zncc, keep, allowed, check)
    if cys.size and min_pixels is not None:
        vr_levels = vr_in.astype(np.uint8) + vr.astype(np.uint8)  # 2 inside, 1 outermost pixels, 0 outside
        d, zncc, keep = _refine_cut_kernel(L, R, Rx, vl_in.astype(np.uint8), vr_levels, cys, cxs, d0, coy, cfy,
                                           int(radius), int(iterations), float(max_shift), float(min_texture),
                                           int(min_pixels), numba.get_num_threads())
        # the match itself must stay inside the right view
        _scatter(out, conf, cys, cxs, d, zncc, keep, vr, True)
    return out, conf


#: the refinement's numba kernels, whose cached code tells whether this environment compiled the depth
#: pipeline already (``prismstereo depth``'s first run)
REFINE_KERNELS = (_refine_kernel, _refine_cut_kernel)
