"""The rig's working depth range, and the rectification of a strongly converging pair at its working depth."""

from __future__ import annotations

import numpy as np
import pytest

from prismstereo.cameras import calibrate_rig
from prismstereo.cameras.overlap import overlap_span, working_depth_range
from prismstereo.config import thesis_biprism
from prismstereo.rectify import rectify_pair
from prismstereo.rectify.verify import true_correspondences, vertical_residual


def test_working_depth_range_follows_the_overlap():
    near, far = working_depth_range(thesis_biprism())
    # the 6.4° bi-prism's views overlap from ~0.27 m to infinity; one pixel of disparity is 4 % of the depth at 5.1 m
    assert 230.0 < near < 350.0 and 4500.0 < far < 5500.0
    near20, far20 = working_depth_range(thesis_biprism(20.0))
    assert 200.0 < near20 < 260.0 and 300.0 < far20 < 400.0


@pytest.fixture(scope="module")
def pair20():
    rig = thesis_biprism(20.0)
    views = calibrate_rig(rig)
    return rig, rectify_pair(rig, views[0], views[1])


def test_strong_biprism_pair_is_cropped_to_its_common_view(pair20):
    rig, pair = pair20
    assert pair.disparity_offset > 1000.0
    assert pair.size[0] < 800  # 1951 px with one principal point for both views
    corr = true_correspondences(rig, pair.left_face, pair.right_face, n=3000, depth_range=(260.0, 320.0))
    res, _ = vertical_residual(pair, corr)
    assert np.median(np.abs(_)) <= 0.2 and res.p95 <= 0.5
    # image disparity + offset is the true one: Q (and so the 'q' triangulation) recovers the points
    pl, pr = (corr.pixels_a, corr.pixels_b) if corr.face_a == pair.left_face else (corr.pixels_b, corr.pixels_a)
    xl, xr = pair.real_to_rectified(pl, "left"), pair.real_to_rectified(pr, "right")
    d = xl[:, 0] - xr[:, 0]
    assert d.min() >= 0.0 and d.max() < pair.size[0]
    pts = pair.reproject(xl, d)
    rel = np.abs(pts[:, 2] - corr.points[:, 2]) / corr.points[:, 2]
    assert np.median(rel) < 2e-3


def test_overlap_span_interpolates_or_keeps_the_samples():
    depths = np.array([100.0, 200.0, 400.0, 800.0, 1600.0])
    frac = np.array([0.0, 0.5, 1.0, 0.5, 0.0])
    # level 0.25: halfway in fraction between the first two and the last two samples, in log depth
    near, far = overlap_span(depths, frac)
    assert np.isclose(near, np.sqrt(100.0 * 200.0)) and np.isclose(far, np.sqrt(800.0 * 1600.0))
    assert overlap_span(depths, frac, interpolate=False) == (200.0, 800.0)
    assert overlap_span(depths, frac, fraction=0.8, interpolate=False) == (400.0, 400.0)
