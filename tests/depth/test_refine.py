"""Sub-pixel refinement along the epipolar curve: the right window on the rows where the match lies."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from prismstereo.depth.confidence import confident_matches
from prismstereo.depth.refine import refine_disparity


def _diagonal_pair(d: float, dy: float, *, h: int = 60, w: int = 140) -> tuple[np.ndarray, np.ndarray]:
    """Two diagonal gratings, and the same texture whose match of left (x, y) is (x − d, y + dy) (both
    evaluated exactly)."""

    def texture(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return (128 + 60 * np.sin(0.45 * (x + y)) + 20 * np.sin(0.23 * (x - 2.0 * y))).astype(np.float32)

    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    return texture(xx, yy), texture(xx + d, yy - dy)


def test_row_offset_removes_the_bias_a_vertical_offset_gives_a_diagonal_texture() -> None:
    d, dy = 9.3, 0.3
    left, right = _diagonal_pair(d, dy)
    init = np.full(left.shape, 9.0, dtype=np.float32)
    inner = (slice(10, -10), slice(25, -25))
    same_row, _ = refine_disparity(left, right, init, radius=5)
    rows = np.full(left.shape, dy)
    along, conf = refine_disparity(left, right, init, radius=5, row_offset=rows)
    # on stripes at 45° a row offset of dy reads as a disparity offset of about dy
    assert abs(float(np.median(same_row[inner])) - d) > 0.15
    assert abs(float(np.median(along[inner])) - d) < 0.02
    assert np.nanmedian(conf[inner]) > 0.98
    # a zero offset is the same as none
    zero, _ = refine_disparity(left, right, init, radius=5, row_offset=np.zeros(left.shape))
    assert np.array_equal(zero, same_row)


def test_the_left_right_check_reads_the_right_view_on_its_own_curve() -> None:
    """With the epipolar offsets the right view's refinement (mirrored) agrees with the left's, so the
    sub-pixel check keeps the matches; on the left rows alone it does not see the same disparity."""

    class _Constant:
        def __init__(self, dy: float) -> None:
            self.dy = dy

        def row_offset(self, ys, xs, d):  # type: ignore[no-untyped-def]
            return np.where(np.isfinite(d), self.dy, np.nan)

        def row_offset_map(self, disparity):  # type: ignore[no-untyped-def]
            return np.where(np.isfinite(disparity), np.float32(self.dy), np.float32(np.nan))

    d, dy = 9.3, 0.3
    left, right = _diagonal_pair(d, dy)
    init = np.full(left.shape, 9.0, dtype=np.float32)
    inner = (slice(10, -10), slice(25, -25))
    disp, conf = confident_matches(left, right, init, radius=5, min_confidence=0.5, max_lr_gap=0.1,
                                   epipolar=_Constant(dy))  # type: ignore[arg-type]
    assert np.mean(np.isfinite(disp[inner])) > 0.95
    assert abs(float(np.nanmedian(disp[inner])) - d) < 0.02


@pytest.mark.slow
def test_rendered_triprism_refines_closer_to_exact_correspondences() -> None:
    """A tri-prism capture of a plane with a grating (rendered by exact refraction): refined from the
    rounded true disparities, the disparities along the epipolar curves are closer to the exact
    correspondences than those on the left pixels' rows."""
    sim = pytest.importorskip("prismstereo.simulate")
    from prismstereo.apps.demo import scaled_rig
    from prismstereo.config import thesis_triprism
    from prismstereo.depth import DepthConfig
    from prismstereo.depth import pipeline as pl
    from prismstereo.optics import project_exact, trace_pixels

    rig = scaled_rig(thesis_triprism(), 2)
    cfg = pl.validate_config(rig, DepthConfig(method="sad"))
    views = pl.virtual_cameras(rig, cfg)
    pair = pl.rectify_geometry(rig, views, cfg)
    z = 1500.0
    n = 256
    yy, xx = np.mgrid[0:n, 0:n] / n
    img = 0.5 + 0.2 * np.sin(2 * np.pi * (9.0 * xx + 7.0 * yy)) + 0.12 * np.sin(2 * np.pi * (5.0 * xx - 11.0 * yy))
    tex = sim.ImageTexture(image=np.repeat((np.clip(img, 0, 1) * 255).astype(np.uint8)[..., None], 3, 2),
                           size=(90.0, 90.0))
    cap = sim.render_capture(rig, sim.Scene(objects=(sim.Plane(center=(0.0, 0.0, z), texture=tex),), supersample=1))
    left, right = pl.rectify_capture(pair, cap.image)
    vl, vr = pair.valid_masks()
    ys, xs = np.nonzero(vl)
    px = np.stack([xs, ys], axis=1).astype(np.float64)
    rays = trace_pixels(rig, pair.rectified_to_real(px, "left"), face=int(pair.left_face), bounded=False)
    pr, ok = project_exact(rig, rays.point_at_depth(z), face=int(pair.right_face))
    r = pair.real_to_rectified(pr, "right")
    h, w = vl.shape
    ri, ci = np.rint(r[:, 1]).astype(np.int64), np.rint(r[:, 0]).astype(np.int64)
    ok &= (ri >= 0) & (ri < h) & (ci >= 0) & (ci < w)
    ok[ok] &= vr[ri[ok], ci[ok]]
    ys, xs, d_true = ys[ok], xs[ok], (xs - r[:, 0])[ok]
    assert ys.size > 5000
    init = np.full((h, w), np.nan, dtype=np.float32)
    init[ys, xs] = np.rint(d_true)
    errs = {}
    for name, epi in (("rows", None), ("curves", pl.epipolar_curves(pair))):
        disp, _ = confident_matches(left, right, init, min_confidence=0.5, valid_left=vl, valid_right=vr,
                                    epipolar=epi)
        e = np.abs(disp[ys, xs] - d_true)
        errs[name] = float(np.median(e[np.isfinite(e)]))
    assert errs["curves"] < 0.75 * errs["rows"], errs


def test_cut_windows_follow_the_curve_near_a_horizontal_edge_of_the_right_view() -> None:
    """Next to the right view's top edge the windows are cut to the rows both views have; with the row
    offset they are refined there as accurately as inside, and as many as without it."""
    d, dy = 9.3, -0.3
    left, right = _diagonal_pair(d, dy)
    valid_r = np.ones(left.shape, dtype=bool)
    valid_r[:15] = False
    init = np.full(left.shape, 9.0, dtype=np.float32)
    band = (slice(12, 22), slice(25, -25))  # windows reach above row 15
    kw = dict(radius=5, min_pixels=49, valid_left=np.ones(left.shape, dtype=bool), valid_right=valid_r)
    along, conf = refine_disparity(left, right, init, row_offset=np.full(left.shape, dy), **kw)
    _, conf_rows = refine_disparity(left, right, init, **kw)
    assert np.isfinite(conf[band]).sum() >= np.isfinite(conf_rows[band]).sum() > 0
    refined = np.isfinite(conf[band])
    assert np.all(np.abs(along[band][refined] - d) < 0.05)



def _fine_pair(d: float, *, seed: int, h: int = 40, w: int = 140) -> tuple[np.ndarray, np.ndarray]:
    """A fine random texture (white noise through a σ = 0.7 px Gaussian: energy up to near Nyquist) and its
    copy shifted by exactly ``d`` px, band-limited (Fourier) shift: right(x) = left(x + d)."""
    rng = np.random.default_rng(seed)
    base = cv2.GaussianBlur(rng.standard_normal((h, w)), (0, 0), 0.7)
    base /= base.std()
    f = np.fft.fftfreq(w)
    shifted = np.real(np.fft.ifft(np.fft.fft(base, axis=1) * np.exp(2j * np.pi * f * d), axis=1))
    return (128 + 10 * base).astype(np.float32), (128 + 10 * shifted).astype(np.float32)


def test_the_prefilter_recovers_subpixel_shifts_of_a_fine_texture_without_bias():
    """Linear sampling between pixels damps fine texture by a phase-dependent amount, which pulls the
    estimate towards the phases that damp least: on this texture 0.12–0.18 px at a quarter pixel. The
    low-pass before sampling leaves under 0.03 px at every phase."""
    worst: dict[float | None, float] = {}
    for prefilter in (None, 0.7):
        biases = []
        for frac in (0.2, 0.3, 0.5, 0.7, 0.8):
            d = 12.0 + frac
            left, right = _fine_pair(d, seed=11)
            init = np.full(left.shape, np.float32(round(d)))
            out, conf = refine_disparity(left, right, init, radius=5, min_texture=0.01, prefilter=prefilter)
            inner = (slice(8, -8), slice(30, -10))
            assert np.isfinite(conf[inner]).mean() > 0.95
            biases.append(float(np.median(out[inner] - d)))
        worst[prefilter] = max(abs(b) for b in biases)
    assert worst[None] > 0.1  # the bias is there to remove on this texture
    assert worst[0.7] < 0.03


def test_the_prefilter_ignores_what_lies_beyond_a_views_valid_region_and_its_rim():
    """The low-pass is normalised over each view's valid region less its outermost pixels (the remap blends
    those with what lies beyond): changing them, or the fill outside, changes no refined value."""
    left, right = _fine_pair(12.4, seed=12)
    h, w = left.shape
    vl = np.zeros((h, w), dtype=bool)
    vl[:, 25:] = True
    vr = np.zeros((h, w), dtype=bool)
    vr[:, :120] = True
    init = np.full((h, w), np.float32(12.0))
    runs = []
    for fill in (0.0, 255.0):
        lf, rf = left.copy(), right.copy()
        lf[:, :26] = fill  # outside, and the rim column 25
        rf[:, 119:] = fill
        runs.append(refine_disparity(lf, rf, init, radius=5, min_texture=0.01, prefilter=0.7, valid_left=vl,
                                     valid_right=vr, min_pixels=49))
    (d0, c0), (d1, c1) = runs
    np.testing.assert_array_equal(d0, d1)
    np.testing.assert_array_equal(c0, c1)
    assert np.isfinite(c0[10:-10, 27:40]).mean() > 0.9  # the cut windows at the left view's edge are refined


def _masked_sums_reference(L, R, Rx, VL, VR, y, x, b0, r, oy, fy):  # noqa: ANN001, ANN202
    """The masked window sums pixel by pixel, with the rule of ``_masked_tap_sums`` spelled out."""
    h, w = VL.shape
    out = np.zeros(21)
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            yl, xl, xa, yr = y + dy, x + dx, b0 + dx, y + dy + oy
            if not (0 <= yl < h and 0 <= xl < w and VL[yl, xl] and 0 <= xa and xa + 1 < w):
                continue
            near, far = (yr, yr + 1) if fy < 0.5 else (yr + 1, yr)
            if not (0 <= near < h and VR[near, xa] >= 2 and VR[near, xa + 1] >= 2):
                continue
            if fy != 0.0 and not (0 <= far < h and VR[far, xa] >= 1 and VR[far, xa + 1] >= 1):
                continue
            ya, yb = min(max(yr, 0), h - 1), min(max(yr + 1, 0), h - 1)
            ra, rb = ((1 - fy) * float(R[ya, c]) + fy * float(R[yb, c]) for c in (xa, xa + 1))
            ja, jb = ((1 - fy) * float(Rx[ya, c]) + fy * float(Rx[yb, c]) for c in (xa, xa + 1))
            lv = float(L[yl, xl])
            out += [1, lv, lv * lv, ra, rb, ja, jb, lv * ja, lv * jb, ra * ja, ra * jb, rb * ja, rb * jb, ja * ja,
                    ja * jb, jb * jb, ra * ra, ra * rb, rb * rb, lv * ra, lv * rb]
    return out


def test_cut_window_sums_count_only_the_pixels_inside_both_views() -> None:
    """The masked sums of the cut windows, from the padded column-major strips the cut kernel builds a row at a
    time, equal the pixel-by-pixel rule, at the image's edges (windows and taps off it), across holes of both
    views, with and without a row fraction (fy below and above one half)."""
    from prismstereo.depth.refine import _cut_sums, _strip, _weight_strip

    rng = np.random.default_rng(3)
    h, w, r = 24, 30, 3
    k = 2 * r + 1
    pad = k + 1
    L = rng.uniform(0, 255, (h, w)).astype(np.float32)
    R = rng.uniform(0, 255, (h, w)).astype(np.float32)
    Rx = rng.normal(0, 20, (h, w)).astype(np.float32)
    VL = (rng.uniform(size=(h, w)) > 0.15).astype(np.uint8)
    VR = rng.choice(np.array([0, 1, 2, 2, 2], dtype=np.uint8), size=(h, w))
    for _ in range(150):
        y, x = int(rng.integers(0, h)), int(rng.integers(0, w))
        b0, oy = x - int(rng.integers(-2, 6)), int(rng.integers(-2, 2))
        fy = float(rng.choice([0.0, 0.3, 0.8]))
        strips = [np.full((w + 2 * pad) * k, np.nan) for _ in range(7)]
        for s in strips:  # the padding as the kernel sets it, the columns it does not build left NaN
            s[:pad * k] = 0.0
            s[(w + pad) * k:] = 0.0
        TL, WL, TR, TD, TJ, TE, WR = strips
        _strip(L, TL, None, y - r, k, max(x - r, 0), min(x + r + 1, w), pad)
        _weight_strip(VL, WL, y - r, k, max(x - r, 0), min(x + r + 1, w), pad, 0, 1, 0, 0)
        c0, c1 = max(b0 - r, 0), min(b0 + r + 2, w)
        _strip(R, TR, TD, y + oy - r, k, c0, c1, pad)
        _strip(Rx, TJ, TE, y + oy - r, k, c0, c1, pad)
        near = 1 if fy >= 0.5 else 0
        _weight_strip(VR, WR, y + oy - r, k, c0, c1, pad, near, 2, 1 - near, 0 if fy == 0.0 else 1)
        got = np.empty(21)
        _cut_sums(TL, WL, TR, TD, TJ, TE, WR, x, b0, r, pad, w, fy, got)
        want = _masked_sums_reference(L, R, Rx, VL, VR, y, x, b0, r, oy, fy)
        # a pixel counted wrongly moves a sum by a whole term, ≥ 1e-3 of it here
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-6)


def _select_reference(d0, static, vl, whole_r, offs, cut_mode):  # noqa: ANN001, ANN202
    """The pixel selection of ``_select_pixels`` in numpy (the rule the refinement used before the kernel)."""

    def _split_rows(offset, ys, xs):  # noqa: ANN001, ANN202
        if offset is None:
            return np.zeros(ys.size, dtype=np.int64), np.zeros(ys.size, dtype=np.float64)
        off = np.nan_to_num(offset[ys, xs].astype(np.float64), nan=0.0, posinf=0.0, neginf=0.0)
        base = np.floor(off)
        return base.astype(np.int64), (off - base).astype(np.float64)

    h, w = d0.shape
    finite = np.isfinite(d0)
    ok = finite & static
    if cut_mode:
        ys0, xs0 = np.nonzero(ok)
        xr0 = np.rint(xs0 - d0[ys0, xs0]).astype(np.int64)
        oy0, fy0 = _split_rows(offs, ys0, xs0)
        yr0 = ys0 + oy0
        yr1 = yr0 + (fy0 > 0.0)
        inside = (xr0 >= 0) & (xr0 < w) & (yr0 >= 0) & (yr1 < h)
        stay = np.zeros(ys0.size, dtype=bool)
        stay[inside] = whole_r[yr0[inside], xr0[inside]] & whole_r[yr1[inside], xr0[inside]]
        ok[ys0[~stay], xs0[~stay]] = False
    cut = finite & vl & ~ok if cut_mode else np.zeros((h, w), dtype=bool)
    out = []
    for m in (ok, cut):
        ys, xs = np.nonzero(m)
        out += [ys, xs, *_split_rows(offs, ys, xs)]
    return out


@pytest.mark.parametrize("cut_mode", [False, True])
@pytest.mark.parametrize("with_offsets", [False, True])
def test_the_pixel_selection_kernel_is_the_numpy_rule(cut_mode: bool, with_offsets: bool) -> None:
    """``_select_pixels`` picks the same whole and cut windows, in the same order, with the same split row offsets
    (integer part and fraction, 0 where not finite), as the numpy rule: matches off the image, NaN and infinite
    offsets, offsets that move the right window off the top and bottom rows."""
    from prismstereo.depth.refine import _select_pixels

    rng = np.random.default_rng(5)
    h, w = 40, 60
    d0 = rng.uniform(-5, 30, (h, w)).astype(np.float32)
    d0[rng.uniform(size=(h, w)) < 0.2] = np.nan
    static = rng.uniform(size=(h, w)) > 0.3
    vl = rng.uniform(size=(h, w)) > 0.2
    whole_r = rng.uniform(size=(h, w)) > 0.25
    offs = rng.normal(0, 1.5, (h, w)).astype(np.float32)
    offs[rng.uniform(size=(h, w)) < 0.05] = np.nan
    offs[0, :5] = np.inf
    offs[1, :5] = -np.inf
    offs[2, :5] = np.float32(2.0)  # integer offsets: fraction 0, one row read
    got = _select_pixels(d0, static, vl, whole_r, offs if with_offsets else np.zeros((1, 1), np.float32),
                         with_offsets, cut_mode)
    want = _select_reference(d0, static, vl, whole_r, offs if with_offsets else None, cut_mode)
    assert got[0].size > 100 and (not cut_mode or got[4].size > 100)
    for g, r in zip(got, want, strict=True):
        assert g.dtype == r.dtype
        np.testing.assert_array_equal(g, r)


def test_the_low_pass_select_kernel_is_the_numpy_formula() -> None:
    """``_low_pass_select`` gives numpy's float32 result bit for bit, the thresholds' float32 values included
    (a weight of exactly float32(1e-3) is not above 1e-3 in float32, though it is in float64)."""
    from prismstereo.depth.refine import _low_pass_select

    rng = np.random.default_rng(6)
    h, w = 30, 50
    img = rng.uniform(0, 255, (h, w)).astype(np.float32)
    num = rng.uniform(0, 255, (h, w)).astype(np.float32)
    den = rng.uniform(0, 1, (h, w)).astype(np.float32)
    den.flat[::7] = np.float32(1e-3)
    den.flat[1::7] = np.float32(1.0 - 1e-3)
    den.flat[2::11] = 0.0
    den.flat[3::11] = 1.0
    valid = rng.uniform(size=(h, w)) > 0.3
    cut = valid & (den < 1.0 - 1e-3)
    want = np.where(cut, img, np.where(den > 1e-3, num / np.maximum(den, 1e-6), img)).astype(np.float32)
    got = _low_pass_select(img, num, den, valid)
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, want)
    assert not np.array_equal(np.where(den > np.float64(1e-3), 1, 0), np.where(den > 1e-3, 1, 0))


def _bilinear(img: np.ndarray, yr: int, fy: float, xf: float) -> float:
    """``img`` at column ``xf``, linear between the rows ``yr`` and ``yr + 1`` (weight ``fy`` on ``yr + 1``),
    edge-replicated (the sampler the refinement's spec names: cv2 BORDER_REPLICATE)."""
    h, w = img.shape
    x0 = int(np.floor(xf))
    a = xf - x0
    xa, xb = min(max(x0, 0), w - 1), min(max(x0 + 1, 0), w - 1)
    ya, yb = min(max(yr, 0), h - 1), min(max(yr + 1, 0), h - 1)
    row = [(1.0 - a) * float(img[yy, xa]) + a * float(img[yy, xb]) for yy in (ya, yb)]
    return (1.0 - fy) * row[0] + fy * row[1]


def _gauss_newton_reference(L, R, Rx, y, x, init, oy, fy, r, iterations, max_shift, min_texture):  # noqa: ANN001, ANN202
    """One pixel's refinement written directly: each iteration samples the right window at the current d
    (bilinear, on the rows moved by ``oy + fy``), steps by ``Σ r·Jz / Σ Jz²`` on the zero-mean windows
    (``r = Lz − Rz``, J sampled from ``Rx``), clamped to ±0.5 and to ±``max_shift`` around ``init``; the
    confidence is the ZNCC of the final windows."""
    dys, dxs = np.mgrid[-r:r + 1, -r:r + 1]
    lw = np.array([float(L[y + a, x + b]) for a, b in zip(dys.ravel(), dxs.ravel(), strict=True)])
    lz = lw - lw.mean()
    m = lw.size

    def windows(d: float) -> tuple[np.ndarray, np.ndarray]:
        rw = np.array([_bilinear(R, y + a + oy, fy, x + b - d) for a, b in zip(dys.ravel(), dxs.ravel(), strict=True)])
        jw = np.array([_bilinear(Rx, y + a + oy, fy, x + b - d) for a, b in zip(dys.ravel(), dxs.ravel(), strict=True)])
        return rw, jw

    d, textured = init, True
    for _ in range(iterations):
        rw, jw = windows(d)
        jz = jw - jw.mean()
        num = float(np.sum((lz - (rw - rw.mean())) * jz))
        den = float(np.sum(jz * jz))
        textured = den > min_texture * m
        step = min(max(num / den if textured else 0.0, -0.5), 0.5)
        d = min(max(d - step, init - max_shift), init + max_shift)
    rw, _ = windows(d)
    rz = rw - rw.mean()
    zncc = float(np.sum(lz * rz) / np.sqrt(np.sum(lz * lz) * np.sum(rz * rz)))
    return d, zncc, textured and abs(d - init) < max_shift - 1e-3


def test_the_whole_window_kernel_is_a_direct_gauss_newton_and_zncc() -> None:
    """``_refine_kernel`` (window sums from column-major strips, shared by a row's pixels, the iterations
    interleaved over them) gives the direct numpy Gauss–Newton and ZNCC of every pixel on random images:
    several pixels a row with different integer row offsets and fractions (0 included), starts up to 0.8 px
    off (the iterations move to other integer taps), windows at the image's left and right edges (the
    edge-replicating path) and on the top and bottom rows' offsets (rows clamped). Tolerance: d to 2e-5 px,
    the ZNCC to 1e-5 (float32 outputs; the kernel sums in float32, in another order)."""
    from prismstereo.depth.refine import _refine_kernel

    rng = np.random.default_rng(11)
    h, w, r = 30, 70, 3
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    texture = 128 + 50 * np.sin(0.7 * xx + 0.3 * yy) + 30 * np.sin(0.31 * xx - 0.5 * yy)
    L = (texture + rng.normal(0, 4, (h, w))).astype(np.float32)
    R = (np.roll(texture, -6, axis=1) + rng.normal(0, 4, (h, w))).astype(np.float32)
    Rx = cv2.Sobel(R, cv2.CV_32F, 1, 0, ksize=3, scale=1.0 / 8.0)
    pix = sorted({(int(rng.integers(r, h - r)), int(rng.integers(r, w - r))) for _ in range(160)})
    pix += [(r, 3), (r + 1, w - r - 1), (h - r - 1, 4), (h - r - 1, w - 5)]
    pix = sorted(set(pix))
    ys = np.array([p[0] for p in pix], dtype=np.int64)
    xs = np.array([p[1] for p in pix], dtype=np.int64)
    d0 = np.full((h, w), np.nan, dtype=np.float32)
    d0[ys, xs] = (6.0 + rng.uniform(-0.8, 0.8, ys.size)).astype(np.float32)
    # windows that leave the row on one side or the other
    d0[ys[-4:], xs[-4:]] = np.array([5.8, -1.2, 6.1, -1.7], dtype=np.float32)
    oys = rng.integers(-1, 2, ys.size).astype(np.int64)
    fys = rng.choice(np.array([0.0, 0.25, 0.5, 0.9]), ys.size)
    oys[-4:] = np.array([-1, 1, 1, -1])  # right rows off the top and bottom edges: clamped
    kw = dict(r=r, iterations=6, max_shift=0.85, min_texture=0.01)
    d, zncc, keep = _refine_kernel(L, R, Rx, ys, xs, d0, oys, fys, r, 6, 0.85, 0.01, 2)
    want = np.array([_gauss_newton_reference(L, R, Rx, int(y), int(x), float(d0[y, x]), int(oy), float(fy), **kw)
                     for y, x, oy, fy in zip(ys, xs, oys, fys, strict=True)], dtype=np.float64)
    assert 0.2 < np.mean(np.floor(xs - want[:, 0]) != np.floor(xs - d0[ys, xs])) < 0.9  # taps move
    np.testing.assert_allclose(d, want[:, 0], rtol=0, atol=2e-5)
    np.testing.assert_allclose(zncc, want[:, 1], rtol=0, atol=1e-5)
    np.testing.assert_array_equal(keep, want[:, 2].astype(bool))
    assert keep.mean() > 0.5


def _derived(S: np.ndarray, fa: float, m: int) -> np.ndarray:
    """What the whole-window kernel takes from its window sums at a fraction ``fa``: the Gauss–Newton
    numerator and denominator, the right window's variance and Σ lz·R (each invariant to a constant added to R)."""
    fb = 1.0 - fa
    sr, sj = fb * S[0] + fa * S[1], fb * S[2] + fa * S[3]
    slj = fb * S[4] + fa * S[5]
    srj = fb * fb * S[6] + fb * fa * (S[7] + S[8]) + fa * fa * S[9]
    sjj = fb * fb * S[10] + 2.0 * fb * fa * S[11] + fa * fa * S[12]
    srr = fb * fb * S[13] + 2.0 * fb * fa * S[14] + fa * fa * S[15]
    slr = fb * S[16] + fa * S[17]
    return np.array([slj - (srj - sr * sj / m), sjj - sj * sj / m, srr - sr * sr / m, slr])


def _window_sums_reference(L, R, Rx, y, x, b0, r, oy, fy):  # noqa: ANN001, ANN202
    """The 18 window sums of the whole-window kernel in numpy float64, from the definition (rows inside)."""
    f64 = np.float64
    lz = L[y - r:y + r + 1, x - r:x + r + 1].astype(f64)
    lz = lz - lz.mean()

    def tap(img, b):  # noqa: ANN001, ANN202
        top = img[y + oy - r:y + oy + r + 1, b - r:b + r + 1].astype(f64)
        below = img[y + oy - r + 1:y + oy + r + 2, b - r:b + r + 1].astype(f64)
        return top + fy * (below - top)

    ra, rb, ja, jb = tap(R, b0), tap(R, b0 + 1), tap(Rx, b0), tap(Rx, b0 + 1)
    terms = (ra, rb, ja, jb, lz * ja, lz * jb, ra * ja, ra * jb, rb * ja, rb * jb, ja * ja, ja * jb, jb * jb,
             ra * ra, ra * rb, rb * rb, lz * ra, lz * rb)
    return np.array([t.sum() for t in terms])


def test_float32_window_sums_keep_a_faint_texture_on_a_bright_surface() -> None:
    """The whole-window kernel's float32 window sums (:func:`_window_sums32`, from float32 strips) give the
    Gauss–Newton step's numerator and denominator, the right window's variance and Σ lz·R of float64 sums
    to 1e-4 of each, on windows of grey level ~230 whose texture is 0.3 grey levels with a 6-level offset between
    the views: float32 sums of the raw grey levels (terms of ~5e4 for a variance of ~0.05 a pixel) would be off
    by more than the texture, and centring R on the left window's mean (which keeps the views' offset in every
    term) misses the variance by 3e-4 of it; R is centred on its own value."""
    from prismstereo.depth.refine import _strip, _window_sums32

    rng = np.random.default_rng(5)
    h, w, r = 16, 48, 5
    k, m = 2 * r + 1, (2 * r + 1) ** 2
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    tex = 0.3 * np.sin(0.9 * xx + 0.4 * yy) + 0.1 * rng.normal(size=(h, w))
    L = (230.0 + tex).astype(np.float32)
    R = (236.0 + np.roll(tex, -4, axis=1)).astype(np.float32)
    Rx = cv2.Sobel(R, cv2.CV_32F, 1, 0, ksize=3, scale=1.0 / 8.0)
    TL, TR, TD, TJ, TE = (np.zeros(w * k, dtype=np.float32) for _ in range(5))
    checked = 0
    for y, oy in ((7, 0), (8, -1)):
        _strip(L, TL, None, y - r, k, 0, w, 0)
        _strip(R, TR, TD, y + oy - r, k, 0, w, 0)
        _strip(Rx, TJ, TE, y + oy - r, k, 0, w, 0)
        for x in range(r + 6, w - r - 2, 3):
            b0 = x - 4 - int(rng.integers(0, 2))
            fy = float(rng.choice([0.0, 0.37, 0.93]))
            got = np.empty((1, 18))
            lmean = float(np.mean(L[y - r:y + r + 1, x - r:x + r + 1].astype(np.float64)))
            _window_sums32(TL, TR, TD, TJ, TE, (x - r) * k, (b0 - r) * k, k, m, lmean, fy, got, 0)
            want = _window_sums_reference(L, R, Rx, y, x, b0, r, oy, fy)
            for fa in (0.0, 0.4, 0.85):
                g, wv = _derived(got[0], fa, m), _derived(want, fa, m)
                np.testing.assert_allclose(g, wv, rtol=1e-4, atol=1e-4 * np.abs(wv).max())
                checked += 1
    assert checked > 40
