from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from prismstereo.optics import closest_points_between_lines, normalize, refract

unit_components = st.floats(-1.0, 1.0, allow_nan=False)


def _unit(x, y, z):
    v = np.array([x, y, z])
    n = np.linalg.norm(v)
    return None if n < 1e-3 else v / n


@settings(max_examples=300, deadline=None)
@given(unit_components, unit_components, unit_components, unit_components, unit_components,
       unit_components, st.floats(1.0, 2.5), st.floats(1.0, 2.5))
def test_snell_law_and_coplanarity(dx, dy, dz, nx, ny, nz, n1, n2):
    d, n = _unit(dx, dy, dz), _unit(nx, ny, nz)
    if d is None or n is None or abs(np.dot(d, n)) < 1e-3:
        return
    t, valid = refract(d, n, n1, n2)
    sin_i = np.linalg.norm(np.cross(d, n))
    if n1 * sin_i > n2 * (1 + 1e-9):
        assert not valid and np.all(np.isnan(t))  # total internal reflection
        return
    if not valid:
        assert n1 * sin_i > n2 * (1 - 1e-9)
        return
    sin_t = np.linalg.norm(np.cross(t, n))
    assert abs(n1 * sin_i - n2 * sin_t) < 1e-9
    assert abs(np.linalg.det(np.stack([d, n, t]))) < 1e-9  # incident, normal, refracted are coplanar
    assert np.sign(np.dot(t, n)) == np.sign(np.dot(d, n))  # the ray crosses the interface
    assert abs(np.linalg.norm(t) - 1.0) < 1e-12


@settings(max_examples=300, deadline=None)
@given(unit_components, unit_components, unit_components, unit_components, unit_components,
       unit_components, st.floats(1.0, 2.5), st.floats(1.0, 2.5))
def test_refraction_is_reversible(dx, dy, dz, nx, ny, nz, n1, n2):
    d, n = _unit(dx, dy, dz), _unit(nx, ny, nz)
    if d is None or n is None or abs(np.dot(d, n)) < 1e-3:
        return
    t, valid = refract(d, n, n1, n2)
    if not valid:
        return
    back, ok = refract(-t, n, n2, n1)
    assert ok
    np.testing.assert_allclose(back, -d, atol=1e-9)


def test_normal_incidence_passes_straight_and_batches():
    d = normalize(np.array([[0, 0, 1.0], [0.1, 0, 1.0]]))
    t, valid = refract(d, np.array([0, 0, -1.0]), 1.0, 1.5)
    assert valid.all()
    np.testing.assert_allclose(t[0], [0, 0, 1])
    assert t[1, 0] < d[1, 0]  # bent toward the normal in the denser medium


def test_total_internal_reflection_is_invalid():
    d = normalize(np.array([0.8, 0.0, 0.6]))  # 53° from the normal
    t, valid = refract(d, np.array([0, 0, 1.0]), 1.5, 1.0)
    assert not valid
    assert np.isnan(t).all()


def test_midpoint_of_common_perpendicular():
    mid, gap = closest_points_between_lines(
        np.array([0, 0, 0.0]), np.array([1, 0, 0.0]), np.array([0, 1, 2.0]), np.array([0, 0, 1.0])
    )
    np.testing.assert_allclose(mid, [0, 0.5, 0])
    assert gap == 1.0
    mid, _ = closest_points_between_lines(
        np.array([0, 0, 0.0]), np.array([1, 0, 0.0]), np.array([0, 1, 0.0]), np.array([1, 0, 0.0])
    )
    assert np.isnan(mid).all()  # parallel lines have no unique midpoint
