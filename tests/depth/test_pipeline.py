"""The depth pipeline end to end on simulated captures, with accuracy against the simulator's truth."""

from __future__ import annotations

import numpy as np
import pytest

from prismstereo.apps.demo import demo_scene, scaled_rig
from prismstereo.config import pyramid_rig, thesis_triprism
from prismstereo.depth import DepthConfig, run_depth, triangulate_matches, validate_inputs
from prismstereo.depth.outputs import OUTPUT_FILES, write_depth_outputs
from prismstereo.depth.refine import refine_disparity
from prismstereo.errors import ConfigError, ImageError
from prismstereo.evaluation.depth_metrics import evaluate_depth
from prismstereo.io import read_pfm, read_ply


def test_accuracy_targets_on_a_slanted_plane(plane_run):
    acc = plane_run.accuracy
    assert acc["median_rel"] <= 0.0025
    assert acc["within_1pct"] >= 0.90
    assert acc["coverage"] >= 0.70
    assert acc["n_points"] > 10_000


def test_triangulations_agree_on_the_same_matches(plane_run, plane_gt):
    res = plane_run
    ys, xs = np.nonzero(res.valid)
    d = res.disparity[ys, xs].astype(np.float64)
    zgt = plane_gt.depth[ys, xs]
    meds = {}
    for method in ("exact", "midpoint", "dlt", "q"):
        tri = triangulate_matches(res.rig, res.pair, ys, xs, d, method=method, views=res.views)
        assert tri.valid.mean() > 0.99
        meds[method] = float(np.nanmedian(np.abs(tri.points[:, 2] - zgt) / zgt))
    assert meds["exact"] <= 0.0025
    for method in ("midpoint", "dlt", "q"):
        assert meds[method] < 0.01  # the fitted pinhole approximates refraction well at these depths


def test_exact_triangulation_with_true_disparities_is_exact(plane_run, plane_gt):
    """Geometry alone does not limit accuracy: true correspondences give the true points."""
    from prismstereo.optics import project_exact

    res = plane_run
    gt = plane_gt
    ys, xs = np.nonzero(gt.common)
    sel = slice(None, None, 97)
    ys, xs = ys[sel], xs[sel]
    X = gt.points[ys, xs]
    pr, ok = project_exact(res.rig, X, face=res.pair.right_face, tolerance_px=1e-9)
    rr = res.pair.real_to_rectified(pr, "right")
    d = xs - rr[:, 0]
    tri = triangulate_matches(res.rig, res.pair, ys, xs, d, method="exact", views=res.views)
    ok &= tri.valid
    assert ok.mean() > 0.95
    rel = np.linalg.norm(tri.points[ok] - X[ok], axis=1) / np.linalg.norm(X[ok], axis=1)
    # the remap table is sampled bilinearly: rectified -> real pixel is exact to ~1e-5 px
    assert np.median(rel) < 1e-5


def test_outputs_are_written_together(plane_run, tmp_path):
    out = tmp_path / "out"
    paths = write_depth_outputs(plane_run, out, report=True)
    assert sorted(p.name for p in out.iterdir()) == sorted(OUTPUT_FILES)
    assert set(paths) == set(OUTPUT_FILES)
    depth = read_pfm(out / "depth.pfm")
    assert depth.shape == plane_run.left.shape[:2]
    pts, cols = read_ply(out / "points.ply")
    assert pts.shape[0] == int(plane_run.valid.sum()) and cols is not None
    assert np.isfinite(pts).all()
    assert np.allclose(np.nanmedian(depth), np.median(pts[:, 2]), rtol=1e-3)
    conf = read_pfm(out / "confidence.pfm")
    assert conf.shape == depth.shape
    assert np.array_equal(np.isfinite(conf), np.isfinite(depth))
    from plyfile import PlyData

    vertex = PlyData.read(str(out / "points.ply"))["vertex"]
    assert "confidence" in vertex.data.dtype.names
    ply_conf = np.asarray(vertex["confidence"])
    assert ply_conf.shape[0] == pts.shape[0]
    assert np.array_equal(ply_conf, conf[plane_run.valid])  # same row-major order as the points
    assert ply_conf.min() >= plane_run.config.min_confidence and ply_conf.max() <= 1.0


def test_roi_restricts_the_points(plane_capture):
    rig, _, cap = plane_capture
    res = run_depth(rig, cap.image, config=DepthConfig(roi=(60, 100, 80, 60), method="sad"))
    ys, xs = np.nonzero(res.valid)
    assert ys.size > 1000
    assert xs.min() >= 60 and xs.max() < 140 and ys.min() >= 100 and ys.max() < 160


@pytest.mark.parametrize("rig", [scaled_rig(thesis_triprism(), 2), scaled_rig(pyramid_rig(4), 2)],
                         ids=["triprism", "pyramid4"])
def test_multi_face_rigs_run_end_to_end(rig):
    from prismstereo.simulate import render_capture

    scene = demo_scene()
    cap = render_capture(rig, scene, supersample=1)
    res = run_depth(rig, cap.image, config=DepthConfig(method="sad"))
    acc = evaluate_depth(res, scene=scene)
    assert res.faces == (0, 1) or res.faces == (1, 0)
    assert acc["n_points"] > 1000
    assert acc["median_rel"] < 0.01


def test_validation_errors(plane_capture):
    rig, _, cap = plane_capture
    with pytest.raises(ImageError, match="expected a 512×384 capture"):
        validate_inputs(rig, cap.image[:100], DepthConfig())
    with pytest.raises(ConfigError, match="^DepthConfig.method: "):
        validate_inputs(rig, cap.image, DepthConfig(method="nope"))
    with pytest.raises(ConfigError, match="^DepthConfig.views: "):
        validate_inputs(rig, cap.image, DepthConfig(views=(0, 0)))
    with pytest.raises(ConfigError, match="^DepthConfig.views: "):
        validate_inputs(rig, cap.image, DepthConfig(views=(0, 5)))
    with pytest.raises(ConfigError, match="^DepthConfig.depth_range: "):
        validate_inputs(rig, cap.image, DepthConfig(depth_range=(100.0, 5000.0)))
    with pytest.raises(ConfigError, match="^DepthConfig.triangulation: "):
        validate_inputs(rig, cap.image, DepthConfig(triangulation="magic"))
    with pytest.raises(ConfigError, match="refine_prefilter"):
        validate_inputs(rig, cap.image, DepthConfig(refine_prefilter=-0.5))


def test_refinement_recovers_a_subpixel_shift():
    rng = np.random.default_rng(0)
    base = rng.uniform(0, 255, (60, 400)).astype(np.float32)
    import cv2

    base = cv2.GaussianBlur(base, (0, 0), 1.2)
    true_d = 20.37
    xs = np.arange(400, dtype=np.float32)[None, :].repeat(60, 0)
    ys = np.arange(60, dtype=np.float32)[:, None].repeat(400, 1)
    right = cv2.remap(base, xs + true_d, ys, cv2.INTER_CUBIC)  # right(x) = left(x + d)
    init = np.full((60, 400), 20.0, dtype=np.float32)
    d, conf = refine_disparity(base, right, init, radius=3)
    inner = d[10:50, 40:360]
    assert abs(float(np.median(inner)) - true_d) < 0.03  # bilinear sampling leaves ~0.02 px of bias
    assert np.nanmedian(conf[10:50, 40:360]) > 0.95


def test_the_steps_compose_to_run_depth(plane_capture, plane_run):
    """The pipeline is its ordered steps: calling them by hand gives run_depth's result; the result is frozen."""
    import dataclasses

    from prismstereo.depth import pipeline as pl

    rig, _, cap = plane_capture
    img, cfg = pl.validate_inputs(rig, cap.image, DepthConfig())
    views = pl.virtual_cameras(rig, cfg)
    pair = pl.rectify_geometry(rig, views, cfg)
    left, right = pl.rectify_capture(pair, img)
    region = pl.search_region(rig, pair, cfg, left, right)
    matched = pl.match_pair(left, right, pair, region, cfg)
    # the default refinement tries the dense map where no match was kept (refine_fill_agree, refine_grow_radius):
    # it is computed
    assert pl.needs_dense_map(cfg) and matched.filled is not None
    bare = dataclasses.replace(cfg, refine_fill_agree=None, refine_grow_radius=None, refine_interp_sigma=None)
    assert not pl.needs_dense_map(bare) and pl.needs_dense_map(dataclasses.replace(bare, refine_fill=True))
    assert pl.needs_dense_map(dataclasses.replace(bare, refine_interp_sigma=8.0))
    assert pl.needs_dense_map(dataclasses.replace(bare, refine_grow_radius=16))
    assert not pl.needs_dense_map(dataclasses.replace(bare, refine_grow_radius=16, refine_max_lr_gap=None))
    # a run that reads no dense map skips the matcher's hole filling; the cross-checked matches are the same
    no_dense = pl.match_pair(left, right, pair, region, bare)
    assert no_dense.filled is None and no_dense.info["dense_map"] is False
    assert np.isfinite(matched.filled).sum() > np.isfinite(no_dense.raw).sum()
    np.testing.assert_array_equal(no_dense.disparity, matched.disparity)
    np.testing.assert_array_equal(no_dense.raw, matched.raw)
    disp, _ = pl.refine_matches(left, right, pair, matched.disparity, cfg, epipolar=pl.epipolar_curves(pair),
                                filled=matched.filled, right_excluded=region.right_excluded)
    disp = pl.remove_speckles(disp, region, cfg)
    from prismstereo.depth.triangulation import ray_table

    pts = pl.triangulate_disparity(rig, pair, views, disp, cfg, rays=ray_table(rig, pair))
    np.testing.assert_array_equal(pts.depth, plane_run.depth)
    np.testing.assert_array_equal(disp, plane_run.disparity)
    assert region.disparity_range == plane_run.disparity_range and cfg == plane_run.config
    with pytest.raises(dataclasses.FrozenInstanceError):
        plane_run.depth = pts.depth  # type: ignore[misc]


def test_the_plane_growth_confirms_its_windows_from_its_own_zncc_threshold(plane_capture, monkeypatch):
    """refine_grow_min_confidence lowers the growth's threshold (only with the plane test, only below
    min_confidence); the matches and the fill keep min_confidence."""
    import dataclasses

    from prismstereo.depth import pipeline as pl

    rig, _, cap = plane_capture
    img, cfg = pl.validate_inputs(rig, cap.image, DepthConfig())
    views = pl.virtual_cameras(rig, cfg)
    pair = pl.rectify_geometry(rig, views, cfg)
    left, right = pl.rectify_capture(pair, img)
    disparity = np.full(left.shape[:2], 30.0, dtype=np.float32)
    asked: list[tuple[str, float | None]] = []

    def matches(left, right, disparity, **kwargs):  # what the steps are asked, not their work
        asked.append(("matches", kwargs["min_confidence"]))
        return disparity, np.ones_like(disparity)

    def growth(left, right, disparity, confidence, filled, **kwargs):
        asked.append(("growth", kwargs["min_confidence"]))
        return disparity, confidence

    monkeypatch.setattr(pl, "confident_matches", matches)
    monkeypatch.setattr(pl, "confident_growth", growth)
    for over, want in (({}, 0.3), ({"refine_grow_fit": "mean"}, 0.5), ({"refine_grow_min_confidence": None}, 0.5),
                       ({"min_confidence": 0.2}, 0.2)):
        asked.clear()
        c = dataclasses.replace(cfg, refine_fill_agree=None, **over)
        pl.refine_matches(left, right, pair, disparity, c, epipolar=None, filled=disparity)
        assert asked == [("matches", c.min_confidence), ("growth", want)], over


def test_a_map_without_a_cross_check_is_refined_with_confirmed_right_seeds(plane_capture, plane_run, monkeypatch):
    """match_pair records whether its matches passed the matcher's left–right check (coop's map has none;
    ``use_filled`` refines the dense map); the run's refinement is told so."""
    from prismstereo.depth import pipeline as pl

    rig, _, cap = plane_capture
    assert plane_run.match_info["cross_checked"] is True  # bpasw's cross-checked matches
    assert pl.run_depth(rig, cap.image, config=DepthConfig(use_filled=True)).match_info["cross_checked"] is False
    seen: list[bool] = []
    real_cm = pl.confident_matches

    def recording(*args, **kwargs):
        seen.append(kwargs["seeds_checked"])
        return real_cm(*args, **kwargs)

    monkeypatch.setattr(pl, "confident_matches", recording)
    monkeypatch.setattr(pl, "UNCHECKED_MATCHERS", frozenset({"bpasw"}))  # bpasw's map taken as unchecked
    res = pl.run_depth(rig, cap.image, config=DepthConfig())
    assert res.match_info["cross_checked"] is False and seen == [False]
    assert res.valid.sum() >= 0.99 * plane_run.valid.sum()  # its confirmed values stand for the right view


def test_coarse_to_fine_depth_matches_the_full_search(plane_capture):
    """Issue 30: the depth run with coarse-to-fine forced on keeps the full search's accuracy and coverage,
    and run.json records what ran; a memory budget too small for any tile is refused."""
    import pytest

    from prismstereo.depth import DepthConfig, run_depth
    from prismstereo.errors import ConfigError, MatchingError
    from prismstereo.evaluation.depth_metrics import evaluate_depth, ground_truth_for_run

    rig, scene, cap = plane_capture
    out = {}
    for mode in ("off", "on"):
        res = run_depth(rig, cap.image, config=DepthConfig(method="sgm", coarse_to_fine=mode))
        out[mode] = evaluate_depth(res, gt=ground_truth_for_run(res, scene=scene))
        info = res.summary()["matching"]
        assert info["coarse_to_fine"] is (mode == "on")
        assert res.summary()["config"]["coarse_to_fine"] == mode
    assert abs(out["on"]["median_rel"] - out["off"]["median_rel"]) * 100 < 0.02
    assert abs(out["on"]["coverage"] - out["off"]["coverage"]) * 100 < 2.0
    with pytest.raises(MatchingError, match="max_memory"):
        run_depth(rig, cap.image, config=DepthConfig(method="sgm", max_memory=2**20))
    with pytest.raises(ConfigError, match="coarse_to_fine"):
        run_depth(rig, cap.image, config=DepthConfig(coarse_to_fine="maybe"))


def test_a_third_window_refines_the_weak_kept_matches_and_drops_none(plane_capture, monkeypatch):
    """refine_third_radius: the kept matches below refine_third_below are refined again from the matcher's value
    with the third window; its values confirmed with a higher ZNCC replace theirs, the others keep theirs, none
    is dropped."""
    import dataclasses

    from prismstereo.depth import pipeline as pl

    rig, _, cap = plane_capture
    img, cfg = pl.validate_inputs(rig, cap.image, DepthConfig())
    pair = pl.rectify_geometry(rig, pl.virtual_cameras(rig, cfg), cfg)
    left, right = pl.rectify_capture(pair, img)
    h, w = left.shape[:2]
    t = w // 3
    disparity = np.full((h, w), 30.0, dtype=np.float32)
    calls: list[tuple[int, int | None, np.ndarray]] = []

    def matches(left, right, disparity, **kwargs):  # what the windows are asked, not their work
        calls.append((kwargs["radius"], kwargs["retry_radius"], np.isfinite(disparity)))
        nan = np.float32(np.nan)
        if len(calls) == 1:  # the first two windows: strong, weak and weaker thirds, the last column dropped
            conf = np.full((h, w), 0.99, dtype=np.float32)
            conf[:, t:2 * t], conf[:, 2 * t:] = 0.9, 0.6
            d = disparity + np.float32(0.1)
            d[:, -1], conf[:, -1] = nan, nan
            return d, conf
        d = np.where(np.isfinite(disparity), disparity + np.float32(0.3), nan)  # the third confirms even rows
        d[1::2] = nan
        c3 = np.where(np.isfinite(d), np.float32(0.97), nan)
        c3[0::4] = 0.55  # confirmed, but matching worse than the weaker third's 0.6
        return d, c3

    monkeypatch.setattr(pl, "confident_matches", matches)
    c = dataclasses.replace(cfg, refine_fill_agree=None, refine_grow_radius=None, refine_interp_sigma=None,
                            refine_third_radius=16)
    disp, conf = pl.refine_matches(left, right, pair, disparity, c, epipolar=None)
    assert [call[:2] for call in calls] == [(c.refine_radius, c.refine_retry_radius), (16, None)]
    asked = calls[1][2]
    assert not asked[:, :t].any() and asked[:, t:-1].all() and not asked[:, -1].any()
    np.testing.assert_allclose(disp[2::4, t:-1], 30.3)
    np.testing.assert_allclose(conf[2::4, t:-1], 0.97)
    np.testing.assert_allclose(disp[1::2, t:-1], 30.1)
    np.testing.assert_allclose(disp[0::4, t:-1], 30.1)
    np.testing.assert_allclose(disp[:, :t], 30.1)
    assert np.isnan(disp[:, -1]).all()
    calls.clear()
    pl.refine_matches(left, right, pair, disparity, dataclasses.replace(c, refine_third_radius=None), epipolar=None)
    assert len(calls) == 1
