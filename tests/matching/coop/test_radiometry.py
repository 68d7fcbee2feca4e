"""Radiometric compensation of the right view (coop's colour costs under an exposure or lighting change)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from prismstereo.errors import ConfigError
from prismstereo.matching.coop.radiometry import RadiometryParams, compensate_right

D = 6


def _pair(h: int = 120, w: int = 160, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """A textured fronto-parallel pair at disparity D (the right view is the left shifted by D px)."""
    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur(rng.uniform(0, 255, (h, w + D, 3)).astype(np.float32), (0, 0), 1.5)
    tex = cv2.normalize(tex, None, 20, 235, cv2.NORM_MINMAX)
    tex = np.clip(np.rint(tex), 0, 255).astype(np.uint8)
    return np.ascontiguousarray(tex[:, :w]), np.ascontiguousarray(tex[:, D:])


def _ad_at_truth(left: np.ndarray, right: np.ndarray) -> float:
    return float(np.median(np.abs(left[:, D:].astype(float) - right[:, :-D].astype(float)).mean(axis=2)))


def test_an_exposure_change_is_undone() -> None:
    left, right = _pair()
    dark = np.clip(np.rint(0.55 * right.astype(np.float32) + 12.0), 0, 255).astype(np.uint8)
    assert _ad_at_truth(left, dark) > 30
    out, info = compensate_right(left, dark, max_disp=16)
    assert info["radiometry_applied"] == 1.0 and info["radiometry_census_only"] == 0.0
    assert info["radiometry_samples"] >= 500
    assert info["radiometry_ad_after"] < info["radiometry_ad_before"] - 3.0
    assert out.shape == dark.shape and out.dtype == np.uint8
    assert _ad_at_truth(left, out) < 3.0


def test_equal_radiometry_returns_the_view_itself() -> None:
    left, right = _pair()
    out, info = compensate_right(left, right, max_disp=16)
    assert out is right and info["radiometry_applied"] == 0.0 and info["radiometry_census_only"] == 0.0
    out, info = compensate_right(left, right, max_disp=16, params=RadiometryParams(enabled=False))
    assert out is right and info == {"radiometry_applied": 0.0, "radiometry_census_only": 0.0}
    # too few matches to estimate a transfer from: unchanged
    dark = (right // 2).astype(np.uint8)
    out, info = compensate_right(left, dark, max_disp=16, params=RadiometryParams(min_samples=10**6))
    assert out is dark and info["radiometry_applied"] == 0.0


def test_a_small_brightness_offset_is_undone_though_the_median_difference_barely_drops() -> None:
    left, right = _pair()
    bright = np.clip(right.astype(np.int16) + 2, 0, 255).astype(np.uint8)  # 2 levels: below min_gain's 3
    out, info = compensate_right(left, bright, max_disp=16, params=RadiometryParams(min_offset=1.0))
    assert info["radiometry_ad_before"] - info["radiometry_ad_after"] < RadiometryParams().min_gain
    assert info["radiometry_offset_before"] <= -1.5 and abs(info["radiometry_offset_after"]) < 0.5
    assert info["radiometry_applied"] == 1.0 and out is not bright
    assert _ad_at_truth(left, out) < _ad_at_truth(left, bright) - 1.0
    # the default (min_offset 0): the gain rule alone, which a 2-level offset does not pass
    out, info = compensate_right(left, bright, max_disp=16)
    assert out is bright and info["radiometry_applied"] == 0.0


def test_a_change_of_light_no_intensity_map_undoes_asks_for_census_alone() -> None:
    left, right = _pair()
    h, w = right.shape[:2]
    # a light from the side: the gain goes from 0.35 to 1.6 across the view
    gain = np.linspace(0.35, 1.6, w, dtype=np.float32)[None, :, None]
    lit = np.clip(np.rint(right.astype(np.float32) * gain), 0, 255).astype(np.uint8)
    _, info = compensate_right(left, lit, max_disp=16)
    assert info["radiometry_census_only"] == 1.0
    assert info["radiometry_ad_after"] > RadiometryParams().max_residual


@pytest.mark.parametrize("kw", [{"scale": 0}, {"radius": -1}, {"uniqueness": 1.0}, {"min_samples": 3},
                                {"min_gain": -1.0}, {"min_offset": -1.0}, {"max_residual": -0.5}])
def test_bad_parameters_name_the_field(kw: dict) -> None:
    with pytest.raises(ConfigError, match="radiometry"):
        RadiometryParams(**kw)


def test_coop_reads_radiometry_from_a_mapping() -> None:
    from prismstereo.matching.coop.pipeline import DataTermParams

    assert DataTermParams(radiometry={"min_gain": 5.0}).radiometry == RadiometryParams(min_gain=5.0)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="radiometry"):
        DataTermParams(radiometry={"nope": 1})  # type: ignore[arg-type]


def test_census_alone_accepts_zero_colour_truncations_and_rejects_negative_ones() -> None:
    from prismstereo.matching.coop.coopcost import CostParams

    CostParams(tau_color=0.0, tau_grad=0.0)  # the census-only cost coop switches to
    with pytest.raises(ConfigError, match="tau_color"):
        CostParams(tau_color=-1.0)


def test_coop_matches_a_pair_lit_from_the_side_on_census_alone() -> None:
    # the census-only path of coop_match (a change of light no intensity map undoes) runs to a map
    from prismstereo.matching.coop.pipeline import coop_match

    left, right = _pair(h=64, w=96)
    gain = np.linspace(0.35, 1.6, right.shape[1], dtype=np.float32)[None, :, None]
    lit = np.clip(np.rint(right.astype(np.float32) * gain), 0, 255).astype(np.uint8)
    res = coop_match(left, lit, max_disp=12)
    assert res.info["radiometry_census_only"] == 1.0
    inner = res.disparity[8:-8, 20:-8]
    assert np.mean(np.abs(inner - D) <= 1.0) > 0.9


def test_an_offset_the_compensation_leaves_is_removed_for_the_fallbacks_map_only() -> None:
    from prismstereo.matching.coop.pipeline import _compensate_views
    from prismstereo.matching.coop.radiometry import RadiometryParams as RP
    from prismstereo.matching.coop.steps import FallbackParams

    left, right = _pair()
    bright = np.clip(right.astype(np.int16) + 2, 0, 255).astype(np.uint8)
    rgt, fb_right, info = _compensate_views(left, bright, max_disp=16, radiometry=RP(), fallback=FallbackParams())
    assert rgt is bright and fb_right is not None and info["radiometry_fallback_offset"] == 1.0
    assert info["radiometry_applied"] == 0.0 and _ad_at_truth(left, fb_right) < _ad_at_truth(left, bright) - 1.0
    rgt, fb_right, info = _compensate_views(left, bright, max_disp=16, radiometry=RP(),
                                            fallback=FallbackParams(radiometry_offset=0.0))
    assert rgt is bright and fb_right is None and info["radiometry_fallback_offset"] == 0.0
    # an exposure change the gain rule removes: the whole pipeline reads the mapped view, the fallback too
    dark = np.clip(np.rint(0.55 * right.astype(np.float32) + 12.0), 0, 255).astype(np.uint8)
    rgt, fb_right, info = _compensate_views(left, dark, max_disp=16, radiometry=RP(), fallback=FallbackParams())
    assert rgt is not dark and fb_right is None and info["radiometry_applied"] == 1.0
    with pytest.raises(ConfigError, match="radiometry_offset"):
        FallbackParams(radiometry_offset=-1.0)


def test_coop_takes_the_fallbacks_map_from_the_offset_compensated_pair() -> None:
    from prismstereo.matching.coop.pipeline import coop_match
    from prismstereo.matching.coop.steps import FallbackParams, StepParams

    left, right = _pair(h=64, w=96)
    bright = np.clip(right.astype(np.int16) + 2, 0, 255).astype(np.uint8)
    # the large segments not wholly covered by evidence fall back: the fallback builds its own BPASW volume
    steps = StepParams(fallback=FallbackParams(bare_share=1e-4, bare_coverage=1.0))
    res = coop_match(left, bright, max_disp=12, steps=steps)
    assert res.info["radiometry_fallback_offset"] == 1.0 and res.info["radiometry_applied"] == 0.0
    assert res.info["fallback_pixels"] > 0
    inner = res.disparity[8:-8, 20:-8]
    assert np.mean(np.abs(inner - D) <= 1.0) > 0.9
