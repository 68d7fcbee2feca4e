"""Streaming depth: frames of a camera, a video or a folder that fills up, processed as they arrive.

:func:`run_stream` prepares the per-rig set-up once (:func:`~prismstereo.depth.pipeline.prepare_depth`: the
cached rectification, epipolar and exact-ray tables) and runs a three-stage thread pipeline with bounded
queues, so that decoding the next frame and writing the last one overlap the depth of the current one:

reader (:func:`open_source`: decode) → depth (:func:`~prismstereo.depth.pipeline.run_depth_frame`, in the
calling thread) → writer (per-frame folder written all-or-nothing with
:func:`~prismstereo.batch.outputs.write_frame_folder`, and/or one colourised depth video).

Each queue holds at most ``queue_size`` frames, so a fast camera never piles frames up in memory: the
reader waits (a live camera's driver then drops frames, which is what a live stream should do). OpenCV's
decode/encode and the refinement's and triangulation's numba kernels release the GIL, so the stages run
on the cores at once.

Sources (:func:`open_source`):

- a camera index (``"0"``): ``cv2.VideoCapture(index)``; one that cannot be opened is an
  :class:`~prismstereo.errors.ImageError` before anything else happens;
- a video file: read in order to its end;
- a folder: its images in name order, then every new image that appears (a file counts once its size has
  stayed the same for one poll and it decodes), until no new image came for ``idle_timeout`` seconds.

Ctrl-C (SIGINT; in the main thread a handler is installed for the stream's duration) ends the stream after the
frame in progress: the reader stops, the writer finishes the frames whose depth is done, and the summary
comes back with ``interrupted`` set; no frame folder is left half-written. A second Ctrl-C interrupts at once.
A frame of the wrong size from a camera or video is an error before the first depth (the whole stream
would be); in a folder it is that frame's failure (logged, counted) and the stream goes on.

With ``temporal`` (a :class:`~prismstereo.matching.temporal.TemporalPrior`, on by default for a matcher that searches
per-pixel bands, ``sgm``: the ``fast`` preset), a frame is matched within a band around the previous frame's matches
(:func:`~prismstereo.matching.temporal.prior_band`) instead of the whole range; a frame whose banded matches fail the
check (:func:`~prismstereo.matching.temporal.band_failed`: a scene cut, a fast motion) is matched again over the
whole range, and every ``keyframe_every``-th frame, the first and every one after a change of the range are full
ones. ``stream.json`` records the rules and how many frames were banded, full and matched again.

Without a configured depth range (``narrow_range``, default on) the first frame's images narrow the
rig's range as :func:`~prismstereo.depth.pipeline.run_depth` does for one capture (the rig's whole range
is ~5× the disparities of a room-sized scene: 394 against 75 px on the 1024×768 robot rig), and the
stream keeps that band. A frame whose consistent matches sit at a limit of the band that the rig's range
does not share (more than :data:`~prismstereo.matching.diagnostics.LIMIT_SHARE` of them: the scene came
nearer or went farther) searches the range again on its own images and is matched again; so does every
frame while the images could not narrow it (the rig's range is searched meanwhile).
"""

from __future__ import annotations

import dataclasses
import logging
import os
import queue
import signal
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from prismstereo.batch.frames import IMAGE_SUFFIXES, VIDEO_SUFFIXES
from prismstereo.batch.outputs import parse_outputs, remove_partial, write_frame_folder
from prismstereo.config import Rig
from prismstereo.depth.pipeline import (
    DepthConfig,
    DepthRun,
    DepthSetup,
    prepare_depth,
    rectify_capture,
    run_depth_frame,
    search_region,
    validate_image,
)
from prismstereo.depth.presets import preset_record
from prismstereo.errors import ConfigError, GeometryError, ImageError
from prismstereo.io import read_image, write_json
from prismstereo.io.atomic import check_output_dir
from prismstereo.matching.diagnostics import LIMIT_SHARE, limit_shares
from prismstereo.matching.temporal import BANDED_MATCHERS, DEFAULT_PRIOR, TemporalPrior, band_failed, prior_band
from prismstereo.viz.colorize import colorize_depth

log = logging.getLogger(__name__)

__all__ = ["STREAM_OUTPUTS", "StreamFrame", "StreamSummary", "open_source", "run_stream", "source_kind"]

#: default files per frame of a stream: 16-bit depth in mm and the disparity
STREAM_OUTPUTS = ("disparity.pfm", "depth.png")
_END = object()


@dataclass(frozen=True)
class StreamFrame:
    """One frame of a source: its name, the RGB uint8 capture (None when it could not be read) and why not,
    and the seconds its decode took."""

    name: str
    image: np.ndarray | None
    error: str = ""
    t_read: float = 0.0


@dataclass
class StreamSummary:
    """What a stream did.

    Attributes
    ----------
    frames : int
        Frames whose depth was computed and written.
    failed : list of (name, error)
        Frames that could not be read or processed (folder sources).
    wall_s : float
        Seconds from the first frame read to the last one written (the set-up excluded).
    setup_s : float
    interrupted : bool
        Ctrl-C ended the stream.
    stage_s : dict
        Mean seconds per frame: ``read``, ``depth`` (the pipeline's own total), ``write``.
    out_dir : Path
    """

    frames: int = 0
    failed: list[tuple[str, str]] = field(default_factory=list)
    wall_s: float = 0.0
    setup_s: float = 0.0
    interrupted: bool = False
    stage_s: dict[str, float] = field(default_factory=dict)
    out_dir: Path = Path(".")

    @property
    def frames_per_s(self) -> float:
        return self.frames / self.wall_s if self.wall_s > 0 else 0.0

    def text(self) -> str:
        s = self.stage_s
        lines = [f"stream: {self.frames} frames in {self.wall_s:.1f} s ({self.frames_per_s:.2f} frames/s; per frame "
                 f"read {s.get('read', 0.0):.3f} s, depth {s.get('depth', 0.0):.3f} s, write "
                 f"{s.get('write', 0.0):.3f} s, overlapped), {len(self.failed)} failed"
                 + (", interrupted" if self.interrupted else "")]
        lines += [f"  {name}: {err}" for name, err in self.failed]
        lines.append(f"wrote {self.out_dir}")
        return "\n".join(lines)


def source_kind(source: str) -> str:
    """``"camera"`` (an integer), ``"folder"`` or ``"video"``.

    Raises
    ------
    ConfigError
        A path that is neither a folder nor an existing video file.
    """
    s = str(source).strip()
    if s.isdigit():
        return "camera"
    p = Path(s)
    if p.is_dir():
        return "folder"
    if p.is_file() and p.suffix.lower() in VIDEO_SUFFIXES:
        return "video"
    if p.is_file():
        raise ConfigError(f"source: expected a camera index, a video ({', '.join(VIDEO_SUFFIXES)}) or a folder, "
                          f"got the file {s!r}")
    raise ConfigError(f"source: expected a camera index, a video file or a folder, got {s!r} (no such file)")


def _rgb(bgr: np.ndarray) -> np.ndarray:
    if bgr.ndim == 2:
        return np.ascontiguousarray(np.repeat(bgr[:, :, None], 3, axis=2))
    return np.ascontiguousarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))


def _capture_frames(cap: Any, stem: str, stop: threading.Event) -> Iterator[StreamFrame]:
    i = 0
    try:
        while not stop.is_set():
            t = time.perf_counter()
            ok, bgr = cap.read()
            if not ok or bgr is None:
                return
            yield StreamFrame(f"{stem}_{i:06d}", _rgb(bgr), t_read=time.perf_counter() - t)
            i += 1
    finally:
        cap.release()


def _folder_frames(folder: Path, stop: threading.Event, poll_s: float, idle_timeout: float) -> Iterator[StreamFrame]:
    done: set[str] = set()
    sizes: dict[str, int] = {}
    last_new = time.monotonic()
    while not stop.is_set():
        ready = []
        for p in sorted(folder.iterdir()):
            if p.name in done or not p.is_file() or p.suffix.lower() not in IMAGE_SUFFIXES or p.name.startswith("."):
                continue
            try:
                size = p.stat().st_size
            except OSError:
                continue
            if size > 0 and sizes.get(p.name) == size:
                ready.append(p)
            sizes[p.name] = size
        for p in ready:
            done.add(p.name)
            last_new = time.monotonic()
            t = time.perf_counter()
            try:
                img = read_image(p)
            except ImageError as exc:
                yield StreamFrame(p.stem, None, error=str(exc).splitlines()[0])
            else:
                yield StreamFrame(p.stem, img, t_read=time.perf_counter() - t)
            # the time the consumer held the frame (a full queue, a slow first depth) is not idle time: the
            # folder was not being watched, so the idle clock starts again when the reader looks again
            last_new = time.monotonic()
            if stop.is_set():
                return
        if not ready:
            if time.monotonic() - last_new > idle_timeout:
                return
            stop.wait(poll_s)


def _quiet_open(what: int | str) -> Any:
    """``cv2.VideoCapture(what)`` without OpenCV's own warnings on stderr (a failure is reported by the
    caller, in one line); OpenCV's log level is put back afterwards."""
    logging_mod = getattr(getattr(cv2, "utils", None), "logging", None)
    if logging_mod is None:  # pragma: no cover - an OpenCV build without its logging module
        return cv2.VideoCapture(what)
    level = logging_mod.getLogLevel()
    logging_mod.setLogLevel(logging_mod.LOG_LEVEL_SILENT)
    try:
        return cv2.VideoCapture(what)
    finally:
        logging_mod.setLogLevel(level)


def open_source(source: str, *, stop: threading.Event | None = None, poll_s: float = 0.2,
                idle_timeout: float = 10.0) -> Iterator[StreamFrame]:
    """The frames of a source, as they arrive (module docstring); opened here, read lazily.

    Parameters
    ----------
    source : str
        Camera index, video file or folder.
    stop : threading.Event, optional
        Set it to end the iteration (the camera or video is released).
    poll_s : float
        Folder: seconds between looks for new images.
    idle_timeout : float
        Folder: stop when no new image came for this long, s.

    Returns
    -------
    iterator of StreamFrame
        ``image`` None and ``error`` set for a folder image that cannot be read.

    Raises
    ------
    ImageError
        A camera index or a video that OpenCV cannot open (before any frame is read).
    ConfigError
        Not a source (:func:`source_kind`); a negative ``poll_s`` or ``idle_timeout``.
    """
    if poll_s <= 0 or idle_timeout < 0:
        raise ConfigError(f"idle_timeout/poll_s: expected a positive poll and a timeout >= 0, got {poll_s}, "
                          f"{idle_timeout}")
    stop = stop or threading.Event()
    kind = source_kind(source)
    if kind == "folder":
        return _folder_frames(Path(source), stop, poll_s, idle_timeout)
    if kind == "camera":
        cap = _quiet_open(int(source))
        if not cap.isOpened():
            cap.release()
            raise ImageError(f"source: expected a camera that OpenCV can open, got camera {int(source)} "
                             "(not connected, busy or no permission)")
        return _capture_frames(cap, f"cam{int(source)}", stop)
    cap = _quiet_open(str(source))
    if not cap.isOpened():
        cap.release()
        raise ImageError(f"source: expected a video OpenCV can open (mp4, avi, ...), got {str(source)!r}")
    return _capture_frames(cap, Path(source).stem, stop)


def _put(q: queue.Queue[Any], item: Any, stop: threading.Event) -> bool:
    """Put into a bounded queue unless ``stop`` is set first (then False)."""
    while not stop.is_set():
        try:
            q.put(item, timeout=0.1)
            return True
        except queue.Full:
            continue
    return False


class _VideoOut:
    """A colourised depth video (``cv2.VideoWriter``), opened at the first frame."""

    def __init__(self, path: Path, fps: float, depth_range: tuple[float, float]) -> None:
        self.path, self.fps, self.range = path, fps, depth_range
        self.writer: Any = None

    def write(self, depth: np.ndarray) -> None:
        rgb = colorize_depth(depth, vmin=self.range[0], vmax=self.range[1])
        if self.writer is None:
            fourcc = cv2.VideoWriter.fourcc(*("mp4v" if self.path.suffix.lower() in (".mp4", ".m4v") else "MJPG"))
            self.writer = cv2.VideoWriter(str(self.path), fourcc, self.fps, (rgb.shape[1], rgb.shape[0]))
            if not self.writer.isOpened():
                raise ImageError(f"video: expected a video file OpenCV can write, got {str(self.path)!r}")
        self.writer.write(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))

    def close(self) -> None:
        if self.writer is not None:
            self.writer.release()


def run_stream(rig: Rig, source: str, out: str | os.PathLike[str], *, config: DepthConfig | None = None,
               outputs: str | Sequence[str] | None = STREAM_OUTPUTS, video: str | os.PathLike[str] | None = None,
               video_fps: float = 10.0, idle_timeout: float = 10.0, poll_s: float = 0.2, queue_size: int = 2,
               max_frames: int | None = None, on_frame: Callable[[str, DepthRun], None] | None = None,
               echo: Callable[[str], None] | None = None, report_every: float = 2.0,
               narrow_range: bool = True, preset: str | None = None,
               temporal: TemporalPrior | None = DEFAULT_PRIOR) -> StreamSummary:
    """Depth of every frame of ``source`` as it arrives, into ``out/frames/<name>/`` (module docstring).

    Parameters
    ----------
    rig : Rig
    source : str
        Camera index, video file or folder (:func:`open_source`).
    out : output folder
        ``frames/<name>/`` per frame (``outputs``), ``stream.json`` (configuration and totals).
    config : DepthConfig, optional
    outputs : names or comma-separated text, or None/empty for none
        Files per frame among :data:`~prismstereo.batch.outputs.OUTPUT_CHOICES` (default
        :data:`STREAM_OUTPUTS`).
    video : path, optional
        Also write a colourised depth video (mp4/avi) of the frames, at ``video_fps``.
    idle_timeout, poll_s : float
        Folder sources: stop after this long without a new image; seconds between polls.
    queue_size : int
        Frames each queue holds (≥ 1).
    max_frames : int, optional
        Stop after this many frames.
    on_frame : callable, optional
        Called with (name, result) of each finished frame, in the writer thread.
    echo : callable, optional
        Receives a frames/s line every ``report_every`` seconds.
    narrow_range : bool
        Without a configured depth range, narrow the rig's range with the frames' images (module
        docstring); False: every frame searches the rig's whole range.
    preset : str, optional
        The preset ``config`` was resolved from (:func:`~prismstereo.depth.presets.apply_preset`), recorded in
        ``stream.json`` with its settings as resolved (``preset_profile``).
    temporal : TemporalPrior or None
        Match each frame within a band around the previous frame's matches (module docstring), for a matcher of
        :data:`~prismstereo.matching.temporal.BANDED_MATCHERS` (others: not used); None: every frame searches
        the whole range.

    Returns
    -------
    StreamSummary

    Raises
    ------
    ConfigError, ImageError, GeometryError, OutputError
        Before any depth: bad arguments, a source that cannot be opened, a first camera/video frame of
        the wrong size, an output folder that cannot be written.
    """
    chosen: tuple[str, ...] = () if not outputs else parse_outputs(outputs)
    if not chosen and video is None:
        raise ConfigError("outputs: expected files per frame or a video, got neither")
    if queue_size < 1:
        raise ConfigError(f"queue_size: expected 1 or more, got {queue_size}")
    if max_frames is not None and max_frames < 1:
        raise ConfigError(f"max_frames: expected 1 or more, got {max_frames}")
    if video_fps <= 0:
        raise ConfigError(f"video_fps: expected a positive rate, got {video_fps}")
    out_dir = Path(out)
    check_output_dir(out_dir)
    stop = threading.Event()
    frames = open_source(source, stop=stop, poll_s=poll_s, idle_timeout=idle_timeout)
    kind = source_kind(source)
    t = time.perf_counter()
    setup = prepare_depth(rig, config=config)
    summary = StreamSummary(setup_s=time.perf_counter() - t, out_dir=out_dir)
    want = (rig.camera.height, rig.camera.width)
    first = next(iter(frames), None) if kind != "folder" else None
    if first is not None and first.image is not None and first.image.shape[:2] != want:
        stop.set()
        raise ImageError(f"source: expected frames of the rig's camera size {want[1]}×{want[0]}, got "
                         f"{first.image.shape[1]}×{first.image.shape[0]}")
    frames_dir = out_dir / "frames"
    frames_dir.mkdir(parents=True, exist_ok=True)
    remove_partial(frames_dir)
    vid = None if video is None else _VideoOut(Path(video), video_fps, setup.depth_range)
    record: dict[str, Any] = {"command": "stream", "source": str(source), "kind": kind,
                              "config": setup.config.to_dict(), "outputs": list(chosen)}
    if preset is not None:
        record["preset_profile"] = preset_record(preset, setup.config)
    write_json(out_dir / "stream.json", {**record, "disparity_range": list(setup.disparity_range)})
    in_q: queue.Queue[Any] = queue.Queue(maxsize=queue_size)
    out_q: queue.Queue[Any] = queue.Queue(maxsize=queue_size)
    sums = {"read": 0.0, "depth": 0.0, "write": 0.0}
    errors: list[BaseException] = []
    narrow = narrow_range and setup.config.depth_range is None
    current, searches = setup, 0
    prior = _Prior(temporal if setup.config.method in BANDED_MATCHERS else None)

    def reader() -> None:
        n = 0
        try:
            stream = frames if first is None else _chain(first, frames)
            for item in stream:
                if not _put(in_q, item, stop):
                    break
                n += 1
                if max_frames is not None and n >= max_frames:
                    break
        except BaseException as exc:  # noqa: BLE001 - handed to the caller's thread
            errors.append(exc)
        finally:
            _put(in_q, _END, threading.Event())

    def writer() -> None:
        while True:
            item = out_q.get()
            if item is _END:
                return
            name, res, row = item
            t0 = time.perf_counter()
            try:
                if chosen:
                    write_frame_folder(res, frames_dir, name, chosen, row=row)
                if vid is not None:
                    vid.write(res.depth)
                if on_frame is not None:
                    on_frame(name, res)
                summary.frames += 1
            except Exception as exc:  # noqa: BLE001 - one frame's failure, the stream goes on
                summary.failed.append((name, _line(exc)))
            sums["write"] += time.perf_counter() - t0

    threads = [threading.Thread(target=reader, name="stream-reader", daemon=True),
               threading.Thread(target=writer, name="stream-writer", daemon=True)]
    t_start = time.perf_counter()
    last_report = t_start
    previous = _catch_interrupt(stop, summary)
    for th in threads:
        th.start()
    try:
        while True:
            item = in_q.get()
            if item is _END:
                break
            if stop.is_set():  # interrupted: what is still queued is not processed
                continue
            if item.image is None:
                summary.failed.append((item.name, item.error))
                continue
            sums["read"] += item.t_read
            t0 = time.perf_counter()
            try:
                if narrow and current.region.source != "rig+images":
                    current = _narrowed(setup, item.image)
                    searches += 1
                res = prior.depth(current, item.image)
                if narrow and _left_band(res, current, setup):
                    current = _narrowed(setup, item.image)
                    searches += 1
                    res = prior.depth(current, item.image)
            except (ImageError, ConfigError) as exc:
                summary.failed.append((item.name, _line(exc)))
                log.warning("frame %s: %s", item.name, _line(exc))
                continue
            sums["depth"] += time.perf_counter() - t0
            c = res.counts()
            row = {"name": item.name, "source": str(source), "status": "ok", "points": c["points"],
                   "t_depth_s": res.timings.get("total", 0.0), "match": prior.last}
            out_q.put((item.name, res, row))
            now = time.perf_counter()
            if echo is not None and now - last_report >= report_every:
                done = summary.frames
                echo(f"stream: {done} frames, {done / (now - t_start):.2f} frames/s")
                last_report = now
    except KeyboardInterrupt:
        summary.interrupted = True
    finally:
        stop.set()
        while threads[0].is_alive():  # let the reader hand over its end marker
            try:
                in_q.get(timeout=0.1)
            except queue.Empty:
                pass
        out_q.put(_END)
        threads[1].join()
        if previous is not None:
            signal.signal(signal.SIGINT, previous)
        if vid is not None:
            vid.close()
        remove_partial(frames_dir)
    summary.wall_s = time.perf_counter() - t_start
    n = max(summary.frames, 1)
    summary.stage_s = {k: v / n for k, v in sums.items()}
    write_json(out_dir / "stream.json", {**record, "disparity_range": list(current.disparity_range),
                                         "depth_range_mm": [round(z, 1) for z in current.depth_range],
                                         "depth_range_source": current.region.source,
                                         "range_searches": searches,
                                         "temporal_prior": prior.record(),
                                         "setup_s": round(summary.setup_s, 4), "frames": summary.frames,
                                         "failed": [list(f) for f in summary.failed],
                                         "wall_s": round(summary.wall_s, 4),
                                         "frames_per_s": round(summary.frames_per_s, 4),
                                         "stage_s": {k: round(v, 4) for k, v in summary.stage_s.items()},
                                         "interrupted": summary.interrupted})
    if errors and not summary.interrupted:
        raise errors[0]
    return summary


class _Prior:
    """A stream's temporal prior (module docstring): the previous frame's matches, the frames since the last
    full one, and the counts for ``stream.json``. Used by the depth thread only."""

    def __init__(self, rules: TemporalPrior | None) -> None:
        self.rules = rules
        self.previous: np.ndarray | None = None
        self.range: tuple[int, int] | None = None
        self.since_full = 0
        self.reference = 0
        self.last = "full"
        self.counts = {"banded": 0, "full": 0, "matched_again": 0}

    def depth(self, setup: DepthSetup, image: np.ndarray) -> DepthRun:
        """The frame's depth: banded where the rules allow and the banded matches pass the check, else over the
        whole range."""
        rules, band = self.rules, None
        lo, hi = setup.disparity_range
        if (rules is not None and self.previous is not None and self.range == (lo, hi)
                and self.since_full + 1 < rules.keyframe_every):
            band = prior_band(self.previous, min_disp=lo, max_disp=hi, radius=rules.radius,
                              wide_radius=rules.wide_radius, margin=rules.margin)
            if band.full_share > rules.max_full_share:
                band = None
        res = run_depth_frame(setup, image, band=band)
        self.last = "full"
        if band is not None and rules is not None and res.raw_disparity is not None:
            why = band_failed(res.raw_disparity, band, min_disp=lo, max_disp=hi, reference_matches=self.reference,
                              rules=rules)
            if why:
                log.info("stream: the banded match failed its check (%s): matched again over the whole range", why)
                self.counts["matched_again"] += 1
                res = run_depth_frame(setup, image)
                band = None
                self.last = "matched again"
            else:
                self.last = "banded"
        if band is None:
            self.since_full = 0
            self.counts["full"] += 1
            self.reference = 0 if res.raw_disparity is None else int(np.isfinite(res.raw_disparity).sum())
        else:
            self.since_full += 1
            self.counts["banded"] += 1
        self.previous, self.range = res.raw_disparity, (lo, hi)
        return res

    def record(self) -> dict[str, Any] | None:
        """``stream.json``'s ``temporal_prior``: the rules and the frames banded, full and matched again (None:
        not used)."""
        if self.rules is None:
            return None
        return {**self.rules.to_dict(), "frames": dict(self.counts)}


def _narrowed(setup: DepthSetup, image: np.ndarray) -> DepthSetup:
    """``setup`` (the rig's whole range) with its search region narrowed by one frame's images
    (:func:`~prismstereo.depth.pipeline.search_region`, the rig-only part from the set-up)."""
    left, right = rectify_capture(setup.pair, validate_image(setup.rig, image))
    try:
        region = search_region(setup.rig, setup.pair, setup.config, left, right, known=setup.rig_range)
    except GeometryError as exc:  # the rig's range then (and the next frame tries again)
        log.warning("stream: the frame's images could not narrow the depth range (%s): searching the rig's range",
                    _line(exc))
        return setup
    return dataclasses.replace(setup, region=region)


def _left_band(res: DepthRun, current: DepthSetup, rig_setup: DepthSetup) -> bool:
    """Whether a frame's consistent matches sit at a limit of the narrowed band that the rig's range does
    not share (the scene left the band)."""
    if current.region.source != "rig+images" or res.raw_disparity is None:
        return False
    lo, hi = current.disparity_range
    rig_lo, rig_hi = rig_setup.disparity_range
    at_lo, at_hi, n = limit_shares(res.raw_disparity, None, min_disp=lo, max_disp=hi)
    return n > 0 and ((at_hi > LIMIT_SHARE and hi < rig_hi) or (at_lo > LIMIT_SHARE and lo > rig_lo))


def _catch_interrupt(stop: threading.Event, summary: StreamSummary) -> Any:
    """In the main thread, make Ctrl-C end the stream after the frame in progress (a KeyboardInterrupt raised
    inside a numba kernel would abort it); a second Ctrl-C interrupts at once. Returns the previous handler
    to put back (None: not the main thread, nothing installed)."""
    if threading.current_thread() is not threading.main_thread():
        return None
    previous = signal.getsignal(signal.SIGINT)

    def handler(signum: int, frame: Any) -> None:
        if stop.is_set():
            raise KeyboardInterrupt
        summary.interrupted = True
        stop.set()

    signal.signal(signal.SIGINT, handler)
    return previous


def _chain(first: Any, rest: Iterator[Any]) -> Iterator[Any]:
    yield first
    yield from rest


def _line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0] if text else ''}".rstrip(": ")

