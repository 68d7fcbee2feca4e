"""``prismstereo design`` from the command line: outputs that load in the other commands, error paths."""

from __future__ import annotations

import json

import numpy as np
import pytest

from prismstereo.cli import main
from prismstereo.config import load_rig, thesis_biprism
from prismstereo.design.verify import verify_scene
from prismstereo.io import read_image, write_image
from prismstereo.simulate import render_capture

#: a 256×192 sensor with the thesis camera's field of view (fast to search, render and match)
CAMERA = ["--width", "256", "--height", "192", "--pixel-size", str(0.00465 * 4), "--focal-length", "25"]


def _run(argv, capsys):
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


def test_design_outputs_and_depth_runs_on_the_rig(tmp_path, capsys):
    out = tmp_path / "design"
    code, text, err = _run(["design", *CAMERA, "--range", "1200,1800", "--glass", "n=1.5", "-o", str(out)], capsys)
    assert code == 0, err
    assert "best: 2 faces" in text and "expected error" in text
    assert "note: the glass's dispersion" not in text  # n=1.5: no Abbe number
    assert sorted(p.name for p in out.iterdir()) == ["design.json", "design.png", "rig.toml"]
    rig = load_rig(out / "rig.toml")
    assert rig.camera.width == 256 and rig.prism.faces == 2 and rig.prism.refractive_index == 1.5
    doc = json.loads((out / "design.json").read_text())
    assert doc["n_candidates"] == len(doc["candidates"]) > 10
    assert doc["best"]["prism"] == rig.to_dict()["prism"]
    per = doc["prediction"]["per_depth"]
    assert per[0]["depth_mm"] == 1200 and per[-1]["depth_mm"] == 1800
    assert {"baseline_mm", "disparity_px", "field_width_mm", "relative_error", "error_mm"} <= set(per[0])
    assert all(c["rejected"] in (None, "tir", "size", "overlap", "field", "balance", "accuracy")
               for c in doc["candidates"])
    assert len(doc["prediction"]["sub_images"]) == 2
    png = read_image(out / "design.png")
    assert png.shape[0] > 400 and png.shape[1] > 600
    # the rig loads in the depth command: a capture of a plane through the proposed prism
    cap = render_capture(rig, verify_scene(rig, 1500.0))
    write_image(tmp_path / "capture.png", cap.image)
    code, text, err = _run(["depth", str(out / "rig.toml"), str(tmp_path / "capture.png"), "-o", str(tmp_path / "d"),
                            "--method", "sad", "--depth-range", "1200,1800", "-q"], capsys)
    assert code == 0, err
    assert (tmp_path / "d" / "depth.pfm").is_file()


def test_design_with_a_rig_file_ranks_its_prism(tmp_path, capsys):
    rig = thesis_biprism()
    small = rig.__class__(camera=rig.camera.__class__(width=256, height=192, focal_length=25.0,
                                                      pixel_size=0.00465 * 4), prism=rig.prism)
    small.save(tmp_path / "rig.toml")
    code, text, err = _run(["design", str(tmp_path / "rig.toml"), "--range", "1200,1800", "--glass", "n=1.5",
                            "-o", str(tmp_path / "o")], capsys)
    assert code == 0, err
    assert "given: 2 faces, corner angle 6.40°" in text and "meets the request" in text
    doc = json.loads((tmp_path / "o" / "design.json").read_text())
    given = [c for c in doc["candidates"] if c["source"] == "given"]
    assert len(given) == 1 and given[0]["rejected"] is None
    assert doc["best"]["prediction"]["per_depth"][-1]["relative_error"] <= \
        given[0]["prediction"]["per_depth"][-1]["relative_error"]


@pytest.mark.parametrize(("argv", "match"), [
    (["--range", "1200,1800"], "--width --height --pixel-size --focal-length, got no --width"),
    ([*CAMERA, "--range", "1200"], "--range: expected two numbers"),
    ([*CAMERA, "--range", "1200,1800", "--accuracy", "good"], "--accuracy: expected"),
    ([*CAMERA, "--range", "1200,1800", "--faces", "two"], "--faces: expected"),
    ([*CAMERA, "--range", "1200,1800", "--glass", "wood"], "glass: expected one of"),
    ([*CAMERA, "--range", "1200,1800", "--max-size", "5"], "max_size 5 mm binds"),
    ([*CAMERA, "--range", "1800,1200"], "near, far"),
])
def test_design_errors_are_one_line(tmp_path, capsys, argv, match):
    out = tmp_path / "o"
    code, text, err = _run(["design", *argv, "-o", str(out)], capsys)
    assert code == 2
    assert match in err and err.count("\n") == 1 and err.startswith("prismstereo design: error: ")
    assert not out.exists()


def test_design_rig_and_camera_options_conflict(tmp_path, capsys):
    thesis_biprism().save(tmp_path / "rig.toml")
    code, _, err = _run(["design", str(tmp_path / "rig.toml"), *CAMERA, "--range", "1200,1800", "-o",
                         str(tmp_path / "o")], capsys)
    assert code == 2 and "got both" in err


def test_design_accuracy_in_percent(tmp_path, capsys):
    code, text, err = _run(["design", *CAMERA, "--range", "1200,1800", "--accuracy", "0.5%", "-o",
                            str(tmp_path / "o")], capsys)
    assert code == 0, err
    doc = json.loads((tmp_path / "o" / "design.json").read_text())
    assert doc["request"]["accuracy"] == pytest.approx(0.005)
    assert doc["colour_spread_px"] > 0.5 and "note: the glass's dispersion spreads red and blue" in text  # N-BK7
    errs = [c["prediction"]["per_depth"][-1]["relative_error"] for c in doc["candidates"] if c["rejected"] is None]
    assert errs and max(errs) <= 0.005
    assert np.isfinite(errs).all()


@pytest.mark.slow
def test_design_verify_prints_predicted_against_measured(tmp_path, capsys):
    rig = thesis_biprism()
    small = rig.__class__(camera=rig.camera.__class__(width=256, height=192, focal_length=25.0,
                                                      pixel_size=0.00465 * 4), prism=rig.prism)
    small.save(tmp_path / "rig.toml")
    code, text, err = _run(["design", str(tmp_path / "rig.toml"), "--range", "1200,1800", "--glass", "n=1.5",
                            "--preset", "fast", "--verify", "-o", str(tmp_path / "o")], capsys)
    assert code == 0, err
    assert "verify (best prism, preset fast" in text and "verify (given prism" in text
    doc = json.loads((tmp_path / "o" / "design.json").read_text())
    for name in ("best", "given"):
        rows = doc["verify"][name]
        assert [r["depth_mm"] for r in rows] == [1200.0, 1400.0, 1600.0, 1800.0]
        assert all(r["measured_rel"] > 0 and r["predicted_rel"] > 0 for r in rows)
        # a row that disagrees is flagged on stderr
        assert all(r["agrees"] for r in rows) or "disagree" in err


def test_camera_from_a_camera_only_toml(tmp_path):
    from prismstereo.apps.design_command import camera_from_options

    (tmp_path / "camera.toml").write_text("[camera]\nwidth = 640\nheight = 480\nfx = 2000.0\nfy = 2000.0\n")
    cam, prism = camera_from_options(str(tmp_path / "camera.toml"), width=None, height=None, pixel_size=None,
                                     focal_length=None)
    assert cam.width == 640 and cam.focal_px == 2000.0 and prism is None
    (tmp_path / "bad.toml").write_text("[scene]\nx = 1\n")
    with pytest.raises(Exception, match=r"\[camera\] table"):
        camera_from_options(str(tmp_path / "bad.toml"), width=None, height=None, pixel_size=None, focal_length=None)


def test_design_with_a_rejected_given_prism(tmp_path, capsys):
    """A given prism that fails a check is reported with its reason; the proposal is still written."""
    from prismstereo.config import PrismSpec, Rig

    cam = thesis_biprism().camera.__class__(width=256, height=192, focal_length=25.0, pixel_size=0.00465 * 4)
    Rig(camera=cam, prism=PrismSpec(faces=2, corner_angle=20.0, refractive_index=1.5, apex_distance=210.0,
                                    back_distance=230.0)).save(tmp_path / "rig.toml")
    code, text, err = _run(["design", str(tmp_path / "rig.toml"), "--range", "1200,1800", "--glass", "n=1.5",
                            "-o", str(tmp_path / "o")], capsys)
    assert code == 0, err
    assert "given: 2 faces, corner angle 20.00°" in text and "rejected (" in text
    assert (tmp_path / "o" / "rig.toml").is_file()
