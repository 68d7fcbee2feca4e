"""``prismstereo simulate``: render a scene file into a folder of capture + ground truth, atomically.

``write_capture`` and ``check_render_memory`` live in :mod:`prismstereo.api` (re-exported here).
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

from prismstereo.api import SIMULATION_FILES, Simulation, check_render_memory, simulate, write_capture
from prismstereo.config import Rig
from prismstereo.io import check_output_dir
from prismstereo.simulate.render import Capture
from prismstereo.simulate.scene import Scene
from prismstereo.simulate.scene_toml import load_scene

log = logging.getLogger(__name__)

__all__ = ["OUTPUT_FILES", "SimulationResult", "check_render_memory", "simulate_to_folder", "write_capture"]

OUTPUT_FILES = SIMULATION_FILES


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
        """One human line: size, faces, time, coverage, the files written."""
        line = Simulation(rig=self.rig, scene=self.scene, capture=self.capture).summary()
        return f"{line}; wrote {', '.join(OUTPUT_FILES)} to {self.out_dir}"


def simulate_to_folder(
    scene_path: str | os.PathLike[str],
    out_dir: str | os.PathLike[str],
    *,
    supersample: int | None = None,
) -> SimulationResult:
    """Render a scene file and write capture.png, depth_gt.pfm, faces.png, rig.toml and scene.toml
    (:func:`prismstereo.api.simulate`, then its ``save``).

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
    load_scene(scene_path)  # the scene checked before the output folder
    check_output_dir(out_dir)  # before the render
    sim = simulate(scene_path, supersample=supersample)
    sim.save(out_dir)
    result = SimulationResult(out_dir=Path(out_dir), rig=sim.rig, scene=sim.scene, capture=sim.capture)
    log.info("%s", result.summary())
    return result
