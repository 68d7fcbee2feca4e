"""Disparity plane fitting with outlier rules and merging (thesis §6.1)."""

from __future__ import annotations

import numpy as np

from prismstereo.matching.segments.planes import (
    PlaneParams,
    build_segment_index,
    curved_segment_surfaces,
    fit_planes,
    merge_planes,
    plane_similarity,
    render_planes,
)


def _scene(seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    h, w = 40, 60
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    labels = (xx >= 30).astype(np.int32)
    truth = np.array([[0.05, -0.02, 6.0], [-0.1, 0.03, 15.0]])
    disp = truth[labels, 0] * xx + truth[labels, 1] * yy + truth[labels, 2]
    rng = np.random.default_rng(seed)
    noisy = disp.copy()
    out = rng.random(disp.shape) < 0.25  # a quarter of the pixels are gross outliers
    # gross outliers, all farther than t_outlier from the true plane (rule of Eq. 6.9)
    noisy[out] += rng.choice([-1.0, 1.0], out.sum()) * rng.uniform(2.0, 15.0, out.sum())
    reliable = np.ones((h, w), bool)
    reliable[rng.random(disp.shape) < 0.05] = False  # cross-check failures (Eq. 6.7)
    noisy[~reliable] = np.nan
    return labels, noisy, reliable, truth


def test_planes_recovered_exactly_despite_outliers() -> None:
    labels, noisy, reliable, truth = _scene()
    idx = build_segment_index(labels)
    planes, inl = fit_planes(idx, noisy, reliable)
    np.testing.assert_allclose(planes, truth, atol=1e-8)
    assert (inl > 0.6 * 1200).all()


def test_unreliable_segment_gets_no_plane() -> None:
    labels, noisy, reliable, _ = _scene(1)
    reliable[:, :30] = False
    reliable[:, :30][::10, ::10] = True  # 1 % reliable < 1 - γ_segment (Eq. 6.8)
    idx = build_segment_index(labels)
    planes, _ = fit_planes(idx, noisy, reliable, params=PlaneParams(gamma_segment=0.9))
    assert np.isnan(planes[0]).all() and np.isfinite(planes[1]).all()


def test_merge_joins_coplanar_neighbours_only() -> None:
    h, w = 30, 90
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    labels = (xx // 30).astype(np.int32)  # three segments side by side
    disp = np.where(labels < 2, 0.02 * xx + 5.0, 20.0)
    idx = build_segment_index(labels)
    rel = np.ones((h, w), bool)
    planes, _ = fit_planes(idx, disp, rel)
    pairs = np.array([[0, 1], [1, 2]], np.int32)
    cluster, cpl = merge_planes(idx, planes, pairs, disp, rel)
    assert cluster[0] == cluster[1] != cluster[2]
    np.testing.assert_allclose(render_planes(idx, cpl, cluster), disp, atol=1e-6)


def test_similarity_is_one_for_identical_planes_and_small_for_far_ones() -> None:
    p = np.array([[0.1, 0.0, 3.0]])
    c = np.array([[10.0, 10.0]])
    assert plane_similarity(p, p, c, c)[0] == 1.0
    assert plane_similarity(p, p + [0, 0, 5.0], c, c)[0] < 0.01


def _cloth(h: int = 40, w: int = 60) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One segment on a surface curved along x (a fold of cloth): its robust plane (within 1 px of 92 % of
    it) is up to 1.3 px off at the segment's ends. Returns labels, true disparity and the plane map."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    true = 30.0 + 0.05 * yy + 0.002 * (xx - w / 2) ** 2
    labels = np.zeros((h, w), np.int32)
    idx = build_segment_index(labels)
    planes, _ = fit_planes(idx, true, np.ones((h, w), bool))
    return labels, true, render_planes(idx, planes, np.zeros(1, np.int32))


def test_segment_on_a_curved_surface_takes_the_quadric_of_its_evidence() -> None:
    labels, true, plane = _cloth()
    rng = np.random.default_rng(5)
    evidence = rng.random(true.shape) < 0.6  # the cross-checked evidence: 60 % of the pixels, 0.15 px noise
    reference = (true + rng.normal(0.0, 0.15, true.shape)).astype(np.float32)
    planar = np.ones(true.shape, bool)
    assert (np.abs(plane - true) > 1.0).mean() > 0.05  # one plane cannot follow the fold
    out, curved = curved_segment_surfaces(labels, plane, planar, evidence, reference)
    assert curved.tolist() == [True]
    assert (np.abs(out - true) > 1.0).mean() == 0.0 and np.abs(out - true).max() < 0.5
    # the rule off (no curvature is large enough): the plane stays
    same, curved = curved_segment_surfaces(labels, plane, planar, evidence, reference, min_amplitude=10.0)
    assert not curved.any()
    np.testing.assert_array_equal(same, plane.astype(np.float32))
    # pixels another step chose (not on their segment's plane) are left alone
    planar[:, :10] = False
    part, _ = curved_segment_surfaces(labels, plane, planar, evidence, reference)
    np.testing.assert_array_equal(part[:, :10], plane[:, :10].astype(np.float32))


def test_evidence_offset_or_tilted_from_the_plane_is_not_a_curve() -> None:
    """Evidence that differs from the plane by a constant or a tilt (a biased initial map, a quantised
    ground truth) is no reason to leave the plane: only a curved residual is followed."""
    h, w = 40, 60
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    labels = np.zeros((h, w), np.int32)
    plane = (12.0 + 0.01 * xx).astype(np.float32)
    rng = np.random.default_rng(2)
    for bias in (0.6 + 0 * xx, 0.015 * (xx - w / 2) + 0.01 * (yy - h / 2)):
        reference = (plane + bias + rng.normal(0.0, 0.15, (h, w))).astype(np.float32)
        out, curved = curved_segment_surfaces(labels, plane, np.ones((h, w), bool), np.ones((h, w), bool),
                                              reference)
        assert not curved.any()
        np.testing.assert_array_equal(out, plane)
    # too little evidence for a quadric: nothing
    labels2, true, plane2 = _cloth()
    sparse = np.zeros(true.shape, bool)
    sparse[::8, ::8] = True  # 40 px < min_evidence
    out, curved = curved_segment_surfaces(labels2, plane2, np.ones(true.shape, bool), sparse, true)
    assert not curved.any()


def test_segment_index_lists_each_segments_pixels_in_raster_order() -> None:
    rng = np.random.default_rng(3)
    labels = rng.integers(0, 40, (23, 31)).astype(np.int32)
    labels[labels == 7] = 8  # an empty segment inside the range
    index = build_segment_index(labels)
    order = np.argsort(labels.ravel(), kind="stable")
    assert np.array_equal(index.order, order)
    assert np.array_equal(np.diff(index.starts), np.bincount(labels.ravel(), minlength=40))
    assert index.order.dtype == np.int64 and index.starts.dtype == np.int64


def test_render_planes_is_the_float64_plane_rounded_once_and_nan_without_a_plane() -> None:
    rng = np.random.default_rng(4)
    labels = rng.integers(0, 6, (17, 29)).astype(np.int32)
    planes = rng.normal(size=(4, 3)) * [0.3, 0.3, 20.0]
    assign = np.array([0, 3, -1, 1, 2, 3])
    yy, xx = np.mgrid[0:17, 0:29]
    a = assign[labels]
    pl = planes[np.clip(a, 0, None)]
    expect = np.where(a >= 0, pl[..., 0] * xx + pl[..., 1] * yy + pl[..., 2], np.nan).astype(np.float32)
    out = render_planes(build_segment_index(labels), planes, assign)
    assert out.dtype == np.float32 and np.array_equal(out, expect, equal_nan=True)


def test_plane_fits_do_not_depend_on_the_number_of_threads() -> None:
    import numba

    rng = np.random.default_rng(5)
    labels = (np.arange(60)[None, :] // 6 + 10 * (np.arange(40)[:, None] // 8)).astype(np.int32)
    yy, xx = np.mgrid[0:40, 0:60].astype(np.float64)
    disp = 0.1 * xx - 0.05 * yy + 20.0 + rng.normal(0, 0.5, xx.shape) + 3.0 * (labels % 3)
    reliable = rng.random(xx.shape) > 0.1
    index = build_segment_index(labels)
    prev = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = fit_planes(index, disp, reliable)
        numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
        two = fit_planes(index, disp, reliable)
    finally:
        numba.set_num_threads(prev)
    assert np.isfinite(one[0][:, 0]).sum() > 40
    assert np.array_equal(one[0], two[0], equal_nan=True) and np.array_equal(one[1], two[1])
