"""simulate_to_folder and the CLI end to end; failures leave no partial output."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import prismstereo.api as folder_mod
from prismstereo.apps.simulate_folder import OUTPUT_FILES, simulate_to_folder
from prismstereo.cli import main
from prismstereo.config import load_rig
from prismstereo.errors import ConfigError
from prismstereo.io import read_image, read_pfm
from prismstereo.simulate import load_scene

SCENE = """
[camera]
width = 96
height = 72
focal_length = 25.0
pixel_size = 0.0496

[prism]
faces = 2
corner_angle = 6.4
refractive_index = 1.5
apex_distance = 210.0
back_distance = 215.6

[render]
supersample = 2
background = [0.5, 0.5, 0.5]

[[objects]]
type = "rectangle"
center = [0.0, 0.0, 1500.0]
size = [2000.0, 2000.0]
texture = { type = "noise", scale = 30.0 }

[[objects]]
type = "sphere"
center = [0.0, 0.0, 1200.0]
radius = 30.0
"""


def _write(tmp_path: Path, text: str = SCENE) -> Path:
    p = tmp_path / "scene.toml"
    p.write_text(text)
    return p


def test_simulate_to_folder_writes_everything(tmp_path: Path) -> None:
    out = tmp_path / "out"
    res = simulate_to_folder(_write(tmp_path), out, supersample=1)
    assert sorted(p.name for p in out.iterdir()) == sorted(OUTPUT_FILES)
    img = read_image(out / "capture.png")
    assert img.shape == (72, 96, 3) and img.dtype == np.uint8
    depth = read_pfm(out / "depth_gt.pfm")
    np.testing.assert_allclose(depth, res.capture.depth, equal_nan=True)
    assert np.nanmin(depth) > 1100 and np.nanmax(depth) <= 1500 + 1e-3
    faces = read_image(out / "faces.png", gray=True)
    assert set(np.unique(faces).tolist()) <= {0, 1, 255}
    assert load_rig(out / "rig.toml") == res.rig
    rig2, scene2 = load_scene(out / "scene.toml")
    assert rig2 == res.rig and scene2.supersample == 1
    line = res.summary()
    assert "96x72" in line and "coverage" in line and "\n" not in line


def test_invalid_scene_writes_nothing(tmp_path: Path) -> None:
    out = tmp_path / "out"
    bad = SCENE.replace('type = "sphere"', 'type = "cone"')
    with pytest.raises(ConfigError, match="cone"):
        simulate_to_folder(_write(tmp_path, bad), out)
    assert not out.exists() or not any(out.iterdir())


def test_failure_while_writing_leaves_no_partial_output(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("mine")

    def boom(*args: object, **kwargs: object) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(folder_mod, "write_pfm", boom)
    with pytest.raises(OSError, match="disk full"):
        simulate_to_folder(_write(tmp_path), out, supersample=1)
    assert sorted(p.name for p in out.iterdir()) == ["keep.txt"]


def test_cli_simulate(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "cli"
    assert main(["simulate", str(_write(tmp_path)), "-o", str(out), "--supersample", "1"]) == 0
    assert "rendered 96x72" in capsys.readouterr().out
    assert all((out / f).is_file() for f in OUTPUT_FILES)
    bad = _write(tmp_path, SCENE.replace("radius = 30.0", "radius = -3.0"))
    assert main(["simulate", str(bad), "-o", str(tmp_path / "bad")]) == 2
    err = capsys.readouterr().err
    assert "radius" in err and err.count("\n") == 1
