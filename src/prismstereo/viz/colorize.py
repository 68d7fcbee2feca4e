"""Colourised disparity and depth maps (uint8 RGB), invalid pixels black."""

from __future__ import annotations

import cv2
import numpy as np

from prismstereo.errors import ImageError

__all__ = ["colorize_depth", "colorize_disparity", "colorbar"]


def _colorize(values: np.ndarray, vmin: float | None, vmax: float | None, colormap: int,
              invert: bool) -> np.ndarray:
    v = np.asarray(values, dtype=np.float64)
    if v.ndim != 2:
        raise ImageError(f"expected an H×W map, got shape {v.shape}")
    finite = np.isfinite(v)
    lo = float(vmin) if vmin is not None else (float(v[finite].min()) if finite.any() else 0.0)
    hi = float(vmax) if vmax is not None else (float(v[finite].max()) if finite.any() else 1.0)
    span = hi - lo if hi > lo else 1.0
    t = np.clip((np.where(finite, v, lo) - lo) / span, 0.0, 1.0)
    if invert:
        t = 1.0 - t
    u8 = np.rint(t * 255.0).astype(np.uint8)
    bgr = cv2.applyColorMap(u8, colormap)
    rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    rgb[~finite] = 0
    return rgb


def colorize_disparity(disp: np.ndarray, *, vmin: float | None = None, vmax: float | None = None,
                       colormap: int = cv2.COLORMAP_TURBO) -> np.ndarray:
    """Disparity (H×W, px, NaN invalid) to uint8 RGB H×W×3: near (large d) red, far blue, NaN black.

    ``vmin``/``vmax`` default to the finite range of ``disp``.
    """
    return _colorize(disp, vmin, vmax, colormap, invert=False)


def colorize_depth(depth: np.ndarray, *, vmin: float | None = None, vmax: float | None = None,
                   colormap: int = cv2.COLORMAP_TURBO) -> np.ndarray:
    """Depth (H×W, e.g. mm, NaN/inf invalid) to uint8 RGB H×W×3: near red, far blue, invalid black."""
    return _colorize(depth, vmin, vmax, colormap, invert=True)


def colorbar(*, vmin: float, vmax: float, height: int = 256, width: int = 24,
             colormap: int = cv2.COLORMAP_TURBO, invert: bool = False) -> np.ndarray:
    """Vertical colour bar (uint8 RGB, ``height×width×3``), ``vmax`` at the top, matching the maps."""
    col = np.linspace(vmax, vmin, height)[:, None] * np.ones((1, width))
    return _colorize(col, vmin, vmax, colormap, invert)
