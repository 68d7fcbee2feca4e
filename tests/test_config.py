from __future__ import annotations

import math

import pytest

from prismstereo.config import CameraSpec, PrismSpec, load_rig, rig_from_dict, thesis_biprism, thesis_triprism
from prismstereo.errors import ConfigError

GOOD = {
    "camera": {"width": 1024, "height": 768, "focal_length": 25.0, "pixel_size": 0.00465},
    "prism": {"faces": 2, "corner_angle": 6.4, "refractive_index": 1.5, "apex_distance": 210.0,
              "back_distance": 215.6},
}


def _with(section: str, **changes: object) -> dict:
    data = {k: dict(v) for k, v in GOOD.items()}
    for key, value in changes.items():
        if value is None:
            data[section].pop(key)
        else:
            data[section][key] = value
    return data


def test_good_rig_loads_and_round_trips(tmp_path):
    rig = rig_from_dict(GOOD)
    assert rig.camera.focal_px == pytest.approx(25.0 / 0.00465)
    assert rig.camera.center == (511.5, 383.5)
    path = tmp_path / "rig.toml"
    rig.save(path)
    assert load_rig(path) == rig


def test_triprism_matches_thesis_geometry():
    rig = thesis_triprism()
    assert rig.prism.corner_angle == pytest.approx(math.degrees(math.atan(4 / (37.3 * 0.5))))
    assert rig.prism.corner_angle == pytest.approx(12.1, abs=0.01)
    assert rig.prism.back_distance == pytest.approx(220.8)
    assert rig.prism.inradius == pytest.approx(37.3 * 0.5)


@pytest.mark.parametrize(
    ("section", "changes", "message"),
    [
        ("camera", {"width": None}, "missing key"),
        ("prism", {"faces": None}, "missing key"),
        ("camera", {"colour": 3}, "unknown key"),
        ("prism", {"thickness": 3.0}, "unknown key"),
        ("camera", {"width": 0}, "positive"),
        ("camera", {"height": -5}, "positive"),
        ("camera", {"width": 10.5}, "integer"),
        ("camera", {"focal_length": 0.0}, "positive"),
        ("camera", {"pixel_size": -1.0}, "positive"),
        ("camera", {"focal_length": float("nan")}, "finite"),
        ("camera", {"principal_point": [1.0]}, "cx, cy"),
        ("prism", {"refractive_index": 1.0}, "> 1"),
        ("prism", {"refractive_index": 0.8}, "> 1"),
        ("prism", {"back_distance": 210.0}, "behind the apex"),
        ("prism", {"back_distance": 200.0}, "behind the apex"),
        ("prism", {"corner_angle": 0.0}, "(0, 90)"),
        ("prism", {"corner_angle": 90.0}, "(0, 90)"),
        ("prism", {"corner_angle": -3.0}, "(0, 90)"),
        ("prism", {"corner_angle": float("nan")}, "finite"),
        ("prism", {"faces": 1}, ">= 2"),
        ("prism", {"faces": "two"}, "integer"),
        ("prism", {"height": 10.0}, "at most"),
        ("prism", {"height": 0.0}, "positive"),
        ("prism", {"apex_distance": -1.0}, "positive"),
        ("prism", {"rotation": float("inf")}, "finite"),
    ],
)
def test_config_errors(section, changes, message):
    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace(")", r"\)")):
        rig_from_dict(_with(section, **changes))


def test_missing_and_unknown_tables():
    with pytest.raises(ConfigError, match=r"missing table \[prism\]"):
        rig_from_dict({"camera": GOOD["camera"]})
    with pytest.raises(ConfigError, match="unknown table"):
        rig_from_dict({**GOOD, "lens": {}})


def test_bad_files(tmp_path):
    with pytest.raises(ConfigError, match="no such file"):
        load_rig(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[camera\nwidth = 3")
    with pytest.raises(ConfigError, match="syntax error"):
        load_rig(bad)


def test_dataclasses_are_frozen_and_validate_directly():
    rig = thesis_biprism()
    with pytest.raises(AttributeError):
        rig.prism.faces = 3  # type: ignore[misc]
    with pytest.raises(ConfigError):
        PrismSpec(faces=2, corner_angle=6.4, refractive_index=1.5, apex_distance=210, back_distance=100)
    with pytest.raises(ConfigError):
        CameraSpec(width=10, height=10, focal_length=float("nan"), pixel_size=0.01)
    with pytest.raises(ConfigError):
        rig.with_prism(refractive_index=float("nan"))
