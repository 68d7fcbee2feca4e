"""Rectification: regions, rectifying transforms, epipolar verification on exact correspondences, Q, CLI."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from prismstereo.cameras import PinholeCamera, VirtualView, calibrate_rig
from prismstereo.cli import main
from prismstereo.config import Rig, pyramid_rig, thesis_biprism, thesis_triprism
from prismstereo.errors import GeometryError, ImageError
from prismstereo.rectify import (
    disparity_range,
    rectify_pair,
    rectify_views,
    split_capture,
    true_correspondences,
    vertical_residual,
    view_regions,
)


@pytest.fixture(scope="module")
def rig() -> Rig:
    return thesis_biprism(6.4)


@pytest.fixture(scope="module")
def views(rig: Rig) -> list[VirtualView]:
    return calibrate_rig(rig, method="fit")


@pytest.fixture(scope="module")
def regions(rig: Rig):  # type: ignore[no-untyped-def]
    return view_regions(rig)


@pytest.fixture(scope="module")
def pair(rig: Rig, views: list[VirtualView], regions):  # type: ignore[no-untyped-def]
    return rectify_pair(rig, views[0], views[1], regions=regions)


@pytest.fixture(scope="module")
def corr(rig: Rig, regions):  # type: ignore[no-untyped-def]
    return true_correspondences(rig, 1, 0, n=1500, depth_range=(800.0, 2500.0), regions=regions)


def test_regions_split_the_image(rig: Rig, regions) -> None:  # type: ignore[no-untyped-def]
    assert [r.face for r in regions] == [0, 1]
    m0, m1 = regions[0].mask, regions[1].mask
    assert not np.any(m0 & m1)
    # face 0 = right half, face 1 = left half, with a band dropped along the apex edge
    assert regions[0].bbox[0] > rig.camera.width // 2 and regions[1].bbox[2] < rig.camera.width // 2
    wide = view_regions(rig, margin_px=0)
    assert wide[0].area > regions[0].area
    img = np.arange(rig.camera.height * rig.camera.width, dtype=np.float32).reshape(rig.camera.height, -1)
    subs = split_capture(img, rig, regions=regions)
    for s, r in zip(subs, regions, strict=True):
        x0, y0 = s.offset
        rr, cc = np.nonzero(s.mask)
        assert np.array_equal(s.image[rr, cc], img[rr + y0, cc + x0])
        assert r.mask[rr + y0, cc + x0].all()
    with pytest.raises(ImageError, match="expected an image of the rig's sensor size"):
        split_capture(np.zeros((10, 10)), rig)


def test_pair_orientation_and_conventions(pair, views: list[VirtualView]) -> None:  # type: ignore[no-untyped-def]
    # left = face 1 (the left virtual camera), the baseline points along +X
    assert (pair.left_face, pair.right_face) == (1, 0)
    assert pair.C_right[0] > pair.C_left[0]
    R = pair.R
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-12) and np.isclose(np.linalg.det(R), 1.0)
    assert np.allclose(R[0], (pair.C_right - pair.C_left) / pair.baseline_mm)
    assert R[1] @ np.array([0.0, 1.0, 0.0]) > 0.99  # y as the real camera's Y
    assert pair.K[0, 0] == pytest.approx(5376.344, rel=1e-4)
    w, h = pair.size
    assert pair.map_left.shape == (h, w, 2) and pair.map_left.dtype == np.float32
    assert 500 < w < 800 and 700 < h < 800
    assert pair.valid_left.mean() > 0.6 and pair.valid_right.mean() > 0.6
    js = pair.to_json()
    assert {"views", "baseline_mm", "Q"} <= set(js) and {"K", "R", "C", "P"} <= set(js["views"][0])


def test_rectified_epipolar_lines_are_horizontal(pair, corr) -> None:  # type: ignore[no-untyped-def]
    res, dy = vertical_residual(pair, corr)
    assert res.n > 1000
    assert res.rms <= 0.2 and res.p95 <= 0.5
    # disparity d = x_left − x_right ≥ 0 in front, inside disparity_range
    xl = pair.real_to_rectified(corr.pixels_a, "left")[:, 0]
    xr = pair.real_to_rectified(corr.pixels_b, "right")[:, 0]
    d = xl - xr
    lo, hi = disparity_range(pair, 800.0, 2500.0)
    assert np.all(d > 0)
    assert lo - 1 <= d.min() and d.max() <= hi + 1


def test_exact_remap_meets_target(rig: Rig, views: list[VirtualView], regions, corr) -> None:  # type: ignore[no-untyped-def]
    p = rectify_pair(rig, views[0], views[1], remap="exact", regions=regions)
    res, _ = vertical_residual(p, corr)
    assert res.rms <= 0.1 and res.p95 <= 0.25


def test_maps_and_inverse_agree(pair, corr) -> None:  # type: ignore[no-untyped-def]
    for side, px in (("left", corr.pixels_a), ("right", corr.pixels_b)):
        rect = pair.real_to_rectified(px[:200], side)
        back = pair.rectified_to_real(rect, side)
        assert np.nanmax(np.abs(back - px[:200])) < 0.02


def test_q_maps_disparity_back_to_points(pair, corr) -> None:  # type: ignore[no-untyped-def]
    # exactly, for the rectified pinholes
    X = corr.points[:300]
    pl, pr = pair.project(X, "left"), pair.project(X, "right")
    assert np.allclose(pl[:, 1], pr[:, 1])
    back = pair.reproject(pl, pl[:, 0] - pr[:, 0])
    assert np.allclose(back, X, atol=1e-6)
    # and for the true correspondences through the fitted model: depth error well under 1 %
    xl = pair.real_to_rectified(corr.pixels_a, "left")
    xr = pair.real_to_rectified(corr.pixels_b, "right")
    pts = pair.reproject(xl, xl[:, 0] - xr[:, 0])
    rel = np.abs(pts[:, 2] - corr.points[:, 2]) / corr.points[:, 2]
    assert np.median(rel) < 0.002
    assert np.allclose(pair.world_to_left(pair.left_to_world(X)), X)


def test_rotated_rig_still_rectifies() -> None:
    rig = thesis_biprism(6.4).with_prism(rotation=30.0)
    views = calibrate_rig(rig)
    regions = view_regions(rig)
    pair = rectify_pair(rig, views[0], views[1], regions=regions)
    base = pair.C_right - pair.C_left
    assert abs(np.degrees(np.arctan2(base[1], base[0]))) == pytest.approx(30.0, abs=1.0)
    corr = true_correspondences(rig, 0, 1, n=800, regions=regions)
    res, _ = vertical_residual(pair, corr)
    assert res.rms <= 0.2 and res.p95 <= 0.5


def test_views_that_do_not_overlap_raise(rig: Rig, views: list[VirtualView], regions) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(GeometryError, match="expected two different faces"):
        rectify_pair(rig, views[0], views[0], regions=regions)
    cam = views[0].camera
    tilt = cv2.Rodrigues(np.array([np.radians(25.0), 0.0, 0.0]))[0]
    up = dataclasses.replace(views[0], camera=PinholeCamera(K=cam.K, R=tilt @ cam.R, C=cam.C, dist=cam.dist))
    with pytest.raises(GeometryError, match="do not overlap"):
        rectify_pair(rig, up, views[1], regions=regions)
    same_centre = dataclasses.replace(views[1], camera=PinholeCamera(K=cam.K, R=cam.R, C=cam.C))
    with pytest.raises(GeometryError, match="distinct optical centres"):
        rectify_pair(rig, views[0], same_centre, regions=regions)


def test_multiview_shared_orientation_and_pairs() -> None:
    rig = pyramid_rig(4)
    views = calibrate_rig(rig, method="thesis")
    rv = rectify_views(rig, views, pairs=False)
    assert np.allclose(rv.R, np.eye(3))
    # faces 0 (+X) and 2 (−X) have a horizontal baseline: row-aligned in the shared frame
    assert (2, 0) in rv.horizontal_pairs
    assert len(rv.maps) == 4 and rv.maps[0].shape[:2] == rv.size[::-1]
    tri = thesis_triprism()
    p = rectify_pair(tri, *calibrate_rig(tri, method="fit")[:2])
    # over the depths at which the tri-prism's views share a field (0.3-3 m; the models are fitted there):
    # 0.39 px RMS, where models fitted over a fixed 0.5-3 m range leave 0.51
    corr = true_correspondences(tri, p.left_face, p.right_face, n=1500, depth_range=(300.0, 3000.0))
    res, _ = vertical_residual(p, corr)
    assert res.rms <= 0.45 and res.p95 <= 1.0


def test_cli_rectify_end_to_end(tmp_path, rig: Rig) -> None:  # type: ignore[no-untyped-def]
    rig_path = tmp_path / "rig.toml"
    rig.save(rig_path)
    rng = np.random.default_rng(0)
    img = cv2.GaussianBlur(rng.integers(0, 255, (rig.camera.height, rig.camera.width, 3), dtype=np.uint8), (5, 5), 0)
    cv2.imwrite(str(tmp_path / "cap.png"), img)
    out = tmp_path / "out"
    assert main(["rectify", str(rig_path), str(tmp_path / "cap.png"), "-o", str(out)]) == 0
    names = {p.name for p in out.iterdir()}
    assert {"left.png", "right.png", "rectification.json", "epipolar_before.png", "epipolar_after.png"} <= names
    left = cv2.imread(str(out / "left.png"))
    assert left.shape[0] > 700


def test_cli_rectify_wrong_size_exits_2(tmp_path, rig: Rig, capsys) -> None:  # type: ignore[no-untyped-def]
    rig_path = tmp_path / "rig.toml"
    rig.save(rig_path)
    cv2.imwrite(str(tmp_path / "small.png"), np.zeros((100, 120, 3), np.uint8))
    out = tmp_path / "out"
    assert main(["rectify", str(rig_path), str(tmp_path / "small.png"), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "expected a 1024×768 capture (the rig's sensor size), got 120×100" in err  # from the PNG header
    assert not out.exists() or not any(out.iterdir())
