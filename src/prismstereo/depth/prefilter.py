"""The JPEG block grid of a capture: how strongly it shows, and a deblocking filter for the matcher's input.

JPEG codes a capture in 8×8 blocks from the sensor's origin; at quality 85 a block's coarse quantisation leaves a
step at its border that repeats every 8 px in both views of the prism. A matcher then finds a second, false
minimum wherever the two views' blocks line up. :func:`block_grid` measures the steps (the mean absolute
difference across block borders against the one between the pixels inside a block) and :func:`deblock` smooths
each border where the step is small (a compression step, not a texture edge): the in-loop filter of H.264 in
its weak form, run once across the columns' borders and once across the rows'.
"""

from __future__ import annotations

import numpy as np

__all__ = ["block_grid", "deblock"]


def _steps(a: np.ndarray) -> tuple[float, float]:
    """Mean |difference| between horizontal neighbours across the 8-px block borders, and between all other
    horizontal neighbours, of ``a`` (H, W, C) float32."""
    d = np.abs(np.diff(a, axis=1))  # d[:, x] between x and x + 1
    w = d.shape[1]
    border = np.zeros(w, dtype=bool)
    border[7::8] = True
    return float(d[:, border].mean()), float(d[:, ~border].mean())


def block_grid(image: np.ndarray) -> float:
    """How much larger the steps across the 8×8 block borders of ``image`` are than the steps inside the
    blocks, both directions together.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array
        The capture in sensor pixels (the grid starts at its origin), 0..255.

    Returns
    -------
    float
        (mean |step| across borders) / (mean |step| inside blocks) − 1: ≈ 0 on a capture that was never
        block-coded; NaN for an image smaller than 16×16 or one without any step.
    """
    a = np.asarray(image, dtype=np.float32)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.shape[0] < 16 or a.shape[1] < 16:
        return float("nan")
    bx, ix = _steps(a)
    by, iy = _steps(np.swapaxes(a, 0, 1))
    inside = ix + iy
    if not inside > 0.0:
        return float("nan")
    return float((bx + by) / inside - 1.0)


def _deblock_columns(a: np.ndarray, *, alpha: float, beta: float, tc: float) -> np.ndarray:
    """The weak filter across every vertical block border of ``a`` (H, W, C) float32 (a copy)."""
    out = a.copy()
    w = a.shape[1]
    q = np.arange(8, w - 1, 8)
    q = q[q >= 2]
    p0, p1, q0, q1 = a[:, q - 1], a[:, q - 2], a[:, q], a[:, q + 1]
    # a texture edge has a large step or a large slope beside it: left as it is
    smooth = (np.abs(p0 - q0) < alpha) & (np.abs(p1 - p0) < beta) & (np.abs(q1 - q0) < beta)
    delta = np.clip(((q0 - p0) * 4.0 - (q1 - p1)) / 8.0, -tc, tc) * smooth
    out[:, q - 1] = p0 + delta
    out[:, q] = q0 - delta
    return out


def deblock(image: np.ndarray, *, alpha: float = 12.0, beta: float = 4.0, tc: float = 2.0) -> np.ndarray:
    """``image`` with the steps across its 8×8 block borders smoothed where they are small.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array
        The capture in sensor pixels, 0..255.
    alpha : float
        Largest step across a border (grey levels) that is filtered; larger steps are texture edges.
    beta : float
        Largest step beside the border, on either side, for the border to be filtered.
    tc : float
        Largest change of a pixel (grey levels).

    Returns
    -------
    ndarray, float32, the shape of ``image``
    """
    a = np.asarray(image, dtype=np.float32)
    flat = a.ndim == 2
    if flat:
        a = a[:, :, None]
    kw = dict(alpha=float(alpha), beta=float(beta), tc=float(tc))
    a = _deblock_columns(a, **kw)
    a = np.swapaxes(_deblock_columns(np.ascontiguousarray(np.swapaxes(a, 0, 1)), **kw), 0, 1)
    a = np.ascontiguousarray(a)
    return a[:, :, 0] if flat else a
