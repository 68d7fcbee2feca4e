"""Disparity plane fitting with outlier rules and merging (thesis §6.1)."""

from __future__ import annotations

import numpy as np

from prismstereo.matching.segments.planes import (
    PlaneParams,
    build_segment_index,
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
