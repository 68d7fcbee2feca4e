"""``prismstereo simulate``: render a scene file into a folder of capture + ground truth, atomically."""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from prismstereo.config import Rig
from prismstereo.errors import ConfigError
from prismstereo.io import atomic_write_text, check_output_dir, output_dir, write_image, write_pfm
from prismstereo.io.memory import check_fits_in_memory
from prismstereo.simulate.render import Capture, render_capture
from prismstereo.simulate.scene import Scene
from prismstereo.simulate.scene_toml import load_scene, scene_to_toml

log = logging.getLogger(__name__)

OUTPUT_FILES = ("capture.png", "depth_gt.pfm", "faces.png", "rig.toml", "scene.toml")


@dataclass(frozen=True)
class SimulationResult:
    """What :func:`simulate_to_folder` wrote."""

    out_dir: Path
    rig: Rig
    scene: Scene
    capture: Capture

    @property
    def files(self) -> list[Path]:
        return [self.out_dir / f for f in OUTPUT_FILES]

    def summary(self) -> str:
        """One human line: size, faces, time, coverage."""
        cap = self.capture
        h, w = cap.depth.shape
        faces = ", ".join(f"{self.rig.view_name(k)} {100 * v:.1f}%" for k, v in sorted(cap.face_coverage().items()))
        return (
            f"rendered {w}x{h} ({cap.supersample}x{cap.supersample} samples) through a "
            f"{self.rig.prism.faces}-face prism in {cap.seconds:.2f} s: depth coverage {100 * cap.coverage:.1f}%, "
            f"faces [{faces}]; wrote {', '.join(OUTPUT_FILES)} to {self.out_dir}"
        )


def write_capture(out_dir: str | os.PathLike[str], rig: Rig, scene: Scene, capture: Capture) -> None:
    """Write the five outputs of docs/cli.md into an existing folder (each file atomically)."""
    d = Path(out_dir)
    write_image(d / "capture.png", capture.image)
    write_pfm(d / "depth_gt.pfm", capture.depth)
    write_image(d / "faces.png", capture.faces)
    rig.save(d / "rig.toml")
    atomic_write_text(d / "scene.toml", scene_to_toml(rig, scene))


def check_render_memory(rig: Rig, scene: Scene) -> None:
    """Refuse (ConfigError) a render whose buffers cannot fit in the memory available now."""
    w, h, ss = rig.camera.width, rig.camera.height, scene.supersample
    # per supersample: ray origin + direction (float64 ×6), hit depth, face, colour (float64 ×3): ~100 bytes
    check_fits_in_memory(w * h * ss * ss * 100, what=f"a {w}×{h} render with {ss}×{ss} samples per pixel",
                         hint="lower [camera] width/height (docs/rig.md) or --supersample", error=ConfigError)


def simulate_to_folder(
    scene_path: str | os.PathLike[str],
    out_dir: str | os.PathLike[str],
    *,
    supersample: int | None = None,
) -> SimulationResult:
    """Render a scene file and write capture.png, depth_gt.pfm, faces.png, rig.toml and scene.toml.

    The scene is validated before anything is rendered or written; outputs are staged and moved into
    ``out_dir`` only when all of them are written, so a failure leaves no partial output.

    Parameters
    ----------
    scene_path : path of the scene TOML (see :mod:`prismstereo.simulate.scene_toml`).
    out_dir : output folder (created if needed).
    supersample : int, optional
        Samples per pixel side; overrides ``[render] supersample``.

    Returns
    -------
    SimulationResult, with ``.summary()``.
    """
    rig, scene = load_scene(scene_path)
    if supersample is not None:
        if isinstance(supersample, bool) or not isinstance(supersample, int | np.integer) or not 1 <= supersample <= 16:
            raise ConfigError(f"--supersample: expected an integer in 1..16, got {supersample!r}")
        scene = replace(scene, supersample=int(supersample))
    check_output_dir(out_dir)  # before the render
    check_render_memory(rig, scene)
    capture = render_capture(rig, scene)
    with output_dir(out_dir) as staging:
        write_capture(staging, rig, scene, capture)
    result = SimulationResult(out_dir=Path(out_dir), rig=rig, scene=scene, capture=capture)
    log.info("%s", result.summary())
    return result
