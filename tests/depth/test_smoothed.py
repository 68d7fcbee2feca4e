"""The pixel-scale noise of a capture and the refinement profile of demosaiced / compressed captures."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from prismstereo.apps.demo import demo_rig
from prismstereo.depth import DepthConfig, run_depth
from prismstereo.depth.pipeline import validate_inputs
from prismstereo.depth.smoothed import pixel_noise, smoothed_config
from prismstereo.errors import ConfigError
from prismstereo.evaluation.depth_metrics import evaluate_depth
from prismstereo.simulate import Scene, render_capture
from prismstereo.simulate.render import jpeg_roundtrip
from prismstereo.simulate.rgbd import middlebury_rgbd

REPO_ROOT = Path(__file__).resolve().parents[2]


def _textured(noise: float, seed: int = 0) -> np.ndarray:
    """(120, 160, 3) float: a smooth texture (its colours alike, as in a photograph) plus white noise of
    ``noise`` grey levels per channel."""
    rng = np.random.default_rng(seed)
    base = cv2.GaussianBlur((rng.random((120, 160)) * 255).astype(np.float32), (0, 0), 2.0)
    base = (128.0 + 3.0 * (base - base.mean()))[..., None] * np.array([1.0, 0.9, 0.8], dtype=np.float32)
    return np.clip(base + rng.normal(0.0, noise, base.shape), 0, 255).astype(np.float32)


def test_pixel_noise_reads_white_noise_and_ignores_smooth_texture():
    grey_sigma = 2.0 * np.sqrt(0.299**2 + 0.587**2 + 0.114**2)  # σ 2 per channel, in the grey image
    assert abs(pixel_noise(_textured(2.0)) - grey_sigma) < 0.15 * grey_sigma
    assert pixel_noise(_textured(0.0)) < 0.2 * grey_sigma
    assert np.isnan(pixel_noise(np.zeros((2, 5))))


def test_jpeg_removes_the_pixel_scale_the_profile_keys_on():
    img8 = np.clip(np.rint(_textured(1.5)), 0, 255).astype(np.uint8)
    assert pixel_noise(img8) > 0.8
    assert pixel_noise(jpeg_roundtrip(img8, quality=85)) < 0.5


def test_smoothed_config_switches_the_refinement_profile_below_the_threshold():
    cfg = DepthConfig()
    sharp = np.clip(np.rint(_textured(1.5)), 0, 255).astype(np.uint8)
    smooth = jpeg_roundtrip(sharp, quality=85)
    assert smoothed_config(cfg, sharp) is cfg
    got = smoothed_config(cfg, smooth)
    assert got.refine_retry_below == cfg.refine_smoothed_retry_below
    assert got.refine_fill_agree == cfg.refine_smoothed_fill_agree and not got.refine_fill
    assert got.refine_smoothed_below is None  # what run.json records reproduces the run
    assert (got.refine_grow_fit, got.refine_grow_agree, got.refine_grow_spread) == (
        cfg.refine_smoothed_grow_fit, cfg.refine_smoothed_grow_agree, cfg.refine_smoothed_grow_spread)
    kept = smoothed_config(dataclasses.replace(cfg, refine_smoothed_grow_fit=None, refine_smoothed_grow_agree=None,
                                               refine_smoothed_grow_spread=None), smooth)
    assert (kept.refine_grow_fit, kept.refine_grow_agree, kept.refine_grow_spread) == (
        cfg.refine_grow_fit, cfg.refine_grow_agree, cfg.refine_grow_spread)
    off = DepthConfig(refine_smoothed_below=None)
    assert smoothed_config(off, smooth) is off
    assert smoothed_config(DepthConfig(refine=False), smooth).refine_retry_below == cfg.refine_retry_below
    assert smoothed_config(DepthConfig(refine_fill_agree=None), smooth).refine_fill_agree is None


def test_smoothed_config_gives_the_matcher_its_smoothed_capture_parameters():
    cfg = DepthConfig()
    smooth = jpeg_roundtrip(np.clip(np.rint(_textured(1.5)), 0, 255).astype(np.uint8), quality=85)
    got = smoothed_config(cfg, smooth)
    assert got.matcher_params == {**cfg.matcher_params, **cfg.smoothed_matcher_params["bpasw"]}
    assert got.matcher_params["census_weight"] == 0.0
    assert got.min_confidence == cfg.refine_smoothed_min_confidence > cfg.min_confidence
    # a method without smoothed-capture parameters keeps its match and its confidence
    coop = smoothed_config(DepthConfig(method="coop"), smooth)
    assert coop.matcher_params == {} and coop.min_confidence == cfg.min_confidence
    assert coop.refine_retry_below == cfg.refine_smoothed_retry_below
    plain = smoothed_config(DepthConfig(smoothed_matcher_params={}), smooth)
    assert plain.matcher_params == {} and plain.min_confidence == cfg.min_confidence
    # no confidence filter stays none; a stricter one is kept
    assert smoothed_config(DepthConfig(min_confidence=None), smooth).min_confidence is None
    assert smoothed_config(DepthConfig(min_confidence=0.9), smooth).min_confidence == 0.9
    assert smoothed_config(DepthConfig(refine_smoothed_min_confidence=None), smooth).min_confidence == 0.5


def test_smoothed_matcher_params_are_checked_before_the_match(biprism):
    with pytest.raises(ConfigError, match="smoothed_matcher_params"):
        DepthConfig(smoothed_matcher_params={"bpasw": 0.0})
    img = np.zeros((biprism.camera.height, biprism.camera.width, 3), dtype=np.uint8)
    with pytest.raises(ConfigError, match="census_wieght"):
        validate_inputs(biprism, img, DepthConfig(smoothed_matcher_params={"bpasw": {"census_wieght": 0.0}}))
    again = DepthConfig.from_dict(DepthConfig().to_dict())
    assert again.smoothed_matcher_params == DepthConfig().smoothed_matcher_params


@pytest.fixture(scope="module")
def bowling_captures():
    """(rig, ideal scene, ideal image, smoothed scene, smoothed image): Middlebury bowling1 as a surface
    seen by the demo rig (512×384), rendered lossless and with Bayer RGGB + edge-aware demosaicing + JPEG 85."""
    env = os.environ.get("PRISMSTEREO_MIDDLEBURY")  # the v2 folder; the 2005/2006 one lies beside it
    data = Path(env).parent if env else REPO_ROOT.parent / "shared" / "data"
    folder = data / "middlebury-extra" / "bowling1"
    if not (folder / "manifest.json").is_file():
        pytest.skip(f"Middlebury 2005/2006 data not found at {folder}")
    rig = demo_rig()
    half_view = rig.camera.width / 2.0 / rig.camera.focal_px * 1400.0
    surf = middlebury_rgbd(folder, center_depth=1400.0, width=1.3 * half_view)
    ideal = Scene(objects=(surf,), supersample=2, noise=1.5, seed=1, name="bowling1")
    real = dataclasses.replace(ideal, bayer="RGGB", demosaic="edge-aware", jpeg_quality=85)
    return rig, ideal, render_capture(rig, ideal).image, real, render_capture(rig, real).image


def test_census_free_match_raises_coverage_on_a_smoothed_capture_only(bowling_captures):
    rig, ideal, ideal_img, real, real_img = bowling_captures
    assert pixel_noise(real_img) < DepthConfig().refine_smoothed_below < pixel_noise(ideal_img)
    main = DepthConfig(smoothed_matcher_params={}, refine_smoothed_min_confidence=None)
    new_run, old_run = run_depth(rig, real_img, config=DepthConfig()), run_depth(rig, real_img, config=main)
    new, old = evaluate_depth(new_run, scene=real), evaluate_depth(old_run, scene=real)
    assert new_run.config.matcher_params["census_weight"] == 0.0 and new_run.config.min_confidence == 0.8
    assert new["coverage"] > old["coverage"] + 0.03
    assert new["within_1pct"] > 0.75
    # a lossless capture keeps the pixel scale: the same run, map for map
    a, b = run_depth(rig, ideal_img, config=DepthConfig()), run_depth(rig, ideal_img, config=main)
    assert a.config.matcher_params["census_weight"] == 0.5
    assert np.array_equal(a.disparity, b.disparity, equal_nan=True)
    assert np.array_equal(a.depth, b.depth, equal_nan=True)
