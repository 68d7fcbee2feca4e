"""Thin lens: aperture, the modelled apex band, and tracing rays from aperture points through the prism."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from prismstereo.config import pyramid_rig, thesis_biprism
from prismstereo.errors import ConfigError
from prismstereo.optics import trace_rays
from prismstereo.optics.lens import aperture_diameter, aperture_points, apex_band_mask, apex_band_width_px


def test_thesis_apex_band_is_about_70_px_at_f8() -> None:
    rig = thesis_biprism()
    assert aperture_diameter(rig, f_number=8.0) == pytest.approx(3.125)
    w = apex_band_width_px(rig, f_number=8.0, focus_distance=1400.0)
    # f_px · D · (1/a − 1/F) = (25 / 0.00465) · 3.125 · (1/210 − 1/1400)
    assert w == pytest.approx(25 / 0.00465 * 3.125 * (1 / 210 - 1 / 1400), rel=1e-12)
    assert 67.5 < w < 68.5
    assert apex_band_width_px(rig, f_number=8.0, focus_distance=210.0) == 0.0
    assert apex_band_width_px(rig, f_number=4.0, focus_distance=1400.0) == pytest.approx(2 * w)
    mask = apex_band_mask(rig, f_number=8.0, focus_distance=1400.0)
    cols = np.nonzero(mask.any(axis=0))[0]
    assert mask.all(axis=0)[cols].all()  # a vertical band: whole columns
    assert abs(cols.size - w) <= 1.0 and abs(cols.mean() - rig.camera.center[0]) <= 0.5


def test_band_mask_follows_decenter_and_faces() -> None:
    rig = thesis_biprism().with_prism(decenter=(2.0, 0.0))
    cols = np.nonzero(apex_band_mask(rig, f_number=8.0, focus_distance=1400.0).any(axis=0))[0]
    shift = 2.0 / 210.0 * rig.camera.focal_px
    assert cols.mean() == pytest.approx(rig.camera.center[0] + shift, abs=0.6)
    tri = pyramid_rig(3)
    m = apex_band_mask(tri, f_number=8.0, focus_distance=1400.0)
    assert 0.02 < m.mean() < 0.3 and m[int(tri.camera.center[1]), int(tri.camera.center[0])]


@pytest.mark.parametrize(("kw", "match"), [({"f_number": 0.0, "focus_distance": 1000.0}, "f_number"),
                                           ({"f_number": 8.0, "focus_distance": -1.0}, "focus_distance"),
                                           ({"f_number": float("nan"), "focus_distance": 1.0}, "f_number")])
def test_lens_parameter_errors(kw: dict[str, float], match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        apex_band_width_px(thesis_biprism(), **kw)


def test_lens_needs_a_focal_length_in_mm() -> None:
    rig = thesis_biprism()
    cam = dataclasses.replace(rig.camera, focal_length=None, pixel_size=None, fx=5376.0, fy=5376.0)
    with pytest.raises(ConfigError, match="focal length in mm"):
        aperture_diameter(dataclasses.replace(rig, camera=cam), f_number=8.0)


def test_aperture_points_cover_the_disc() -> None:
    p = aperture_points(64, 4.0)
    r = np.hypot(p[:, 0], p[:, 1])
    assert r.max() < 2.0 and np.abs(p.mean(axis=0)).max() < 0.1
    assert np.mean(r < 2.0 / np.sqrt(2)) == pytest.approx(0.5, abs=0.02)  # equal areas
    with pytest.raises(ConfigError, match="samples"):
        aperture_points(0, 1.0)


@pytest.mark.parametrize("posed", [False, True])
def test_trace_rays_from_origins(posed: bool) -> None:
    rig = thesis_biprism()
    if posed:
        rig = rig.with_prism(tilt=(-0.9, 1.1), decenter=(-0.8, 0.7), rotation=-1.5)
    rng = np.random.default_rng(0)
    d = np.column_stack([rng.uniform(-0.09, 0.09, 500), rng.uniform(-0.07, 0.07, 500), np.ones(500)])
    a = trace_rays(rig, d)
    b = trace_rays(rig, d, origins=np.zeros((500, 3)))
    np.testing.assert_allclose(b.origins, a.origins, atol=1e-9)
    np.testing.assert_allclose(b.directions, a.directions, atol=1e-12)
    np.testing.assert_array_equal(b.face, a.face)
    # a ray from an aperture point parallel to a centre ray leaves parallel to it (same face), shifted
    o = np.zeros((500, 3))
    o[:, 0] = 1.0
    c = trace_rays(rig, d, origins=o)
    same = c.valid & a.valid & (c.face == a.face)
    assert same.mean() > 0.9
    np.testing.assert_allclose(c.directions[same], a.directions[same], atol=1e-12)
    assert np.allclose(c.entry_points[same] - a.entry_points[same], 0.0, atol=2.0)
    with pytest.raises(ValueError, match="one origin per direction"):
        trace_rays(rig, d, origins=np.zeros((3, 3)))
