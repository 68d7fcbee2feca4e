"""The one-call API (prismstereo.api, docs/api.md): the README's Library section runs as written, results
save what the commands write, options are checked before any image is read."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import prismstereo
from prismstereo import api
from prismstereo.cli import main
from prismstereo.depth.outputs import OUTPUT_FILES
from prismstereo.depth.pipeline import DepthConfig, run_depth
from prismstereo.errors import ConfigError, ImageError
from prismstereo.io import read_image, read_pfm

REPO = Path(__file__).resolve().parents[1]
SRC = REPO / "src"


def _readme_library_block() -> str:
    text = (REPO / "README.md").read_text()
    section = text[text.index("## Library"):text.index("## Layout")]
    blocks = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    assert len(blocks) == 1, "the README's Library section has one Python block"
    return blocks[0]


def test_readme_shows_rig_and_capture_to_depth_and_points_in_two_lines() -> None:
    code = [line.split("#", 1)[0].strip() for line in _readme_library_block().splitlines()]
    i = next(k for k, line in enumerate(code) if "prismstereo.depth(" in line)
    assert code[i].startswith("result = prismstereo.depth(") and code[i + 1] == "points, colours = result.points()"


@pytest.mark.slow
def test_readme_library_section_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The README's fenced Python block, executed as written in an empty folder."""
    monkeypatch.chdir(tmp_path)
    scope: dict[str, object] = {"__name__": "readme"}
    exec(compile(_readme_library_block(), "README.md", "exec"), scope)  # noqa: S102 - our own README
    result = scope["result"]
    points, colours = scope["points"], scope["colours"]
    assert isinstance(result, api.DepthResult)
    assert isinstance(points, np.ndarray) and points.shape[1] == 3 and len(points) > 1000
    assert isinstance(colours, np.ndarray) and colours.shape == points.shape and colours.dtype == np.uint8
    # the built-in scene lies at 1.2-2.2 m: the points are there
    assert 1150 < float(np.median(points[:, 2])) < 2300
    assert sorted(p.name for p in (tmp_path / "depth").iterdir()) == sorted(OUTPUT_FILES)
    assert sorted(p.name for p in (tmp_path / "sim").iterdir()) == sorted(api.SIMULATION_FILES)


def _cli_args(folder: Path, out: Path) -> list[str]:
    return ["depth", str(folder / "rig.toml"), str(folder / "capture.png"), "-o", str(out), "--method", "sad",
            "--roi", "60,60,80,80", "--depth-range", "1200,2200", "-q"]


def test_depth_saves_what_the_command_writes(capture_folder: Path, tmp_path: Path) -> None:
    res = prismstereo.depth(capture_folder / "rig.toml", capture_folder / "capture.png", method="sad",
                            roi=(60, 60, 80, 80), depth_range=(1200, 2200), progress=False)
    written = res.save(tmp_path / "api", report=False)
    assert sorted(written) == sorted(n for n in OUTPUT_FILES if n != "report.png")
    assert main(_cli_args(capture_folder, tmp_path / "cli")) == 0
    assert sorted(p.name for p in (tmp_path / "cli").iterdir()) == sorted(OUTPUT_FILES)
    for name in ("depth.pfm", "disparity.pfm", "confidence.pfm"):
        np.testing.assert_array_equal(read_pfm(tmp_path / "api" / name), read_pfm(tmp_path / "cli" / name))
    pts, cols = res.points()
    assert pts.shape == (int(np.isfinite(res.depth).sum()), 3) and cols.dtype == np.uint8
    assert res.disparity is not None and res.confidence is not None and res.grid == "rectified left"
    assert res.config.matcher_params  # resolved: every matcher parameter with its default
    assert res.summary()["inputs"]["rig"] == str(capture_folder / "rig.toml")


def test_depth_from_arrays_is_run_depth(capture_folder: Path) -> None:
    rig = prismstereo.load_rig(capture_folder / "rig.toml")
    sim_image = read_image(capture_folder / "capture.png")
    res = prismstereo.depth(rig, sim_image, method="sad", roi=(60, 60, 40, 40), depth_range=(1200, 2200),
                            refine=False, progress=False)
    ref = run_depth(rig, sim_image, config=DepthConfig(method="sad", roi=(60, 60, 40, 40),
                                                       depth_range=(1200, 2200), refine=False), progress=False)
    np.testing.assert_array_equal(res.depth, ref.depth)
    assert res.inputs == {"rig": None, "image": None, "gt": None}


@pytest.mark.parametrize(("options", "name"), [
    ({"min_confidence": 5}, "min_confidence"),
    ({"views": (0, 7)}, "views"),
    ({"method": "nope"}, "method"),
    ({"depth_range": (10, 20)}, "depth_range"),
    ({"colour": "red"}, "colour"),
    ({"preset": "fastest"}, "preset"),
    ({"preset": "fast", "method": "sad"}, "preset"),
])
def test_options_are_checked_before_the_image_is_read(capture_folder: Path, tmp_path: Path,
                                                      options: dict[str, object], name: str) -> None:
    with pytest.raises(ConfigError) as info:
        prismstereo.depth(capture_folder / "rig.toml", tmp_path / "no such capture.png", **options)
    message = str(info.value)
    assert re.match(rf"(DepthConfig\.)?{name}: ", message), message
    assert "--" not in message


def test_bad_image_and_rig_name_their_parameter(capture_folder: Path, tmp_path: Path) -> None:
    with pytest.raises(ImageError, match="no such capture"):
        prismstereo.depth(capture_folder / "rig.toml", tmp_path / "no such capture.png")
    with pytest.raises(ImageError, match="^image: "):
        prismstereo.depth(capture_folder / "rig.toml", [[1, 2], [3, 4]])  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="^rig: "):
        prismstereo.depth(42, np.zeros((4, 4)))  # type: ignore[arg-type]


def test_the_entry_points_keep_their_subpackages() -> None:
    """``prismstereo.depth`` is the function and ``prismstereo.depth.pipeline`` the module, in any order."""
    code = ("import prismstereo.depth.pipeline, prismstereo.simulate.scene, prismstereo\n"
            "from prismstereo.depth import pipeline\n"
            "assert prismstereo.depth.pipeline is pipeline and prismstereo.depth.run_depth is pipeline.run_depth\n"
            "assert callable(prismstereo.depth) and callable(prismstereo.simulate)\n"
            "assert prismstereo.simulate.Scene is prismstereo.simulate.scene.Scene\n"
            "import inspect\n"
            "assert 'preset' in inspect.signature(prismstereo.depth).parameters\n"
            "assert prismstereo.DepthResult is prismstereo.api.DepthResult\n"
            "print('ok')")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={"PYTHONPATH": str(SRC), "PATH": "/usr/bin:/bin", "NUMBA_DISABLE_JIT": "0"})
    assert out.stdout.strip() == "ok", out.stderr
    with pytest.raises(AttributeError):
        prismstereo.no_such_thing  # noqa: B018


def test_simulate_and_save(tmp_path: Path) -> None:
    scene = tmp_path / "scene.toml"
    scene.write_text((REPO / "tests" / "simulate" / "test_sim_folder.py").read_text().split('SCENE = """')[1]
                     .split('"""')[0])
    sim = prismstereo.simulate(scene, supersample=1)
    assert sim.image.shape == (72, 96, 3) and sim.depth_gt.shape == (72, 96) and sim.faces.dtype == np.uint8
    files = sim.save(tmp_path / "out")
    assert sorted(p.name for p in files) == sorted(p.name for p in (tmp_path / "out").iterdir())
    with pytest.raises(ConfigError, match="^supersample: "):
        prismstereo.simulate(scene, supersample=0)
    with pytest.raises(ConfigError, match="^rig: "):
        prismstereo.simulate(sim.scene)
    again = prismstereo.simulate(sim.scene, rig=sim.rig, supersample=1)
    np.testing.assert_array_equal(again.image, sim.image)


def test_calibrate_prism_checks_its_options_first(capture_folder: Path, tmp_path: Path) -> None:
    missing = [tmp_path / "none.png"]
    with pytest.raises(ConfigError, match="^board: "):
        prismstereo.calibrate_prism(capture_folder / "rig.toml", missing)
    with pytest.raises(ConfigError, match="^square: "):
        prismstereo.calibrate_prism(capture_folder / "rig.toml", missing, board="8x6")
    with pytest.raises(ConfigError, match="^board: "):
        prismstereo.calibrate_prism(capture_folder / "rig.toml", missing, board="8x6", square=20.0,
                                    from_scene=True)
    with pytest.raises(ImageError, match="^captures: "):
        prismstereo.calibrate_prism(capture_folder / "rig.toml", [], from_scene=True)


@pytest.mark.slow
def test_the_worked_example_of_docs_api_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """docs/api.md's first Python block (simulate, depth with ground truth, points, save), as written."""
    block = re.findall(r"```python\n(.*?)```", (REPO / "docs" / "api.md").read_text(), flags=re.S)[0]
    monkeypatch.chdir(tmp_path)
    scope: dict[str, object] = {"__name__": "api_md"}
    exec(compile(block, "docs/api.md", "exec"), scope)  # noqa: S102 - our own documentation
    result = scope["result"]
    assert isinstance(result, api.DepthResult) and result.accuracy is not None
    assert result.accuracy["median_rel"] < 0.005
    assert sorted(p.name for p in (tmp_path / "depth").iterdir()) == sorted(OUTPUT_FILES)
