"""What ``prismstereo batch`` does, kept out of cli.py (no algorithm code there)."""

from __future__ import annotations

import logging
import sys
from collections.abc import Sequence
from typing import Any

from prismstereo.errors import ConfigError

__all__ = ["BATCH_EPILOG", "batch_command"]

BATCH_EPILOG = """\
INPUT: image files, folders (their images and videos), globs ('caps/*.png', quoted) or videos (mp4, avi, ...;
one frame per index, decoded on the workers). Outputs: OUT/frames/<name>/ per frame (written complete or not
at all), OUT/summary.csv and summary.json (one row per frame), OUT/run.json (the resolved configuration).
Running the same command again skips finished frames and redoes failed ones.
Exit codes: 0 every frame done; 3 some frames failed (see summary.csv; the others are written);
2 bad arguments (before any frame is processed); 130 interrupted (Ctrl-C; finished frames are kept)."""


def batch_command(rig_path: str, inputs: Sequence[str], out_dir: str, *, method: str = "bpasw",
                  params: dict[str, Any] | None = None, depth_range: tuple[float, float] | None = None,
                  roi: tuple[int, int, int, int] | None = None, views: Any = None, triangulation: str = "exact",
                  calibration: str = "fit", refine: bool = True, outputs: str | None = None,
                  scheduler: str | None = None, workers: int | None = None, threads_per_worker: int = 1,
                  processes: bool = True, retries: int = 2, numba_threads: int | None = None,
                  min_confidence: float | None = None, preset: str | None = None) -> int:
    """Run ``prismstereo batch``: print the summary, return the exit code (0, or 3 when frames failed).
    ``preset``: the profile ``method`` came from; its depth settings apply where no option sets them."""
    # imported when the command runs: ``prismstereo --help`` starts without Dask and the numerical packages
    from prismstereo.batch.runner import run_batch
    from prismstereo.config import load_rig
    from prismstereo.depth.presets import config_with_preset

    rig = load_rig(rig_path)
    if views == "all":
        raise ConfigError("--views: expected a pair I,J for batch, got 'all' (the all-view sweep is depth-only)")
    if views is not None and len(views) != 2:
        raise ConfigError(f"--views: expected two faces I,J, got {','.join(map(str, views))}")
    given: dict[str, Any] = dict(matcher_params=dict(params or {}), depth_range=depth_range, roi=roi,
                                 views=None if views is None else (int(views[0]), int(views[1])),
                                 triangulation=triangulation, calibration=calibration, refine=refine)
    if min_confidence is not None:
        given["min_confidence"] = min_confidence
    config = config_with_preset(method, preset, given)

    if logging.getLogger("prismstereo").getEffectiveLevel() > logging.INFO:
        import distributed  # noqa: F401 - its import sets its loggers' levels: lower them afterwards

        # without -v, Dask's own start-up and shut-down chatter would bury the summary
        logging.getLogger("distributed").setLevel(logging.WARNING)

    def echo(line: str) -> None:
        print(line, file=sys.stderr)

    summary = run_batch(rig, inputs, out_dir, config=config, outputs=outputs, scheduler=scheduler, workers=workers,
                        threads_per_worker=threads_per_worker, processes=processes, retries=retries,
                        numba_threads=numba_threads, echo=echo, preset=preset)
    print(summary.text())
    return summary.exit_code

