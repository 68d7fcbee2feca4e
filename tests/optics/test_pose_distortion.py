"""Posed (tilted, decentred, rotated) prisms and lens distortion in tracing and exact projection."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from prismstereo.config import Rig, pyramid_rig, thesis_biprism, thesis_triprism
from prismstereo.optics import (
    distort_points,
    project_exact,
    rays_from_pixels,
    refract,
    trace_pixels,
    undistort_points,
)

DIST = (-0.10, 0.12, 0.0008, -0.0005, 0.01)


def posed(rig: Rig, *, rotation: float = 1.4, tilt=(1.0, -0.8), decenter=(1.0, -0.6), dist=DIST) -> Rig:
    cam = dataclasses.replace(rig.camera, distortion=dist)
    return dataclasses.replace(rig, camera=cam).with_prism(rotation=rig.prism.rotation + rotation, tilt=tilt,
                                                           decenter=decenter)


def _rot(tx: float, ty: float, rz: float) -> np.ndarray:
    a, b, c = np.radians([tx, ty, rz])
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    rzm = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    return ry @ rx @ rzm


@pytest.mark.parametrize("base", [thesis_biprism(), thesis_triprism(), pyramid_rig(4)])
def test_posed_trace_obeys_snell_at_the_posed_surfaces(base):
    # Independent of the tracer's frame change: build the posed faces from docs/rig.md directly.
    rig = posed(base, rotation=2.0, tilt=(1.5, -1.0), decenter=(1.2, -0.7), dist=(0, 0, 0, 0, 0))
    p = rig.prism
    rng = np.random.default_rng(3)
    px = rng.uniform([100, 100], [924, 668], size=(400, 2))
    b = trace_pixels(rig, px)
    assert b.valid.mean() > 0.95
    v = b.valid
    R = _rot(p.tilt[0], p.tilt[1], p.rotation)
    a0 = np.array([0.0, 0.0, p.apex_distance])
    apex = a0 + np.array([p.decenter[0], p.decenter[1], 0.0])
    theta = np.radians(360.0 * b.face[v] / p.faces)
    t = np.tan(np.radians(p.corner_angle))
    n_nom = np.stack([t * np.cos(theta), t * np.sin(theta), -np.ones_like(theta)], axis=1)
    n_cam = n_nom @ R.T / np.linalg.norm(n_nom, axis=1, keepdims=True)
    # the entry point lies on the posed face plane through the apex, the exit on the posed back plane
    np.testing.assert_allclose(np.einsum("ij,ij->i", b.entry_points[v] - apex, n_cam), 0.0, atol=1e-9)
    back_n = R @ np.array([0.0, 0.0, 1.0])
    back_pt = apex + R @ np.array([0.0, 0.0, p.back_distance - p.apex_distance])
    np.testing.assert_allclose((b.origins[v] - back_pt) @ back_n, 0.0, atol=1e-9)
    # the camera ray passes through the entry point, and Snell's law holds at both surfaces
    d0 = rays_from_pixels(px[v], rig.camera.K)
    np.testing.assert_allclose(np.cross(d0, b.entry_points[v]), 0.0, atol=1e-9)
    inside, _ = refract(d0, n_cam, 1.0, p.refractive_index)
    np.testing.assert_allclose(b.glass_directions[v], inside, atol=1e-12)
    out, _ = refract(inside, back_n, p.refractive_index, 1.0)
    np.testing.assert_allclose(b.directions[v], out, atol=1e-12)


def test_zero_pose_and_distortion_keep_results_bit_identical():
    rig = thesis_triprism()
    explicit = dataclasses.replace(rig, camera=dataclasses.replace(rig.camera, distortion=(0.0,) * 5)).with_prism(
        tilt=(0.0, 0.0), decenter=(0.0, 0.0))
    px = np.random.default_rng(0).uniform([0, 0], [1023, 767], size=(500, 2))
    a, b = trace_pixels(rig, px), trace_pixels(explicit, px)
    assert np.array_equal(a.directions, b.directions, equal_nan=True)
    assert np.array_equal(a.origins, b.origins, equal_nan=True)
    # a pose of 1e-9 mm goes through the posed frame change and agrees to rounding
    tiny = rig.with_prism(decenter=(1e-12, 0.0))
    c = trace_pixels(tiny, px)
    np.testing.assert_allclose(c.directions, a.directions, atol=1e-12)


@settings(max_examples=15, deadline=None)
@given(
    faces=st.sampled_from([3, 4]),
    rotation=st.floats(-3.0, 3.0),
    tx=st.floats(-2.0, 2.0),
    ty=st.floats(-2.0, 2.0),
    dx=st.floats(-1.5, 1.5),
    dy=st.floats(-1.5, 1.5),
    k1=st.floats(-0.2, 0.2),
    seed=st.integers(0, 1000),
)
def test_posed_pyramid_round_trip(faces, rotation, tx, ty, dx, dy, k1, seed):
    base = thesis_triprism() if faces == 3 else pyramid_rig(4)
    rig = posed(base, rotation=rotation, tilt=(tx, ty), decenter=(dx, dy), dist=(k1, 0.1, 0.0, 0.0, 0.0))
    rng = np.random.default_rng(seed)
    px = rng.uniform([0, 0], [1023, 767], size=(60, 2))
    b = trace_pixels(rig, px)
    X = b.point_at_depth(rng.uniform(500.0, 3000.0, size=px.shape[0]))
    for f in range(faces):
        sel = b.face == f
        if not sel.any():
            continue
        q, ok = project_exact(rig, X[sel], face=f)
        assert ok.all()
        np.testing.assert_allclose(q, px[sel], atol=1e-5)


def _row_faces(rig: Rig, v: float) -> np.ndarray:
    u = np.arange(rig.camera.width, dtype=np.float64)
    return trace_pixels(rig, np.stack([u, np.full_like(u, v)], axis=1)).face


def test_posed_biprism_apex_line_moves_with_decenter_and_rotation():
    rig = thesis_biprism().with_prism(decenter=(1.0, 0.0))
    # the apex (x = 1 mm at 210 mm) is seen f·1/210 ≈ 25.6 px right of the centre
    edge = np.flatnonzero(np.diff(_row_faces(rig, 384.0)) != 0)
    assert edge.size == 1 and abs(edge[0] + 0.5 - (511.5 + rig.camera.focal_px / 210.0)) < 1.5
    turned = thesis_biprism().with_prism(rotation=2.0)
    top = np.flatnonzero(np.diff(_row_faces(turned, 0.0)) != 0)[0]
    bottom = np.flatnonzero(np.diff(_row_faces(turned, 767.0)) != 0)[0]
    # the apex line turns with the prism: across 767 rows it moves by 767·tan(2°) ≈ 26.8 px
    assert abs((top - bottom) - 767 * np.tan(np.radians(2.0))) < 1.5


def test_sub_image_split_follows_the_real_apex_line():
    from prismstereo.apps.demo import scaled_rig
    from prismstereo.rectify.regions import view_regions

    rig = scaled_rig(thesis_biprism(), 4).with_prism(decenter=(1.0, 0.0))  # 256×192, f = 1344 px
    right = view_regions(rig, margin_px=2)[0].mask
    first = np.argmax(right[96])  # the right view starts 2 px (the margin) past the apex line
    assert abs(first - (127.5 + 1344.1 / 210.0 + 2.5)) < 1.5


def test_distortion_matches_opencv():
    rng = np.random.default_rng(1)
    xy = rng.uniform(-0.3, 0.3, size=(200, 2))
    K = np.eye(3)
    obj = np.concatenate([xy, np.ones((200, 1))], axis=1)
    ocv, _ = cv2.projectPoints(obj, np.zeros(3), np.zeros(3), K, np.array(DIST))
    np.testing.assert_allclose(distort_points(xy, DIST), ocv[:, 0], atol=1e-14)
    back = undistort_points(distort_points(xy, DIST), DIST)
    np.testing.assert_allclose(back, xy, atol=1e-13)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    ocv_und = cv2.undistortPoints(ocv, K, np.array(DIST), None, None, None, crit)[:, 0]
    np.testing.assert_allclose(back, ocv_und, atol=1e-9)


def test_distorted_pixel_ray_goes_through_the_undistorted_point():
    rig = posed(thesis_biprism())
    cam = rig.camera
    rng = np.random.default_rng(2)
    px = rng.uniform([0, 0], [1023, 767], size=(300, 2))
    d = rays_from_pixels(px, cam.K, cam.distortion)
    reproj, _ = cv2.projectPoints(d, np.zeros(3), np.zeros(3), cam.K, np.array(cam.distortion))
    np.testing.assert_allclose(reproj[:, 0], px, atol=1e-8)


def test_undistort_reports_folds_as_nan():
    # strong barrel distortion folds back beyond r ≈ 1.3; no undistorted point maps there
    out = undistort_points(np.array([[3.0, 0.0], [0.1, 0.0]]), (-0.4, 0.0, 0.0, 0.0, 0.0))
    assert np.isnan(out[0]).all() and np.isfinite(out[1]).all()
