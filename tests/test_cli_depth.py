"""``prismstereo depth`` and ``prismstereo demo`` from the command line: outputs, accuracy, error paths."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from prismstereo.apps.demo import plane_scene, scaled_rig
from prismstereo.cli import main
from prismstereo.config import thesis_biprism
from prismstereo.depth.outputs import OUTPUT_FILES
from prismstereo.io import read_ply, write_image


def _run(argv, capsys):
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


def test_depth_end_to_end_with_ground_truth(capture_folder, tmp_path, capsys):
    out = tmp_path / "out"
    code, text, err = _run(["depth", str(capture_folder / "rig.toml"), str(capture_folder / "capture.png"),
                            "-o", str(out), "--gt", str(capture_folder / "depth_gt.pfm")], capsys)
    assert code == 0, err
    assert "median relative depth error" in text and "wrote" in text
    assert sorted(p.name for p in out.iterdir()) == sorted(OUTPUT_FILES)
    run = json.loads((out / "run.json").read_text())
    assert run["config"]["triangulation"] == "exact" and run["config"]["method"] == "bpasw"
    assert set(run["timings_s"]) >= {"cameras", "rectify", "match", "triangulate"}
    acc = run["accuracy"]
    assert acc["median_rel"] <= 0.0025 and acc["within_1pct"] >= 0.9 and acc["coverage"] >= 0.7
    pts, cols = read_ply(out / "points.ply")
    assert pts.shape[0] == run["counts"]["points"] > 10_000
    assert np.isfinite(pts).all() and cols is not None
    assert 1000 < np.median(pts[:, 2]) < 2500


def test_depth_options(capture_folder, tmp_path, capsys):
    out = tmp_path / "out"
    code, _, err = _run(["depth", str(capture_folder / "rig.toml"), str(capture_folder / "capture.png"),
                         "-o", str(out), "--method", "sad", "--triangulation", "q", "--depth-range", "1000,3000",
                         "--roi", "40,40,120,120", "--views", "1,0", "-p", "radius=3", "--min-confidence", "0",
                         "--refine-fill"], capsys)
    assert code == 0, err
    run = json.loads((out / "run.json").read_text())
    assert run["config"]["min_confidence"] == 0.0 and run["config"]["refine_fill"] is True
    assert run["config"]["roi"] == [40, 40, 120, 120] and run["config"]["matcher_params"]["radius"] == 3
    # the resolved configuration: every matcher parameter with its default
    assert run["config"]["matcher_params"]["cross_check"] is True and "subpixel" in run["config"]["matcher_params"]
    assert run["config"]["depth_range"] == [1000.0, 3000.0]


def _assert_failed_cleanly(code, err, out_dir):
    assert code == 2
    assert err.count("\n") == 1 and err.startswith("prismstereo depth: error: ")
    assert not out_dir.exists() or not any(out_dir.iterdir())


def test_wrong_capture_size(capture_folder, tmp_path, capsys):
    img = tmp_path / "small.png"
    write_image(img, np.zeros((100, 120, 3), np.uint8))
    out = tmp_path / "out"
    code, _, err = _run(["depth", str(capture_folder / "rig.toml"), str(img), "-o", str(out)], capsys)
    _assert_failed_cleanly(code, err, out)
    assert "512×384" in err


@pytest.mark.parametrize("content", [b"", b"not an image at all" * 10], ids=["empty", "corrupt"])
def test_empty_or_corrupt_image(capture_folder, tmp_path, capsys, content):
    img = tmp_path / "capture.png"
    img.write_bytes(content)
    out = tmp_path / "out"
    code, _, err = _run(["depth", str(capture_folder / "rig.toml"), str(img), "-o", str(out)], capsys)
    _assert_failed_cleanly(code, err, out)


def test_missing_image(capture_folder, tmp_path, capsys):
    out = tmp_path / "out"
    code, _, err = _run(["depth", str(capture_folder / "rig.toml"), str(tmp_path / "nope.png"), "-o", str(out)],
                        capsys)
    _assert_failed_cleanly(code, err, out)


def test_output_under_a_file(capture_folder, tmp_path, capsys):
    blocker = tmp_path / "file.txt"
    blocker.write_text("x")
    out = blocker / "out"
    code, _, err = _run(["depth", str(capture_folder / "rig.toml"), str(capture_folder / "capture.png"),
                         "-o", str(out)], capsys)
    assert code == 2 and err.count("\n") == 1 and "output folder" in err
    assert blocker.read_text() == "x"


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0, reason="root ignores folder permissions")
def test_unwritable_output_folder(capture_folder, tmp_path, capsys):
    parent = tmp_path / "locked"
    parent.mkdir()
    parent.chmod(0o500)
    try:
        code, _, err = _run(["depth", str(capture_folder / "rig.toml"), str(capture_folder / "capture.png"),
                             "-o", str(parent / "out")], capsys)
    finally:
        parent.chmod(0o700)
    _assert_failed_cleanly(code, err, parent / "out")


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="needs Linux /proc")
def test_output_on_a_read_only_filesystem(capture_folder, capsys):
    out = "/proc/prismstereo-depth-test-out"
    code, _, err = _run(["depth", str(capture_folder / "rig.toml"), str(capture_folder / "capture.png"),
                         "-o", out], capsys)
    assert code == 2 and err.count("\n") == 1 and "output folder" in err
    assert not os.path.exists(out)


def test_views_that_do_not_overlap(tmp_path, capsys):
    """A 20° bi-prism deviates each view by ~10°, more than the half field of view: beyond ~0.4 m they never
    meet (they cross just in front of the prism, 0.22–0.33 m, which the default range would search)."""
    rig = scaled_rig(thesis_biprism(20.0), 4)
    rig.save(tmp_path / "rig.toml")
    write_image(tmp_path / "capture.png", np.random.default_rng(0).integers(0, 255, (192, 256, 3), np.uint8))
    out = tmp_path / "out"
    code, _, err = _run(["depth", str(tmp_path / "rig.toml"), str(tmp_path / "capture.png"), "-o", str(out),
                         "--depth-range", "800,5000"], capsys)
    _assert_failed_cleanly(code, err, out)
    assert "do not overlap" in err


@pytest.mark.parametrize("args,needle", [(["--views", "0,0"], "--views"), (["--method", "nope"], "--method"),
                                         (["--depth-range", "5000,800"], "--depth-range"),
                                         (["--roi", "1,2,3"], "--roi"), (["--views", "0,7"], "--views"),
                                         (["--min-confidence", "1.5"], "--min-confidence")])
def test_bad_options(capture_folder, tmp_path, capsys, args, needle):
    out = tmp_path / "out"
    code, _, err = _run(["depth", str(capture_folder / "rig.toml"), str(capture_folder / "capture.png"),
                         "-o", str(out), *args], capsys)
    _assert_failed_cleanly(code, err, out)
    assert needle in err


def test_demo(tmp_path, capsys):
    out = tmp_path / "demo"
    code, text, err = _run(["demo", "-o", str(out)], capsys)
    assert code == 0, err
    for line in ("median relative depth error", "95th percentile", "within 1 %", "coverage of the common view",
                 "outputs in"):
        assert line in text
    names = {p.name for p in out.iterdir()}
    assert names >= set(OUTPUT_FILES) | {"capture.png", "depth_gt.pfm", "rig.toml"}
    acc = json.loads((out / "run.json").read_text())["accuracy"]
    assert acc["median_rel"] <= 0.0025 and acc["within_1pct"] >= 0.9 and acc["coverage"] >= 0.7


def test_all_views_of_a_triprism(tmp_path, capsys):
    """``--views all`` with N >= 3 faces runs the all-view sweep (multiview) and writes its outputs."""
    from prismstereo.config import thesis_triprism
    from prismstereo.simulate import render_capture

    rig = scaled_rig(thesis_triprism(), 4)
    cap = render_capture(rig, plane_scene(500.0, tilt_deg=15.0), supersample=1)
    rig.save(tmp_path / "rig.toml")
    write_image(tmp_path / "capture.png", cap.image)
    out = tmp_path / "out"
    code, text, err = _run(["depth", str(tmp_path / "rig.toml"), str(tmp_path / "capture.png"), "-o", str(out),
                            "--views", "all", "--depth-range", "400,700"], capsys)
    assert code == 0, err
    assert "all views" in text
    assert {"depth.pfm", "points.ply", "run.json"} <= {p.name for p in out.iterdir()}


def test_depth_replays_a_run_from_its_run_json(capture_folder, tmp_path, capsys):
    """``depth --config run.json`` reruns the recorded rig, capture and resolved configuration: same outputs."""
    first, again = tmp_path / "first", tmp_path / "again"
    code, _, err = _run(["depth", str(capture_folder / "rig.toml"), str(capture_folder / "capture.png"),
                         "-o", str(first), "--method", "sad", "-p", "radius=4", "--roi", "60,60,90,90",
                         "--depth-range", "1200,2200", "--triangulation", "midpoint"], capsys)
    assert code == 0, err
    run = json.loads((first / "run.json").read_text())
    # the resolved configuration: the parameter given and every default of the matcher and the steps
    assert run["config"]["matcher_params"]["radius"] == 4 and "tolerance" in run["config"]["matcher_params"]
    assert run["config"]["min_confidence"] == 0.5 and run["config"]["views"] == [1, 0]
    code, _, err = _run(["depth", "--config", str(first / "run.json"), "-o", str(again)], capsys)
    assert code == 0, err
    rerun = json.loads((again / "run.json").read_text())
    assert rerun["config"] == run["config"] and rerun["counts"] == run["counts"]
    for name in ("disparity.pfm", "depth.pfm", "points.ply"):
        assert (again / name).read_bytes() == (first / name).read_bytes(), name
    # an option given on the command line overrides the replayed one
    code, _, err = _run(["depth", "--config", str(first / "run.json"), "-o", str(tmp_path / "q"),
                         "--triangulation", "q"], capsys)
    assert code == 0, err
    assert json.loads((tmp_path / "q" / "run.json").read_text())["config"]["triangulation"] == "q"


def test_depth_config_that_is_not_a_run_json(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text("{\"config\": {\"no_such_key\": 1}}")
    code, _, err = _run(["depth", "--config", str(bad), "-o", str(tmp_path / "out")], capsys)
    assert code == 2 and "no_such_key" in err
