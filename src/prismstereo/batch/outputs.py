"""Files of a batch: one folder per frame, written all-or-nothing, and the summary of the run.

A frame's files are written into a hidden ``OUT/frames/.tmp-<name>-*`` folder that is renamed to
``OUT/frames/<name>`` once complete (one ``rename``), so a frame folder either has every requested file or
does not exist. ``frame.json`` (the frame's summary row) is always written; a folder is *finished* when it
holds ``frame.json`` with status ``ok`` and every requested output.
"""

from __future__ import annotations

import csv
import io
import json
import os
import shutil
import tempfile
import time
import uuid
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from prismstereo.depth.outputs import OUTPUT_FILES, write_depth_files
from prismstereo.depth.pipeline import DepthRun
from prismstereo.errors import ConfigError
from prismstereo.io import atomic_write_text, write_image, write_json

__all__ = ["DEFAULT_OUTPUTS", "OUTPUT_CHOICES", "SUMMARY_FIELDS", "depth_png", "finished_row", "parse_outputs",
           "remove_partial", "write_frame_folder", "write_summary"]

#: files a frame folder can hold: ``depth``'s files plus ``depth.png`` (16-bit, Z in mm, 0 = none; for video)
OUTPUT_CHOICES = (*OUTPUT_FILES, "depth.png")
#: the same files as ``prismstereo depth``
DEFAULT_OUTPUTS = tuple(OUTPUT_FILES)
FRAME_JSON = "frame.json"
#: columns of summary.csv (summary.json has the same keys plus the per-stage timings)
SUMMARY_FIELDS = ("name", "source", "index", "status", "resumed", "points", "coverage", "t_read_s", "t_depth_s",
                  "t_write_s", "t_total_s", "rss_mb", "worker", "warnings", "error")


def parse_outputs(outputs: str | Sequence[str] | None) -> tuple[str, ...]:
    """Validate an ``--outputs`` choice (comma-separated text or names) in :data:`OUTPUT_CHOICES` order.

    Raises
    ------
    ConfigError
        An unknown file name or an empty choice.
    """
    if outputs is None:
        return DEFAULT_OUTPUTS
    names = [s.strip() for s in (outputs.split(",") if isinstance(outputs, str) else outputs) if s.strip()]
    bad = [n for n in names if n not in OUTPUT_CHOICES]
    if bad or not names:
        raise ConfigError(f"outputs: expected names among {','.join(OUTPUT_CHOICES)}, "
                          f"got {','.join(names) or '(none)'}")
    return tuple(n for n in OUTPUT_CHOICES if n in names)


def depth_png(depth: np.ndarray) -> np.ndarray:
    """(h, w) float Z mm → uint16 Z in whole mm (0 = no depth; beyond 65535 mm clipped to 65535)."""
    z = np.where(np.isfinite(depth), np.rint(depth), 0.0)
    return np.clip(z, 0, 65535).astype(np.uint16)


def _write_files(result: DepthRun, stage: Path, outputs: Sequence[str], extra: dict[str, Any]) -> None:
    assert result.depth is not None
    if "depth.png" in outputs:
        write_image(stage / "depth.png", depth_png(result.depth))
    write_depth_files(result, stage, [n for n in outputs if n in OUTPUT_FILES], {**result.summary(), **extra})


def write_frame_folder(result: DepthRun, frames_dir: Path, name: str, outputs: Sequence[str], *,
                       row: dict[str, Any], extra: dict[str, Any] | None = None) -> Path:
    """Write a frame's outputs and ``frame.json`` (``row``) to ``frames_dir/name`` all-or-nothing.

    An earlier folder of the same name (an unfinished or differently configured frame) is replaced.
    ``row["t_write_s"]`` is set to the time spent writing the outputs.
    """
    t0 = time.perf_counter()
    tmp = Path(tempfile.mkdtemp(prefix=f".tmp-{name}-", dir=frames_dir))
    try:
        # mkdtemp makes owner-only folders; the frame folder should get the usual permissions
        mask = os.umask(0)
        os.umask(mask)
        os.chmod(tmp, 0o777 & ~mask)
        _write_files(result, tmp, outputs, extra or {})
        row["t_write_s"] = time.perf_counter() - t0
        write_json(tmp / FRAME_JSON, row)
        final = frames_dir / name
        if final.exists():
            old = frames_dir / f".old-{name}-{uuid.uuid4().hex[:8]}"
            os.replace(final, old)
            os.replace(tmp, final)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return final


def finished_row(frames_dir: Path, name: str, outputs: Sequence[str]) -> dict[str, Any] | None:
    """The stored row of a finished frame folder, or None when the frame must be (re)done."""
    folder = frames_dir / name
    try:
        row = json.loads((folder / FRAME_JSON).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(row, dict) or row.get("status") != "ok":
        return None
    if not all((folder / n).is_file() for n in outputs):
        return None
    return row


def remove_partial(frames_dir: Path) -> int:
    """Delete the hidden staging folders an interrupted run left in ``frames_dir``; returns how many."""
    n = 0
    if frames_dir.is_dir():
        for p in frames_dir.iterdir():
            if p.is_dir() and (p.name.startswith(".tmp-") or p.name.startswith(".old-")):
                shutil.rmtree(p, ignore_errors=True)
                n += 1
    return n


def _csv_value(v: Any) -> Any:
    if isinstance(v, float):
        return "" if v != v else f"{v:.6g}"
    if v is None:
        return ""
    return v


def write_summary(out_dir: Path, rows: Sequence[dict[str, Any]], totals: dict[str, Any]) -> None:
    """Write ``summary.csv`` (one row per frame, :data:`SUMMARY_FIELDS`) and ``summary.json`` atomically."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(SUMMARY_FIELDS), extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    for r in rows:
        writer.writerow({k: _csv_value(r.get(k)) for k in SUMMARY_FIELDS})
    atomic_write_text(out_dir / "summary.csv", buf.getvalue())
    write_json(out_dir / "summary.json", {**totals, "frames": list(rows)})
