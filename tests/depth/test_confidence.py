"""Per-match confidence, the confidence filter and the speckle filter; the default's density on a held-out texture."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from prismstereo.depth.confidence import confident_matches, remove_speckles


def _shifted_pair(d: float, *, seed: int = 0, h: int = 40, w: int = 120) -> tuple[np.ndarray, np.ndarray]:
    """A smooth random texture and its copy shifted right by ``d`` px (left x ↔ right x − d)."""
    import cv2

    rng = np.random.default_rng(seed)
    base = cv2.GaussianBlur(rng.random((h, w + 40)).astype(np.float32) * 255, (0, 0), 1.2)
    xs = np.arange(w, dtype=np.float32)
    left = base[:, 20:20 + w]
    right = np.stack([np.interp(xs + 20 + d, np.arange(w + 40), row) for row in base]).astype(np.float32)
    return left, right


def test_confidence_is_high_on_texture_and_refines_to_the_true_disparity():
    left, right = _shifted_pair(7.3)
    init = np.full(left.shape, 7.0, dtype=np.float32)
    disp, conf = confident_matches(left, right, init, radius=5, min_confidence=None)
    inner = (slice(8, -8), slice(20, -20))
    assert np.nanmedian(conf[inner]) > 0.95
    assert abs(float(np.nanmedian(disp[inner])) - 7.3) < 0.02
    assert np.all((conf[np.isfinite(conf)] >= 0) & (conf[np.isfinite(conf)] <= 1))


def test_matches_the_refinement_cannot_confirm_get_zero_and_the_threshold_drops_them():
    left, right = _shifted_pair(7.3)
    left[:, :40] = right[:, :40] = 100.0  # no texture: nothing to refine on
    init = np.full(left.shape, 7.0, dtype=np.float32)
    init[0, 0] = np.nan
    disp, conf = confident_matches(left, right, init, radius=3, min_confidence=None)
    flat = (slice(5, -5), slice(5, 25))
    assert np.all(conf[flat] == 0.0) and np.all(disp[flat] == 7.0)  # kept, flagged
    assert np.isnan(disp[0, 0]) and np.isnan(conf[0, 0])  # no match, no confidence
    kept, kconf = confident_matches(left, right, init, radius=3, min_confidence=0.5)
    assert np.all(np.isnan(kept[flat])) and np.all(np.isnan(kconf[flat]))
    assert np.isfinite(kept[20, 60]) and kconf[20, 60] >= 0.5
    assert np.array_equal(np.isfinite(kept), np.isfinite(kconf))


def test_matches_near_the_edge_of_a_view_are_refined_on_the_cut_window():
    left, right = _shifted_pair(7.3)
    valid = np.ones(left.shape, dtype=bool)
    valid[:, 60:] = False  # the left view ends at column 60
    init = np.where(valid, np.float32(7.0), np.float32(np.nan))
    band = (slice(8, -8), slice(55, 60))  # the 11 px window is cut by the edge, down to the last column
    d_one, c_one = confident_matches(left, right, init, radius=5, border_radius=None, valid_left=valid)
    d_two, c_two = confident_matches(left, right, init, radius=5, border_radius=3, valid_left=valid)
    assert np.all(c_one[band] == 0.0)
    assert np.all(c_two[band] > 0.9) and np.all(np.abs(d_two[band] - 7.3) < 0.1)  # from 0.3 px off
    inner = (slice(8, -8), slice(20, 50))
    assert np.array_equal(d_one[inner], d_two[inner])  # windows inside the view: the same refinement


def test_a_thin_common_view_is_kept_to_its_edges_and_its_blended_rim_is_left_out():
    """A 12 px wide strip seen by both views (a tri-prism's common view is such a strip): every window
    there is cut by an edge of the left view or of the right one; the views' outermost pixels are darkened
    as the remap leaves them (blended with what lies beyond the region)."""
    true_d = 7.3
    left, right = _shifted_pair(true_d, seed=3, w=160)
    valid_l = np.zeros(left.shape, dtype=bool)
    valid_l[:, 70:] = True  # the left view starts at column 70
    valid_r = np.zeros(left.shape, dtype=bool)
    valid_r[:, :75] = True  # the right view ends at column 75: left columns 70..81 see into it
    for img, valid in ((left, valid_l), (right, valid_r)):
        rim = valid & ~(np.roll(valid, 1, axis=1) & np.roll(valid, -1, axis=1))
        img[rim] *= 0.6
        img[~valid] = 0.0
    strip = np.zeros(left.shape, dtype=bool)
    strip[5:-5, 70:82] = True
    init = np.where(strip, np.float32(7.0), np.float32(np.nan))
    d, c = confident_matches(left, right, init, radius=5, border_radius=3, min_confidence=0.5,
                             valid_left=valid_l, valid_right=valid_r)
    kept = np.isfinite(d) & strip
    err = np.abs(d[kept] - true_d)
    assert kept.sum() >= 0.85 * strip.sum()
    assert np.median(err) < 0.05 and np.percentile(err, 90) < 0.15  # with the rim in the windows: 0.39, 0.49
    d_old, _ = confident_matches(left, right, init, radius=5, border_radius=None, min_confidence=0.5,
                                 valid_left=valid_l, valid_right=valid_r)
    assert np.isfinite(d_old[strip]).mean() < 0.3  # whole windows only: a few columns of the strip


def test_remove_speckles_drops_small_patches_only():
    d = np.full((60, 60), np.nan, dtype=np.float32)
    d[5:45, 5:45] = 20.0 + np.linspace(0, 0.5, 40)[None, :]  # a smooth surface
    d[50:53, 50:53] = 35.0  # an isolated wrong match
    out = remove_speckles(d, max_size=20)
    assert np.isnan(out[50:53, 50:53]).all()
    assert np.array_equal(out[5:45, 5:45], d[5:45, 5:45])


def _held_out_scene():
    """Two surfaces with textures unlike the noise the pipeline was developed on: gratings, sparse dots."""
    from prismstereo.simulate import ImageTexture, NoiseTexture, Plane, Rectangle, Scene

    rng = np.random.default_rng(1401)
    n = 256
    y, x = np.mgrid[0:n, 0:n] / n
    grating = np.zeros((n, n, 3))
    for _ in range(4):
        f = rng.uniform(3.0, 14.0, 2)
        grating += np.sin(2 * np.pi * (f @ np.stack([x.ravel(), y.ravel()])).reshape(n, n)
                          + rng.uniform(0, 6.3))[..., None] * rng.uniform(0.3, 1.0, 3)
    grating = np.clip(0.5 + 0.12 * grating, 0, 1)
    dots = np.full((n, n, 3), 0.55)
    k = n * n // 40
    iy, ix = rng.integers(0, n - 1, k), rng.integers(0, n - 1, k)
    c = rng.random((k, 3))
    for dy in (0, 1):
        for dx in (0, 1):
            dots[iy + dy, ix + dx] = c
    return Scene(objects=(
        Plane(center=(0.0, 0.0, 1800.0), name="wall",
              texture=NoiseTexture(scale=40.0, octaves=4, persistence=0.6, contrast=1.2, seed=1402)),
        Rectangle(center=(-15.0, -35.0, 1350.0), size=(110.0, 80.0), rotation=(0.0, 25.0, 0.0), name="grating",
                  texture=ImageTexture(image=(grating * 255).astype(np.uint8), size=(80.0, 80.0))),
        Rectangle(center=(10.0, 55.0, 1500.0), size=(110.0, 70.0), rotation=(15.0, -20.0, 0.0), name="dots",
                  texture=ImageTexture(image=(dots * 255).astype(np.uint8), size=(60.0, 60.0))),
    ), supersample=2, name="held-out")


@pytest.fixture(scope="module")
def held_out_run():
    from prismstereo.apps.demo import demo_rig
    from prismstereo.depth import DepthConfig, run_depth
    from prismstereo.evaluation.depth_metrics import evaluate_depth
    from prismstereo.simulate import render_capture

    rig, scene = demo_rig(), _held_out_scene()
    cap = render_capture(rig, scene)
    res = run_depth(rig, cap.image, config=DepthConfig(depth_range=(1100.0, 2400.0)), progress=False)
    return dataclasses.replace(res, accuracy=evaluate_depth(res, scene=scene))


def test_default_keeps_most_of_the_view_accurately_on_a_held_out_texture(held_out_run):
    acc = held_out_run.accuracy
    assert acc["coverage"] >= 0.80
    assert acc["median_rel"] <= 0.001
    assert acc["within_1pct"] >= 0.90


def test_confidence_is_aligned_with_the_depth_map(held_out_run):
    res = held_out_run
    assert res.confidence is not None and res.confidence.shape == res.depth.shape
    assert np.array_equal(np.isfinite(res.confidence), np.isfinite(res.depth))
    c = res.confidence[np.isfinite(res.confidence)]
    assert c.min() >= res.config.min_confidence and c.max() <= 1.0


def _coverage_and_errors(res, gt, d):
    """Share of the true common view with a disparity in ``d``, and the relative depth errors of those points
    triangulated with exact rays."""
    from prismstereo.depth import triangulate_matches

    ys, xs = np.nonzero(np.isfinite(d) & gt.common)
    tri = triangulate_matches(res.rig, res.pair, ys, xs, d[ys, xs].astype(np.float64), method="exact",
                              views=res.views)
    z = gt.depth[ys, xs][tri.valid]
    return ys.size / gt.common.sum(), np.abs(tri.points[tri.valid, 2] - z) / z


def test_the_left_right_check_drops_matches_pulled_across_depth_edges(held_out_run):
    """The sub-pixel left–right check on the rendered held-out capture: fewer points off by more than 1 %
    (windows across the panels' edges), the median and the coverage kept."""
    from prismstereo.evaluation.depth_metrics import ground_truth_for_run

    res = held_out_run
    gt = ground_truth_for_run(res, scene=_held_out_scene())
    vl, vr = res.pair.valid_masks()
    stats = {}
    for gap in (None, 0.5):
        d, _ = confident_matches(res.left, res.right, res.raw_disparity, min_confidence=0.5, max_lr_gap=gap,
                                 valid_left=vl, valid_right=vr)
        cov, err = _coverage_and_errors(res, gt, d)
        stats[gap] = (cov, np.median(err), np.percentile(err, 95), np.mean(err <= 0.01))
    (_, med0, p95_0, in0), (cov1, med1, p95_1, in1) = stats[None], stats[0.5]
    assert in1 >= in0 + 0.005 and p95_1 <= 0.95 * p95_0  # 97.4 -> 98.3 %, 0.66 -> 0.59 %
    assert med1 <= med0 and cov1 >= 0.9


def test_the_low_pass_before_the_refinement_lowers_the_depth_error_on_held_out_textures(held_out_run):
    """The rendered held-out capture (gratings, sparse dots): with the views low-passed along their rows
    before the refinement (the default), the median depth error drops (0.061 -> 0.056 % when written), the
    coverage stays."""
    from prismstereo.evaluation.depth_metrics import ground_truth_for_run

    res = held_out_run
    gt = ground_truth_for_run(res, scene=_held_out_scene())
    vl, vr = res.pair.valid_masks()
    stats = {}
    for prefilter in (None, res.config.refine_prefilter):
        d, _ = confident_matches(res.left, res.right, res.raw_disparity, min_confidence=0.5, valid_left=vl,
                                 valid_right=vr, prefilter=prefilter)
        cov, err = _coverage_and_errors(res, gt, d)
        stats[prefilter] = (cov, np.median(err))
    (cov0, med0), (cov1, med1) = stats[None], stats[res.config.refine_prefilter]
    assert res.config.refine_prefilter is not None
    assert med1 <= 0.95 * med0 and cov1 >= cov0 - 0.02


def _gauss_newton_reference(L, R, y, x, d, *, radius, iterations, max_shift, min_texture):
    """The refinement of one pixel written plainly: each iteration resamples its window (bilinear) at the
    current d, zero-mean SSD Gauss–Newton step, then the ZNCC at the final d (module docstring of refine)."""
    import cv2

    Rx = cv2.Sobel(R, cv2.CV_32F, 1, 0, ksize=3, scale=1.0 / 8.0).astype(np.float64)
    Rf = R.astype(np.float64)
    win = L[y - radius:y + radius + 1, x - radius:x + radius + 1].astype(np.float64)
    lz = win - win.mean()
    cols = np.arange(x - radius, x + radius + 1, dtype=np.float64)
    rows = np.arange(y - radius, y + radius + 1)

    def sample(img, xf):
        x0 = np.floor(xf).astype(np.int64)
        a = xf - x0
        return (1 - a) * img[rows][:, x0] + a * img[rows][:, x0 + 1]

    init = d
    for _ in range(iterations):
        rv, jv = sample(Rf, cols - d), sample(Rx, cols - d)
        jz = jv - jv.mean()
        den = float((jz * jz).sum())
        step = float(((lz - (rv - rv.mean())) * jz).sum()) / den if den > min_texture * lz.size else 0.0
        d = min(max(d - min(max(step, -0.5), 0.5), init - max_shift), init + max_shift)
    rz = sample(Rf, cols - d)
    rz = rz - rz.mean()
    return d, float((lz * rz).sum() / np.sqrt((lz * lz).sum() * (rz * rz).sum()))


def test_the_refinement_equals_resampling_the_window_at_every_iteration():
    """The kernel sums each integer tap position once and interpolates the sums; per pixel, that is the
    plain Gauss–Newton that resamples the window at every step, to float rounding."""
    from prismstereo.depth.refine import refine_disparity

    left, right = _shifted_pair(7.3, seed=3)
    rng = np.random.default_rng(4)
    init = (7.3 + rng.uniform(-0.9, 0.9, left.shape)).astype(np.float32)  # taps cross integers while refining
    disp, conf = refine_disparity(left, right, init, radius=4, iterations=6, max_shift=1.0, min_texture=0.01)
    for y, x in zip(rng.integers(6, 34, 25), rng.integers(15, 110, 25), strict=True):
        d_ref, z_ref = _gauss_newton_reference(left, right, int(y), int(x), float(init[y, x]), radius=4,
                                               iterations=6, max_shift=1.0, min_texture=0.01)
        if np.isfinite(conf[y, x]):
            assert abs(disp[y, x] - d_ref) < 1e-4 and abs(conf[y, x] - z_ref) < 1e-4
        else:  # not kept: it hit the ±max_shift bound
            assert abs(abs(d_ref - init[y, x]) - 1.0) < 1e-3


def test_the_left_right_check_refines_only_what_it_reads_with_the_same_result():
    """The right view is refined only at the pixels the check reads; the result is that of refining every
    right pixel a match lands on."""
    from prismstereo.depth import confidence as cm
    from prismstereo.depth.refine import refine_disparity

    left, right = _shifted_pair(7.3, seed=5)
    rng = np.random.default_rng(6)
    init = (7.0 + rng.uniform(-0.6, 0.6, left.shape)).astype(np.float32)
    init[:, 70:] += 3.0  # a depth jump: windows across it disagree between the views
    init[rng.random(left.shape) < 0.1] = np.nan
    for min_conf in (None, 0.5):
        disp, conf = confident_matches(left, right, init, radius=5, min_confidence=min_conf, max_lr_gap=0.5,
                                       prefilter=0.7)
        d0, z0 = refine_disparity(left, right, init, radius=5, iterations=6, max_shift=1.0, min_texture=0.01,
                                  min_pixels=49, prefilter=0.7)
        every = cm._mirror(refine_disparity(cm._mirror(right), cm._mirror(left),
                                            cm._mirror(cm._seen_from_right(init)), radius=5, iterations=6,
                                            max_shift=1.0, min_texture=0.01, min_pixels=49, prefilter=0.7)[0])
        c0 = np.where(np.isfinite(z0), np.clip(z0, 0, 1), 0).astype(np.float32)
        c0[cm._lr_gap(d0, every) > 0.5] = 0.0
        keep = np.isfinite(d0) if min_conf is None else np.isfinite(d0) & (c0 >= min_conf)
        assert ((c0 == 0) & (z0 > 0.9)).any() and (c0 > 0.9).any()  # the check did drop good windows
        assert np.array_equal(np.isfinite(disp), keep)
        assert np.array_equal(disp[keep], d0[keep]) and np.array_equal(conf[keep], c0[keep])


def test_unconfirmed_values_of_an_unchecked_map_do_not_stand_for_the_right_view_in_the_check():
    """A map without a cross-check (coop's) also has values where the scene is not seen in the right view; with
    ``seeds_checked=False`` those whose own window does not match do not win the right pixels of true matches
    (the largest disparity wins there) and so do not make the check drop them; as cross-checked seeds they do."""
    import cv2

    from prismstereo.depth import confidence as cm

    left, right = _shifted_pair(7.3, seed=7)
    rng = np.random.default_rng(8)
    left = left.copy()
    unseen = rng.random((left.shape[0], left.shape[1] - 70)).astype(np.float32) * 255
    left[:, 70:] = cv2.GaussianBlur(unseen, (0, 0), 1.2)  # not in the right view
    dense = np.full(left.shape, 7.0, dtype=np.float32)
    dense[:, 70:] = 40.0  # a guess there, landing on the right pixels of columns 37..79
    checked = dense.copy()
    checked[:, 70:] = np.nan  # what a cross-check would have kept
    kw = dict(radius=5, min_confidence=0.5, max_lr_gap=0.45)
    d_new, _ = confident_matches(left, right, dense, seeds_checked=False, **kw)
    d_old, _ = confident_matches(left, right, dense, seeds_checked=True, **kw)
    d_checked, _ = confident_matches(left, right, checked, **kw)
    hit = (slice(8, -8), slice(40, 62))  # true matches whose right pixels the guesses land on
    assert np.isfinite(d_new[hit]).mean() > 0.95 and np.nanmax(np.abs(d_new[hit] - 7.3)) < 0.05
    assert np.isfinite(d_old[hit]).mean() < 0.1  # the guesses as right seeds: the check drops the true matches
    # as if the map had been cross-checked, but for the few guesses a random window confirms by chance
    assert (np.isfinite(d_new[:, :62]) != np.isfinite(d_checked[:, :62])).mean() < 0.02
    assert np.isfinite(d_new[:, 76:]).mean() < 0.05  # the guesses themselves are not confirmed
    # a confirmed value wins its right pixel; an unconfirmed one only where no confirmed one lands
    seeds = np.array([[np.nan, 1.0, 2.0, np.nan, 2.0, np.nan]], dtype=np.float32)  # right pixels -, 0, 0, -, 2, -
    ok = np.array([[False, True, False, False, False, False]])
    assert np.array_equal(cm._seen_from_right(seeds), [[2.0, np.nan, 2.0, np.nan, np.nan, np.nan]], equal_nan=True)
    assert np.array_equal(cm._seen_confirmed(seeds, seeds, ok), [[1.0, np.nan, 2.0, np.nan, np.nan, np.nan]],
                          equal_nan=True)
    other = seeds.copy()
    other[0, 2] = 2.5  # refined from another value than the seed's: its window says nothing of the seed
    assert cm._seen_confirmed(seeds, other, ok)[0, 0] == 2.0


def test_confident_fill_adds_the_filled_values_the_check_confirms_and_only_those():
    from prismstereo.depth.confidence import confident_fill
    from prismstereo.errors import ConfigError

    left, right = _shifted_pair(7.3)
    raw = np.full(left.shape, 7.0, dtype=np.float32)
    raw[:, 30:70] = np.nan  # the matcher's cross-check rejected these
    filled = np.full(left.shape, 7.0, dtype=np.float32)
    filled[:, 50:70] = 12.0  # its dense map guessed wrong there
    kw = dict(radius=5, min_confidence=0.5, max_lr_gap=0.45)
    d1, c1 = confident_matches(left, right, raw, **kw)
    d2, c2 = confident_fill(left, right, d1, c1, filled, **kw)
    right_part = (slice(8, -8), slice(35, 45))
    wrong_part = (slice(8, -8), slice(55, 65))
    assert np.all(np.isnan(d1[right_part]))
    assert np.all(np.abs(d2[right_part] - 7.3) < 0.05) and np.all(c2[right_part] >= 0.5)
    assert np.all(np.isnan(d2[wrong_part]))  # 4.7 px off: the refinement cannot reach it, nothing is added
    kept = np.isfinite(d1)
    assert np.array_equal(d2[kept], d1[kept]) and np.array_equal(c2[kept], c1[kept])  # the first try stays
    assert np.array_equal(np.isfinite(d2), np.isfinite(c2))
    with pytest.raises(ConfigError, match="max_lr_gap"):
        confident_fill(left, right, d1, c1, filled, radius=5, max_lr_gap=None)


def test_a_wider_window_retries_the_weak_matches_only_and_makes_them_precise():
    strong_l, strong_r = _shifted_pair(7.3, seed=3, h=60, w=160)
    rng = np.random.default_rng(4)
    # weak texture under sensor noise on the left part, the strong texture itself on the right part
    left = (0.08 * strong_l + rng.normal(0.0, 1.5, strong_l.shape)).astype(np.float32)
    right = (0.08 * strong_r + rng.normal(0.0, 1.5, strong_r.shape)).astype(np.float32)
    left[:, 100:], right[:, 100:] = strong_l[:, 100:], strong_r[:, 100:]
    init = np.full(left.shape, 7.0, dtype=np.float32)
    kw = dict(radius=5, min_confidence=0.5, max_lr_gap=0.45)
    d5, c5 = confident_matches(left, right, init, **kw)
    d_r, c_r = confident_matches(left, right, init, retry_radius=11, retry_below=0.95, **kw)
    weak, strong = (slice(14, -14), slice(20, 85)), (slice(14, -14), slice(112, -20))
    assert np.mean(np.isfinite(d_r[weak])) > np.mean(np.isfinite(d5[weak])) + 0.05
    assert np.nanmedian(np.abs(d_r[weak] - 7.3)) < 0.7 * np.nanmedian(np.abs(d5[weak] - 7.3))
    first = np.isfinite(c5) & (c5 >= 0.95)
    assert first[strong].mean() > 0.9
    assert np.array_equal(d_r[first], d5[first]) and np.array_equal(c_r[first], c5[first])  # not retried


def _weak_and_strong(seed: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Weak texture under sensor noise on columns < 100, a strong one beyond (true disparity 7.3 px)."""
    strong_l, strong_r = _shifted_pair(7.3, seed=3, h=60, w=160)
    rng = np.random.default_rng(seed)
    left = (0.08 * strong_l + rng.normal(0.0, 1.5, strong_l.shape)).astype(np.float32)
    right = (0.08 * strong_r + rng.normal(0.0, 1.5, strong_r.shape)).astype(np.float32)
    left[:, 100:], right[:, 100:] = strong_l[:, 100:], strong_r[:, 100:]
    return left, right


def test_retry_drop_zeroes_only_the_weak_matches_the_wider_window_does_not_confirm():
    left, right = _weak_and_strong()
    init = np.full(left.shape, 7.0, dtype=np.float32)
    kw = dict(radius=5, min_confidence=None, max_lr_gap=0.45, retry_radius=11, retry_below=0.95)
    d0, c0 = confident_matches(left, right, init, **kw)
    d1, c1 = confident_matches(left, right, init, retry_drop=True, **kw)
    _, c5 = confident_matches(left, right, init, radius=5, min_confidence=None, max_lr_gap=0.45)
    _, c11 = confident_matches(left, right, init, radius=11, min_confidence=None, max_lr_gap=0.45)
    unconfirmed = ~(c5 >= 0.95) & ~(c11 > 0.0)
    assert unconfirmed.sum() > 50  # the weak part has some
    assert np.array_equal(d1, d0, equal_nan=True)
    assert np.all(c1[unconfirmed] == 0.0)
    assert np.array_equal(c1[~unconfirmed], c0[~unconfirmed], equal_nan=True)
    kept, _ = confident_matches(left, right, init, retry_drop=True, **{**kw, "min_confidence": 0.5})
    assert not np.isfinite(kept[unconfirmed]).any()


def test_an_agreeing_fill_keeps_the_filled_values_both_windows_confirm_alike():
    from prismstereo.depth.confidence import confident_fill
    from prismstereo.errors import ConfigError

    left, right = _weak_and_strong()
    none = np.full(left.shape, np.nan, dtype=np.float32)
    filled = np.full(left.shape, 7.0, dtype=np.float32)
    kw = dict(radius=5, min_confidence=0.5, max_lr_gap=0.45, retry_radius=11, retry_below=0.95)
    d_all, c_all = confident_fill(left, right, none, none, filled, **kw)
    d_ag, c_ag = confident_fill(left, right, none, none, filled, agree=0.5, **kw)
    ag = np.isfinite(d_ag)
    assert np.all(np.isfinite(d_all[ag]))  # a subset of the one-pass fill, with its values
    assert np.allclose(d_ag[ag], d_all[ag]) and np.allclose(c_ag[ag], c_all[ag])
    weak = (slice(None), slice(0, 100))
    far_all = np.nanmean(np.abs(d_all[weak] - 7.3) > 0.5)
    far_ag = np.nanmean(np.abs(d_ag[weak] - 7.3) > 0.5)
    assert far_ag < 0.5 * far_all  # the values the two windows disagree on are the wrong ones
    assert np.isfinite(d_ag[14:-14, 124:-20]).mean() > 0.9  # the strong texture is kept (off its border)
    with pytest.raises(ConfigError, match="agree"):
        confident_fill(left, right, none, none, filled, agree=0.5, radius=5, max_lr_gap=0.45)


def _weak_slanted_plane(seed: int = 5, h: int = 90, w: int = 160, slope: float = 0.02
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A weak texture under sensor noise on a plane slanted along the rows: true disparity 7.3 px at the
    middle row, ``slope`` px more per row down; returns left, right and the true disparity."""
    import cv2

    rng = np.random.default_rng(seed)
    base = cv2.GaussianBlur(rng.random((h, w + 40)).astype(np.float32) * 255, (0, 0), 1.2) * 0.08
    true = (7.3 + slope * (np.arange(h, dtype=np.float32) - h / 2))[:, None] * np.ones((1, w), np.float32)
    xs = np.arange(w, dtype=np.float32)
    left = base[:, 20:20 + w] + rng.normal(0.0, 1.5, (h, w))
    right = np.stack([np.interp(xs + 20 + true[y, 0], np.arange(w + 40), base[y]) for y in range(h)])
    right = right + rng.normal(0.0, 1.5, (h, w))
    return left.astype(np.float32), right.astype(np.float32), true


def test_growth_recovers_a_weak_slanted_plane_from_its_kept_neighbours_and_only_where_they_agree():
    from prismstereo.depth.confidence import confident_growth, neighbour_disparity
    from prismstereo.errors import ConfigError

    left, right, true = _weak_slanted_plane()
    h, w = true.shape
    # kept values on every other 12-px block (what the two windows kept), none elsewhere
    blocks = ((np.arange(h)[:, None] // 12 + np.arange(w)[None, :] // 12) % 2 == 0)
    kept = np.where(blocks, true, np.nan).astype(np.float32)
    conf = np.where(blocks, np.float32(0.9), np.float32(np.nan))
    filled = np.rint(true).astype(np.float32)  # the matcher's integer guesses
    kw = dict(min_confidence=0.5, max_lr_gap=0.45)
    d, c = confident_growth(left, right, kept, conf, filled, **kw)
    assert np.array_equal(d[blocks], kept[blocks]) and np.array_equal(c[blocks], conf[blocks])
    inner = np.zeros((h, w), dtype=bool)
    inner[20:-20, 30:-30] = True
    grown = np.isfinite(d) & ~blocks & inner
    assert grown.sum() > 0.5 * (~blocks & inner).sum()  # most of the holes off the border
    assert np.mean(np.abs(d[grown] - true[grown]) < 0.5) > 0.97
    assert np.all((c[grown] >= 0.5) & (c[grown] <= 1.0))
    # a second pass keeps the first one's values and grows from them only
    d2, _ = confident_growth(left, right, kept, conf, filled, passes=2, **kw)
    assert np.array_equal(d2[np.isfinite(d)], d[np.isfinite(d)]) and np.isfinite(d2).sum() >= np.isfinite(d).sum()
    # neighbours that say 1 px more than the refinement finds: their surface is not continued
    d_off, _ = confident_growth(left, right, kept + np.float32(1.0), conf, filled, **kw)
    assert (np.isfinite(d_off) & ~blocks & inner).sum() < 0.02 * (~blocks & inner).sum()
    # neighbours on two surfaces 3 px apart (a depth edge): none where they are mixed
    step = np.where(np.arange(w)[None, :] < w // 2, kept, kept + np.float32(3.0)).astype(np.float32)
    _, _, spread = neighbour_disparity(step, sigma=8.0)
    d_step, _ = confident_growth(left, right, step, conf, np.where(np.isfinite(step), step, filled), **kw)
    assert not (np.isfinite(d_step) & ~blocks & (spread >= 0.5)).any()
    with pytest.raises(ConfigError, match="max_lr_gap"):
        confident_growth(left, right, kept, conf, filled, max_lr_gap=None)


def test_plane_growth_continues_a_steep_weak_floor_the_mean_does_not_and_stops_at_a_step():
    from prismstereo.depth.confidence import confident_growth, neighbour_disparity
    from prismstereo.errors import ConfigError

    # 0.08 px more per row: the kept values spread about their mean by ~0.6 px over the kernel's reach
    left, right, true = _weak_slanted_plane(slope=0.08)
    h, w = true.shape
    blocks = ((np.arange(h)[:, None] // 12 + np.arange(w)[None, :] // 12) % 2 == 0)
    kept = np.where(blocks, true, np.nan).astype(np.float32)
    conf = np.where(blocks, np.float32(0.9), np.float32(np.nan))
    filled = np.rint(true).astype(np.float32)
    kw = dict(min_confidence=0.5, max_lr_gap=0.45)
    inner = np.zeros((h, w), dtype=bool)
    inner[20:-20, 30:-30] = True
    holes = ~blocks & inner
    d_mean, _ = confident_growth(left, right, kept, conf, filled, fit="mean", **kw)
    d_plane, c_plane = confident_growth(left, right, kept, conf, filled, fit="plane", **kw)
    assert (np.isfinite(d_mean) & holes).sum() < 0.02 * holes.sum()
    grown = np.isfinite(d_plane) & holes
    assert grown.sum() > 0.5 * holes.sum()
    assert np.mean(np.abs(d_plane[grown] - true[grown]) < 0.5) > 0.97
    assert np.all((c_plane[grown] >= 0.5) & (c_plane[grown] <= 1.0))
    assert np.array_equal(d_plane[blocks], kept[blocks]) and np.array_equal(c_plane[blocks], conf[blocks])
    # neighbours on two surfaces 3 px apart (a depth edge), the right one saying 3 px more than the image:
    # nothing grows there, nor where that surface weighs more than a sixth of the neighbours
    right_half = np.arange(w)[None, :] >= w // 2
    step = np.where(right_half, kept + np.float32(3.0), kept).astype(np.float32)
    near = neighbour_disparity(np.where(right_half & blocks, np.float32(0.0), np.float32(np.nan)), sigma=8.0)[1]
    d_step, _ = confident_growth(left, right, step, conf, np.where(np.isfinite(step), step, filled), fit="plane",
                                 **kw)
    new = np.isfinite(d_step) & ~blocks
    assert not (new & right_half).any()
    share_other = near / np.maximum(neighbour_disparity(step, sigma=8.0)[1], 1e-6)
    assert not (new & (share_other > 0.16)).any()
    assert (new & holes & (np.arange(w)[None, :] < w // 2 - 30)).sum() > 0.5 * (
        holes & (np.arange(w)[None, :] < w // 2 - 30)).sum()  # the far side still grows
    with pytest.raises(ConfigError, match="fit"):
        confident_growth(left, right, kept, conf, filled, fit="median", **kw)


def test_a_depth_tolerance_grows_where_a_pixel_is_a_smaller_share_of_depth_and_leaves_the_rest_alone():
    from prismstereo.depth.confidence import confident_growth

    left, right, true = _weak_slanted_plane()
    h, w = true.shape
    blocks = ((np.arange(h)[:, None] // 12 + np.arange(w)[None, :] // 12) % 2 == 0)
    conf = np.where(blocks, np.float32(0.9), np.float32(np.nan))
    filled = np.rint(true).astype(np.float32)
    kw = dict(min_confidence=0.5, max_lr_gap=0.45, fit="plane", agree=0.2)
    inner = np.zeros((h, w), dtype=bool)
    inner[20:-20, 30:-30] = True
    holes = ~blocks & inner
    # the kept values 0.3 px above the image's: 0.2 px rejects the window's values; on a rig whose true
    # disparity is 200 px (d0 = 200 - 7.3) 0.22 % of depth is 0.44 px and lets them grow
    biased = np.where(blocks, true + np.float32(0.3), np.nan).astype(np.float32)
    tri = dict(agree_depth=0.0022, disparity_offset=200.0 - 7.3)
    d_px, _ = confident_growth(left, right, biased, conf, filled, **kw)
    d_tri, c_tri = confident_growth(left, right, biased, conf, filled, **tri, **kw)
    assert (np.isfinite(d_px) & holes).sum() < 0.1 * holes.sum()
    grown = np.isfinite(d_tri) & holes
    assert grown.sum() > 0.5 * holes.sum()
    assert np.mean(np.abs(d_tri[grown] - true[grown]) < 0.5) > 0.97  # the window's value, not the neighbours'
    assert np.array_equal(d_tri[blocks], biased[blocks]) and np.array_equal(c_tri[blocks], conf[blocks])
    # 1 px off is 0.5 % of depth there: still nothing grows
    off = np.where(blocks, true + np.float32(1.0), np.nan).astype(np.float32)
    assert (np.isfinite(confident_growth(left, right, off, conf, filled, **tri, **kw)[0]) & holes).sum() < (
        0.02 * holes.sum())
    # where 0.22 % of depth is less than 0.2 px (true disparity 87 px, a bi-prism's scene beyond 1.4 m), the
    # same as px only, bit for bit, on the biased and on the exact neighbours
    bi = dict(agree_depth=0.0022, disparity_offset=80.0)
    for kept in (biased, np.where(blocks, true, np.nan).astype(np.float32)):
        a = confident_growth(left, right, kept, conf, filled, **kw)
        b = confident_growth(left, right, kept, conf, filled, **bi, **kw)
        assert np.array_equal(a[0], b[0], equal_nan=True) and np.array_equal(a[1], b[1], equal_nan=True)
    assert (np.isfinite(a[0]) & holes).sum() > 0.5 * holes.sum()  # the exact neighbours grow either way


def _strip_in_front(seed: int = 3, h: int = 80, w: int = 200) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, int]:
    """A strongly textured strip (columns 70–129, disparity 12 px) in front of a weakly textured background
    (7 px) under sensor noise, the right view rendered with the strip's occlusion; returns left, right, the
    true disparity and the strip's columns."""
    import cv2

    rng = np.random.default_rng(seed)
    grid = np.arange(w + 40)
    bg = cv2.GaussianBlur(rng.random((h, w + 40)).astype(np.float32) * 255, (0, 0), 1.2) * 0.25
    fg = cv2.GaussianBlur(rng.random((h, w + 40)).astype(np.float32) * 255, (0, 0), 1.2)
    x0, x1, d_bg, d_fg = 70, 130, 7.0, 12.0
    xs = np.arange(w, dtype=np.float64)
    on_left = (xs >= x0) & (xs < x1)
    left = np.stack([np.where(on_left, np.interp(xs, grid, fg[y]), np.interp(xs, grid, bg[y])) for y in range(h)])
    on_right = (xs + d_fg >= x0) & (xs + d_fg < x1)
    right = np.stack([np.where(on_right, np.interp(xs + d_fg, grid, fg[y]), np.interp(xs + d_bg, grid, bg[y]))
                      for y in range(h)])
    true = np.where(on_left, d_fg, d_bg)[None, :] * np.ones((h, 1))
    left = left + rng.normal(0.0, 1.0, left.shape)
    right = right + rng.normal(0.0, 1.0, right.shape)
    return left.astype(np.float32), right.astype(np.float32), true.astype(np.float32), x0, x1


def test_a_second_smaller_window_grows_the_surface_beside_an_edge_the_wide_window_straddles():
    from prismstereo.depth.confidence import confident_growth

    left, right, true, x0, x1 = _strip_in_front()
    h, w = true.shape
    xs = np.arange(w)[None, :] * np.ones((h, 1), dtype=int)
    rows = (np.arange(h)[:, None] >= 16) & (np.arange(h)[:, None] < h - 16)
    # the background's holes beside the strip (beyond the 5 px it occludes); nothing kept on the strip
    holes = (((xs >= x0 - 24) & (xs < x0 - 5)) | ((xs >= x1) & (xs < x1 + 24))) & rows
    kept = np.where(~holes & ((xs < x0 - 5) | (xs >= x1)), true, np.nan).astype(np.float32)
    conf = np.where(np.isfinite(kept), np.float32(0.9), np.float32(np.nan))
    filled = np.rint(true).astype(np.float32)
    kw = dict(min_confidence=0.5, max_lr_gap=0.45, fit="plane", agree=0.2)
    near = holes & (((xs >= x0 - 16) & (xs < x0)) | ((xs >= x1) & (xs < x1 + 16)))
    one, _ = confident_growth(left, right, kept, conf, filled, passes=3, **kw)
    two, c_two = confident_growth(left, right, kept, conf, filled, passes=3, second_radius=5, **kw)
    # the 33×33 window reaches the strip's stronger texture within 16 px of it and confirms nothing there
    assert (np.isfinite(one) & near).sum() == 0
    grown = np.isfinite(two) & holes
    assert (grown & near).sum() > 0.4 * near.sum() and grown.sum() > 2 * (np.isfinite(one) & holes).sum()
    assert np.mean(np.abs(two[grown] - true[grown]) < 0.5) > 0.97
    assert np.all((c_two[grown] >= 0.5) & (c_two[grown] <= 1.0))
    assert not (np.isfinite(two) & (xs >= x0 - 5) & (xs < x1)).any()  # neither the occluded nor the strip
    # what the wide window confirmed keeps its value (one pass: the second window only where it did not)
    a, _ = confident_growth(left, right, kept, conf, filled, **kw)
    b, _ = confident_growth(left, right, kept, conf, filled, second_radius=5, **kw)
    assert np.array_equal(b[np.isfinite(a)], a[np.isfinite(a)])
    # neighbours 1 px off the image: the small window's values break with them too, nothing grows
    off = np.where(np.isfinite(kept), kept + np.float32(1.0), np.nan).astype(np.float32)
    d_off, _ = confident_growth(left, right, off, conf, filled, passes=3, second_radius=5, **kw)
    assert (np.isfinite(d_off) & holes).sum() < 0.02 * holes.sum()


def test_neighbour_plane_is_the_weighted_fit_through_the_neighbours_near_the_value():
    import cv2

    from prismstereo.depth.confidence import neighbour_plane

    yy, xx = np.mgrid[0:60, 0:70].astype(np.float64)
    truth = 80.0 + 0.05 * xx - 0.08 * yy
    d = truth.astype(np.float32)
    d[20:40, 20:45] = np.nan
    d[:, 50:] += np.float32(4.0)  # a second surface, outside the inlier band
    ys, xs = np.array([25, 30, 30]), np.array([22, 32, 46])
    plane, spread, inl, total = neighbour_plane(d, ys, xs, truth[ys, xs], sigma=4.0, inlier=2.0)
    assert np.allclose(plane, truth[ys, xs], atol=1e-3) and np.all(spread < 1e-2)
    # (30, 46) sees the other surface, the two others only their own
    assert inl[2] < 0.9 * total[2] and np.allclose(inl[:2], total[:2], rtol=0, atol=1e-9)
    # against a direct weighted least-squares fit of noisy values at one pixel
    rng = np.random.default_rng(1)
    noisy = (truth + rng.normal(0.0, 0.3, truth.shape)).astype(np.float32)
    noisy[rng.random(truth.shape) < 0.4] = np.nan
    p2, sp2, inl2, tot2 = neighbour_plane(noisy, np.array([30]), np.array([25]), np.array([truth[30, 25]]),
                                          sigma=3.0, inlier=100.0)
    g = cv2.getGaussianKernel(19, 3.0).astype(np.float64)[:, 0]
    win = noisy[21:40, 16:35].astype(np.float64)
    wts = np.outer(g, g) * np.isfinite(win)
    v, u = np.mgrid[-9:10, -9:10].astype(np.float64)
    a = np.stack([np.ones(361), u.ravel(), v.ravel()], 1)
    sw = np.sqrt(wts.ravel())
    theta = np.linalg.lstsq(a * sw[:, None], np.nan_to_num(win.ravel()) * sw, rcond=None)[0]
    res = np.nan_to_num(win.ravel()) - a @ theta
    assert abs(p2[0] - theta[0]) < 1e-6 and abs(inl2[0] - wts.sum()) < 1e-9 and abs(tot2[0] - wts.sum()) < 1e-9
    assert abs(sp2[0] - np.sqrt((wts.ravel() * res ** 2).sum() / wts.sum())) < 1e-6
    # values on one row only: the plane is not determined across it, their mean stands for it
    line = np.full((30, 30), np.nan, dtype=np.float32)
    line[15, :] = 50.0
    p3, _, _, _ = neighbour_plane(line, np.array([12]), np.array([15]), np.array([50.2]), sigma=3.0, inlier=1.0)
    assert abs(p3[0] - 50.0) < 1e-6


def test_neighbour_disparity_is_the_weighted_mean_and_spread_of_the_finite_values():
    from prismstereo.depth.confidence import neighbour_disparity

    d = np.full((30, 30), np.nan, dtype=np.float32)
    d[:, :15] = 80.0
    d[:, 15:] = 84.0
    d[10:20, 10:20] = np.nan
    mean, support, spread = neighbour_disparity(d, sigma=3.0)
    assert np.allclose(mean[5:25, :6], 80.0, atol=1e-4) and np.allclose(spread[5:25, :6], 0.0, atol=1e-2)
    import cv2

    g = cv2.getGaussianKernel(19, 3.0).astype(np.float64)
    wts = (g @ g.T) * np.isfinite(d[6:25, 6:25])  # the finite values in reach of (15, 15)
    vals = np.nan_to_num(d[6:25, 6:25].astype(np.float64))
    ref = (wts * vals).sum() / wts.sum()
    ref_sd = np.sqrt((wts * (vals - ref) ** 2).sum() / wts.sum())
    assert abs(float(mean[15, 15]) - ref) < 1e-3 and abs(float(spread[15, 15]) - ref_sd) < 1e-2
    assert abs(float(support[15, 15]) - wts.sum()) < 1e-4
    assert support[15, 15] < 0.5 < support[15, 5]  # a hole's middle has few finite values in reach


def test_plane_interpolation_keeps_the_neighbours_plane_where_the_dense_value_lies_on_it_and_nowhere_else():
    from prismstereo.depth.confidence import plane_interpolation

    h, w = 60, 90
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    true = 30.0 + 0.05 * xx + 0.03 * yy  # a slanted surface
    kept = true.copy()
    kept[25:35, 30:45] = np.nan  # a hole no window confirmed
    conf = np.where(np.isfinite(kept), np.float32(0.9), np.float32(np.nan)).astype(np.float32)
    dense = np.rint(true).astype(np.float32)  # the matcher's integer values, right
    d, c = plane_interpolation(kept, conf, dense, sigma=8.0, passes=2)
    hole = ~np.isfinite(kept)
    got = hole & np.isfinite(d)
    # all but where the integer value is off (its inlier band then cuts the slant one-sidedly: share < 0.95)
    assert got.sum() > 0.75 * hole.sum() and (np.abs(true - dense)[hole & ~got] > 0.2).all()
    assert np.max(np.abs(d[got] - true[got])) < 0.02  # the plane's value, not the integer one
    assert (c[got] >= 0.3).all() and (c[got] <= 1.0).all()
    assert np.array_equal(d[~hole], kept[~hole]) and np.array_equal(c[~hole], conf[~hole])
    # a dense value a pixel off the surface around it is not kept
    d_off, _ = plane_interpolation(kept, conf, dense + np.float32(1.0), sigma=8.0)
    assert not np.isfinite(d_off[hole]).any()
    # two surfaces around the hole, 3 px apart, half and half: neither is the pixel's (share < 0.9)
    step = np.where(xx < 37.5, true, true + 3.0).astype(np.float32)
    kept_step = np.where(hole, np.float32(np.nan), step).astype(np.float32)
    d_step, _ = plane_interpolation(kept_step, conf, np.rint(step).astype(np.float32), sigma=8.0, passes=1)
    near = hole & (np.abs(xx - 37.5) < 3)
    assert not np.isfinite(d_step[near]).any()
    # a dense value whose right pixel is outside the right view is not used
    vr = np.ones((h, w), dtype=bool)
    vr[:, : int(np.rint(45 - 33.0))] = False  # x − d < 12 for every hole pixel
    d_vr, _ = plane_interpolation(kept, conf, dense, sigma=8.0, valid_right=vr)
    assert not np.isfinite(d_vr[hole]).any()


def test_beside_an_occluder_the_growth_cuts_its_windows_and_its_plane_test_to_the_pixels_own_surface():
    from prismstereo.depth.confidence import confident_growth

    left, right, true, x0, x1 = _strip_in_front()
    h, w = true.shape
    xs = np.arange(w)[None, :] * np.ones((h, 1), dtype=int)
    rows = (np.arange(h)[:, None] >= 16) & (np.arange(h)[:, None] < h - 16)
    # the background's holes on both sides of the strip, the strip kept: two surfaces around every hole
    holes = (((xs >= x0 - 20) & (xs < x0 - 5)) | ((xs >= x1) & (xs < x1 + 15))) & rows
    occluded = (xs >= x0 - 5) & (xs < x0)
    kept = np.where(~holes & ~occluded, true, np.nan).astype(np.float32)
    conf = np.where(np.isfinite(kept), np.float32(0.9), np.float32(np.nan))
    filled = np.rint(true).astype(np.float32)
    kw = dict(min_confidence=0.5, max_lr_gap=0.45, fit="plane", agree=0.2, second_radius=5, passes=2)
    whole, _ = confident_growth(left, right, kept, conf, filled, **kw)
    cut, c_cut = confident_growth(left, right, kept, conf, filled, cut=1.5, gap=1.5, **kw)
    # whole windows reach the strip and the share test counts the strip against the background's plane
    assert (np.isfinite(whole) & holes).sum() < 0.4 * holes.sum()
    grown = np.isfinite(cut) & holes
    for side in (xs < x0, xs >= x1):
        assert (grown & side).sum() > 0.95 * (holes & side).sum()
    assert np.all(np.abs(cut[grown] - true[grown]) < 0.5)
    assert np.all((c_cut[grown] >= 0.5) & (c_cut[grown] <= 1.0))
    assert not (np.isfinite(cut) & occluded).any()
    # neighbours 1 px off the image: the cut windows' values break with them, nothing grows
    off = np.where(np.isfinite(kept), kept + np.float32(1.0), np.nan).astype(np.float32)
    d_off, _ = confident_growth(left, right, off, conf, filled, cut=1.5, gap=1.5, **kw)
    assert (np.isfinite(d_off) & holes).sum() < 0.02 * holes.sum()
