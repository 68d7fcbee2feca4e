"""Middlebury harness: metrics on synthetic maps, and a small real run (skipped without the data)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from prismstereo.errors import ConfigError
from prismstereo.evaluation.metrics import bad_pixel_rate, mean_abs_error
from prismstereo.evaluation.middlebury import (
    SCENES,
    MiddleburyScene,
    evaluate_disparity,
    evaluate_method,
    load_scene,
    load_scene_folder,
)


def test_bad_pixel_rate_counts_nan_as_bad() -> None:
    gt = np.array([[1.0, 2.0, np.nan, 4.0]], np.float32)
    d = np.array([[1.5, 3.5, 0.0, np.nan]], np.float32)
    assert bad_pixel_rate(d, gt, threshold=1.0) == pytest.approx(100 * 2 / 3)
    assert bad_pixel_rate(d, gt, threshold=2.0) == pytest.approx(100 * 1 / 3)
    assert mean_abs_error(d, gt) == pytest.approx(1.0)
    mask = np.array([[True, False, True, False]])
    assert bad_pixel_rate(d, gt, mask) == 0.0


def test_evaluate_disparity_synthetic_scene() -> None:
    gt = np.full((4, 5), 3.0, np.float32)
    masks = {m: np.ones((4, 5), bool) for m in ("nonocc", "all", "disc")}
    scene = MiddleburyScene("x", np.zeros((4, 5, 3), np.uint8), np.zeros((4, 5, 3), np.uint8), gt, masks, 7, 1)
    d = gt.copy()
    d[0, :] = 5.0
    ev = evaluate_disparity(d, scene)
    assert ev["bad"]["1.0"]["nonocc"] == pytest.approx(25.0)
    assert ev["bad"]["2.0"]["all"] == pytest.approx(0.0)
    assert ev["mae"]["disc"] == pytest.approx(0.5)


def test_load_scene(middlebury_dir: Path) -> None:
    for name in SCENES:
        sc = load_scene(name, middlebury_dir)
        assert sc.left.shape == sc.right.shape and sc.left.dtype == np.uint8
        assert sc.gt.dtype == np.float32 and np.nanmax(sc.gt) <= sc.max_disp + 1
        assert all(m.dtype == bool for m in sc.masks.values())
    assert [load_scene(s, middlebury_dir).max_disp for s in SCENES] == [15, 19, 59, 59]


def test_ground_truth_is_perfect(middlebury_dir: Path) -> None:
    sc = load_scene("venus", middlebury_dir)
    ev = evaluate_disparity(sc.gt, sc)
    assert ev["bad"]["0.5"]["all"] == 0.0


def test_tsukuba_bpasw_and_sgbm_bounds(middlebury_dir: Path, tmp_path: Path) -> None:
    """Measured: BPASW Tsukuba 2.70 nonocc / 2.96 all, SGBM 3.86 nonocc; the bounds leave margin."""
    res = evaluate_method("bpasw", data_dir=middlebury_dir, out_dir=tmp_path, scenes=("tsukuba",))
    b = res["scenes"]["tsukuba"]["bad"]["1.0"]
    assert b["nonocc"] < 5.0 and b["all"] < 6.0
    assert (tmp_path / "tsukuba.pfm").is_file() and (tmp_path / "tsukuba.png").is_file()
    data = json.loads((tmp_path / "results.json").read_text())
    assert data["method"] == "bpasw" and "tsukuba" in data["scenes"]
    res2 = evaluate_method("sgbm", data_dir=middlebury_dir, scenes=("tsukuba",))
    assert res2["scenes"]["tsukuba"]["bad"]["1.0"]["nonocc"] < 8.0


def _synthetic_pair(h: int = 24, w: int = 40, d: int = 5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(3)
    right = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    left = np.roll(right, d, axis=1)
    gt = np.full((h, w), float(d), np.float32)
    gt[:, :d] = np.nan  # occluded/unknown left border
    return left, right, gt


def test_load_shared_layout_reads_scale_and_range_from_manifest(tmp_path: Path) -> None:
    from prismstereo.io import write_image

    left, right, gt = _synthetic_pair()
    scene = tmp_path / "data" / "myscene"
    scene.mkdir(parents=True)
    write_image(scene / "left.png", left)
    write_image(scene / "right.png", right)
    write_image(scene / "disp_left.png", np.nan_to_num(gt * 3, nan=0).astype(np.uint8))
    known = np.isfinite(gt)
    for m in ("nonocc", "all", "disc"):
        write_image(scene / f"{m}.png", (known * 255).astype(np.uint8))
    (scene / "manifest.json").write_text(json.dumps({"ground_truth": {"scale_factor": 3},
                                                     "disparity_search_range": {"min": 0, "max": 11}}))
    (tmp_path / "data" / "notes").mkdir()  # a non-scene folder is ignored
    from prismstereo.evaluation.middlebury import list_scenes

    assert list_scenes(tmp_path / "data") == ("myscene",)
    sc = load_scene("myscene", tmp_path / "data")
    assert sc.max_disp == 11 and sc.scale == 3
    np.testing.assert_allclose(sc.gt[known], 5.0)
    assert np.isnan(sc.gt[~known]).all() and sc.masks["nonocc"].sum() == known.sum()
    res = evaluate_method("bpasw", data_dir=tmp_path / "data")
    assert list(res["scenes"]) == ["myscene"] and res["scenes"]["myscene"]["bad"]["1.0"]["nonocc"] < 20.0
    (scene / "manifest.json").write_text(json.dumps({"ground_truth": {}}))
    with pytest.raises(ConfigError, match="scale_factor"):
        load_scene("myscene", tmp_path / "data")
    with pytest.raises(ConfigError, match="expected a scene among"):
        load_scene("other", tmp_path / "data")


def test_load_middlebury2014_layout(tmp_path: Path) -> None:
    from prismstereo.io import write_image, write_pfm

    left, right, gt = _synthetic_pair()
    scene = tmp_path / "Adiron-perfect"
    scene.mkdir()
    write_image(scene / "im0.png", left)
    write_image(scene / "im1.png", right)
    write_pfm(scene / "disp0GT.pfm", np.where(np.isfinite(gt), gt, np.inf).astype(np.float32))
    mask = np.where(np.isfinite(gt), 255, 0).astype(np.uint8)
    mask[:, 5:7] = 128  # occluded
    write_image(scene / "mask0nocc.png", mask)
    (scene / "calib.txt").write_text("cam0=[100 0 20; 0 100 12; 0 0 1]\ndoffs=0\nbaseline=100\nwidth=40\n"
                                     "height=24\nndisp=16\nvmin=3\nvmax=7\n")
    sc = load_scene("Adiron-perfect", tmp_path)
    assert sc.max_disp == 15 and sc.left.shape == (24, 40, 3)
    assert sc.masks["nonocc"].sum() == (mask == 255).sum() and sc.masks["all"].sum() == np.isfinite(gt).sum()
    assert not sc.masks["disc"].any()  # a single plane has no discontinuity
    np.testing.assert_allclose(sc.gt[sc.masks["all"]], 5.0)
    assert load_scene_folder(scene).name == "Adiron-perfect"  # the folder itself as the data dir
    (scene / "calib.txt").write_text("width=40\n")
    with pytest.raises(ConfigError, match="ndisp"):
        load_scene_folder(scene)


def _write_2014_scene(folder: Path) -> None:
    from prismstereo.io import write_image, write_pfm

    left, right, gt = _synthetic_pair(h=32, w=64)
    folder.mkdir(parents=True)
    write_image(folder / "im0.png", left)
    write_image(folder / "im1.png", right)
    write_pfm(folder / "disp0GT.pfm", np.where(np.isfinite(gt), gt, np.inf).astype(np.float32))
    write_image(folder / "mask0nocc.png", np.where(np.isfinite(gt), 255, 0).astype(np.uint8))
    (folder / "calib.txt").write_text("width=64\nheight=32\nndisp=16\n")


def test_evaluate_2014_with_sgbm_baseline(tmp_path: Path) -> None:
    from prismstereo.evaluation.middlebury import format_results_table

    _write_2014_scene(tmp_path / "data" / "Synth")
    res = evaluate_method("bpasw", data_dir=tmp_path / "data", baseline="sgbm")
    assert res["layout"] == "2014" and res["baseline"]["method"] == "sgbm"
    b = res["baseline"]["scenes"]["Synth"]
    assert 0.0 <= b["bad"]["2.0"]["nonocc"] <= 100.0 and b["seconds"] > 0
    assert res["baseline"]["average"]["bad2.0_nonocc"] == pytest.approx(b["bad"]["2.0"]["nonocc"])
    table = format_results_table(res)
    head = table.splitlines()[0].split("|")
    assert head[2].strip() == "bad2 nonocc" and head[-2].strip() == "sgbm s"  # bad 2.0 first for the 2014 set
    row = table.splitlines()[2].split("|")
    assert float(row[2]) == pytest.approx(res["scenes"]["Synth"]["bad"]["2.0"]["nonocc"], abs=0.01)
    assert float(row[-4]) == pytest.approx(b["bad"]["2.0"]["nonocc"], abs=0.01)
    assert "ratio" in table.splitlines()[-1]
    # without a baseline, and for the shared layout, bad 1.0 stays first
    plain = evaluate_method("bpasw", data_dir=tmp_path / "data")
    assert "baseline" not in plain and "sgbm" not in format_results_table(plain)
    with pytest.raises(ConfigError):
        evaluate_method("bpasw", data_dir=tmp_path / "data", baseline="no-such-matcher")
