"""RGB-D scene objects: exact ray intersection of the height field, skin and unknown ground truth, files."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from prismstereo.apps.simulate_folder import simulate_to_folder
from prismstereo.config import Rig
from prismstereo.errors import ConfigError
from prismstereo.io import read_pfm, write_image, write_pfm
from prismstereo.optics import trace_pixels
from prismstereo.simulate import Scene, intersect_scene, load_scene, render_capture, scene_from_dict, scene_to_toml
from prismstereo.simulate.rgbd import (
    depth_from_disparity,
    fill_unknown_depth,
    middlebury_rgbd,
    surface_mesh,
)
from prismstereo.simulate.scene import RGBDSurface

H, W, F = 40, 56, 60.0
CX, CY = (W - 1) / 2.0, (H - 1) / 2.0


def _rays_of_grid() -> np.ndarray:
    vv, uu = np.mgrid[0:H, 0:W].astype(np.float64)
    return np.stack([(uu - CX) / F, (vv - CY) / F, np.ones_like(uu)], axis=-1)


def _plane_depth(normal: np.ndarray, dist: float) -> np.ndarray:
    """Source depth map of the plane n·p = dist seen by the source camera (Z = dist / (n·r))."""
    return dist / (_rays_of_grid() @ normal)


def _texture(seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (H, W, 3)).astype(np.uint8)


def _analytic_plane_hit(surf: RGBDSurface, normal: np.ndarray, dist: float, o: np.ndarray, d: np.ndarray
                        ) -> np.ndarray:
    """World points where rays o + t d meet the plane after the surface's pose: n·Rᵀ(x − c)/s = dist."""
    R, c, s = surf.matrix, np.asarray(surf.origin), surf.scale
    nw = R @ normal
    t = (dist * s + nw @ c - o @ nw) / (d @ nw)
    return o + t[:, None] * d


def _inside_grid(surf: RGBDSurface, pts: np.ndarray, margin: float = 0.5) -> np.ndarray:
    p = (pts - np.asarray(surf.origin)) @ surf.matrix / surf.scale
    u = F * p[:, 0] / p[:, 2] + CX
    v = F * p[:, 1] / p[:, 2] + CY
    return (u >= margin) & (u <= W - 1 - margin) & (v >= margin) & (v <= H - 1 - margin)


@pytest.mark.parametrize("pose", ["placed", "turned"])
def test_planar_depth_map_renders_to_the_analytic_plane(pose: str) -> None:
    n = np.array([0.25, -0.15, 1.0])
    n /= np.linalg.norm(n)
    depth = _plane_depth(n, 1800.0)
    if pose == "placed":
        surf = RGBDSurface.placed(_texture(), depth, focal=(F, F), center_depth=1200.0, scale=0.4)
    else:
        surf = RGBDSurface(image=_texture(), depth=depth, focal=(F, F), origin=(30.0, -20.0, 400.0),
                           rotation=(4.0, -6.0, 10.0), scale=0.5)
    rng = np.random.default_rng(1)
    o = rng.uniform(-5.0, 5.0, (4000, 3))
    d = np.column_stack([rng.uniform(-0.35, 0.35, 4000), rng.uniform(-0.3, 0.3, 4000), np.ones(4000)])
    hits = intersect_scene(o, d, Scene(objects=(surf,)))
    truth = _analytic_plane_hit(surf, n, 1800.0, o, d)
    inside = _inside_grid(surf, truth)
    assert inside.sum() > 1500 and (~inside).sum() > 100
    assert np.all(hits.hit[inside])
    rel = np.abs(hits.points[inside] - truth[inside]).max(axis=1) / truth[inside, 2]
    assert rel.max() < 1e-9
    # outside the depth map's pixel grid the surface does not exist
    outside = ~_inside_grid(surf, truth, margin=-0.5)
    assert not hits.hit[outside].any()


def test_planar_depth_map_through_the_prism(small_biprism: Rig) -> None:
    n = np.array([-0.1, 0.2, 1.0])
    n /= np.linalg.norm(n)
    surf = RGBDSurface.placed(_texture(), _plane_depth(n, 2000.0), focal=(F, F), center_depth=1000.0)
    cap = render_capture(small_biprism, Scene(objects=(surf,), supersample=1))
    vv, uu = np.nonzero(np.isfinite(cap.depth))
    assert vv.size > 0.8 * cap.depth.size  # the copy fills the view (same angles as the photograph)
    rays = trace_pixels(small_biprism, np.stack([uu, vv], axis=1).astype(np.float64))
    truth = _analytic_plane_hit(surf, n, 2000.0, rays.origins, rays.directions)
    rel = np.abs(cap.depth[vv, uu] - truth[:, 2]) / truth[:, 2]
    assert rel.max() < 1e-6  # float32 depth
    assert set(np.unique(cap.faces[vv, uu])) == {0, 1}


def test_colour_is_the_photograph_at_the_hit_projection() -> None:
    img = _texture(5)
    depth = np.full((H, W), 1000.0)
    surf = RGBDSurface(image=img, depth=depth, focal=(F, F))  # source camera at the world origin
    # rays through the source pixel centres see exactly those pixels
    vv, uu = np.mgrid[2:H - 2:3, 2:W - 2:3]
    d = np.stack([(uu.ravel() - CX) / F, (vv.ravel() - CY) / F, np.ones(uu.size)], axis=1)
    hits = intersect_scene(np.zeros_like(d), d, Scene(objects=(surf,)))
    expect = img[vv.ravel(), uu.ravel()].astype(np.float32) / 255.0
    np.testing.assert_allclose(hits.colors, expect, atol=1e-5)


def test_step_renders_its_skin_as_unknown() -> None:
    depth = np.full((H, W), 1000.0)
    depth[:, W // 2:] = 1500.0  # a 50 % jump between columns W/2 − 1 and W/2
    surf = RGBDSurface(image=_texture(), depth=depth, focal=(F, F), origin=(-40.0, 0.0, 0.0))
    # cells of the jump are skin (both triangles), no others
    _, flags = surface_mesh(surf)
    bad_cols = np.nonzero(flags.any(axis=0))[0]
    assert list(bad_cols) == [W // 2 - 1] and np.all(flags[:, W // 2 - 1] == 3)
    # seen from 40 mm to the right of the source camera the skin is in view: a hit without ground truth
    u = np.linspace(0.0, W - 1.0, 800)
    d = np.stack([(u - CX) / F, np.zeros_like(u), np.ones_like(u)], axis=1)
    o = np.zeros_like(d)
    hits = intersect_scene(o, d, Scene(objects=(surf,)))
    z = hits.points[:, 2]
    skin = hits.hit & ~np.isfinite(z)
    assert skin.sum() >= 5 and np.all(np.isfinite(hits.colors[hits.hit]))
    known = hits.hit & np.isfinite(z)
    assert set(np.round(z[known]).astype(int)) == {1000, 1500}
    # skin hits lie between the two terraces along the ray, i.e. between the foreground and background hits
    xs = np.nonzero(skin)[0]
    assert np.all(np.isfinite(z[xs.min() - 1])) and np.all(np.isfinite(z[xs.max() + 1]))
    # a lower threshold than the step keeps it, a higher one makes it a surface
    _, flags_hi = surface_mesh(RGBDSurface(image=_texture(), depth=depth, focal=(F, F), jump=0.6))
    assert not flags_hi.any()


def test_unknown_depth_is_filled_and_has_no_ground_truth() -> None:
    depth = np.full((H, W), 1200.0)
    depth[:, :10] = 900.0
    depth[10:20, 10:16] = np.nan  # an occlusion beside the foreground: filled with the background
    filled = fill_unknown_depth(depth)
    assert np.all(filled[10:20, 10:16] == 1200.0) and np.all(np.isfinite(filled))
    surf = RGBDSurface(image=_texture(), depth=depth, focal=(F, F))
    _, flags = surface_mesh(surf)
    assert np.all(flags[10:19, 10:15] == 3) and not flags[25:, 20:].any()
    vv, uu = np.mgrid[12:18, 11:15]
    d = np.stack([(uu.ravel() - CX) / F, (vv.ravel() - CY) / F, np.ones(uu.size)], axis=1)
    hits = intersect_scene(np.zeros_like(d), d, Scene(objects=(surf,)))
    assert np.all(hits.hit) and np.all(np.isnan(hits.points[:, 2]))
    # a row without any known depth takes the nearest known pixel
    depth2 = depth.copy()
    depth2[5] = np.nan
    assert np.all(np.isfinite(fill_unknown_depth(depth2)[5]))


def test_depth_from_disparity_and_its_errors() -> None:
    z = depth_from_disparity(np.array([[10.0, np.nan, -60.0, np.inf]]), focal_px=1000.0, baseline_mm=100.0,
                             doffs_px=50.0)
    assert z[0, 0] == pytest.approx(100.0 * 1000.0 / 60.0) and np.isnan(z[0, 1:]).all()
    for kw in ({"focal_px": 0.0, "baseline_mm": 1.0}, {"focal_px": 1.0, "baseline_mm": -1.0},
               {"focal_px": 1.0, "baseline_mm": 1.0, "doffs_px": float("nan")}):
        with pytest.raises(ConfigError, match=next(iter(k for k in kw if not (kw[k] == 1.0)))):
            depth_from_disparity(np.ones((2, 2)), **kw)


def test_surface_validation_errors() -> None:
    with pytest.raises(ConfigError, match="colour image's size"):
        RGBDSurface(image=_texture(), depth=np.ones((H, W + 1)), focal=(F, F))
    with pytest.raises(ConfigError, match="known"):
        RGBDSurface(image=_texture(), depth=np.full((H, W), np.nan), focal=(F, F))
    with pytest.raises(ConfigError, match="focal"):
        RGBDSurface(image=_texture(), depth=np.ones((H, W)), focal=(0.0, F))
    with pytest.raises(ConfigError, match="scale"):
        RGBDSurface(image=_texture(), depth=np.ones((H, W)), focal=(F, F), scale=-1.0)
    with pytest.raises(ConfigError, match="jump"):
        RGBDSurface(image=_texture(), depth=np.ones((H, W)), focal=(F, F), jump=0.0)
    with pytest.raises(ConfigError, match="scale or width"):
        RGBDSurface.placed(_texture(), np.ones((H, W)), focal=(F, F), center_depth=1000.0, scale=1.0, width=10.0)
    with pytest.raises(ConfigError, match="center_depth"):
        RGBDSurface.placed(_texture(), np.ones((H, W)), focal=(F, F), center_depth=-5.0)


def test_placed_width_and_scale() -> None:
    depth = np.full((H, W), 2000.0)
    s = RGBDSurface.placed(_texture(), depth, focal=(F, F), center_depth=800.0, width=100.0)
    pts = s.points()
    assert pts[0, -1, 0] - pts[0, 0, 0] == pytest.approx(100.0 * (W - 1) / W)
    assert np.allclose(pts[..., 2], 800.0)
    s2 = RGBDSurface.placed(_texture(), depth, focal=(F, F), center_depth=800.0)
    assert s2.scale == pytest.approx(0.4) and s2.origin == (0.0, 0.0, 0.0)


# --------------------------------------------------------------------------- scene files
def _files(tmp_path: Path) -> dict[str, Path]:
    n = np.array([0.1, 0.0, 1.0])
    n /= np.linalg.norm(n)
    depth = _plane_depth(n, 1500.0).astype(np.float32)
    disp = (100.0 * F / depth - 5.0).astype(np.float32)  # baseline 100 mm, doffs 5 px
    write_image(tmp_path / "color.png", _texture())
    write_pfm(tmp_path / "depth.pfm", depth)
    write_pfm(tmp_path / "disp.pfm", disp)
    write_image(tmp_path / "small.png", _texture()[:-2])
    return {"color": tmp_path / "color.png", "depth": tmp_path / "depth.pfm", "disp": tmp_path / "disp.pfm"}


def _scene_dict(obj: dict[str, Any]) -> dict[str, Any]:
    return {
        "camera": {"width": 64, "height": 48, "focal_length": 25.0, "pixel_size": 0.0744},
        "prism": {"faces": 2, "corner_angle": 6.4, "refractive_index": 1.5, "apex_distance": 210.0,
                  "back_distance": 215.6},
        "render": {"supersample": 1},
        "objects": [obj],
    }


DEPTH_OBJ: dict[str, Any] = {"type": "rgbd", "name": "wall", "color": "color.png", "depth": "depth.pfm",
                             "focal_px": F, "center_depth": 1000.0, "scale": 0.5}
DISP_OBJ: dict[str, Any] = {"type": "rgbd", "color": "color.png", "disparity": "disp.pfm", "baseline": 100.0,
                            "doffs": 5.0, "focal_px": [F, F], "principal_point": [CX, CY], "origin": [0.0, 0.0, 100.0],
                            "rotation": [0.0, 2.0, 0.0], "scale": 0.6, "jump": 0.05}


def test_scene_file_depth_and_disparity_round_trip(tmp_path: Path) -> None:
    _files(tmp_path)
    _, sc1 = scene_from_dict(_scene_dict(DEPTH_OBJ), base_dir=tmp_path)
    rig2, sc2 = scene_from_dict(_scene_dict(DISP_OBJ), base_dir=tmp_path)
    a, b = sc1.objects[0], sc2.objects[0]
    assert isinstance(a, RGBDSurface) and isinstance(b, RGBDSurface)
    assert a.scale == 0.5 and a.origin[2] == pytest.approx(1000.0 - 0.5 * a.median_depth)
    np.testing.assert_allclose(a.depth, b.depth, rtol=1e-5)  # the disparity file is the same plane
    text = scene_to_toml(rig2, sc2)
    (tmp_path / "resolved.toml").write_text(text)
    _, sc3 = load_scene(tmp_path / "resolved.toml")
    c = sc3.objects[0]
    assert isinstance(c, RGBDSurface)
    assert (c.origin, c.rotation, c.scale, c.jump, c.focal, c.principal_point) == \
        (b.origin, b.rotation, b.scale, b.jump, b.focal, b.principal_point)
    np.testing.assert_array_equal(c.depth, b.depth)


@pytest.mark.parametrize(("change", "match"), [
    ({"color": "nope.png"}, "color: expected an existing file"),
    ({"depth": "nope.pfm"}, "depth: expected an existing file"),
    ({"color": "small.png"}, "colour image's size"),
    ({"focal_px": -3.0}, "focal_px: expected a positive"),
    ({"focal_px": None}, "focal_px"),
    ({"center_depth": None}, "center_depth .* or origin"),
    ({"origin": [0.0, 0.0, 0.0]}, "both"),
    ({"width": 10.0}, "scale or width"),
    ({"disparity": "disp.pfm"}, "depth .* or disparity"),
    ({"baseline": 10.0}, "go.* with disparity"),
    ({"rotation": [0.0, 1.0, 0.0]}, "go with origin"),
    ({"color": None}, "missing key color"),
    ({"bogus": 1}, "unknown key"),
    ({"jump": 0.0}, "jump"),
])
def test_scene_file_depth_errors(tmp_path: Path, change: dict[str, Any], match: str) -> None:
    _files(tmp_path)
    obj = copy.deepcopy(DEPTH_OBJ)
    for k, v in change.items():
        if v is None:
            obj.pop(k, None)
        else:
            obj[k] = v
    with pytest.raises(ConfigError, match=match):
        scene_from_dict(_scene_dict(obj), base_dir=tmp_path)


@pytest.mark.parametrize(("change", "match"), [
    ({"baseline": None}, "missing key baseline"),
    ({"baseline": 0.0}, "baseline: expected a positive"),
    ({"doffs": float("nan")}, "doffs: expected a finite"),
    ({"disparity_scale": -1.0}, "disparity_scale"),
    ({"depth_scale": 2.0}, "depth_scale goes with depth"),
    ({"disparity": "color.png", "doffs": 1e9}, "known"),
    ({"middlebury": "."}, "middlebury reads"),
])
def test_scene_file_disparity_errors(tmp_path: Path, change: dict[str, Any], match: str) -> None:
    _files(tmp_path)
    obj = copy.deepcopy(DISP_OBJ)
    for k, v in change.items():
        if v is None:
            obj.pop(k, None)
        else:
            obj[k] = v
    if change.get("doffs") == 1e9:
        obj["doffs"] = -1e9  # every d + doffs ≤ 0: no known depth
    with pytest.raises(ConfigError, match=match):
        scene_from_dict(_scene_dict(obj), base_dir=tmp_path)


def test_rgbd_without_files_cannot_be_written(small_biprism: Rig) -> None:
    surf = RGBDSurface(image=_texture(), depth=np.ones((H, W)), focal=(F, F))
    with pytest.raises(ConfigError, match="files it was read from"):
        scene_to_toml(small_biprism, Scene(objects=(surf,)))


def test_simulate_writes_rgbd_ground_truth_with_unknown_skin(tmp_path: Path) -> None:
    depth = np.full((H, W), 1000.0, dtype=np.float32)
    depth[:, W // 2:] = 1500.0
    write_image(tmp_path / "color.png", _texture())
    write_pfm(tmp_path / "step.pfm", depth)
    scene = _scene_dict({"type": "rgbd", "color": "color.png", "depth": "step.pfm", "focal_px": F,
                         "origin": [-40.0, 0.0, 0.0]})
    import tomli_w

    (tmp_path / "scene.toml").write_text(tomli_w.dumps(scene))
    res = simulate_to_folder(tmp_path / "scene.toml", tmp_path / "out")
    gt = read_pfm(tmp_path / "out" / "depth_gt.pfm")
    known = gt[np.isfinite(gt)]
    assert set(np.round(known).astype(int)) <= {1000, 1500} and {1000, 1500} <= set(np.round(known).astype(int))
    hit = res.capture.object_ids >= 0
    assert np.any(hit & ~np.isfinite(gt))  # the skin: seen, without ground truth
    _, again = load_scene(tmp_path / "out" / "scene.toml")
    assert isinstance(again.objects[0], RGBDSurface)


# --------------------------------------------------------------------------- Middlebury folders
def test_middlebury_folder_errors(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="calib.txt .* or manifest.json"):
        middlebury_rgbd(tmp_path, center_depth=1000.0)
    (tmp_path / "manifest.json").write_text(json.dumps({"left": "left.png"}))
    with pytest.raises(ConfigError, match="depth' block"):
        middlebury_rgbd(tmp_path, center_depth=1000.0)
    (tmp_path / "manifest.json").unlink()
    (tmp_path / "calib.txt").write_text("cam0=[1 0 0; 0 1 0; 0 0 1]\ndoffs=3\n")
    with pytest.raises(ConfigError, match="baseline"):
        middlebury_rgbd(tmp_path, center_depth=1000.0)
    (tmp_path / "calib.txt").write_text("cam0=[1 0 0; 0 1 0; 0 0 1]\ndoffs=3\nbaseline=100\n")
    with pytest.raises(ConfigError, match="color"):
        middlebury_rgbd(tmp_path, center_depth=1000.0)


@pytest.mark.parametrize("folder", ["middlebury-extra/cloth3", "middlebury-2014/Piano"])
def test_middlebury_scene_depth(folder: str, middlebury_dir: Path) -> None:
    path = middlebury_dir.parent / folder
    if not path.is_dir():
        pytest.skip(f"{path} not available")
    surf = middlebury_rgbd(path, center_depth=1400.0, width=150.0)
    assert surf.image.shape[:2] == surf.depth.shape
    known = np.isfinite(surf.depth)
    assert known.mean() > 0.8
    z = surf.points()[..., 2][known]
    assert np.median(z) == pytest.approx(1400.0, rel=1e-6)
    # the Middlebury scenes lie between 1 and 5 m before scaling
    assert 500.0 < np.nanmin(surf.depth) < np.nanmax(surf.depth) < 8000.0
