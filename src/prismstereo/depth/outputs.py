"""Files of a depth run (docs/cli.md, docs/formats.md), written together through a staging folder.

A pair run: ``disparity.pfm`` (px, inf = invalid), ``disparity.png`` (colourised), ``depth.pfm`` (world Z in
mm on the rectified left grid, inf = invalid), ``confidence.pfm`` (each point's confidence on the same grid),
``points.ply`` (valid points, mm, world frame, RGB, confidence), ``report.png`` and ``run.json``. An
all-view run (no disparity; its grid is the real capture): ``depth.pfm``, ``depth.png`` and ``views.png``
(views that triangulated each pixel), ``points.ply`` (no confidence) and ``run.json``. If anything fails,
the output folder is left as it was.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from prismstereo.depth.pipeline import DepthRun
from prismstereo.io import output_dir, write_image, write_json, write_pfm, write_ply
from prismstereo.viz.colorize import colorize_depth, colorize_disparity
from prismstereo.viz.report import write_depth_report

__all__ = ["ALL_VIEW_FILES", "OUTPUT_FILES", "output_files", "write_depth_files", "write_depth_outputs"]

#: the files of a pair run
OUTPUT_FILES = ("disparity.pfm", "disparity.png", "depth.pfm", "confidence.pfm", "points.ply", "report.png",
                "run.json")
#: the files of an all-view run
ALL_VIEW_FILES = ("depth.pfm", "depth.png", "views.png", "points.ply", "run.json")


def output_files(result: DepthRun, *, report: bool = True) -> list[str]:
    """The names :func:`write_depth_outputs` writes for ``result``."""
    names = OUTPUT_FILES if result.pair is not None else ALL_VIEW_FILES
    return [n for n in names if report or n != "report.png"]


def write_depth_outputs(result: DepthRun, out_dir: str | os.PathLike[str], *, report: bool = True,
                        extra: dict[str, Any] | None = None,
                        also: Callable[[Path], None] | None = None) -> dict[str, Path]:
    """Write the outputs of ``result`` into ``out_dir`` (created if needed) all-or-nothing.

    Parameters
    ----------
    result : DepthRun
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
    names = output_files(result, report=report)
    target = Path(out_dir)
    with output_dir(target) as stage:
        write_depth_files(result, stage, names, summary)
        if also is not None:
            also(stage)
    return {n: target / n for n in names}


def write_depth_files(result: DepthRun, folder: Path, names: Sequence[str], summary: dict[str, Any]) -> None:
    """Write the files ``names`` (among :data:`OUTPUT_FILES` and :data:`ALL_VIEW_FILES`) of ``result`` into an
    existing ``folder``.

    The one writer of a depth run's files, for :func:`write_depth_outputs` and the per-frame folders of a
    batch; ``folder`` is a staging folder, so the caller decides how the files appear together.
    ``summary`` is what ``run.json`` and the report show. Files that need what the run has not (a
    disparity or a report of an all-view run, the view counts of a pair run) are skipped.
    """
    pts, cols = result.point_cloud()
    disparity = result.disparity
    if "disparity.pfm" in names and disparity is not None:
        write_pfm(folder / "disparity.pfm", disparity)
    if "disparity.png" in names and disparity is not None:
        write_image(folder / "disparity.png", colorize_disparity(disparity, colorbar="disparity (px)"))
    if "depth.pfm" in names:
        write_pfm(folder / "depth.pfm", result.depth)
    if "depth.png" in names and result.pair is None:
        write_image(folder / "depth.png", colorize_depth(result.depth, colorbar="depth Z (mm)"))
    if "views.png" in names and result.view_counts is not None:
        counts = result.view_counts
        write_image(folder / "views.png", colorize_disparity(
            np.where(counts > 0, counts.astype(np.float32), np.float32(np.nan)), vmin=0.0,
            vmax=float(len(result.faces)), colorbar="views per pixel"))
    # an all-view run has no per-point confidence: its files and points carry none
    confidence = result.point_confidence() if result.confidence is not None else None
    if "confidence.pfm" in names and confidence is not None:
        write_pfm(folder / "confidence.pfm", confidence)
    if "points.ply" in names:
        assert result.valid is not None
        props = None if confidence is None else {"confidence": confidence[result.valid]}
        write_ply(folder / "points.ply", pts, cols, properties=props)
    if "report.png" in names and disparity is not None and result.right is not None:
        write_depth_report(folder / "report.png", capture=result.image, left=result.left, right=result.right,
                           disparity=disparity, depth=result.depth, points=pts, colors=cols, summary=summary)
    if "run.json" in names:
        write_json(folder / "run.json", summary)
