"""Coverage against the common view at the depths found, and the warning it drives; the automatic search range
on a tri-prism capture whose wide common view gathers false coarse matches."""

from __future__ import annotations

import dataclasses
import json
import logging

import cv2
import numpy as np
import pytest

from prismstereo.apps.demo import robot_scene, scaled_rig
from prismstereo.config import thesis_triprism
from prismstereo.depth import DepthConfig, prepare_depth, run_depth
from prismstereo.depth.pipeline import diagnose, rectify_capture
from prismstereo.depth.search_range import (
    MIN_SCENE_POINTS,
    confident_coarse,
    depth_warnings,
    disparity_clusters,
    estimate_disparity_range,
    scene_coverage,
)
from prismstereo.simulate import NoiseTexture, Rectangle, Scene, render_capture


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
    rig = scaled_rig(thesis_triprism(), 2)
    return rig, render_capture(rig, robot_scene())


@pytest.fixture(scope="module")
def robot_run(triprism_robot):
    rig, cap = triprism_robot
    return run_depth(rig, cap.image, config=DepthConfig(method="sgm"), progress=False)


def test_an_unchecked_map_counts_the_limits_where_points_were_kept(robot_run):
    """A map without a left–right check (coop) has a value at every pixel; values piled at the far limit on
    pixels that kept no point say nothing of the scene, the same pile on kept pixels does."""
    res = robot_run
    lo = res.disparity_range[0]
    kept = res.valid & np.isfinite(res.disparity)
    raw = np.asarray(res.raw_disparity, dtype=np.float32)
    assert not any("farthest searched depth" in w for w in diagnose(res))
    unchecked = {**res.match_info, "cross_checked": False}

    def piled(where):
        out = raw.copy()
        ys, xs = np.nonzero(where)
        pick = np.random.default_rng(0).choice(ys.size, size=int(0.1 * np.isfinite(raw).sum()), replace=False)
        out[ys[pick], xs[pick]] = lo
        return out

    off = piled(~kept & res.searched())
    assert any("farthest searched depth" in w for w in diagnose(dataclasses.replace(res, raw_disparity=off)))
    assert not any("farthest searched depth" in w
                   for w in diagnose(dataclasses.replace(res, raw_disparity=off, match_info=unchecked)))
    on = piled(kept)
    assert any("farthest searched depth" in w
               for w in diagnose(dataclasses.replace(res, raw_disparity=on, match_info=unchecked)))


def test_a_good_triprism_capture_does_not_warn_and_noise_does(triprism_robot, robot_run):
    """The robot (fronts at 1.50–1.54 m) before its wall (2 m) on the tri-prism: the range found keeps both
    and is a fraction of the rig's (the far false coarse matches of the rig's wide common view left out);
    the coverage is of the common view at the depths found, and the warning stays for noise."""
    rig, cap = triprism_robot
    res = robot_run
    rig_lo, rig_hi = prepare_depth(rig, config=DepthConfig()).rig_range.disparity_px  # type: ignore[union-attr]
    lo, hi = res.disparity_range
    assert res.depth_range_source == "rig+images" and hi - lo < 0.3 * (rig_hi - rig_lo)
    assert res.depth_range[0] < 1500 and res.depth_range[1] > 2000
    assert res.coverage is not None and res.coverage.of == "found" and res.coverage.share > 0.6
    assert res.coverage.depth_mm is not None and 1450 < res.coverage.depth_mm[0] < res.coverage.depth_mm[1] < 2100
    assert not any("got a depth" in w for w in res.warnings), res.warnings
    run = json.loads(json.dumps(res.summary()))
    assert run["coverage"]["of"] == "found" and run["coverage"]["share"] == round(res.coverage.share, 4)
    noise = np.random.default_rng(0).integers(0, 256, cap.image.shape, np.uint8)
    bad = run_depth(rig, noise, config=DepthConfig(method="sgm"), progress=False)
    assert any("no depth recovered" in w or "got a depth" in w for w in bad.warnings), bad.warnings


# --------------------------------------------------------------------------- the range estimate
def test_disparity_clusters_join_small_gaps_only():
    v = np.array([10.2, 10.6, 11.0, 13.9, 30.0, 30.4, 31.6, 80.0])
    # 10–11 and 14 are 2 empty values apart (12, 13): one cluster; 30–32 and 80 stand alone
    assert disparity_clusters(v, gap=2) == [(10, 14), (30, 32), (80, 80)]
    assert disparity_clusters(v, gap=1) == [(10, 11), (14, 14), (30, 32), (80, 80)]
    assert disparity_clusters(np.array([])) == []


def _textured(h, w, seed):
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.integers(0, 256, (h, w)).astype(np.float32), (0, 0), 1.2)
    return np.clip((img - img.mean()) / img.std() * 40 + 128, 0, 255).astype(np.uint8)


def test_confident_coarse_confirms_the_true_shift_only():
    h, w, shift = 60, 120, 12
    base = _textured(h, w + shift, 0)
    left, right = base[:, :w], base[:, shift:]  # left x shows right x − shift
    inside = np.ones((h, w), dtype=bool)
    ok = np.ones((h, w), dtype=bool)
    true = confident_coarse(np.full((h, w), float(shift), np.float32), ok, left, right, inside, inside)
    assert true[10:-10, 30:-10].all()  # away from the borders and from x − shift < 0
    wrong = confident_coarse(np.full((h, w), float(shift + 7), np.float32), ok, left, right, inside, inside)
    assert wrong.mean() < 0.01
    flat = np.full((h, w), 5, np.uint8)
    assert not confident_coarse(np.full((h, w), float(shift), np.float32), ok, flat, flat, inside, inside).any()
    # a window touching a view's invalid part is no confirmation
    half = inside.copy()
    half[:, 60:] = False
    near = confident_coarse(np.full((h, w), float(shift), np.float32), ok, left, right, half, inside)
    assert not near[:, 55:].any() and near[10:-10, 30:50].all()  # a 9-wide window, one pixel to spare


@pytest.fixture(scope="module")
def tri_setup():
    rig = scaled_rig(thesis_triprism(), 2)
    setup = prepare_depth(rig, config=DepthConfig())
    return rig, setup.pair, setup.rig_range


def _range_of(tri_setup, scene):
    """(the new range, the true disparities of the scene in the rig's common view, the rig's range)."""
    rig, pair, known = tri_setup
    cap = render_capture(rig, scene)
    left, right = rectify_capture(pair, cap.image)
    h, w = left.shape[:2]
    ys, xs = np.nonzero(known.region)
    px = np.stack([xs, ys], axis=1).astype(np.float64)
    real = pair.rectified_to_real(px, "left")
    ri, ci = np.rint(real[:, 1]).astype(int), np.rint(real[:, 0]).astype(int)
    inb = (ri >= 0) & (ri < cap.depth.shape[0]) & (ci >= 0) & (ci < cap.depth.shape[1])
    pts = np.full((px.shape[0], 3), np.nan)
    pts[inb] = cap.points[ri[inb], ci[inb]]
    seen = np.isfinite(pts[:, 2])
    true_d = px[seen, 0] - pair.project(pts[seen], "right")[:, 0]  # the rectified right camera's projection
    lo, hi = known.disparity_px
    vl, vr = (np.asarray(m, dtype=bool) for m in pair.valid_masks())
    est, _ = estimate_disparity_range(left, right, known.region, lo=lo, hi=min(hi, w - 1), valid_left=vl,
                                      valid_right=vr)
    return est, true_d, (lo, hi)


def _panel(z, size, seed):
    return Rectangle(center=(0.0, 0.0, z), size=(size, size), texture=NoiseTexture(scale=15.0, seed=seed))


def test_a_scene_before_an_empty_background_gets_a_narrow_range_that_brackets_it(tri_setup, caplog):
    """A panel at 1.5 m and nothing behind it: the tri-prism's common view over the rig's depths is mostly
    unlit background, whose coarse matches (5 clusters) spread over the rig's whole range; the range kept
    brackets the panel with a margin and is a fraction of the rig's."""
    scene = Scene(objects=(_panel(1500.0, 150.0, 3),), supersample=1, noise=1.5, seed=0)
    with caplog.at_level(logging.INFO, logger="prismstereo.depth.search_range"):
        est, true_d, (lo, hi) = _range_of(tri_setup, scene)
    assert est is not None and true_d.size > 10_000
    assert est[0] <= true_d.min() - 5 and est[1] >= true_d.max() + 5
    assert est[1] - est[0] < 0.15 * (hi - lo)
    left_out = [r.getMessage() for r in caplog.records if "left out" in r.getMessage()]
    assert left_out and all("0 confirmed" in m for m in left_out)


def test_both_layers_of_a_two_layer_scene_are_kept(tri_setup):
    scene = Scene(objects=(_panel(1300.0, 120.0, 3), _panel(2200.0, 500.0, 4)), supersample=1, noise=1.5, seed=0)
    est, true_d, (lo, hi) = _range_of(tri_setup, scene)
    near, far = true_d[true_d > 65], true_d[true_d <= 65]
    assert near.size > 1000 and far.size > 1000  # both layers are in the common view
    assert est is not None and est[0] <= far.min() - 3 and est[1] >= near.max() + 3
    assert est[1] - est[0] < 0.3 * (hi - lo)


def test_too_few_confirmed_matches_keep_the_wide_range_and_say_why(tri_setup, caplog):
    """A small panel: its coarse matches are too few for the images to confirm, the far false ones are not;
    the range stays the percentiles of every match (as wide as before), and the log says why."""
    scene = Scene(objects=(_panel(1500.0, 50.0, 3),), supersample=1, noise=1.5, seed=0)
    with caplog.at_level(logging.INFO, logger="prismstereo.depth.search_range"):
        est, true_d, (lo, hi) = _range_of(tri_setup, scene)
    assert true_d.size > 500 and est is not None
    assert est[0] <= true_d.min() and est[1] >= true_d.max() and est[1] - est[0] > 0.5 * (hi - lo)
    assert any("too few to tell" in r.getMessage() for r in caplog.records)
