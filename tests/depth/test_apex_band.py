"""The apex band in a depth run: the camera's lens keys leave the mixed band out of matching."""

from __future__ import annotations

import dataclasses

import numpy as np

from prismstereo.apps.demo import demo_rig
from prismstereo.depth import DepthConfig, prepare_depth
from prismstereo.depth.apex_band import apex_band_info, apex_band_real, apex_band_views
from prismstereo.optics.lens import apex_band_width_px


def _with_lens(rig, n=8.0, focus=1400.0):
    return dataclasses.replace(rig, camera=dataclasses.replace(rig.camera, f_number=n, focus_distance=focus))


def test_without_lens_keys_nothing_is_left_out():
    rig = demo_rig()
    assert apex_band_real(rig) is None and apex_band_info(rig) is None
    setup = prepare_depth(rig, config=DepthConfig(depth_range=(1200.0, 2000.0)))
    assert setup.region.right_excluded is None


def test_the_band_is_left_out_of_the_search_region_and_recorded():
    rig = _with_lens(demo_rig())
    info = apex_band_info(rig)
    assert info is not None and info["f_number"] == 8.0
    assert abs(info["width_px"] - apex_band_width_px(rig, f_number=8.0, focus_distance=1400.0)) < 0.01
    band = apex_band_real(rig)
    assert band is not None and band.any()
    cols = np.flatnonzero(band.any(axis=0))  # a vertical band around the apex line (the image centre)
    assert abs(0.5 * (cols[0] + cols[-1]) - (rig.camera.width - 1) / 2) < 3
    assert abs((cols[-1] - cols[0] + 1) - info["width_px"]) < 4
    cfg = DepthConfig(depth_range=(1200.0, 2000.0))
    plain = prepare_depth(demo_rig(), config=cfg)
    lens = prepare_depth(rig, config=cfg)
    views = apex_band_views(rig, lens.pair)
    assert views is not None and views[0].any() and views[1].any()
    assert not (lens.region.mask & views[0]).any()
    assert np.array_equal(lens.region.mask, plain.region.mask & ~views[0])
    assert lens.region.right_excluded is not None and np.array_equal(lens.region.right_excluded, views[1])
    # a sharper lens (smaller aperture) has a narrower band
    assert apex_band_info(_with_lens(demo_rig(), n=16.0))["width_px"] < info["width_px"]
