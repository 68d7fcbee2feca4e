"""PFM (portable float map), Middlebury convention: rows stored bottom to top, scale < 0 = little-endian.

NaN (invalid) is written as +inf, as the Middlebury tools expect, and read back as NaN.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from prismstereo.errors import ImageError
from prismstereo.io.atomic import atomic_write_bytes


def write_pfm(path: str | os.PathLike[str], array: np.ndarray) -> None:
    """Write an H×W (``Pf``) or H×W×3 (``PF``) float array as little-endian PFM; NaN becomes inf."""
    a = np.asarray(array, dtype=np.float32)
    if a.ndim == 2:
        header = b"Pf"
    elif a.ndim == 3 and a.shape[2] == 3:
        header = b"PF"
    else:
        raise ImageError(f"expected an H×W or H×W×3 array for PFM, got shape {a.shape}")
    a = np.where(np.isnan(a), np.float32(np.inf), a)
    h, w = a.shape[:2]
    body = np.ascontiguousarray(a[::-1]).astype("<f4").tobytes()
    atomic_write_bytes(path, header + b"\n%d %d\n-1.0\n" % (w, h) + body)


def read_pfm(path: str | os.PathLike[str]) -> np.ndarray:
    """Read a PFM file as float32 H×W (or H×W×3), top row first; inf becomes NaN."""
    p = Path(path)
    if not p.is_file():
        raise ImageError(f"expected a PFM file, got {str(p)!r} (no such file)")
    raw = p.read_bytes()
    m = re.match(rb"(P[fF])\s+(\d+)\s+(\d+)\s+([-+0-9.eE]+)\s", raw)
    if m is None:
        raise ImageError(f"expected a PFM header ('Pf' or 'PF'), got {raw[:16]!r} in {str(p)!r}")
    kind, w, h, scale = m.group(1), int(m.group(2)), int(m.group(3)), float(m.group(4))
    channels = 3 if kind == b"PF" else 1
    dtype = "<f4" if scale < 0 else ">f4"
    n = w * h * channels
    data = np.frombuffer(raw, dtype=dtype, count=n, offset=m.end()) if len(raw) - m.end() >= 4 * n else None
    if data is None:
        raise ImageError(f"expected {n} floats in {str(p)!r}, got a truncated file")
    a = data.reshape((h, w, channels) if channels == 3 else (h, w))[::-1].astype(np.float32)
    a[~np.isfinite(a)] = np.nan
    return np.ascontiguousarray(a)
