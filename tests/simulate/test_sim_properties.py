"""Property tests of the intersection kernel (hypothesis): hit points lie on the surfaces they report."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from prismstereo.simulate import Box, Rectangle, Scene, Sphere, intersect_scene

angles = st.tuples(*[st.floats(-180.0, 180.0)] * 3)
coords = st.tuples(st.floats(-50.0, 50.0), st.floats(-50.0, 50.0), st.floats(300.0, 900.0))


def _rays(seed: int, n: int = 400) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    d = np.column_stack([rng.uniform(-0.15, 0.15, n), rng.uniform(-0.15, 0.15, n), np.ones(n)])
    o = np.column_stack([rng.uniform(-20, 20, n), rng.uniform(-20, 20, n), rng.uniform(0, 200, n)])
    return o, d


@settings(max_examples=30, deadline=None)
@given(center=coords, rotation=angles, seed=st.integers(0, 1000))
def test_hits_lie_on_the_reported_surface(center: tuple[float, float, float],
                                          rotation: tuple[float, float, float], seed: int) -> None:
    o, d = _rays(seed)
    rect = Rectangle(center=center, size=(80.0, 60.0), rotation=rotation)
    hits = intersect_scene(o, d, Scene(objects=(rect,)))
    h = hits.hit
    q = (hits.points[h] - np.asarray(center)) @ rect.matrix
    np.testing.assert_allclose(q[:, 2], 0.0, atol=1e-8)
    assert np.all(np.abs(q[:, 0]) <= 40.0 + 1e-9) and np.all(np.abs(q[:, 1]) <= 30.0 + 1e-9)
    np.testing.assert_allclose(hits.points[h], o[h] + hits.distance[h, None] * d[h] / np.linalg.norm(d[h], axis=1,
                               keepdims=True), atol=1e-8)

    sph = Sphere(center=center, radius=35.0, rotation=rotation)
    hs = intersect_scene(o, d, Scene(objects=(sph,)))
    np.testing.assert_allclose(np.linalg.norm(hs.points[hs.hit] - np.asarray(center), axis=1), 35.0, atol=1e-8)

    box = Box(center=center, size=(40.0, 30.0, 20.0), rotation=rotation)
    hb = intersect_scene(o, d, Scene(objects=(box,)))
    local = np.abs((hb.points[hb.hit] - np.asarray(center)) @ box.matrix) / np.array([20.0, 15.0, 10.0])
    np.testing.assert_allclose(local.max(axis=1), 1.0, atol=1e-9)
    # nearest hit: the box's entry point is in front of the ray
    assert np.all(hb.distance[hb.hit] > 0)
