"""A depth run's memory plan, before its capture is read (issue 30)."""

from __future__ import annotations

import pytest

from prismstereo.apps.demo import demo_rig
from prismstereo.depth.memory import check_depth_memory, estimate_depth_memory, resident_bytes
from prismstereo.depth.pipeline import DepthConfig, validate_config
from prismstereo.errors import ConfigError
from prismstereo.matching.scale import ScaleParams, planned_memory


def test_the_plan_adds_what_the_run_holds_to_the_larger_of_the_match_and_the_later_steps() -> None:
    rig = demo_rig()
    cfg = validate_config(rig, DepthConfig(method="sgm", max_memory=8 * 2**30))
    plan = estimate_depth_memory(rig, cfg, shape=(385, 300), disparity_range=(20, 80))
    assert plan.source == "given" and plan.ndisp == 61 and plan.shape == (385, 300)
    assert plan.peak == plan.held + max(plan.match, plan.after)
    scale = ScaleParams(max_memory=8 * 2**30, held=plan.held)
    assert plan.held + plan.match == planned_memory("sgm", 385, 300, max_disp=80, min_disp=20, scale=scale)
    # exact triangulation reads the ray table (96 B per rectified pixel): held grows by it
    q = estimate_depth_memory(rig, validate_config(rig, DepthConfig(method="sgm", triangulation="q")),
                              shape=(385, 300), disparity_range=(20, 80))
    assert plan.held - q.held == pytest.approx(96 * 385 * 300, rel=1e-6)
    # coop holds far more per pixel and disparity
    heavy = estimate_depth_memory(rig, validate_config(rig, DepthConfig(method="coop", max_memory=8 * 2**30)),
                                  shape=(385, 300), disparity_range=(20, 80))
    assert heavy.match > 3 * plan.match
    assert resident_bytes() > 0


def test_without_a_cached_set_up_the_camera_bounds_it(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PRISMSTEREO_CACHE", "0")
    rig = demo_rig()
    plan = estimate_depth_memory(rig, validate_config(rig, DepthConfig(method="sgm")))
    assert plan.source == "camera bounds"
    assert plan.shape == (rig.camera.height + 1, rig.camera.width) and plan.ndisp == rig.camera.width


def test_a_run_that_cannot_fit_outside_the_match_is_refused_before_its_capture_is_read(tmp_path) -> None:
    from prismstereo import api

    rig = demo_rig()
    with pytest.raises(ConfigError, match="max_memory") as err:
        check_depth_memory(rig, validate_config(rig, DepthConfig(method="sgm", max_memory=64 * 2**20)))
    assert "\n" not in str(err.value)
    # the image does not exist: the memory plan refuses first
    with pytest.raises(ConfigError, match="max_memory"):
        api.depth(rig, tmp_path / "missing.png", method="sgm", max_memory=64 * 2**20)
