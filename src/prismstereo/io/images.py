"""Image reading and writing. RGB order at the API; OpenCV's BGR is converted here, at the edge."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from prismstereo.errors import ImageError
from prismstereo.io.atomic import atomic_path


def read_image(path: str | os.PathLike[str], *, gray: bool = False) -> np.ndarray:
    """Read an 8- or 16-bit image file as RGB (H×W×3) or gray (H×W) ``uint8``/``uint16``.

    Raises
    ------
    ImageError
        If the file does not exist, is empty or cannot be decoded.
    """
    p = Path(path)
    if not p.is_file():
        raise ImageError(f"expected an image file, got {str(p)!r} (no such file)")
    if p.stat().st_size == 0:
        raise ImageError(f"expected an image file, got {str(p)!r} (empty file)")
    data = np.fromfile(p, dtype=np.uint8)
    flags = cv2.IMREAD_GRAYSCALE if gray else cv2.IMREAD_UNCHANGED
    img = cv2.imdecode(data, flags)
    if img is None:
        raise ImageError(f"expected a readable image (PNG, JPEG, PPM, ...), got {str(p)!r} (cannot decode)")
    if img.ndim == 3:
        if img.shape[2] == 4:
            img = img[:, :, :3]
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    if not gray and img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    return np.ascontiguousarray(img)


def write_image(path: str | os.PathLike[str], image: np.ndarray) -> None:
    """Write an RGB (H×W×3) or gray (H×W) image atomically; float images are clipped to [0, 255]."""
    img = np.asarray(image)
    if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] not in (1, 3)):
        raise ImageError(f"expected an H×W or H×W×3 image, got shape {img.shape}")
    if img.dtype != np.uint8 and img.dtype != np.uint16:
        img = np.clip(np.nan_to_num(img, nan=0.0), 0, 255).round().astype(np.uint8)
    if img.ndim == 3 and img.shape[2] == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    suffix = Path(path).suffix or ".png"
    ok, buf = cv2.imencode(suffix, img)
    if not ok:
        raise ImageError(f"expected an image format OpenCV can write, got suffix {suffix!r}")
    with atomic_path(path) as tmp:
        tmp.write_bytes(buf.tobytes())
