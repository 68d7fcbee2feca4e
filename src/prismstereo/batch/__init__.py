"""Depth for sequences: many frames (images, folders, globs, videos) on Dask, one set-up per rig.

``run_batch(rig, inputs, out)`` is the library entry point (and ``prismstereo batch`` the command); it works
on a local Dask cluster made for the run, an existing scheduler, or a ``distributed.Client`` of the user's.
See ``docs/batch.md``.
"""

from __future__ import annotations

from prismstereo.batch.frames import Frame, list_frames, read_frame, video_frame_count
from prismstereo.batch.outputs import DEFAULT_OUTPUTS, OUTPUT_CHOICES, SUMMARY_FIELDS, depth_png, parse_outputs
from prismstereo.batch.runner import (
    EXIT_OK,
    EXIT_SOME_FAILED,
    BatchSummary,
    local_cluster,
    process_frame,
    run_batch,
)

__all__ = [
    "DEFAULT_OUTPUTS",
    "EXIT_OK",
    "EXIT_SOME_FAILED",
    "OUTPUT_CHOICES",
    "SUMMARY_FIELDS",
    "BatchSummary",
    "Frame",
    "depth_png",
    "list_frames",
    "local_cluster",
    "parse_outputs",
    "process_frame",
    "read_frame",
    "run_batch",
    "video_frame_count",
]
