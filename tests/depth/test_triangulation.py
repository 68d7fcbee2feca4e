"""Triangulation round trips: exact refraction, midpoint, DLT and Q reprojection."""

from __future__ import annotations

import numpy as np
import pytest

from prismstereo.cameras import sample_points
from prismstereo.cameras.pinhole import PinholeCamera, rotation_from_axis
from prismstereo.config import pyramid_rig, thesis_biprism, thesis_triprism
from prismstereo.depth.triangulation import (
    depth_from_disparity,
    rectified_to_world,
    reproject_disparity,
    triangulate_dlt,
    triangulate_exact,
    triangulate_midpoint,
)
from prismstereo.optics import project_exact


def _points(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    z = rng.uniform(800.0, 3000.0, n)
    x = rng.uniform(-0.04, 0.04, n) * z
    y = rng.uniform(-0.05, 0.05, n) * z
    return np.stack([x, y, z], axis=1)


@pytest.mark.parametrize("rig,faces", [(thesis_biprism(), (1, 0)), (thesis_triprism(), (0, 1)),
                                       (pyramid_rig(4), (0, 2))])
def test_exact_triangulation_recovers_points(rig, faces):
    _, pts = sample_points(rig, faces[0], n=1500, depth_range=(800.0, 3000.0))
    pa, va = project_exact(rig, pts, face=faces[0], tolerance_px=1e-9)
    pb, vb = project_exact(rig, pts, face=faces[1], tolerance_px=1e-9)
    ok = va & vb
    assert ok.sum() > 20
    tri = triangulate_exact(rig, pa[ok], pb[ok], faces=faces)
    assert tri.valid.all()
    rel = np.linalg.norm(tri.points - pts[ok], axis=1) / np.linalg.norm(pts[ok], axis=1)
    assert rel.max() < 1e-6
    assert np.nanmax(tri.gaps) < 1e-3


def test_exact_triangulation_rejects_wrong_face_and_nan():
    rig = thesis_biprism()
    pts = _points(5)
    pa, _ = project_exact(rig, pts, face=1)
    pb, _ = project_exact(rig, pts, face=0)
    tri = triangulate_exact(rig, pb, pa, faces=(1, 0))  # swapped: faces do not match
    assert not tri.valid.any()
    pa[0] = np.nan
    tri = triangulate_exact(rig, pa, pb)
    assert not tri.valid[0] and np.isnan(tri.points[0]).all()


def _stereo_cameras():
    K = np.array([[5000.0, 0.0, 256.0], [0.0, 5000.0, 380.0], [0.0, 0.0, 1.0]])
    ca = PinholeCamera(K=K, R=rotation_from_axis(np.array([0.02, 0.0, 1.0])), C=np.array([-12.0, 0.3, 5.0]))
    cb = PinholeCamera(K=K, R=rotation_from_axis(np.array([-0.02, 0.01, 1.0])), C=np.array([12.0, -0.2, 4.0]))
    return ca, cb


def test_midpoint_and_dlt_on_pinhole_data():
    ca, cb = _stereo_cameras()
    pts = _points(200, seed=3)
    xa, xb = ca.project(pts), cb.project(pts)
    oa, da = ca.unproject(xa)
    ob, db = cb.unproject(xb)
    tri = triangulate_midpoint(oa, da, ob, db)
    assert tri.valid.all()
    np.testing.assert_allclose(tri.points, pts, rtol=1e-8)
    dlt = triangulate_dlt(ca.P, cb.P, xa, xb)
    np.testing.assert_allclose(dlt, pts, rtol=1e-7)


def test_midpoint_of_skew_rays_and_invalid_cases():
    tri = triangulate_midpoint(np.array([[0.0, 0, 0], [0, 0, 0], [0, 0, 0]]),
                               np.array([[1.0, 0, 0], [1, 0, 0], [1, 0, 0]]),
                               np.array([[0.0, 0, 2], [0, 0, 2], [5, -3, 2]]),
                               np.array([[0.0, 1, 0], [1, 0, 0], [0, 1, 0]]))
    # 2nd: parallel rays; 3rd: skew rays meeting nearest at (5,0,0) and (5,0,2)
    assert not tri.valid[1]  # parallel
    assert tri.valid[2]
    np.testing.assert_allclose(tri.points[2], [5.0, 0.0, 1.0])
    np.testing.assert_allclose(tri.gaps[2], 2.0)


def test_q_reprojection_on_rectified_data():
    f, cx, cy, lam = 5000.0, 200.0, 150.0, 24.0
    Q = np.array([[1, 0, 0, -cx], [0, 1, 0, -cy], [0, 0, 0, f], [0, 0, 1 / lam, 0]])
    rng = np.random.default_rng(1)
    Z = rng.uniform(800, 3000, (30, 40))
    disp = f * lam / Z
    pts = reproject_disparity(disp, Q)
    np.testing.assert_allclose(pts[..., 2], Z, rtol=1e-12)
    ys, xs = np.mgrid[0:30, 0:40]
    np.testing.assert_allclose(pts[..., 0], (xs - cx) * Z / f, rtol=1e-10, atol=1e-9)
    np.testing.assert_allclose(depth_from_disparity(disp, focal_px=f, baseline_mm=lam), Z, rtol=1e-12)
    disp[0, 0] = np.nan
    disp[0, 1] = 0.0
    pts = reproject_disparity(disp, Q)
    assert np.isnan(pts[0, 0]).all() and np.isnan(pts[0, 1]).all()
    # the rectified point projects back where it came from through a rectified camera P = K[R|-RC]
    R = rotation_from_axis(np.array([0.01, 0.0, 1.0]))
    C = np.array([-12.0, 0.0, 5.0])
    world = rectified_to_world(pts[5, 7], R, C)
    cam = PinholeCamera(K=np.array([[f, 0, cx], [0, f, cy], [0, 0, 1]]), R=R, C=C)
    np.testing.assert_allclose(cam.project(world), [7.0, 5.0], atol=1e-8)


@pytest.fixture(scope="module")
def demo_setup():  # type: ignore[no-untyped-def]
    from prismstereo.apps.demo import demo_rig
    from prismstereo.depth import DepthConfig, prepare_depth

    rig = demo_rig()
    return rig, prepare_depth(rig, config=DepthConfig(method="sad"))


def test_ray_table_matches_exact_triangulation(demo_setup) -> None:  # type: ignore[no-untyped-def]
    """The table's points are triangulate_exact's within 1e-5 relative to 20 m (d >= 2 px on this rig) and
    within the equivalent of 2e-5 px of disparity everywhere (to 100 m), the same points valid."""
    from prismstereo.depth.triangulation import ray_table, triangulate_matches, triangulate_table

    rig, s = demo_setup
    table = s.rays if s.rays is not None else ray_table(rig, s.pair)
    assert table.shape == (s.pair.size[1], s.pair.size[0])
    rng = np.random.default_rng(5)
    ys, xs = np.nonzero(s.region.mask)
    pick = rng.choice(ys.size, 40000)
    ys, xs = ys[pick], xs[pick]
    d = rng.uniform(*s.region.disparity_range, ys.size)
    d[::50] = np.nan
    got = triangulate_table(table, ys, xs, d)
    ref = triangulate_matches(rig, s.pair, ys, xs, d, method="exact", views=s.views)
    assert ref.valid.sum() > 10000
    assert np.array_equal(got.valid, ref.valid)
    ok = ref.valid
    rel = np.linalg.norm(got.points[ok] - ref.points[ok], axis=1) / np.linalg.norm(ref.points[ok], axis=1)
    z = ref.points[ok, 2]
    assert rel[z < 20000.0].max() < 1e-5
    assert rel[z < 3000.0].max() < 1e-6
    assert (rel * d[ok]).max() < 3e-5  # the equivalent disparity error, px
    np.testing.assert_allclose(got.gaps[ok], ref.gaps[ok], rtol=1e-3, atol=1e-3)
    # the same through triangulate_matches with the table
    via = triangulate_matches(rig, s.pair, ys, xs, d, method="exact", views=s.views, rays=table)
    assert np.array_equal(via.points, got.points, equal_nan=True)


def test_ray_table_off_the_view_is_invalid(demo_setup) -> None:  # type: ignore[no-untyped-def]
    from prismstereo.depth.triangulation import RayTable, triangulate_table

    _, s = demo_setup
    h, w = s.rays.shape
    y = h // 2
    x = np.array([w // 2, w // 2, w // 2, 3])
    d = np.array([float(w), -float(w), np.inf, 5.0])  # right pixel beyond either edge, no disparity
    tri = triangulate_table(s.rays, np.full(4, y), x, d)
    assert not tri.valid.any() and np.isnan(tri.points).all()
    back = RayTable.from_arrays(s.rays.to_arrays())
    assert np.array_equal(back.left_origins, s.rays.left_origins, equal_nan=True)
    with pytest.raises(ValueError):
        RayTable.from_arrays({**s.rays.to_arrays(), "rays_right_d": np.zeros((2, 2, 3))})


def test_points_on_grid_places_the_kept_points_as_numpy_indexing_does() -> None:
    """``points_on_grid`` gives the arrays of the scatter it replaces (fancy indexing of the kept points, depth as
    float32 z), bit for bit, NaN points and a kept gap of NaN included."""
    from prismstereo.depth.triangulation import points_on_grid

    rng = np.random.default_rng(4)
    h, w = 23, 31
    flat = rng.choice(h * w, size=300, replace=False)
    ys, xs = flat // w, flat % w
    pts = rng.normal(0, 1000, (300, 3))
    pts[::17] = np.nan
    gaps = rng.uniform(0, 3, 300)
    gaps[::13] = np.nan
    keep = rng.uniform(size=300) > 0.3
    points = np.full((h, w, 3), np.nan)
    gap = np.full((h, w), np.nan, dtype=np.float32)
    points[ys[keep], xs[keep]] = pts[keep]
    gap[ys[keep], xs[keep]] = gaps[keep]
    valid = np.zeros((h, w), dtype=bool)
    valid[ys[keep], xs[keep]] = True
    depth = np.where(valid, points[..., 2], np.nan).astype(np.float32)
    got = points_on_grid((h, w), ys, xs, pts, gaps, keep)
    for g, want in zip(got, (points, depth, gap, valid), strict=True):
        assert g.dtype == want.dtype and g.shape == want.shape
        np.testing.assert_array_equal(g, want)
    assert valid.sum() > 150
