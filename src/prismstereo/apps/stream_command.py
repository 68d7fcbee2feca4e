"""What ``prismstereo stream`` does, kept out of cli.py (no algorithm code there)."""

from __future__ import annotations

import sys
from typing import Any

from prismstereo.errors import ConfigError

__all__ = ["STREAM_EPILOG", "stream_command"]

STREAM_EPILOG = """\
SOURCE: a camera index (0, 1, ...), a video file (mp4, avi, ...) or a folder that fills up (its images in name
order, then each new one; the stream ends after --idle-timeout seconds without a new image). Frames are read,
matched and written at once (three threads with short queues); frames/s is printed as it goes.
Outputs: OUT/frames/<name>/ per frame (--outputs, default disparity.pfm and depth.png: 16-bit Z in mm, 0 = none),
written complete or not at all; --video PATH also writes a colourised depth video; OUT/stream.json (configuration,
totals). Ctrl-C ends the stream and keeps every finished frame.
Without --depth-range the first frame's images narrow the rig's range (as depth does for one capture) and the
stream keeps that band, searching again on a frame whose matches sit at its limits (the scene moved).
With sgm (the fast preset) each frame searches, per pixel, a band around the previous frame's matches (their min..max
within 8 px, +-3 px), with a full-range frame every 10 frames and wherever the banded matches fail their check (a
scene cut: matches piled at a band limit, or fewer than 90 % of the last full frame's); --no-temporal-prior: every
frame searches the whole range.
Exit codes: 0 done; 2 bad arguments or a source that cannot be opened (before any frame); 3 some frames failed
(folder sources: unreadable or wrong-size images; the others are written); 130 interrupted."""


def stream_command(rig_path: str, source: str, out_dir: str, *, method: str = "sgm",
                   params: dict[str, Any] | None = None, depth_range: tuple[float, float] | None = None,
                   roi: tuple[int, int, int, int] | None = None, views: Any = None, triangulation: str = "exact",
                   refine: bool = True, min_confidence: float | None = None, outputs: str | None = None,
                   video: str | None = None, video_fps: float = 10.0, idle_timeout: float = 10.0,
                   max_frames: int | None = None, preset: str | None = None, temporal_prior: bool = True) -> int:
    """Run ``prismstereo stream``: print the summary, return the exit code (0, 3 when frames failed, 130
    when interrupted). ``preset``: the profile ``method`` came from; its depth settings apply where no option
    sets them. ``temporal_prior``: match each frame within a band around the previous one's matches
    (:class:`~prismstereo.matching.temporal.TemporalPrior`'s defaults; a matcher that searches bands only)."""
    from prismstereo.batch.stream import STREAM_OUTPUTS, run_stream
    from prismstereo.config import load_rig
    from prismstereo.depth.presets import config_with_preset
    from prismstereo.matching.temporal import DEFAULT_PRIOR

    rig = load_rig(rig_path)
    if views == "all":
        raise ConfigError("--views: expected a pair I,J for a stream, got 'all' (the all-view sweep is depth-only)")
    if views is not None and len(views) != 2:
        raise ConfigError(f"--views: expected two faces I,J, got {','.join(map(str, views))}")
    given: dict[str, Any] = dict(matcher_params=dict(params or {}), depth_range=depth_range, roi=roi,
                                 views=None if views is None else (int(views[0]), int(views[1])),
                                 triangulation=triangulation, refine=refine)
    if min_confidence is not None:
        given["min_confidence"] = min_confidence
    config = config_with_preset(method, preset, given)

    def echo(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    chosen: Any = STREAM_OUTPUTS if outputs is None else ("" if outputs.strip().lower() == "none" else outputs)
    summary = run_stream(rig, source, out_dir, config=config, outputs=chosen, video=video, video_fps=video_fps,
                         idle_timeout=idle_timeout, max_frames=max_frames, echo=echo, preset=preset,
                         temporal=DEFAULT_PRIOR if temporal_prior else None)
    print(summary.text())
    if summary.interrupted:
        return 130
    return 3 if summary.failed else 0

