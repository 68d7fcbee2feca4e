from __future__ import annotations

import json

import numpy as np
import pytest

from prismstereo.cameras import (
    PinholeCamera,
    calibrate_rig,
    fit_camera,
    read_cameras_json,
    reprojection_error,
    rotation_from_axis,
    thesis_camera,
    write_cameras_json,
)
from prismstereo.errors import ConfigError, GeometryError


def test_pinhole_project_unproject_round_trip():
    cam = PinholeCamera(K=np.array([[800.0, 0, 320], [0, 790, 240], [0, 0, 1]]),
                        R=rotation_from_axis(np.array([0.1, -0.05, 1.0])), C=np.array([10.0, -3.0, 2.0]),
                        dist=np.array([-0.1, 0.02, 0.001, -0.002, 0.0]))
    pts = np.random.default_rng(0).uniform([-300, -200, 800], [300, 200, 2000], size=(50, 3))
    px = cam.project(pts)
    depth = ((pts - cam.C) @ cam.R.T)[:, 2]
    np.testing.assert_allclose(cam.unproject_depth(px, depth), pts, atol=1e-6)
    P = cam.P
    hom = np.c_[pts, np.ones(len(pts))] @ P.T
    undist = PinholeCamera(K=cam.K, R=cam.R, C=cam.C).project(pts)
    np.testing.assert_allclose(hom[:, :2] / hom[:, 2:], undist, atol=1e-8)


def test_rotation_from_axis_is_about_y_for_xz_axes():
    R = rotation_from_axis(np.array([np.sin(0.1), 0, np.cos(0.1)]))
    expected = np.array([[np.cos(0.1), 0, np.sin(0.1)], [0, 1, 0], [-np.sin(0.1), 0, np.cos(0.1)]]).T
    np.testing.assert_allclose(R, expected, atol=1e-12)


@pytest.mark.parametrize(("rig_name", "bound"), [("biprism", 0.5), ("triprism", 1.0), ("pyramid4", 1.0)])
def test_fit_model_reaches_target(rig_name, bound, request):
    rig = request.getfixturevalue(rig_name)
    views = calibrate_rig(rig, method="fit")
    assert len(views) == rig.prism.faces
    for v in views:
        assert v.rms_px <= bound, (v.face, v.rms_px)


def test_thesis_construction_is_a_rough_model(biprism):
    views = calibrate_rig(biprism, method="thesis")
    for v in views:
        assert 0.5 < v.rms_px < 4.0  # the construction ignores non-central refraction: a few px
        np.testing.assert_allclose(v.camera.K, biprism.camera.K)


@pytest.mark.parametrize("method", ["thesis", "fit"])
def test_biprism_virtual_cameras_mirror_each_other(biprism, method):
    right, left = calibrate_rig(biprism, method=method)
    mirror = np.diag([-1.0, 1.0, 1.0])
    np.testing.assert_allclose(left.camera.C, mirror @ right.camera.C, atol=0.05 if method == "fit" else 0.3)
    assert right.camera.C[0] > 5.0  # the right virtual camera sits on the +X side
    np.testing.assert_allclose(mirror @ right.camera.R @ mirror, left.camera.R, atol=2e-3)
    assert abs(right.rms_px - left.rms_px) < 0.1


def test_fit_beats_thesis_on_every_face(triprism):
    for k in range(3):
        fit_rms, _ = reprojection_error(fit_camera(triprism, k), triprism, k)
        thesis_rms, _ = reprojection_error(thesis_camera(triprism, k), triprism, k)
        assert fit_rms < thesis_rms


def test_cameras_json_round_trip(tmp_path, biprism):
    views = calibrate_rig(biprism, method="thesis")
    path = tmp_path / "cameras.json"
    write_cameras_json(path, biprism, views, method="thesis")
    data = json.loads(path.read_text())
    assert data["method"] == "thesis"
    assert [v["name"] for v in data["views"]] == ["right", "left"]
    assert len(data["views"][0]["P"]) == 3
    rig, back = read_cameras_json(data)
    assert rig == biprism
    np.testing.assert_allclose(back[0].camera.P, views[0].camera.P)


def test_bad_method_and_face(biprism):
    with pytest.raises(ConfigError):
        calibrate_rig(biprism, method="zhang")
    with pytest.raises(GeometryError):
        thesis_camera(biprism, 5)
