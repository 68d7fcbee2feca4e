"""``depth --preset fast|balanced|accurate`` (issue 19): the preset table, the report, the conflict error."""

from __future__ import annotations

import json

import pytest

from prismstereo.cli import main
from prismstereo.errors import ConfigError
from prismstereo.matching import PRESETS, available_matchers, resolve_preset


def test_preset_table() -> None:
    assert PRESETS == {"fast": "sgm", "balanced": "bpasw", "accurate": "coop"}
    assert set(PRESETS.values()) <= set(available_matchers())
    assert resolve_preset("FAST", None) == ("sgm", "fast")
    assert resolve_preset(None, "sad") == ("sad", None)
    assert resolve_preset(None, None) == ("bpasw", None)
    with pytest.raises(ConfigError, match="both"):
        resolve_preset("fast", "sgm")
    with pytest.raises(ConfigError, match="^preset: "):
        resolve_preset("turbo", None)


def test_depth_preset_fast(capture_folder, tmp_path, capsys) -> None:
    out = tmp_path / "out"
    code = main(["depth", str(capture_folder / "rig.toml"), str(capture_folder / "capture.png"), "-o", str(out),
                 "--preset", "fast", "--gt", str(capture_folder / "depth_gt.pfm")])
    text, err = capsys.readouterr()
    assert code == 0, err
    assert "preset fast: method sgm" in text
    run = json.loads((out / "run.json").read_text())
    assert run["preset"] == "fast" and run["config"]["method"] == "sgm"
    acc = run["accuracy"]
    assert acc["median_rel"] <= 0.005 and acc["coverage"] >= 0.7


@pytest.mark.parametrize("extra", [["--preset", "fast", "--method", "sad"], ["--preset", "turbo"]])
def test_depth_preset_errors(capture_folder, tmp_path, capsys, extra) -> None:
    out = tmp_path / "out"
    code = main(["depth", str(capture_folder / "rig.toml"), str(capture_folder / "capture.png"), "-o", str(out),
                 *extra])
    _, err = capsys.readouterr()
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and "--preset" in err
    assert not out.exists()
