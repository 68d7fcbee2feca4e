"""Files of a depth run (docs/cli.md, docs/formats.md), written together through a staging folder.

``disparity.pfm`` (px, inf = invalid), ``disparity.png`` (colourised), ``depth.pfm`` (world Z in mm on the
rectified left grid, inf = invalid), ``confidence.pfm`` (each point's confidence on the same grid),
``points.ply`` (valid points, mm, world frame, RGB, confidence), ``report.png`` and ``run.json``. If
anything fails, the output folder is left as it was.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from prismstereo.depth.pipeline import DepthResult
from prismstereo.io import output_dir, write_image, write_json, write_pfm, write_ply

__all__ = ["OUTPUT_FILES", "write_depth_files", "write_depth_outputs"]

OUTPUT_FILES = ("disparity.pfm", "disparity.png", "depth.pfm", "confidence.pfm", "points.ply", "report.png",
                "run.json")


def write_depth_outputs(result: DepthResult, out_dir: str | os.PathLike[str], *, report: bool = True,
                        extra: dict[str, Any] | None = None,
                        also: Callable[[Path], None] | None = None) -> dict[str, Path]:
    """Write the outputs of ``result`` into ``out_dir`` (created if needed) all-or-nothing.

    Parameters
    ----------
    result : DepthResult
    out_dir : folder
    report : bool
        Also render ``report.png`` (about a second).
    extra : dict, optional
        Merged into ``run.json`` (e.g. the input paths).
    also : callable, optional
        Called with the staging folder to write more files that must appear together with the rest
        (the demo's capture and ground truth).

    Returns
    -------
    dict file name -> final path.
    """
    summary = result.summary()
    if extra:
        summary.update(extra)
    names = [n for n in OUTPUT_FILES if report or n != "report.png"]
    target = Path(out_dir)
    with output_dir(target) as stage:
        write_depth_files(result, stage, names, summary)
        if also is not None:
            also(stage)
    return {n: target / n for n in names}


def write_depth_files(result: DepthResult, folder: Path, names: Sequence[str], summary: dict[str, Any]) -> None:
    """Write the files ``names`` (among :data:`OUTPUT_FILES`) of ``result`` into an existing ``folder``.

    The one writer of a depth run's files, for :func:`write_depth_outputs` and the per-frame folders of a
    batch; ``folder`` is a staging folder, so the caller decides how the files appear together.
    ``summary`` is what ``run.json`` and the report show.
    """
    from prismstereo.viz.colorize import colorize_disparity

    assert result.disparity is not None and result.depth is not None
    pts, cols = result.point_cloud()
    if "disparity.pfm" in names:
        write_pfm(folder / "disparity.pfm", result.disparity)
    if "disparity.png" in names:
        write_image(folder / "disparity.png", colorize_disparity(result.disparity, colorbar="disparity (px)"))
    if "depth.pfm" in names:
        write_pfm(folder / "depth.pfm", result.depth)
    confidence = result.point_confidence()
    if "confidence.pfm" in names:
        write_pfm(folder / "confidence.pfm", confidence)
    if "points.ply" in names:
        assert result.valid is not None
        write_ply(folder / "points.ply", pts, cols, properties={"confidence": confidence[result.valid]})
    if "report.png" in names:
        from prismstereo.viz.report import write_depth_report

        assert result.right is not None and result.left is not None
        write_depth_report(folder / "report.png", capture=result.image, left=result.left, right=result.right,
                           disparity=result.disparity, depth=result.depth, points=pts, colors=cols, summary=summary)
    if "run.json" in names:
        write_json(folder / "run.json", summary)
