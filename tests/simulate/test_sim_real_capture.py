"""Realistic captures: a distorting lens, a misaligned prism, vignetting, dispersion, noise, 8 bits."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from prismstereo.apps.demo import scaled_rig
from prismstereo.config import thesis_biprism
from prismstereo.errors import ConfigError
from prismstereo.optics import project_exact
from prismstereo.simulate import render_capture
from prismstereo.simulate.checkerboard import checkerboard_poses
from prismstereo.simulate.render import dispersed_indices, vignetting_gain
from prismstereo.simulate.scene import CheckerTexture, NoiseTexture, Plane, Scene
from prismstereo.simulate.scene_toml import scene_from_dict, scene_to_dict


@pytest.fixture(scope="module")
def real_rig():
    rig = scaled_rig(thesis_biprism(), 4)  # 256×192
    cam = dataclasses.replace(rig.camera, distortion=(-0.10, 0.12, 0.0, 0.0, 0.0))
    return dataclasses.replace(rig, camera=cam).with_prism(rotation=1.4, tilt=(1.0, -0.8), decenter=(1.0, -0.5))


def _plane_scene(**kw) -> Scene:
    return Scene(objects=(Plane(center=(0.0, 0.0, 1000.0), rotation=(0.0, 20.0, 0.0),
                                texture=NoiseTexture(scale=20.0)),), **kw)


def test_ground_truth_follows_the_posed_prism_and_the_lens(real_rig):
    cap = render_capture(real_rig, _plane_scene(), supersample=1)
    vv, uu = np.mgrid[0:real_rig.camera.height, 0:real_rig.camera.width]
    for face in range(2):
        idx = np.flatnonzero((cap.faces == face).ravel() & np.isfinite(cap.depth).ravel())[::5]
        px, ok = project_exact(real_rig, cap.points.reshape(-1, 3)[idx], face=face, tolerance_px=1e-9)
        assert ok.all()
        np.testing.assert_allclose(px, np.stack([uu.ravel()[idx], vv.ravel()[idx]], axis=1), atol=1e-6)


def test_vignetting_darkens_the_corners(real_rig):
    flat = Scene(objects=(), background=(0.8, 0.8, 0.8), vignetting=0.4)
    plain = render_capture(real_rig, dataclasses.replace(flat, vignetting=0.0), supersample=1, prism=False)
    dark = render_capture(real_rig, flat, supersample=1, prism=False)
    gain = vignetting_gain(real_rig, 0.4)
    assert gain.min() == pytest.approx(0.6, abs=1e-6) and gain.max() <= 1.0
    np.testing.assert_allclose(dark.image[..., 0], np.rint(plain.image[..., 0] * gain), atol=1)
    assert dark.image[0, 0, 0] < plain.image[0, 0, 0] - 70


def test_dispersion_gives_colour_fringes_and_keeps_green(real_rig):
    n_c, n_d, n_f = dispersed_indices(1.5168, 64.17)  # N-BK7
    assert n_d == 1.5168 and n_c == pytest.approx(1.51432, abs=2e-4) and n_f == pytest.approx(1.52238, abs=2e-4)
    grey = Scene(objects=(Plane(center=(0.0, 0.0, 1000.0), texture=CheckerTexture(square=7.0)),))
    plain = render_capture(real_rig, grey, supersample=1)
    fringed = render_capture(real_rig, dataclasses.replace(grey, abbe=20.0), supersample=1)
    assert np.array_equal(plain.image[..., 1], fringed.image[..., 1])
    assert np.array_equal(plain.depth, fringed.depth, equal_nan=True)
    # a grey texture renders grey without dispersion; with it red and blue move apart
    assert np.abs(plain.image[..., 0].astype(int) - plain.image[..., 2]).max() <= 1
    assert np.abs(fringed.image[..., 0].astype(int) - fringed.image[..., 2]).mean() > 3


def test_noise_is_seeded_and_rounded_to_8_bits(real_rig):
    a = render_capture(real_rig, _plane_scene(noise=3.0, seed=4), supersample=1)
    b = render_capture(real_rig, _plane_scene(noise=3.0, seed=4), supersample=1)
    c = render_capture(real_rig, _plane_scene(), supersample=1)
    assert a.image.dtype == np.uint8 and np.array_equal(a.image, b.image)
    assert 2.0 < np.std(a.image.astype(float) - c.image) < 4.0


def test_checkerboards_render_through_a_posed_prism(real_rig):
    import cv2

    rig = scaled_rig(thesis_biprism(), 2)
    cam = dataclasses.replace(rig.camera, distortion=(-0.10, 0.12, 0.0, 0.0, 0.0))
    rig = dataclasses.replace(rig, camera=cam).with_prism(rotation=1.4, tilt=(1.0, -0.8), decenter=(1.0, -0.5))
    pose = checkerboard_poses(rig, n_poses=1, squares=(9, 7), distance_range=(600.0, 700.0), seed=2)[0]
    cap = render_capture(rig, pose.scene, supersample=3)
    grey = cv2.cvtColor(cap.image, cv2.COLOR_RGB2GRAY)
    for face in range(2):
        mask = (cap.faces == face).astype(np.uint8) * 255
        crop = np.where(mask > 0, grey, 115).astype(np.uint8)
        found, corners = cv2.findChessboardCornersSB(crop, (8, 6))
        assert found
        truth, ok = project_exact(rig, pose.corners, face=face)
        assert ok.all()
        # OpenCV may start at either end of the symmetric board
        corners = corners.reshape(-1, 2)
        err = min(np.abs(corners - truth).max(), np.abs(corners[::-1] - truth).max())
        assert err < 0.3


def test_scene_keys_round_trip_and_validate(real_rig):
    data = scene_to_dict(real_rig, _plane_scene(vignetting=0.2, abbe=40.0, noise=1.5))
    rig, scene = scene_from_dict(data)
    assert rig == real_rig and scene.vignetting == 0.2 and scene.abbe == 40.0
    for key, bad in (("vignetting", 1.5), ("vignetting", "x"), ("abbe", 2.0), ("abbe", float("nan"))):
        d = dict(data)
        d["render"] = dict(data["render"], **{key: bad})
        with pytest.raises(ConfigError, match=rf"\[render\] {key}: expected"):
            scene_from_dict(d)
