"""The pixel-scale noise of a capture and the refinement profile of demosaiced / compressed captures."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from prismstereo.depth import DepthConfig
from prismstereo.depth.smoothed import pixel_noise, smoothed_config
from prismstereo.simulate.render import jpeg_roundtrip


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
    # the third window is the smoothed captures' only (None leaves the configuration's)
    assert cfg.refine_third_radius is None and got.refine_third_radius == cfg.refine_smoothed_third_radius is not None
    assert smoothed_config(dataclasses.replace(cfg, refine_smoothed_third_radius=None), smooth).refine_third_radius \
        is None
    assert got.refine_fill_agree == cfg.refine_smoothed_fill_agree and not got.refine_fill
    assert got.refine_smoothed_below is None  # what run.json records reproduces the run
    assert (got.refine_grow_fit, got.refine_grow_agree, got.refine_grow_spread) == (
        cfg.refine_smoothed_grow_fit, cfg.refine_smoothed_grow_agree, cfg.refine_smoothed_grow_spread)
    kept = smoothed_config(dataclasses.replace(cfg, refine_smoothed_grow_fit=None, refine_smoothed_grow_agree=None,
                                               refine_smoothed_grow_spread=None), smooth)
    assert (kept.refine_grow_fit, kept.refine_grow_agree, kept.refine_grow_spread) == (
        cfg.refine_grow_fit, cfg.refine_grow_agree, cfg.refine_grow_spread)
    # the plane interpolation is off on a smoothed capture unless asked for
    assert cfg.refine_interp_sigma is not None and got.refine_interp_sigma is None
    assert smoothed_config(dataclasses.replace(cfg, refine_smoothed_interp=True), smooth).refine_interp_sigma == \
        cfg.refine_interp_sigma
    off = DepthConfig(refine_smoothed_below=None)
    assert smoothed_config(off, smooth) is off
    assert smoothed_config(DepthConfig(refine=False), smooth).refine_retry_below == cfg.refine_retry_below
    assert smoothed_config(DepthConfig(refine_fill_agree=None), smooth).refine_fill_agree is None
