"""Rig keys of real rigs: distortion, fx/fy, tilt, decenter (DESIGN.md §4)."""

from __future__ import annotations

import math

import pytest

from prismstereo.config import load_rig, rig_from_dict
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
