"""Disparity error metrics (Middlebury v2 protocol, thesis Eq. 5.16)."""

from __future__ import annotations

import numpy as np

from prismstereo.errors import ImageError

__all__ = ["bad_pixel_rate", "mean_abs_error"]


def _prep(disp: np.ndarray, gt: np.ndarray, mask: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    d = np.asarray(disp, dtype=np.float64)
    g = np.asarray(gt, dtype=np.float64)
    if d.shape != g.shape:
        raise ImageError(f"expected a disparity map of the ground truth's shape {g.shape}, got {d.shape}")
    m = np.isfinite(g) if mask is None else (np.asarray(mask, dtype=bool) & np.isfinite(g))
    if m.shape != g.shape:
        raise ImageError(f"expected a mask of shape {g.shape}, got {m.shape}")
    return d[m], g[m]


def bad_pixel_rate(disp: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None, *,
                   threshold: float = 1.0) -> float:
    """Percentage of bad pixels ``|d - d_gt| > threshold`` over ``mask`` (thesis Eq. 5.16).

    NaN (invalid) estimates count as bad; pixels of unknown ground truth (NaN) are excluded.
    Returns a percentage in [0, 100] (NaN for an empty mask).
    """
    d, g = _prep(disp, gt, mask)
    if g.size == 0:
        return float("nan")
    err = np.abs(d - g)
    bad = ~(err <= threshold)  # NaN -> bad
    return float(100.0 * bad.mean())


def mean_abs_error(disp: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Mean ``|d - d_gt|`` in pixels over ``mask`` and the finite estimates."""
    d, g = _prep(disp, gt, mask)
    ok = np.isfinite(d)
    if not ok.any():
        return float("nan")
    return float(np.abs(d[ok] - g[ok]).mean())
