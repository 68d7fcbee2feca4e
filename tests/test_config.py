from __future__ import annotations

import math
import re
from pathlib import Path

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


# ------------------------------------------------------------------- real rigs: distortion, fx/fy, tilt, decenter
def test_real_rig_round_trips_through_toml(tmp_path):
    data = _with("camera", distortion=[-0.1, 0.12, 0.001, -0.002, 0.0], fx=5376.3, fy=5377.1,
                 principal_point=[515.0, 380.0], focal_length=None, pixel_size=None)
    data["prism"] |= {"rotation": 1.4, "tilt": [1.0, -0.5], "decenter": [1.0, 0.25]}
    rig = rig_from_dict(data)
    assert rig.camera.K[0, 0] == 5376.3 and rig.camera.K[1, 1] == 5377.1
    assert rig.camera.focal_px == pytest.approx(5376.7)
    assert rig.prism.is_posed and rig.camera.has_distortion
    assert rig.view_name(0) == "right"  # a bi-prism turned 1.4° still has a right and a left view
    path = tmp_path / "rig.toml"
    rig.save(path)
    text = path.read_text()
    assert "distortion" in text and "tilt" in text and "decenter" in text and "focal_length" not in text
    assert load_rig(path) == rig


def test_default_rig_writes_no_new_keys(tmp_path):
    rig = rig_from_dict(GOOD)
    assert rig.camera.distortion == (0.0,) * 5 and rig.prism.tilt == (0.0, 0.0) and not rig.prism.is_posed
    for key in ("distortion", "tilt", "decenter", "fx"):
        assert key not in rig.to_toml()


def test_four_term_distortion_is_padded():
    rig = rig_from_dict(_with("camera", distortion=[0.1, 0.0, 0.0, 0.0]))
    assert rig.camera.distortion == (0.1, 0.0, 0.0, 0.0, 0.0)


@pytest.mark.parametrize(
    ("section", "changes", "needle"),
    [
        ("camera", {"distortion": [0.1, 0.2]}, "[camera] distortion: expected [k1, k2, p1, p2, k3]"),
        ("camera", {"distortion": "none"}, "[camera] distortion: expected"),
        ("camera", {"distortion": [0.1, math.nan, 0, 0, 0]}, "[camera] distortion: expected a finite number"),
        ("camera", {"distortion": [0.1, "x", 0, 0, 0]}, "[camera] distortion: expected a number"),
        ("camera", {"distortion": [1000.0, 0, 0, 0, 0]}, "[camera] distortion: expected every value within"),
        ("camera", {"distortion": [0.0, 0, 2.0, 0, 0]}, "[camera] distortion: expected tangential p1"),
        ("camera", {"fx": 5000.0}, "[camera] fx, fy: expected both or neither"),
        ("camera", {"fx": -5.0, "fy": 5000.0}, "[camera] fx: expected a positive value"),
        ("camera", {"fx": 5000.0, "fy": math.nan}, "[camera] fy: expected a finite number"),
        ("camera", {"fx": True, "fy": 5000.0}, "[camera] fx: expected a number"),
        ("camera", {"focal_length": None}, "expected focal_length and pixel_size, or fx and fy"),
        ("camera", {"f_number": 8.0}, "[camera] f_number, focus_distance: expected both or neither"),
        ("camera", {"focus_distance": 1400.0}, "[camera] f_number, focus_distance: expected both or neither"),
        ("camera", {"f_number": 0.0, "focus_distance": 1400.0}, "[camera] f_number: expected a positive value"),
        ("camera", {"f_number": 8.0, "focus_distance": "far"}, "[camera] focus_distance: expected a number"),
        ("camera", {"f_number": 8.0, "focus_distance": 1400.0, "focal_length": None, "pixel_size": None,
                    "fx": 5000.0, "fy": 5000.0}, "[camera] f_number: expected focal_length or pixel_size"),
        ("prism", {"tilt": [1.0]}, "[prism] tilt: expected [tx, ty] in degrees"),
        ("prism", {"tilt": [1.0, math.inf]}, "[prism] tilt: expected a finite number"),
        ("prism", {"tilt": [45.0, 0.0]}, "[prism] tilt: expected every value within ±30"),
        ("prism", {"tilt": 1.0}, "[prism] tilt: expected [tx, ty]"),
        ("prism", {"decenter": [1.0, "a"]}, "[prism] decenter: expected a number"),
        ("prism", {"decenter": [1.0, math.nan]}, "[prism] decenter: expected a finite number"),
        ("prism", {"decenter": [500.0, 0.0]}, "[prism] decenter: expected every value within ±210"),
        ("prism", {"decenter": [1.0, 2.0, 3.0]}, "[prism] decenter: expected [dx, dy] in mm"),
    ],
)
def test_new_keys_are_validated_with_one_line(section, changes, needle):
    with pytest.raises(ConfigError) as info:
        rig_from_dict(_with(section, **changes))
    msg = str(info.value)
    assert needle in msg and "\n" not in msg


def test_rig_reference_lists_every_key():
    """docs/rig.md's key tables name every key the loader accepts, and no other."""
    from prismstereo.config import _CAMERA_OPTIONAL, _CAMERA_REQUIRED, _PRISM_OPTIONAL, _PRISM_REQUIRED

    text = (Path(__file__).resolve().parents[1] / "docs" / "rig.md").read_text(encoding="utf-8")
    for section, keys in (("camera", _CAMERA_REQUIRED | _CAMERA_OPTIONAL),
                          ("prism", _PRISM_REQUIRED | _PRISM_OPTIONAL)):
        table = text.split(f"## `[{section}]`", 1)[1].split("\n\n", 2)[1]
        documented = {k for row in table.splitlines() if row.startswith("| `")
                      for k in re.findall(r"`(\w+)`", row.split("|")[1])}
        assert documented == keys, section


def test_lens_keys_round_trip_and_default_to_none():
    rig = thesis_biprism()
    assert rig.camera.f_number is None and rig.camera.focus_distance is None
    assert "f_number" not in rig.to_dict()["camera"]
    lens = rig_from_dict(_with("camera", f_number=8, focus_distance=1400))
    assert lens.camera.f_number == 8.0 and lens.camera.focus_distance == 1400.0
    assert rig_from_dict(lens.to_dict()) == lens
