"""The calibrate-camera and calibrate-prism commands end to end on small simulated images."""

from __future__ import annotations

import dataclasses
import json

import numpy as np

from prismstereo.cli import main
from prismstereo.config import load_rig
from prismstereo.io import write_image


def _write(tmp_path, images, stem):
    paths = []
    for i, img in enumerate(images):
        p = tmp_path / f"{stem}{i}.png"
        write_image(p, img)
        paths.append(str(p))
    return paths


def test_calibrate_camera_command(tmp_path, camera_photos, capsys):
    paths = _write(tmp_path, camera_photos, "photo")
    out = tmp_path / "camera.toml"
    assert main(["calibrate-camera", *paths, "--board", "8x6", "--square", "5", "-o", str(out)]) == 0
    text = out.read_text()
    assert "fx" in text and "distortion" in text and "principal_point" in text
    assert "photo0.png" in capsys.readouterr().out
    # too few photos: one line, exit 2, nothing written
    out2 = tmp_path / "none.toml"
    assert main(["calibrate-camera", *paths[:2], "--board", "8x6", "--square", "5", "-o", str(out2)]) == 2
    err = capsys.readouterr().err.strip()
    assert "expected at least 5 photos" in err and "\n" not in err and not out2.exists()
    assert main(["calibrate-camera", *paths, "--board", "8by6", "--square", "5", "-o", str(out2)]) == 2


def test_calibrate_prism_command(tmp_path, board_captures, small_true, small_nominal, capsys):
    _, images = board_captures
    rig_in = tmp_path / "rig.toml"
    dataclasses.replace(small_nominal, camera=small_true.camera).save(rig_in)
    paths = _write(tmp_path, images, "cap")
    out = tmp_path / "calibrated.toml"
    code = main(["calibrate-prism", str(rig_in), *paths, "--board", "8x6", "--square", "5", "-o", str(out),
                 "--free", "rotation,tilt"])
    assert code == 0, capsys.readouterr().err
    rig = load_rig(out)
    assert abs(rig.prism.rotation - 1.4) < 0.1 and rig.camera == small_true.camera
    report = json.loads((tmp_path / "calibrated.report.json").read_text())
    assert set(report["estimates"]) == {"rotation", "tilt_x", "tilt_y"} and report["rms_px"] < 0.3
    assert (tmp_path / "calibrated.residuals.png").stat().st_size > 1000
    # a capture without the board in a sub-image: exit 2, one line, no rig written
    blank = np.full_like(images[0], 115)
    bad = _write(tmp_path, [blank], "blank")
    out2 = tmp_path / "bad.toml"
    capsys.readouterr()
    assert main(["calibrate-prism", str(rig_in), *paths[:2], *bad, "--board", "8x6", "--square", "5",
                 "-o", str(out2)]) == 2
    err = capsys.readouterr().err.strip()
    assert "expected the whole 8x6 board in every sub-image" in err and "\n" not in err
    assert not out2.exists() and not (tmp_path / "bad.report.json").exists()
    assert main(["calibrate-prism", str(rig_in), *paths, "--board", "8x6", "--square", "5", "-o", str(out2),
                 "--free", "tilt,spin"]) == 2
