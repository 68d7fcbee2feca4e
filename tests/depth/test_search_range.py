"""Coverage against the common view at the depths found, and the warning it drives."""

from __future__ import annotations

import numpy as np
import pytest

from prismstereo.depth.search_range import MIN_SCENE_POINTS, depth_warnings, scene_coverage


def _warnings(cov, points):
    return depth_warnings(points=points, region_pixels=10_000, matched=points, confident=points, disparity=None,
                          valid=None, disparity_range=(10, 200), depth_range=(300.0, 2400.0), coverage=cov)


def test_the_view_is_where_the_found_disparities_land_in_the_right_view():
    h, w = 20, 300
    searched = np.ones((h, w), dtype=bool)
    vr = np.zeros((h, w), dtype=bool)
    vr[:, 50:100] = True  # the right view: columns 50–99
    disp = np.full((h, w), np.nan, dtype=np.float32)
    disp[:, 120:140] = 40.0
    disp[:, 140:160] = 60.3  # x − d in 79.7–99.7: inside
    valid = np.isfinite(disp)
    depth = np.where(valid, 1000.0 / np.where(valid, disp, 1), np.nan)
    cov = scene_coverage(disp, valid, depth, searched, vr)
    assert cov.of == "found" and cov.disparity_px == (40, 61)
    # x − d ∈ [50, 99] for some d ∈ [40, 61]: x ∈ [90, 160]
    assert cov.pixels == h * 71 and cov.points == int(valid.sum())
    assert cov.depth_mm is not None and cov.depth_mm[0] < cov.depth_mm[1]
    assert _warnings(cov, cov.points) == []  # 40 of 71 columns
    few = valid & (np.arange(w) < 125)[None, :]  # 5 columns at d = 40 only: x − 40 ∈ [50, 99], x ∈ [90, 139]
    cov_few = scene_coverage(disp, few, depth, searched, vr)
    assert cov_few.disparity_px == (40, 40) and cov_few.pixels == h * 50 and cov_few.share == pytest.approx(0.1)
    (line,) = _warnings(cov_few, cov_few.points)
    assert line.startswith(f"only {100 * cov_few.share:.1f} % of the common view at the depths found (")


def test_too_few_points_fall_back_to_the_searched_view():
    h, w = 20, 300
    searched = np.zeros((h, w), dtype=bool)
    searched[:, 100:] = True
    disp = np.full((h, w), np.nan, dtype=np.float32)
    disp[0, 150:150 + MIN_SCENE_POINTS - 1] = 30.0
    valid = np.isfinite(disp)
    cov = scene_coverage(disp, valid, np.where(valid, 2000.0, np.nan), searched, np.ones((h, w), dtype=bool))
    assert cov.of == "searched" and cov.pixels == int(searched.sum()) and cov.disparity_px is None
    (line,) = _warnings(cov, cov.points)
    assert "of the common view of the searched depths (300–2400 mm)" in line


@pytest.fixture(scope="module")
def triprism_robot():
    from prismstereo.apps.demo import robot_scene, scaled_rig
    from prismstereo.config import thesis_triprism
    from prismstereo.simulate import render_capture

    rig = scaled_rig(thesis_triprism(), 2)
    return rig, render_capture(rig, robot_scene())


def test_a_good_triprism_capture_does_not_warn_and_noise_does(triprism_robot):
    """The tri-prism's common view at the robot's depths is a quarter of that of the rig's whole range (the
    coarse match leaves the range wide): the coverage is of the former, and the warning stays for noise."""
    import json

    from prismstereo.depth import DepthConfig, run_depth

    rig, cap = triprism_robot
    res = run_depth(rig, cap.image, config=DepthConfig(method="sgm"), progress=False)
    c = res.counts()
    assert c["points"] / c["region_pixels"] < 0.3  # what the warning used to read
    assert res.coverage is not None and res.coverage.of == "found" and res.coverage.share > 0.6
    assert res.coverage.depth_mm is not None and 1450 < res.coverage.depth_mm[0] < res.coverage.depth_mm[1] < 2100
    assert not any("got a depth" in w for w in res.warnings), res.warnings
    run = json.loads(json.dumps(res.summary()))
    assert run["coverage"]["of"] == "found" and run["coverage"]["share"] == round(res.coverage.share, 4)
    noise = np.random.default_rng(0).integers(0, 256, cap.image.shape, np.uint8)
    bad = run_depth(rig, noise, config=DepthConfig(method="sgm"), progress=False)
    assert any("no depth recovered" in w or "got a depth" in w for w in bad.warnings), bad.warnings
