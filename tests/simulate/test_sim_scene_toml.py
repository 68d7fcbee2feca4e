"""Scene files: validation (one clear ConfigError line per problem) and resolved round trip."""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from prismstereo.errors import ConfigError
from prismstereo.io import write_image
from prismstereo.simulate import Box, ImageTexture, NoiseTexture, Sphere, load_scene, scene_from_dict, scene_to_toml

REPO = Path(__file__).resolve().parents[2]

BASE: dict[str, Any] = {
    "camera": {"width": 64, "height": 48, "focal_length": 25.0, "pixel_size": 0.0744},
    "prism": {"faces": 2, "corner_angle": 6.4, "refractive_index": 1.5, "apex_distance": 210.0,
              "back_distance": 215.6},
    "render": {"supersample": 2, "seed": 3, "shading": 0.2},
    "objects": [
        {"type": "plane", "center": [0.0, 0.0, 2000.0]},
        {"type": "box", "name": "b", "center": [0.0, 0.0, 1500.0], "size": [40.0, 50.0, 30.0],
         "rotation": [0.0, 20.0, 0.0], "texture": {"type": "noise", "scale": 20.0, "octaves": 5}},
        {"type": "sphere", "center": [10.0, 0.0, 1300.0], "radius": 15.0,
         "texture": {"type": "checker", "square": 5.0}},
        {"type": "rectangle", "center": [0.0, 0.0, 1200.0], "size": [20.0, 10.0], "normal": [0.2, 0.0, -1.0],
         "spin": 5.0, "texture": {"type": "solid", "color": [1.0, 0.5, 0.0]}},
    ],
}


def _with(path: tuple[Any, ...], value: Any, *, delete: bool = False) -> dict[str, Any]:
    data = copy.deepcopy(BASE)
    node: Any = data
    for key in path[:-1]:
        node = node[key]
    if delete:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return data


def test_valid_scene_builds_with_defaults() -> None:
    rig, scene = scene_from_dict(BASE)
    assert rig.prism.faces == 2 and len(scene.objects) == 4
    assert isinstance(scene.objects[1], Box) and isinstance(scene.objects[2], Sphere)
    # default texture: noise seeded with render seed + object index
    assert scene.objects[0].texture == NoiseTexture(seed=3)
    assert scene.supersample == 2 and scene.shading == 0.2


@pytest.mark.parametrize(
    ("path", "value", "match"),
    [
        (("objects", 1, "type"), "cylinder", r"type: expected one of"),
        (("objects", 1, "size"), [40.0, -50.0, 30.0], r"size: expected a list of 3 positive numbers"),
        (("objects", 1, "size"), [40.0, 0.0, 30.0], r"size"),
        (("objects", 2, "radius"), -1.0, r"radius: expected a positive number"),
        (("objects", 1, "center"), [0.0, math.nan, 1.0], r"center: expected a list of 3 finite numbers"),
        (("objects", 2, "radius"), math.nan, r"radius: expected a finite number"),
        (("objects", 1, "colour"), [1, 2, 3], r"unknown key\(s\) colour"),
        (("objects", 1, "texture", "sharpness"), 2, r"texture: unknown key\(s\) sharpness"),
        (("objects", 1, "texture", "type"), "marble", r"texture type: expected one of"),
        (("objects", 1, "texture", "scale"), 0.0, r"scale: expected a positive number"),
        (("objects", 1, "texture", "octaves"), 2.5, r"octaves: expected an integer"),
        (("objects", 3, "texture", "color"), [1.0, 2.0, 0.0], r"color: expected an RGB colour"),
        (("objects", 2, "texture", "square"), -5.0, r"square: expected a positive number"),
        (("objects", 1, "normal"), [0.0, 0.0, -1.0], r"either rotation or normal"),
        (("objects", 3, "normal"), [0.0, 0.0, 0.0], r"normal: expected a non-zero vector"),
        (("render", "supersample"), 0, r"supersample: expected an integer in 1..16"),
        (("render", "shading"), 1.5, r"shading"),
        (("render", "exposure"), 1.0, r"\[render\]: unknown key\(s\) exposure"),
        (("render", "background"), [0.0, 0.0], r"background"),
        (("camera", "width"), -5, r"\[camera\] width"),
        (("lights",), {}, r"unknown table\(s\) lights"),
        (("objects",), [], r"at least one"),
        (("objects", 0, "texture"), {"type": "image", "path": "missing.png"}, r"path: expected an image file"),
    ],
)
def test_config_errors_are_one_clear_line(path: tuple[Any, ...], value: Any, match: str, tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=match) as info:
        scene_from_dict(_with(path, value), base_dir=tmp_path)
    assert "\n" not in str(info.value)


def test_missing_required_key() -> None:
    with pytest.raises(ConfigError, match=r"missing key\(s\) size"):
        scene_from_dict(_with(("objects", 1, "size"), None, delete=True))
    with pytest.raises(ConfigError, match=r"missing key\(s\) center"):
        scene_from_dict(_with(("objects", 2, "center"), None, delete=True))


def test_image_texture_on_plane_needs_a_size(tmp_path: Path) -> None:
    write_image(tmp_path / "t.png", np.zeros((4, 4, 3), np.uint8))
    data = _with(("objects", 0, "texture"), {"type": "image", "path": "t.png"})
    with pytest.raises(ConfigError, match="size"):
        scene_from_dict(data, base_dir=tmp_path)
    data["objects"][0]["texture"]["size"] = [100.0, 100.0]
    _, scene = scene_from_dict(data, base_dir=tmp_path)
    tex = scene.objects[0].texture
    assert isinstance(tex, ImageTexture) and tex.image.shape == (4, 4, 3)


def test_resolved_scene_round_trips(tmp_path: Path) -> None:
    rig, scene = scene_from_dict(BASE)
    path = tmp_path / "resolved.toml"
    path.write_text(scene_to_toml(rig, scene))
    rig2, scene2 = load_scene(path)
    assert rig2 == rig
    assert len(scene2.objects) == len(scene.objects)
    for a, b in zip(scene.objects, scene2.objects, strict=True):
        assert type(a) is type(b) and a.texture == b.texture and a.center == b.center
        np.testing.assert_allclose(a.matrix, b.matrix, atol=1e-12)
    assert (scene2.supersample, scene2.seed, scene2.shading) == (scene.supersample, scene.seed, scene.shading)


@pytest.mark.parametrize("name", ["biprism_robot.toml", "triprism_scene.toml", "biprism_demo.toml"])
def test_examples_load(name: str) -> None:
    path = REPO / "examples" / name
    if not path.exists():
        pytest.skip(f"{name} not present")
    rig, scene = load_scene(path)
    assert len(scene.objects) >= 3


def test_builtin_robot_scene_matches_the_example_file() -> None:
    from prismstereo.io import read_image
    from prismstereo.simulate import ImageTexture as ImgTex
    from prismstereo.simulate import panel_texture_image, robot_scene

    path = REPO / "examples" / "biprism_robot.toml"
    if not path.exists():
        pytest.skip("examples/ not present")
    rig_f, scene_f = load_scene(path)
    rig_b, scene_b = robot_scene(width=1024)
    assert rig_b == rig_f
    assert (scene_b.background, scene_b.shading, scene_b.supersample) == (
        scene_f.background, scene_f.shading, scene_f.supersample)
    for a, b in zip(scene_f.objects, scene_b.objects, strict=True):
        assert (type(a), a.name, a.center) == (type(b), b.name, b.center)
        assert getattr(a, "size", None) == getattr(b, "size", None)
        assert getattr(a, "radius", None) == getattr(b, "radius", None)
        np.testing.assert_allclose(a.matrix, b.matrix, atol=1e-12)
        if isinstance(a.texture, ImgTex):
            assert isinstance(b.texture, ImgTex)
            np.testing.assert_array_equal(a.texture.image, b.texture.image)
        else:
            assert a.texture == b.texture
    np.testing.assert_array_equal(read_image(REPO / "examples" / "textures" / "panel.png"), panel_texture_image())
