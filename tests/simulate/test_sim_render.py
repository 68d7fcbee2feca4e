"""Renderer and ray–scene intersection: exact depth, determinism, antialiasing only at edges."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from prismstereo.config import Rig
from prismstereo.simulate import (
    Box,
    CheckerTexture,
    ImageTexture,
    NoiseTexture,
    Plane,
    Rectangle,
    Scene,
    SolidTexture,
    Sphere,
    intersect_scene,
    render_capture,
    rotation_from_normal,
)
from prismstereo.simulate.render import NO_FACE


def test_fronto_parallel_plane_gives_exact_depth(small_biprism: Rig) -> None:
    scene = Scene(objects=(Plane(center=(0.0, 0.0, 1234.5), texture=NoiseTexture(seed=3)),))
    cap = render_capture(small_biprism, scene, supersample=2)
    valid = cap.faces != NO_FACE
    assert valid.mean() > 0.95
    assert np.all(np.isfinite(cap.depth[valid]))
    assert np.all(np.isnan(cap.depth[~valid]))
    np.testing.assert_allclose(cap.depth[valid], 1234.5, rtol=0, atol=1e-4)
    np.testing.assert_allclose(cap.points[valid][:, 2], 1234.5, rtol=0, atol=1e-9)
    assert set(np.unique(cap.faces[valid]).tolist()) == {0, 1}
    # the bi-prism: face 0 (right virtual camera) is seen in the right half of the image
    assert np.all(cap.faces[:, -5:] == 0) and np.all(cap.faces[:, :5] == 1)


def test_fronto_parallel_rectangle_depth_through_triprism(small_triprism: Rig) -> None:
    scene = Scene(objects=(Rectangle(center=(0.0, 0.0, 600.0), size=(400.0, 400.0),
                                     texture=CheckerTexture(square=5.0)),))
    cap = render_capture(small_triprism, scene, supersample=1)
    hit = np.isfinite(cap.depth)
    assert hit.mean() > 0.5
    np.testing.assert_allclose(cap.depth[hit], 600.0, atol=1e-4)
    assert set(np.unique(cap.faces[cap.faces != NO_FACE]).tolist()) == {0, 1, 2}


def test_render_is_deterministic(small_biprism: Rig) -> None:
    scene = Scene(objects=(Plane(center=(0.0, 0.0, 2000.0)), Sphere(center=(0.0, 0.0, 1500.0), radius=40.0)),
                  shading=0.3, noise=2.0, seed=5)
    a = render_capture(small_biprism, scene, supersample=2)
    b = render_capture(small_biprism, scene, supersample=2)
    assert np.array_equal(a.image, b.image)
    assert np.array_equal(a.depth, b.depth, equal_nan=True)
    assert np.array_equal(a.faces, b.faces)
    c = render_capture(small_biprism, scene, supersample=2, seed=6)
    assert not np.array_equal(a.image, c.image)


def test_supersampling_changes_only_edges(small_biprism: Rig) -> None:
    objs = (
        Plane(center=(0.0, 0.0, 2000.0), texture=SolidTexture((0.2, 0.3, 0.4))),
        Rectangle(center=(-10.0, 5.0, 1500.0), size=(60.0, 40.0), rotation=(0.0, 0.0, 17.0),
                  texture=SolidTexture((0.9, 0.1, 0.1))),
        Box(center=(20.0, -20.0, 1300.0), size=(25.0, 25.0, 25.0), rotation=(0.0, 30.0, 0.0),
            texture=SolidTexture((0.1, 0.9, 0.2))),
    )
    scene = Scene(objects=objs)
    one = render_capture(small_biprism, scene, supersample=1)
    three = render_capture(small_biprism, scene, supersample=3)
    assert np.array_equal(one.depth, three.depth, equal_nan=True)
    diff = np.any(one.image != three.image, axis=2)
    assert diff.any()
    label = one.object_ids.astype(np.int32) * 256 + one.faces
    edge = ndimage.maximum_filter(label, 3) != ndimage.minimum_filter(label, 3)
    assert not np.any(diff & ~edge)


def test_intersection_of_primitives_is_analytic() -> None:
    scene = Scene(objects=(
        Sphere(center=(0.0, 0.0, 100.0), radius=10.0, texture=SolidTexture((1.0, 0.0, 0.0))),
        Rectangle(center=(50.0, 0.0, 200.0), size=(20.0, 20.0), texture=SolidTexture((0.0, 1.0, 0.0))),
        Box(center=(-50.0, 0.0, 300.0), size=(20.0, 20.0, 20.0), texture=SolidTexture((0.0, 0.0, 1.0))),
    ))
    o = np.zeros((5, 3))
    o[4] = np.nan
    d = np.array([[0, 0, 1], [50, 0, 200], [-50, 0, 290], [0, 1, 0], [0, 0, 1]], dtype=float)
    hits = intersect_scene(o, d, scene)
    np.testing.assert_allclose(hits.distance[:3], [90.0, np.hypot(50, 200), np.hypot(50, 290)], atol=1e-9)
    np.testing.assert_array_equal(hits.object_id, [0, 1, 2, -1, -1])
    np.testing.assert_allclose(hits.depth[:3], [90.0, 200.0, 290.0], atol=1e-9)
    np.testing.assert_allclose(hits.colors[:3], np.eye(3), atol=1e-7)
    assert np.all(np.isnan(hits.colors[3:])) and np.all(np.isnan(hits.points[3:]))


def test_checker_texture_edges_are_exact() -> None:
    board = Rectangle(center=(0.0, 0.0, 500.0), size=(40.0, 40.0),
                      texture=CheckerTexture(square=10.0, squares=(2, 2), margin=10.0))
    scene = Scene(objects=(board,))
    # surface (s, t) = (x + 20, y + 20): square (0, 0) [black] covers s, t in [10, 20)
    st = np.array([[15.0, 15.0], [25.0, 15.0], [15.0, 25.0], [25.0, 25.0], [5.0, 5.0], [19.999, 10.001]])
    target = board.surface_to_world(st)
    hits = intersect_scene(np.zeros_like(target), target, scene)
    np.testing.assert_allclose(hits.colors[:, 0], [0, 1, 1, 0, 1, 0])


def test_image_texture_and_rotation_helpers() -> None:
    img = np.zeros((2, 2, 3), dtype=np.uint8)
    img[0, 0] = (255, 0, 0)  # top-left red
    img[1, 1] = (0, 0, 255)  # bottom-right blue
    rect = Rectangle(center=(0.0, 0.0, 100.0), size=(20.0, 20.0), texture=ImageTexture(image=img))
    st = np.array([[5.0, 5.0], [15.0, 15.0]])  # texel centres
    target = rect.surface_to_world(st)
    hits = intersect_scene(np.zeros_like(target), target, Scene(objects=(rect,)))
    np.testing.assert_allclose(hits.colors, [[1, 0, 0], [0, 0, 1]], atol=1e-6)
    # from the front (camera side) the image is upright and unmirrored: s grows with +X, t with +Y
    np.testing.assert_allclose(target[:, :2], [[-5.0, -5.0], [5.0, 5.0]])
    r = Rectangle(center=(0.0, 0.0, 0.0), rotation=rotation_from_normal((1.0, 0.0, -1.0), spin=10.0))
    np.testing.assert_allclose(r.normal, np.array([1.0, 0.0, -1.0]) / np.sqrt(2.0), atol=1e-12)


def test_no_prism_reference_and_invalid_pixels(small_biprism: Rig) -> None:
    scene = Scene(objects=(Rectangle(center=(0.0, 0.0, 1000.0), size=(50.0, 50.0)),), background=(0.0, 1.0, 0.0))
    cap = render_capture(small_biprism, scene, supersample=1, prism=False)
    assert np.all(cap.faces == 0)
    miss = np.isnan(cap.depth)
    assert miss.any() and (~miss).any()
    assert np.all(cap.image[miss] == (0, 255, 0))


def test_bad_render_arguments(small_biprism: Rig) -> None:
    from prismstereo.errors import ConfigError

    scene = Scene(objects=(Plane(),))
    with pytest.raises(ConfigError, match="supersample"):
        render_capture(small_biprism, scene, supersample=0)
    with pytest.raises(ConfigError, match="noise"):
        render_capture(small_biprism, scene, noise=-1.0)


def test_dataclasses_validate_programmatic_scenes() -> None:
    from prismstereo.errors import ConfigError

    with pytest.raises(ConfigError, match="Sphere radius"):
        Sphere(radius=-1.0)
    with pytest.raises(ConfigError, match="Rectangle size"):
        Rectangle(size=(1.0, float("nan")))
    with pytest.raises(ConfigError, match="Box center"):
        Box(center=(0.0, 0.0))  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="NoiseTexture scale"):
        NoiseTexture(scale=0.0)
    with pytest.raises(ConfigError, match="background"):
        Scene(background=(2.0, 0.0, 0.0))
    r = Rectangle(center=[0, 0, 5], size=[1, 2])  # type: ignore[arg-type]
    assert r.center == (0.0, 0.0, 5.0) and r.size == (1.0, 2.0)


def test_ground_truth_points_project_back_to_their_pixels(small_biprism: Rig) -> None:
    from prismstereo.optics import project_exact

    scene = Scene(objects=(Plane(center=(0.0, 0.0, 2000.0)),
                           Sphere(center=(0.0, 0.0, 1400.0), radius=40.0),
                           Box(center=(20.0, 30.0, 1200.0), size=(30.0, 30.0, 30.0), rotation=(20.0, 40.0, 0.0))))
    cap = render_capture(small_biprism, scene, supersample=2)
    rng = np.random.default_rng(0)
    for face in (0, 1):
        vs, us = np.nonzero((cap.faces == face) & np.isfinite(cap.depth))
        pick = rng.choice(len(us), 40, replace=False)
        px, ok = project_exact(small_biprism, cap.points[vs[pick], us[pick]], face=face)
        assert ok.all()
        np.testing.assert_allclose(px, np.stack([us[pick], vs[pick]], axis=1), atol=1e-3)
