"""The frames of a batch: image files, folders, globs and videos, read one frame at a time.

A batch never holds a whole video: :func:`list_frames` only counts a video's frames (container metadata),
and :func:`read_frame` decodes the one frame a task needs, by index, on the worker that runs it.
"""

from __future__ import annotations

import glob
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from prismstereo.errors import ConfigError, ImageError
from prismstereo.io import read_image

__all__ = ["IMAGE_SUFFIXES", "VIDEO_SUFFIXES", "Frame", "list_frames", "read_frame", "video_frame_count"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".ppm", ".pgm", ".pnm", ".bmp", ".tif", ".tiff", ".webp")
VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".m4v", ".webm")
_GLOB_CHARS = set("*?[")


@dataclass(frozen=True)
class Frame:
    """One capture of a batch.

    Attributes
    ----------
    name : str
        Folder name of its outputs (``OUT/frames/<name>/``), unique within the batch.
    source : str
        Image or video file.
    index : int or None
        Frame index in the video (0-based); None for an image file.
    """

    name: str
    source: str
    index: int | None = None

    @property
    def label(self) -> str:
        """``file`` or ``file#index`` for messages."""
        return self.source if self.index is None else f"{self.source}#{self.index}"


def video_frame_count(path: str | os.PathLike[str]) -> int:
    """Number of frames of a video file from its container (OpenCV); nothing is decoded.

    Raises
    ------
    ImageError
        If OpenCV cannot open the file as a video.
    """
    import cv2

    cap = cv2.VideoCapture(str(path))
    try:
        if not cap.isOpened():
            raise ImageError(f"expected a video OpenCV can open (mp4, avi, ...), got {str(path)!r}")
        n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    finally:
        cap.release()
    if n <= 0:
        raise ImageError(f"expected a video with frames, got {str(path)!r} (no frame count)")
    return n


def _expand(item: str) -> list[Path]:
    """Files of one INPUT: a file (kept even if missing: it becomes a failed frame), a folder or a glob."""
    p = Path(item)
    if p.is_dir():
        files = sorted(f for f in p.iterdir()
                       if f.is_file() and f.suffix.lower() in IMAGE_SUFFIXES + VIDEO_SUFFIXES)
        if not files:
            raise ConfigError(f"INPUT: expected a folder with images or videos, got {item!r} (none inside)")
        return files
    if not p.exists() and _GLOB_CHARS & set(item):
        files = sorted(Path(f) for f in glob.glob(item) if Path(f).is_file())
        if not files:
            raise ConfigError(f"INPUT: expected a glob that matches files, got {item!r} (no match)")
        return files
    return [p]


def list_frames(inputs: Sequence[str | os.PathLike[str]]) -> list[Frame]:
    """The frames of a batch, in input order.

    Parameters
    ----------
    inputs : image files, folders (their images and videos, sorted), globs, or video files
        A video contributes one frame per index, named ``<stem>_<index:06d>``; an image is named after its
        stem (``<stem>_2``, ``<stem>_3`` … when stems repeat). A listed file that does not exist is kept: it
        becomes a failed frame of the batch, like a corrupt one. So does a video OpenCV cannot open.

    Raises
    ------
    ConfigError
        No inputs, a folder without images or a glob without a match.
    """
    if not inputs:
        raise ConfigError("INPUT: expected at least one image, folder, glob or video, got none")
    frames: list[Frame] = []
    used: set[str] = set()

    def unique(name: str) -> str:
        out, k = name, 1
        while out in used:
            k += 1
            out = f"{name}_{k}"
        used.add(out)
        return out

    for item in inputs:
        for path in _expand(os.fspath(item)):
            if path.suffix.lower() in VIDEO_SUFFIXES and path.is_file():
                try:
                    n = video_frame_count(path)
                except ImageError:
                    frames.append(Frame(unique(path.stem), str(path), 0))  # fails when read: recorded
                    continue
                frames.extend(Frame(unique(f"{path.stem}_{i:06d}"), str(path), i) for i in range(n))
            else:
                frames.append(Frame(unique(path.stem), str(path)))
    return frames


def read_frame(frame: Frame) -> np.ndarray:
    """The capture of one frame, RGB ``uint8`` (or ``uint16`` for 16-bit image files).

    A video frame is decoded alone: the video is opened, positioned at the frame's index and one frame is
    read (intra-coded codecs such as MJPG seek directly; others decode from the previous key frame).

    Raises
    ------
    ImageError
        Missing, empty or undecodable file; a video frame that cannot be read.
    """

    if frame.index is None:
        return read_image(frame.source)
    import cv2

    if not Path(frame.source).is_file():
        raise ImageError(f"expected a video file, got {frame.source!r} (no such file)")
    cap = cv2.VideoCapture(frame.source)
    try:
        if not cap.isOpened():
            raise ImageError(f"expected a video OpenCV can open (mp4, avi, ...), got {frame.source!r}")
        if frame.index > 0 and not cap.set(cv2.CAP_PROP_POS_FRAMES, float(frame.index)):
            raise ImageError(f"expected a seekable video, got {frame.source!r} (cannot go to frame {frame.index})")
        ok, bgr = cap.read()
    finally:
        cap.release()
    if not ok or bgr is None:
        raise ImageError(f"expected a readable frame {frame.index} in {frame.source!r}, got none (corrupt or short)")
    if bgr.ndim == 2:
        return np.ascontiguousarray(np.repeat(bgr[:, :, None], 3, axis=2))
    return np.ascontiguousarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
