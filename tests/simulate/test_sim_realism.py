"""Camera realism in the simulator: thin lens (defocus, apex band), Bayer mosaic + demosaicing, JPEG."""

from __future__ import annotations

import copy
import dataclasses
from typing import Any

import numpy as np
import pytest

from prismstereo.config import Rig
from prismstereo.errors import ConfigError
from prismstereo.optics.lens import apex_band_width_px
from prismstereo.simulate import NoiseTexture, Plane, Scene, render_capture, scene_from_dict, scene_to_toml
from prismstereo.simulate.render import bayer_mosaic, demosaic, jpeg_roundtrip
from prismstereo.simulate.scene import ThinLens
from prismstereo.simulate.scene_toml import load_scene


def _plane_scene(z: float) -> Scene:
    return Scene(objects=(Plane(center=(0.0, 0.0, z), texture=NoiseTexture(scale=15.0, seed=4)),), supersample=2)


def test_lens_in_focus_differs_from_the_pinhole_only_in_the_apex_band(small_biprism: Rig) -> None:
    focus = 1400.0
    pin = render_capture(small_biprism, _plane_scene(focus))
    lens = render_capture(small_biprism, dataclasses.replace(_plane_scene(focus), lens=ThinLens(8.0, focus, 32)))
    np.testing.assert_array_equal(pin.depth, lens.depth)  # ground truth: the chief rays
    diff = np.abs(pin.image.astype(float) - lens.image.astype(float)).mean(axis=(0, 2))
    w = apex_band_width_px(small_biprism, f_number=8.0, focus_distance=focus)  # 17 px on this sensor
    cx = small_biprism.camera.center[0]
    cols = np.arange(diff.size)
    far = (np.abs(cols - cx) > w) & (cols > 8) & (cols < diff.size - 8)
    assert diff[far].max() < 1.5  # in focus: the same image away from the band
    mixed = np.nonzero(diff > 4.0)[0]
    assert mixed.size and np.all(np.abs(mixed - cx) <= w / 2 + 1)
    assert mixed.max() - mixed.min() + 1 >= 0.5 * w


def test_lens_defocus_blurs_out_of_focus(small_biprism: Rig) -> None:
    def sharpness(img: np.ndarray) -> float:
        g = img.astype(float).mean(axis=2)[20:-20, 10:100]  # inside the left view, away from the apex
        return float(np.abs(np.diff(g, axis=1)).mean())

    scene = dataclasses.replace(_plane_scene(700.0), lens=ThinLens(2.0, 3000.0, 32))
    blurred = render_capture(small_biprism, scene).image
    sharp = render_capture(small_biprism, _plane_scene(700.0)).image
    assert sharpness(blurred) < 0.7 * sharpness(sharp)


@pytest.mark.parametrize("pattern", ["RGGB", "BGGR", "GRBG", "GBRG"])
@pytest.mark.parametrize("method", ["bilinear", "edge-aware", "vng"])
def test_bayer_mosaic_and_demosaic_keep_flat_colours(pattern: str, method: str) -> None:
    img = np.zeros((24, 32, 3), dtype=np.uint8)
    img[...] = (200, 90, 30)
    m = bayer_mosaic(img, pattern)
    assert m.shape == (24, 32)
    assert m[0, 0] == img[0, 0, "RGB".index(pattern[0])] and m[1, 1] == img[0, 0, "RGB".index(pattern[3])]
    out = demosaic(m, pattern, method=method)
    assert np.abs(out[4:-4, 4:-4].astype(int) - img[4:-4, 4:-4]).max() <= 2


def test_bayer_and_jpeg_errors() -> None:
    with pytest.raises(ConfigError, match="bayer"):
        bayer_mosaic(np.zeros((4, 4, 3)), "RGBG")
    with pytest.raises(ConfigError, match="demosaic"):
        demosaic(np.zeros((4, 4), np.uint8), "RGGB", method="magic")
    with pytest.raises(ConfigError, match="jpeg_quality"):
        jpeg_roundtrip(np.zeros((8, 8, 3), np.uint8), quality=0)
    with pytest.raises(ConfigError, match="bayer"):
        Scene(bayer="XYZW")
    with pytest.raises(ConfigError, match="jpeg_quality"):
        Scene(jpeg_quality=101)
    with pytest.raises(ConfigError, match="f_number"):
        ThinLens(f_number=0.1)
    with pytest.raises(ConfigError, match="samples"):
        ThinLens(samples=0)


def test_jpeg_roundtrip_is_lossy_but_close() -> None:
    rng = np.random.default_rng(0)
    img = np.clip(rng.normal(128, 30, (64, 64, 3)), 0, 255).astype(np.uint8)
    img = np.ascontiguousarray(np.repeat(np.repeat(img[::4, ::4], 4, 0), 4, 1))
    out = jpeg_roundtrip(img, quality=85)
    err = np.abs(out.astype(float) - img).mean()
    assert out.shape == img.shape and 0.3 < err < 10.0
    assert np.abs(jpeg_roundtrip(img, quality=100).astype(float) - img).mean() < err


def test_sensor_pipeline_in_render(small_biprism: Rig) -> None:
    base = _plane_scene(1200.0)
    clean = render_capture(small_biprism, base).image
    bay = render_capture(small_biprism, dataclasses.replace(base, bayer="RGGB")).image
    jpg = render_capture(small_biprism, dataclasses.replace(base, jpeg_quality=85)).image
    for img in (bay, jpg):
        err = np.abs(img[8:-8, 8:-8].astype(float) - clean[8:-8, 8:-8]).mean()
        assert 0.2 < err < 25.0


BASE: dict[str, Any] = {
    "camera": {"width": 64, "height": 48, "focal_length": 25.0, "pixel_size": 0.0744},
    "prism": {"faces": 2, "corner_angle": 6.4, "refractive_index": 1.5, "apex_distance": 210.0,
              "back_distance": 215.6},
    "render": {"supersample": 1, "bayer": "GRBG", "demosaic": "vng", "jpeg_quality": 90},
    "lens": {"f_number": 5.6, "focus_distance": 1200.0, "samples": 8},
    "objects": [{"type": "plane", "center": [0.0, 0.0, 2000.0]}],
}


def test_scene_file_realism_round_trip(tmp_path: Any) -> None:
    rig, scene = scene_from_dict(BASE)
    assert scene.lens == ThinLens(5.6, 1200.0, 8) and scene.bayer == "GRBG" and scene.demosaic == "vng"
    assert scene.jpeg_quality == 90
    (tmp_path / "s.toml").write_text(scene_to_toml(rig, scene))
    _, again = load_scene(tmp_path / "s.toml")
    assert (again.lens, again.bayer, again.demosaic, again.jpeg_quality) == \
        (scene.lens, scene.bayer, scene.demosaic, scene.jpeg_quality)
    _, plain = scene_from_dict({k: v for k, v in BASE.items() if k not in ("lens", "render")})
    assert plain.lens is None and plain.bayer is None and plain.jpeg_quality is None


@pytest.mark.parametrize(("path", "value", "match"), [
    (("lens", "f_number"), 0.1, r"\[lens\] f_number"),
    (("lens", "focus_distance"), None, "missing key.*focus_distance"),
    (("lens", "aperture"), 3, "unknown key"),
    (("lens", "samples"), 0, "samples"),
    (("render", "bayer"), "RGBW", "bayer"),
    (("render", "demosaic"), "magic", "demosaic"),
    (("render", "jpeg_quality"), 0, "jpeg_quality"),
    (("render", "jpeg_quality"), 85.5, "jpeg_quality"),
])
def test_scene_file_realism_errors(path: tuple[str, str], value: Any, match: str) -> None:
    data = copy.deepcopy(BASE)
    if value is None:
        del data[path[0]][path[1]]
    else:
        data[path[0]][path[1]] = value
    with pytest.raises(ConfigError, match=match):
        scene_from_dict(data)


def test_demosaic_without_bayer_is_an_error() -> None:
    data = copy.deepcopy(BASE)
    del data["render"]["bayer"]
    with pytest.raises(ConfigError, match="goes with bayer"):
        scene_from_dict(data)
