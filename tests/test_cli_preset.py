"""``depth --preset fast|balanced|accurate`` (issue 19): the preset table, the report, the conflict error; the
presets as profiles (issue 30): the matcher and the depth settings, explicit options winning, run.json's record."""

from __future__ import annotations

import json

import pytest

from prismstereo.api import depth_config
from prismstereo.cli import main
from prismstereo.depth import DepthConfig
from prismstereo.depth.presets import PROFILES, apply_preset, preset_record
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


def test_profiles_balanced_and_accurate_are_the_defaults() -> None:
    """balanced and accurate set nothing beyond their matcher: today's configuration, field for field."""
    assert {p.name: p.method for p in PROFILES.values()} == PRESETS
    assert depth_config(preset="balanced") == DepthConfig(method="bpasw") == DepthConfig()
    assert depth_config(preset="accurate") == DepthConfig(method="coop")
    assert PROFILES["balanced"].settings == () and PROFILES["accurate"].settings == ()


def test_fast_profile_sets_its_own_refinement_and_user_options_win() -> None:
    fast = PROFILES["fast"].as_dict()
    # every refinement and confidence field explicitly: the profile does not follow DepthConfig's defaults
    names = {f for f in DepthConfig.__dataclass_fields__ if f.startswith("refine")} | {"min_confidence"}
    assert names <= set(fast)
    cfg = depth_config(preset="fast")
    assert cfg.method == "sgm" and all(getattr(cfg, k) == v for k, v in fast.items())
    # an option given explicitly wins; the other settings stay the preset's
    cfg = depth_config(preset="fast", refine_radius=7, min_confidence=0.2, matcher_params={"p1": 10})
    assert (cfg.refine_radius, cfg.min_confidence, cfg.matcher_params) == (7, 0.2, {"p1": 10})
    assert cfg.refine_iterations == fast["refine_iterations"]
    rec = preset_record("fast", cfg)
    assert rec["overridden"] == ["min_confidence", "refine_radius"] and rec["settings"]["refine_radius"] == 7
    assert apply_preset(DepthConfig(refine_radius=7), "fast", given=["refine_radius"]).refine_radius == 7
    with pytest.raises(ConfigError, match="^preset: .*both"):
        depth_config(preset="fast", method="sad")
    with pytest.raises(ConfigError, match="^preset: "):
        apply_preset(DepthConfig(), "turbo")


def test_depth_preset_fast(capture_folder, tmp_path, capsys) -> None:
    out = tmp_path / "out"
    code = main(["depth", str(capture_folder / "rig.toml"), str(capture_folder / "capture.png"), "-o", str(out),
                 "--preset", "fast", "--gt", str(capture_folder / "depth_gt.pfm"), "--min-confidence", "0.4"])
    text, err = capsys.readouterr()
    assert code == 0, err
    assert "preset fast: method sgm" in text
    run = json.loads((out / "run.json").read_text())
    assert run["preset"] == "fast" and run["config"]["method"] == "sgm"
    # the profile's settings as the run resolved them, the option given on the command line winning
    fast = PROFILES["fast"].as_dict()
    prof = run["preset_profile"]
    assert prof["method"] == "sgm" and prof["overridden"] == ["min_confidence"]
    assert prof["settings"] == {**fast, "min_confidence": 0.4}
    assert all(run["config"][k] == v for k, v in prof["settings"].items())
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
