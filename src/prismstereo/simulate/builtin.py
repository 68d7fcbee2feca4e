"""Built-in scenes, available without the repository's ``examples/`` folder (e.g. for ``prismstereo demo``).

:func:`robot_scene` is the scene of ``examples/biprism_robot.toml`` (a test keeps the two identical), on
the thesis bi-prism, at any sensor resolution with the same field of view.
"""

from __future__ import annotations

import numpy as np

from prismstereo.config import THESIS_CAMERA, CameraSpec, Rig, thesis_biprism
from prismstereo.errors import ConfigError
from prismstereo.simulate.scene import (
    Box,
    CheckerTexture,
    ImageTexture,
    NoiseTexture,
    Plane,
    Rectangle,
    Scene,
    SceneObject,
    Sphere,
    rotation_from_normal,
)


def panel_texture_image(size: int = 96, *, seed: int = 7) -> np.ndarray:
    """The procedural "control panel" texture of ``examples/textures/panel.png``: (size, size, 3) uint8.

    Colour blocks (8 px), a yellow target in the middle and diagonal stripes that invert the blocks.
    """
    rng = np.random.default_rng(seed)
    n = size
    y, x = np.mgrid[0:n, 0:n].astype(float)
    nb = -(-n // 8)
    img = np.kron(rng.random((nb, nb, 3)), np.ones((8, 8, 1)))[:n, :n]
    c = n / 2.0
    r = np.hypot(x - c, y - c)
    rings = (np.sin(r / 2.2) > 0)[..., None] * np.array([0.9, 0.8, 0.1])
    inner = (r < 0.3125 * n)[..., None]
    img = np.where(inner, rings + 0.1 * img, img)
    stripes = (np.sin((x + 2 * y) / 1.8) > 0.3)[..., None]
    img = np.where(stripes & ~inner, 1 - img, img)
    return np.asarray(np.clip(img, 0.0, 1.0) * 255.0 + 0.5, dtype=np.uint8)


def robot_objects(*, panel: np.ndarray | None = None) -> tuple[SceneObject, ...]:
    """Objects of the bi-prism "robot" scene (mm): all at 1.2–1.8 m in both views' common view, wall at 2.2 m."""
    img = panel_texture_image() if panel is None else panel
    return (
        Plane(center=(0.0, 0.0, 2200.0), rotation=rotation_from_normal((0.0, 0.0, -1.0)), name="wall",
              texture=NoiseTexture(scale=90.0, octaves=7, persistence=0.8, contrast=2.5, seed=11)),
        Rectangle(center=(0.0, 105.0, 1650.0), size=(700.0, 1100.0), rotation=rotation_from_normal((0.0, -1.0, 0.0)),
                  name="floor", texture=NoiseTexture(scale=60.0, octaves=7, persistence=0.75, contrast=2.2, seed=12)),
        Box(center=(0.0, 10.0, 1500.0), size=(56.0, 66.0, 40.0), rotation=(0.0, 20.0, 0.0), name="torso",
            texture=NoiseTexture(scale=25.0, octaves=6, seed=13)),
        Sphere(center=(0.0, -47.0, 1480.0), radius=21.0, rotation=(0.0, 30.0, 0.0), name="head",
               texture=NoiseTexture(scale=12.0, octaves=5, seed=14)),
        Box(center=(-40.0, 8.0, 1460.0), size=(14.0, 58.0, 14.0), rotation=(0.0, 0.0, 12.0), name="left_arm",
            texture=CheckerTexture(square=4.0, colors=((0.9, 0.2, 0.1), (0.1, 0.3, 0.9)))),
        Box(center=(40.0, 8.0, 1460.0), size=(14.0, 58.0, 14.0), rotation=(0.0, 0.0, -12.0), name="right_arm",
            texture=NoiseTexture(scale=10.0, octaves=5, seed=15)),
        Rectangle(center=(-38.0, -62.0, 1260.0), size=(36.0, 30.0), rotation=(10.0, -25.0, 0.0), name="panel",
                  texture=ImageTexture(path="textures/panel.png", image=img)),
        Box(center=(32.0, 62.0, 1230.0), size=(26.0, 26.0, 26.0), rotation=(20.0, 35.0, 0.0), name="crate",
            texture=NoiseTexture(scale=15.0, octaves=5, seed=16)),
        Sphere(center=(-48.0, 62.0, 1780.0), radius=30.0, name="ball",
               texture=CheckerTexture(square=6.0, colors=((0.1, 0.7, 0.2), (0.95, 0.9, 0.3)))),
        Rectangle(center=(44.0, -60.0, 1760.0), size=(56.0, 46.0), rotation=(0.0, 30.0, 0.0), name="sign",
                  texture=NoiseTexture(scale=20.0, octaves=6, seed=17)),
    )


def robot_scene(*, width: int = 1024, supersample: int = 2) -> tuple[Rig, Scene]:
    """The bi-prism "robot" scene on the thesis rig, the sensor scaled to ``width`` px (4:3, same field of view).

    Parameters
    ----------
    width : int
        Sensor width in pixels (height = 3/4 of it); the pixel size scales so the field of view is the
        thesis's (1024 px at 4.65 µm, f = 25 mm). 512 gives a demo-size capture about 4× faster.
    supersample : int

    Returns
    -------
    (Rig, Scene)
    """
    base = thesis_biprism()
    if width % 4 or width < 16:
        raise ConfigError(f"width: expected a width that is a multiple of 4 and >= 16, got {width}")
    thesis = THESIS_CAMERA
    assert thesis.pixel_size is not None
    cam = CameraSpec(width=width, height=width * 3 // 4, focal_length=thesis.focal_length,
                     pixel_size=thesis.pixel_size * thesis.width / width)
    rig = Rig(camera=cam, prism=base.prism, name=f"biprism-robot-{width}")
    scene = Scene(objects=robot_objects(), background=(0.1, 0.1, 0.1), shading=0.3, seed=0,
                  supersample=supersample, name="biprism_robot")
    return rig, scene
