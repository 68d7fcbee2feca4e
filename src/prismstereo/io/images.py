"""Image reading and writing. RGB order at the API; OpenCV's BGR is converted here, at the edge."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from prismstereo.errors import ImageError
from prismstereo.io.atomic import atomic_path
from prismstereo.io.memory import check_fits_in_memory

__all__ = ["as_image", "image_size", "read_image", "to_gray", "write_image"]


#: luminance weights of ITU-R BT.601 (R, G, B), those of OpenCV's ``COLOR_RGB2GRAY``
GRAY_WEIGHTS = (0.299, 0.587, 0.114)


def as_image(image: object, *, name: str = "image", dtype: type = np.uint8, channels: int | None = None,
             unit: bool | None = None) -> np.ndarray:
    """The one rule by which every function turns an input image into what it computes on (docs/conventions.md).

    Accepted: H×W, H×W×1, H×W×3 (RGB) or H×W×4 (RGBA, alpha dropped) arrays of ``uint8`` (the 0..255 scale
    everything is tuned for, kept as it is), ``uint16`` (divided by 257: 65535 → 255), other integers
    (0..255 scale) or finite floats: 0..255 scale, except that a float image whose values all lie in
    [0, 1] (scikit-image's convention) is multiplied by 255.

    Parameters
    ----------
    image : array-like
    name : str
        What the image is, for the error message (``"left"``, ``"capture"``).
    dtype : np.uint8 or np.float32
        ``uint8``: rounded to the nearest integer and clipped to 0..255; ``float32``: the scaled values
        (a uint8 image converted exactly).
    channels : 1, 3 or None
        1: an H×W gray image (:func:`to_gray`); 3: H×W×3 (a gray image repeated); None: as given
        (H×W or H×W×3).
    unit : bool or None
        Whether a float image is on the [0, 1] scale; None: decided from its values. A pair decides once
        for both images.

    Raises
    ------
    ImageError
        Another shape or dtype (bool, complex, object), an empty image, NaN or infinite values.
    """
    arr = np.asarray(image)
    if arr.ndim == 3 and arr.shape[2] in (1, 4):
        arr = arr[:, :, :1] if arr.shape[2] == 1 else arr[:, :, :3]
        arr = arr[:, :, 0] if arr.shape[2] == 1 else arr
    if arr.ndim not in (2, 3) or (arr.ndim == 3 and arr.shape[2] != 3):
        raise ImageError(f"expected {name} as an H×W or H×W×3 image, got shape {arr.shape}")
    if arr.shape[0] < 1 or arr.shape[1] < 1:
        raise ImageError(f"expected a non-empty {name} image, got shape {arr.shape}")
    if arr.dtype.kind not in "uif":
        raise ImageError(f"expected {name} of dtype uint8, uint16 or float, got {arr.dtype}")
    if arr.dtype != np.uint8:
        if arr.dtype == np.uint16:
            f = arr.astype(np.float32) / np.float32(257.0)
        else:
            f = arr.astype(np.float32)
            if arr.dtype.kind == "f":
                if not np.isfinite(f).all():
                    raise ImageError(f"expected a finite {name} image, got NaN or inf values")
                if unit is None:
                    unit = float(f.max()) <= 1.0
                if unit:
                    f = f * np.float32(255.0)
        arr = f
    if channels == 1 and arr.ndim == 3:
        arr = to_gray(arr)
    elif channels == 3 and arr.ndim == 2:
        arr = np.repeat(arr[:, :, None], 3, axis=2)
    if dtype is np.uint8:
        if arr.dtype != np.uint8:
            arr = np.clip(np.rint(arr), 0, 255).astype(np.uint8)
    elif dtype is np.float32:
        arr = arr.astype(np.float32)
    else:
        raise ValueError(f"dtype: expected np.uint8 or np.float32, got {dtype!r}")
    return np.ascontiguousarray(arr)


def to_gray(image: np.ndarray) -> np.ndarray:
    """Luminance (ITU-R BT.601 weights, :data:`GRAY_WEIGHTS`) of an H×W×3 RGB image as float32 H×W, on the
    image's own scale; an H×W (or H×W×1) image is returned as float32. Coerce first (:func:`as_image`)."""
    img = np.ascontiguousarray(image, dtype=np.float32)
    if img.ndim == 3:
        if img.shape[2] == 1:
            return np.ascontiguousarray(img[:, :, 0])
        r, g, b = GRAY_WEIGHTS
        return np.ascontiguousarray(img[:, :, 0] * r + img[:, :, 1] * g + img[:, :, 2] * b)
    return img


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_CHANNELS = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}
#: decoded bytes of an image times this must fit in the memory available (decode, colour conversion,
#: the float copies of the first processing step)
_MEMORY_FACTOR = 8


def _png_header(data: bytes, shown: str) -> tuple[int, int, int]:
    """(width, height, decoded bytes) of a PNG, after checking that every chunk is complete and intact.

    Walking the chunks (lengths and CRCs, no decompression) finds truncated or damaged files before the
    decoder does, so libpng never prints its own messages.
    """
    import zlib

    if len(data) < 33 or data[12:16] != b"IHDR":
        raise ImageError(f"expected a PNG image, got {shown!r} (no PNG header: damaged file)")
    pos, seen_end = 8, False
    while pos + 8 <= len(data):
        length = int.from_bytes(data[pos:pos + 4], "big")
        kind = data[pos + 4:pos + 8]
        end = pos + 12 + length
        if end > len(data):
            raise ImageError(f"expected a complete PNG image, got {shown!r} (truncated in its "
                             f"{kind.decode('latin-1')!r} chunk)")
        crc = int.from_bytes(data[end - 4:end], "big")
        if zlib.crc32(data[pos + 4:end - 4]) & 0xFFFFFFFF != crc:
            raise ImageError(f"expected an intact PNG image, got {shown!r} (damaged {kind.decode('latin-1')!r} "
                             "chunk: checksum mismatch)")
        pos = end
        if kind == b"IEND":
            seen_end = True
            break
    if not seen_end:
        raise ImageError(f"expected a complete PNG image, got {shown!r} (truncated: no end chunk)")
    w = int.from_bytes(data[16:20], "big")
    h = int.from_bytes(data[20:24], "big")
    depth, ctype = data[24], data[25]
    channels = _PNG_CHANNELS.get(ctype, 4)
    return w, h, w * h * max(channels, 3) * (2 if depth == 16 else 1)


def _jpeg_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) from a JPEG's start-of-frame marker, or None if not found."""
    pos = 2
    while pos + 9 < len(data):
        if data[pos] != 0xFF:
            return None
        marker = data[pos + 1]
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:
            pos += 2
            continue
        length = int.from_bytes(data[pos + 2:pos + 4], "big")
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            h = int.from_bytes(data[pos + 5:pos + 7], "big")
            w = int.from_bytes(data[pos + 7:pos + 9], "big")
            return w, h
        pos += 2 + length
    return None


def image_size(path: str | os.PathLike[str]) -> tuple[int, int] | None:
    """(width, height) of a PNG or JPEG file from its header (no decoding), or None for other formats.

    Raises
    ------
    ImageError
        If the file is missing, empty, or a truncated or damaged PNG.
    """
    p = Path(path)
    data = _read_bytes(p)
    if data[:8] == _PNG_SIGNATURE:
        w, h, _ = _png_header(data, str(p))
        return w, h
    if data[:2] == b"\xff\xd8":
        return _jpeg_size(data)
    return None


def _read_bytes(p: Path) -> bytes:
    if not p.is_file():
        raise ImageError(f"expected an image file, got {str(p)!r} (no such file)")
    if p.stat().st_size == 0:
        raise ImageError(f"expected an image file, got {str(p)!r} (empty file)")
    try:
        return p.read_bytes()
    except OSError as exc:
        raise ImageError(f"expected a readable image file, got {str(p)!r} ({exc.strerror})") from None


@contextlib.contextmanager
def _decoder_messages_silenced() -> Iterator[None]:
    """Keep libpng/libjpeg from printing to the process's stderr (the failure becomes an ImageError)."""
    try:
        saved = os.dup(2)
    except OSError:  # no stderr to protect
        yield
        return
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def read_image(path: str | os.PathLike[str], *, gray: bool = False,
               expected_size: tuple[int, int] | None = None, what: str = "image") -> np.ndarray:
    """Read an 8- or 16-bit image file as RGB (H×W×3) or gray (H×W) ``uint8``/``uint16``.

    The header is read first: a PNG is checked to be complete and intact, and its size (PNG, JPEG) is
    compared with ``expected_size`` (width, height) and with the memory available before anything is
    decoded.

    Raises
    ------
    ImageError
        If the file does not exist, is empty, truncated, damaged, of the wrong size, too large for the
        memory, or cannot be decoded.
    """

    p = Path(path)
    raw = _read_bytes(p)
    size: tuple[int, int] | None = None
    decoded = None
    if raw[:8] == _PNG_SIGNATURE:
        w, h, decoded = _png_header(raw, str(p))
        size = (w, h)
    elif raw[:2] == b"\xff\xd8":
        size = _jpeg_size(raw)
        decoded = None if size is None else size[0] * size[1] * 3
    if size is not None and expected_size is not None and tuple(size) != tuple(expected_size):
        ew, eh = expected_size
        raise ImageError(f"expected a {ew}×{eh} {what}, got {size[0]}×{size[1]} ({str(p)!r})")
    if size is not None and decoded is not None:
        check_fits_in_memory(decoded * _MEMORY_FACTOR, what=f"the {size[0]}×{size[1]} image {str(p)!r}",
                             hint="use a smaller image", error=ImageError)
    data = np.frombuffer(raw, dtype=np.uint8)
    flags = cv2.IMREAD_GRAYSCALE if gray else cv2.IMREAD_UNCHANGED
    with _decoder_messages_silenced():
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
