"""All-view depth on a small simulated tri-prism capture (plane sweep + exact multi-ray triangulation)."""

from __future__ import annotations

import numpy as np
import pytest

from prismstereo.config import CameraSpec, Rig, thesis_triprism
from prismstereo.errors import ConfigError, ImageError
from prismstereo.multiview.prism import AllViewsDepth, SweepParams, _multi_ray_point, depth_all_views


def test_multi_ray_point_exact() -> None:
    x = np.array([[3.0, -2.0, 500.0], [10.0, 4.0, 700.0]])
    origins = np.array([[[0.0, 0, 0]] * 2, [[20.0, 0, 10]] * 2, [[-5.0, 15, 5]] * 2])
    dirs = x[None] - origins
    use = np.array([[True, True], [True, False], [True, True]])
    pts = _multi_ray_point(origins, dirs, use)
    np.testing.assert_allclose(pts, x, atol=1e-9)
    none = _multi_ray_point(origins, dirs, np.array([[True, True], [False, False], [False, False]]))
    assert np.isnan(none).all()


@pytest.fixture(scope="module")
def small_capture() -> tuple[Rig, np.ndarray, np.ndarray, np.ndarray]:
    from prismstereo.simulate import NoiseTexture, Plane, Scene, render_capture

    base = thesis_triprism()
    rig = Rig(camera=CameraSpec(width=256, height=192, focal_length=25.0, pixel_size=0.0186), prism=base.prism,
              name="tri-small")
    scene = Scene(objects=(Plane(center=(0.0, 0.0, 500.0), texture=NoiseTexture(scale=8.0, octaves=4, seed=5)),),
                  supersample=1)
    cap = render_capture(rig, scene)
    return rig, cap.image, cap.depth, cap.faces


def _coverage_and_median(res: AllViewsDepth, depth: np.ndarray, faces: np.ndarray) -> tuple[float, float]:
    """Share of the reference face's pixels with a depth, and their median relative error."""
    ev = np.isfinite(depth) & (faces == res.reference)
    ok = ev & np.isfinite(res.depth)
    rel = np.abs(res.depth[ok] - depth[ok]) / depth[ok]
    return float(ok.sum() / ev.sum()), float(np.median(rel))


def test_all_views_plane(small_capture: tuple[Rig, np.ndarray, np.ndarray, np.ndarray]) -> None:
    rig, image, depth, faces = small_capture
    p = SweepParams(radius=2, n_depths=40)
    res = depth_all_views(rig, image, depth_range=(420.0, 620.0), params=p)
    coverage, median = _coverage_and_median(res, depth, faces)
    assert median < 0.005
    assert coverage > 0.5
    assert res.points.shape == (int(res.valid.sum()), 3) and res.colors.shape == res.points.shape
    assert res.counts.max() == 3
    single = depth_all_views(rig, image, depth_range=(420.0, 620.0), params=p, views=[res.views[0]])
    assert _coverage_and_median(single, depth, faces)[0] <= coverage + 1e-9


def test_all_views_errors(small_capture: tuple[Rig, np.ndarray, np.ndarray, np.ndarray]) -> None:
    rig, image, _, _ = small_capture
    with pytest.raises(ConfigError):
        depth_all_views(rig, image, depth_range=(600.0, 400.0))
    with pytest.raises(ConfigError):
        depth_all_views(rig, image, depth_range=(400.0, 600.0), method="bpasw")
    with pytest.raises(ConfigError):
        depth_all_views(rig, image, depth_range=(400.0, 600.0), reference=0, views=[0])
    with pytest.raises(ImageError):
        depth_all_views(rig, image[:-1], depth_range=(400.0, 600.0))


def test_all_views_through_the_depth_pipeline(small_capture: tuple[Rig, np.ndarray, np.ndarray, np.ndarray]
                                              ) -> None:
    """``views="all"`` runs the one depth pipeline: one result type, measured by the one accuracy function."""
    import dataclasses

    from prismstereo.depth import DepthConfig, run_depth
    from prismstereo.evaluation.depth_metrics import evaluate_depth

    rig, image, depth, _ = small_capture
    res = run_depth(rig, image, config=DepthConfig(views="all", depth_range=(420.0, 620.0)))
    assert res.pair is None and res.faces[0] not in res.faces[1:] and len(res.faces) == 3
    assert res.depth.shape == depth.shape and res.view_counts is not None and res.view_counts.max() == 3
    acc = evaluate_depth(res, depth_gt=depth)
    assert acc["median_rel"] < 0.005 and acc["coverage"] > 0.5
    assert dataclasses.replace(res, accuracy=acc).summary()["accuracy"]["median_rel"] == acc["median_rel"]


def test_all_views_command_writes_outputs(small_capture: tuple[Rig, np.ndarray, np.ndarray, np.ndarray],
                                          tmp_path: object, capsys: pytest.CaptureFixture[str]) -> None:
    import json
    from pathlib import Path

    from prismstereo.cli import main
    from prismstereo.depth.outputs import ALL_VIEW_FILES
    from prismstereo.io import read_pfm, read_ply, write_image, write_pfm

    rig, image, depth, _ = small_capture
    tmp = Path(str(tmp_path))
    pr = rig.prism
    (tmp / "rig.toml").write_text(
        f"[camera]\nwidth = {rig.camera.width}\nheight = {rig.camera.height}\nfocal_length = 25.0\n"
        f"pixel_size = 0.0186\n\n[prism]\nfaces = 3\ncorner_angle = {pr.corner_angle}\n"
        f"refractive_index = {pr.refractive_index}\napex_distance = {pr.apex_distance}\n"
        f"back_distance = {pr.back_distance}\nheight = {pr.height}\n")
    write_image(tmp / "cap.png", image)
    write_pfm(tmp / "gt.pfm", np.where(np.isfinite(depth), depth, np.inf).astype(np.float32))
    code = main(["depth", str(tmp / "rig.toml"), str(tmp / "cap.png"), "-o", str(tmp / "out"), "--views", "all",
                 "--depth-range", "420,620", "--gt", str(tmp / "gt.pfm")])
    text, err = capsys.readouterr()
    assert code == 0, err
    assert "coverage" in text and "all views" in text
    assert sorted(p.name for p in (tmp / "out").iterdir()) == sorted(ALL_VIEW_FILES)
    d = read_pfm(tmp / "out" / "depth.pfm")
    assert d.shape == depth.shape
    run = json.loads((tmp / "out" / "run.json").read_text())
    assert run["config"]["views"] == "all" and run["accuracy"]["median_rel"] < 0.005
    pts = read_ply(tmp / "out" / "points.ply")
    assert len(pts[0]) == run["counts"]["points"]
