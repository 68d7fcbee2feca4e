"""Built-in simulated scenes and ``prismstereo demo``.

The scenes are built in code (no data files): textured objects at 1.0–2.0 m in front of the thesis's
bi-prism rig, the distances of the thesis's experiments (§7.3.2, Table 7.2: 1.50–1.52 m).

``run_demo`` renders the simulator's built-in bi-prism "robot" scene (``examples/biprism_demo.toml``),
runs the depth pipeline on the capture, measures the depth against the simulator's exact ground truth and
writes the outputs. The rig is the thesis bi-prism rig at half resolution (512×384 px of 9.3 µm: the same
field of view and optics), which keeps the whole demo, numba compilation included, well under two
minutes on two cores. :func:`demo_scene`, :func:`robot_scene` and :func:`plane_scene` are further test
scenes (tests, benchmarks, Table 7.2).
"""

from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from prismstereo.config import Rig, thesis_biprism
from prismstereo.depth.outputs import write_depth_outputs
from prismstereo.depth.pipeline import DepthConfig, DepthRun, run_depth
from prismstereo.evaluation.depth_metrics import evaluate_depth, format_accuracy
from prismstereo.io import write_image, write_pfm
from prismstereo.progress import progress_bar
from prismstereo.simulate import Box, NoiseTexture, Plane, Rectangle, Scene, Sphere, render_capture
from prismstereo.simulate import robot_scene as builtin_robot

log = logging.getLogger(__name__)

__all__ = ["DemoResult", "demo_rig", "demo_scene", "robot_scene", "plane_scene", "run_demo", "scaled_rig"]


def scaled_rig(rig: Rig, factor: int) -> Rig:
    """The same rig with a sensor ``factor`` times coarser (same field of view, same optics)."""
    cam = rig.camera
    pp = None if cam.principal_point is None else (cam.principal_point[0] / factor, cam.principal_point[1] / factor)
    new = replace(cam, width=cam.width // factor, height=cam.height // factor,
                  pixel_size=None if cam.pixel_size is None else cam.pixel_size * factor, principal_point=pp,
                  fx=None if cam.fx is None else cam.fx / factor, fy=None if cam.fy is None else cam.fy / factor)
    return replace(rig, camera=new, name=f"{rig.name}-1/{factor}")


def demo_rig() -> Rig:
    """The thesis's bi-prism rig (α = 6.4°, n = 1.5) at half resolution: 512×384 px of 9.3 µm."""
    return scaled_rig(thesis_biprism(), 2)


def demo_scene() -> Any:
    """Textured box, ball and slanted panel at 1.25–1.6 m before a wall at 1.9 m.

    The common view of the bi-prism's two virtual cameras is narrow (about 130 × 205 mm at 1.5 m), so the
    objects are small.
    """

    return Scene(
        objects=(
            Plane(center=(0.0, 0.0, 1900.0), texture=NoiseTexture(scale=50.0, seed=1), name="wall"),
            Box(center=(-22.0, -45.0, 1420.0), size=(50.0, 55.0, 50.0), rotation=(10.0, 30.0, 0.0),
                texture=NoiseTexture(scale=20.0, seed=2), name="box"),
            Sphere(center=(28.0, 5.0, 1250.0), radius=26.0, texture=NoiseTexture(scale=15.0, seed=3),
                   name="ball"),
            Rectangle(center=(-10.0, 62.0, 1600.0), size=(90.0, 55.0), rotation=(0.0, -25.0, 0.0),
                      texture=NoiseTexture(scale=25.0, seed=4), name="panel"),
        ),
        supersample=2,
        name="demo",
    )


def robot_scene() -> Any:
    """A boxy "robot" (head, body, arms, legs) with fronts at 1.50–1.53 m before a wall at 2 m.

    Like the thesis's robot of Table 7.2 (measured depths 1504–1523 mm).
    """

    def part(name: str, c: tuple[float, float, float], size: tuple[float, float, float], seed: int) -> Any:
        return Box(center=c, size=size, texture=NoiseTexture(scale=15.0, seed=seed), name=name)

    return Scene(
        objects=(
            Plane(center=(0.0, 0.0, 2000.0), texture=NoiseTexture(scale=50.0, seed=10), name="wall"),
            part("head", (0.0, -75.0, 1524.0), (36.0, 30.0, 40.0), 11),       # front at 1504
            part("body", (0.0, -22.0, 1532.0), (56.0, 70.0, 50.0), 12),       # front at 1507
            part("left arm", (-40.0, -20.0, 1521.0), (18.0, 66.0, 24.0), 13),  # front at 1509
            part("right arm", (40.0, -20.0, 1524.0), (18.0, 66.0, 24.0), 14),  # front at 1512
            part("left leg", (-14.0, 50.0, 1526.0), (20.0, 70.0, 24.0), 15),  # front at 1514
            part("right leg", (14.0, 50.0, 1530.0), (20.0, 70.0, 24.0), 16),  # front at 1518
            part("base", (0.0, 92.0, 1540.0), (80.0, 14.0, 40.0), 17),        # front at 1520
        ),
        supersample=2,
        name="robot",
    )


def plane_scene(distance_mm: float = 1500.0, *, tilt_deg: float = 30.0, seed: int = 21) -> Any:
    """One textured plane through (0, 0, distance) turned by ``tilt_deg`` about the vertical axis."""

    return Scene(
        objects=(Plane(center=(0.0, 0.0, float(distance_mm)), rotation=(0.0, float(tilt_deg), 0.0),
                       texture=NoiseTexture(scale=0.02 * float(distance_mm), seed=seed), name="plane"),),
        supersample=2,
        name=f"plane-{distance_mm:g}mm-tilt{tilt_deg:g}",
    )


@dataclass
class DemoResult:
    """What the demo did: the depth run (with ``accuracy``), the render, timings and output paths."""

    result: DepthRun
    accuracy: dict[str, Any]
    outputs: dict[str, Path]
    seconds: dict[str, float]

    def summary(self) -> str:

        out_dir = next(iter(self.outputs.values())).parent if self.outputs else Path(".")
        t = self.seconds
        lines = [
            f"prismstereo demo: bi-prism capture {self.result.image.shape[1]}×{self.result.image.shape[0]} "
            f"(thesis rig at half resolution), method {self.result.config.method}, "
            f"triangulation {self.result.config.triangulation}",
            format_accuracy(self.accuracy),
            f"time: render {t['render']:.1f} s, depth {t['depth']:.1f} s, evaluation {t['evaluate']:.1f} s, "
            f"outputs {t['write']:.1f} s, total {t['total']:.1f} s",
            f"outputs in {out_dir}/: " + ", ".join(sorted(p.name for p in self.outputs.values())),
        ]
        return "\n".join(lines)


def run_demo(out_dir: str | os.PathLike[str] = "demo_out", *, config: DepthConfig | None = None,
             rig: Rig | None = None, scene: Any = None) -> DemoResult:
    """Render the built-in bi-prism scene, recover its depth, measure it and write everything.

    By default the scene is the simulator's built-in "robot" on the thesis bi-prism rig at 512×384
    (:func:`prismstereo.simulate.robot_scene`, the same as ``examples/biprism_demo.toml``): boxes, balls
    and panels at 1.2–1.8 m, a textured wall at 2.2 m and a floor.

    Writes the depth outputs (docs/cli.md) plus ``capture.png``, ``depth_gt.pfm`` (world Z per real
    pixel) and ``rig.toml`` into ``out_dir``, all or nothing.
    """

    t0 = time.perf_counter()
    if rig is None and scene is None:

        rig, scene = builtin_robot(width=512)  # = examples/biprism_demo.toml
    rig = rig if rig is not None else demo_rig()
    scene = scene if scene is not None else demo_scene()

    seconds: dict[str, float] = {}
    bar = progress_bar(total=4, desc="demo: render", unit="step", leave=False)  # a terminal only
    t = time.perf_counter()
    cap = render_capture(rig, scene)
    seconds["render"] = time.perf_counter() - t
    bar.set_description("demo: depth")
    bar.update(1)
    t = time.perf_counter()
    res = run_depth(rig, cap.image, config=config or DepthConfig())
    seconds["depth"] = time.perf_counter() - t
    bar.set_description("demo: accuracy")
    bar.update(1)
    t = time.perf_counter()
    acc = evaluate_depth(res, scene=scene)
    res = replace(res, accuracy=acc)
    seconds["evaluate"] = time.perf_counter() - t
    bar.set_description("demo: write")
    bar.update(1)
    t = time.perf_counter()

    def also(stage: Path) -> None:
        write_image(stage / "capture.png", cap.image)
        write_pfm(stage / "depth_gt.pfm", cap.depth)
        rig.save(stage / "rig.toml")

    outputs = write_depth_outputs(res, out_dir, also=also,
                                  extra={"demo": {"scene": scene.name, "render_s": seconds["render"]}})
    for name in ("capture.png", "depth_gt.pfm", "rig.toml"):
        outputs[name] = Path(out_dir) / name
    bar.update(1)
    bar.close()
    seconds["write"] = time.perf_counter() - t
    seconds["total"] = time.perf_counter() - t0
    return DemoResult(result=res, accuracy=acc, outputs=outputs, seconds=seconds)

