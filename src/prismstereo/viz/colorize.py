"""Colourised disparity and depth maps (uint8 RGB), invalid pixels black."""

from __future__ import annotations

import cv2
import numpy as np

from prismstereo.errors import ImageError

__all__ = ["colorbar", "colorize_depth", "colorize_disparity", "with_colorbar"]


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


def _limits(values: np.ndarray, vmin: float | None, vmax: float | None) -> tuple[float, float]:
    v = np.asarray(values, dtype=np.float64)
    finite = np.isfinite(v)
    lo = float(vmin) if vmin is not None else (float(v[finite].min()) if finite.any() else 0.0)
    hi = float(vmax) if vmax is not None else (float(v[finite].max()) if finite.any() else 1.0)
    return lo, hi


def with_colorbar(rgb: np.ndarray, *, vmin: float, vmax: float, label: str, colormap: int = cv2.COLORMAP_TURBO,
                  invert: bool = False) -> np.ndarray:
    """``rgb`` (H×W×3 uint8) with a labelled colour bar appended on its right (white panel).

    The bar runs from ``vmax`` (top) to ``vmin`` (bottom) with three value ticks; ``label`` names the
    quantity and its unit, e.g. ``"disparity (px)"``.
    """
    h = rgb.shape[0]
    scale = float(np.clip(h / 600.0, 0.3, 0.6))
    thick = 1
    (tw, th), _ = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)
    bar_h = max(h - 2 * (th + 8), 8)
    bar_w = max(8, int(round(16 * scale / 0.4)))
    ticks = [vmax, (vmin + vmax) / 2.0, vmin]
    texts = [f"{t:.4g}" for t in ticks]
    tick_w = max(cv2.getTextSize(t, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)[0][0] for t in texts)
    panel_w = max(bar_w + 8 + tick_w + 6, tw + 8)
    panel = np.full((h, panel_w, 3), 255, np.uint8)
    top = th + 8
    bar = colorbar(vmin=vmin, vmax=vmax, height=bar_h, width=bar_w, colormap=colormap, invert=invert)
    panel[top:top + bar_h, 4:4 + bar_w] = bar
    cv2.putText(panel, label, (4, th + 3), cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), thick, cv2.LINE_AA)
    for frac, text in zip((0.0, 0.5, 1.0), texts, strict=True):
        y = int(round(top + frac * (bar_h - 1)))
        cv2.line(panel, (4 + bar_w, y), (4 + bar_w + 4, y), (0, 0, 0), 1)
        cv2.putText(panel, text, (4 + bar_w + 7, min(h - 2, y + th // 2)), cv2.FONT_HERSHEY_SIMPLEX, scale,
                    (0, 0, 0), thick, cv2.LINE_AA)
    return np.concatenate([rgb, panel], axis=1)


def colorize_disparity(disp: np.ndarray, *, vmin: float | None = None, vmax: float | None = None,
                       colormap: int = cv2.COLORMAP_TURBO, colorbar: str | None = None) -> np.ndarray:
    """Disparity (H×W, px, NaN invalid) to uint8 RGB H×W×3: near (large d) red, far blue, NaN black.

    ``vmin``/``vmax`` default to the finite range of ``disp``. With ``colorbar`` (a label such as
    ``"disparity (px)"``) a labelled colour bar is appended on the right (the image gets wider).
    """
    rgb = _colorize(disp, vmin, vmax, colormap, invert=False)
    if colorbar is None:
        return rgb
    lo, hi = _limits(disp, vmin, vmax)
    return with_colorbar(rgb, vmin=lo, vmax=hi, label=colorbar, colormap=colormap)


def colorize_depth(depth: np.ndarray, *, vmin: float | None = None, vmax: float | None = None,
                   colormap: int = cv2.COLORMAP_TURBO, colorbar: str | None = None) -> np.ndarray:
    """Depth (H×W, e.g. mm, NaN/inf invalid) to uint8 RGB H×W×3: near red, far blue, invalid black.

    With ``colorbar`` (a label such as ``"depth Z (mm)"``) a labelled colour bar is appended on the right.
    """
    rgb = _colorize(depth, vmin, vmax, colormap, invert=True)
    if colorbar is None:
        return rgb
    lo, hi = _limits(np.where(np.isfinite(depth), depth, np.nan), vmin, vmax)
    return with_colorbar(rgb, vmin=lo, vmax=hi, label=colorbar, colormap=colormap, invert=True)


def colorbar(*, vmin: float, vmax: float, height: int = 256, width: int = 24,
             colormap: int = cv2.COLORMAP_TURBO, invert: bool = False) -> np.ndarray:
    """Vertical colour bar (uint8 RGB, ``height×width×3``), ``vmax`` at the top, matching the maps."""
    col = np.linspace(vmax, vmin, height)[:, None] * np.ones((1, width))
    return _colorize(col, vmin, vmax, colormap, invert)
