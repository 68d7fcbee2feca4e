from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from prismstereo.config import pyramid_rig, thesis_biprism
from prismstereo.errors import GeometryError
from prismstereo.optics import deviation_angle, face_map, pixel_grid, project_exact, trace_pixels


@pytest.mark.parametrize("alpha", [2.0, 4.0, 6.4])
def test_thin_prism_deviation(alpha):
    rig = thesis_biprism(alpha)
    # Pixels near the principal row, left and right of the apex line.
    dev = deviation_angle(rig, np.array([[700.0, 383.5], [320.0, 383.5]]))
    expected = (rig.prism.refractive_index - 1) * alpha
    np.testing.assert_allclose(dev, expected, rtol=0.03)


def test_biprism_faces_split_the_image(biprism):
    fm = face_map(biprism)
    assert fm.shape == (768, 1024)
    assert (fm[:, 512:] == 0).all() and (fm[:, :512] == 1).all()


def test_face_layout_follows_rotation():
    rig = pyramid_rig(4, rotation=0.0)
    fm = face_map(rig)
    h, w = fm.shape
    assert fm[h // 2, w - 60] == 0  # +X
    assert fm[h - 30, w // 2] == 1  # +Y (down)
    assert fm[h // 2, 60] == 2
    assert fm[30, w // 2] == 3
    rotated = face_map(rig.with_prism(rotation=90.0))
    assert rotated[h - 30, w // 2] == 0


def test_rays_leave_through_the_back_plane_and_bend_toward_the_base(biprism):
    b = trace_pixels(biprism, np.array([[900.0, 100.0], [100.0, 700.0]]))
    assert b.valid.all()
    np.testing.assert_allclose(b.origins[:, 2], biprism.prism.back_distance)
    assert b.directions[0, 0] < (900 - 511.5) / biprism.camera.focal_px  # face 0 (+X) bends toward −X
    assert b.directions[1, 0] > (100 - 511.5) / biprism.camera.focal_px
    np.testing.assert_allclose(np.linalg.norm(b.directions, axis=1), 1.0)


def test_invalid_rays_are_nan():
    # A 45° bi-prism with the default height is narrower than the field of view: outer rays miss.
    rig = thesis_biprism(45.0)
    b = trace_pixels(rig, np.array([[0.0, 384.0], [1023.0, 384.0], [530.0, 384.0]]))
    assert list(b.valid) == [False, False, True]
    assert np.isnan(b.origins[:2]).all() and np.isnan(b.directions[:2]).all()
    assert list(b.face[:2]) == [-1, -1]


def test_total_internal_reflection_is_reported():
    # Steep faces and dense glass: the ray meets the back plane beyond the critical angle.
    rig = thesis_biprism(60.0).with_prism(refractive_index=2.4, back_distance=260.0)
    b = trace_pixels(rig, np.array([[600.0, 384.0]]))
    assert not b.valid[0]


def test_slab_behind_faces_shifts_but_does_not_rotate(triprism):
    # A flat slab behind the faces shifts rays laterally but keeps their direction.
    thick = triprism.with_prism(back_distance=triprism.prism.back_distance + 20.0)
    px = np.array([[800.0, 380.0]])
    a, b = trace_pixels(triprism, px), trace_pixels(thick, px)
    np.testing.assert_allclose(a.directions, b.directions, atol=1e-12)
    assert not np.allclose(a.origins[:, :2], b.origins[:, :2])


@settings(max_examples=60, deadline=None)
@given(st.floats(0, 1023), st.floats(0, 767), st.floats(500, 5000))
def test_project_exact_round_trips_with_tracing(u, v, z):
    rig = thesis_biprism()
    px = np.array([[u, v]])
    b = trace_pixels(rig, px)
    point = b.point_at_depth(z)
    found, valid = project_exact(rig, point, face=int(b.face[0]))
    assert valid[0]
    np.testing.assert_allclose(found, px, atol=1e-4)


def test_project_exact_through_every_face_of_a_pyramid(pyramid4):
    grid = pixel_grid(1024, 768, step=50.0).reshape(-1, 2)
    b = trace_pixels(pyramid4, grid)
    pts = b.point_at_depth(1500.0)
    for k in range(4):
        sel = b.face == k
        found, valid = project_exact(pyramid4, pts[sel], face=k)
        assert valid.all()
        np.testing.assert_allclose(found, grid[sel], atol=1e-4)


def test_project_exact_takes_the_order_of_0_1_with_a_warning(biprism):
    """``project_exact(points, rig, face)`` (0.1.0) gives the pixels of ``project_exact(rig, points, face=)``."""
    point = np.array([[20.0, -10.0, 1500.0]])
    new = project_exact(biprism, point, face=0)
    with pytest.warns(DeprecationWarning, match="project_exact"):
        old = project_exact(point, biprism, 0)  # type: ignore[arg-type]
    np.testing.assert_array_equal(old[0], new[0])
    np.testing.assert_array_equal(old[1], new[1])
    with pytest.raises(TypeError, match="face"):
        project_exact(biprism, point, 0)
    with pytest.raises(TypeError, match="face"):
        project_exact(biprism, point)


def test_project_exact_reports_points_not_seen_through_a_face(biprism):
    # A point far to the right, seen through face 1 would need a ray through the wrong half.
    point = np.array([[3000.0, 0.0, 1500.0]])
    _, valid = project_exact(biprism, point, face=1)
    assert not valid[0]
    _, valid = project_exact(biprism, np.array([[0.0, 0.0, 100.0]]), face=0)  # in front of the prism
    assert not valid[0]
    with pytest.raises(GeometryError):
        project_exact(biprism, point, face=2)


def test_a_full_frame_traces_in_one_vectorised_call(biprism):
    # every pixel of the thesis bi-prism meets a face (no gap at the apex), exit points on the back plane
    grid = pixel_grid(biprism.camera.width, biprism.camera.height)
    b = trace_pixels(biprism, grid)
    assert b.valid.mean() == 1.0
    assert math.isclose(float(np.nanmax(b.origins[..., 2])), 215.6)
