"""Per-match confidence and the filters that turn the matcher's disparities into the points of a depth run.

The pipeline's ``refine`` and ``speckles`` steps are these plain functions on arrays:

- :func:`confident_matches` refines every cross-checked match to sub-pixel precision
  (:func:`~prismstereo.depth.refine.refine_disparity`) and gives it a confidence in [0, 1]: the zero-mean
  normalised cross-correlation of the two refined windows (negative values clipped to 0) where the
  refinement could confirm the match, 0 where it could not (window without texture or off a view, or the
  refinement moved it by a pixel or more: the matcher's value was off). Where the window is cut by the
  edge of a view, it is cut to the pixels both views have (``min_pixels`` of
  :func:`~prismstereo.depth.refine.refine_disparity`): near the edges of a small common view (a
  tri-prism's) that is a large share of it. Matches below ``min_confidence`` are dropped;
  ``min_confidence=None`` keeps them all with their confidence, for the user to filter.
- :func:`remove_speckles` drops connected patches of disparity smaller than a share of the matched region.
"""

from __future__ import annotations

import cv2
import numpy as np

from prismstereo.depth.refine import refine_disparity

__all__ = ["confident_matches", "remove_speckles"]


def confident_matches(left: np.ndarray, right: np.ndarray, disparity: np.ndarray, *, radius: int = 5,
                      iterations: int = 6, max_shift: float = 1.0, min_texture: float = 0.01,
                      min_confidence: float | None = None,
                      border_radius: int | None = 3, valid_left: np.ndarray | None = None,
                      valid_right: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Refine matches, rate them and keep the confident ones.

    Parameters
    ----------
    left, right : (H, W) or (H, W, 3) arrays
        The rectified pair.
    disparity : (H, W) float array
        The matcher's disparities of ``left``, px, NaN = no match.
    radius : int
        Half-size of the refinement window, px.
    iterations, max_shift : int, float
        The refinement's Gauss–Newton iterations and largest move from the matcher's value, px.
    min_texture : float
        Mean squared horizontal gradient (grey levels²/px²) a window needs to be refined.
    min_confidence : float or None
        Drop matches whose confidence is below this; None keeps every match.
    border_radius : int or None
        Where the ``radius`` window is cut by the edge of the image or of a view (rectified left, or right
        at the match), the window is cut to its pixels inside both and refined if it keeps at least as many
        as a full ``border_radius`` window, (2·border_radius + 1)²; None: such matches are not refined.
    valid_left, valid_right : (H, W) bool, optional
        Valid regions of the rectified views.

    Returns
    -------
    disparity : (H, W) float32
        Refined disparities (the matcher's value where the refinement could not confirm it), NaN where
        there is no match or it was dropped.
    confidence : (H, W) float32
        Confidence in [0, 1] of each remaining match, NaN where ``disparity`` is NaN.
    """
    min_pixels = None if border_radius is None else (2 * border_radius + 1) ** 2
    disp, zncc = refine_disparity(left, right, disparity, radius=radius, iterations=iterations,
                                  max_shift=max_shift, min_texture=min_texture,
                                  valid_left=valid_left, valid_right=valid_right, min_pixels=min_pixels)
    matched = np.isfinite(disp)
    conf = np.where(np.isfinite(zncc), np.clip(zncc, 0.0, 1.0), np.float32(0.0)).astype(np.float32)
    keep = matched if min_confidence is None else matched & (conf >= min_confidence)
    nan = np.float32(np.nan)
    return np.where(keep, disp, nan).astype(np.float32), np.where(keep, conf, nan).astype(np.float32)


def remove_speckles(disparity: np.ndarray, *, max_size: int) -> np.ndarray:
    """Drop connected patches of disparity (neighbours within 1 px) of at most ``max_size`` pixels.

    OpenCV ``filterSpeckles`` on the disparity in 1/16 px; a map too large for its 16-bit range is returned
    unchanged.

    Parameters
    ----------
    disparity : (H, W) float array
        Px, NaN = none.
    max_size : int
        Largest patch removed, pixels.

    Returns
    -------
    (H, W) float32
        ``disparity`` with the small patches set to NaN.
    """
    disp = np.asarray(disparity, dtype=np.float32)
    finite = np.isfinite(disp)
    if not finite.any() or float(np.nanmax(disp)) * 16 > 32000:
        return disp
    d16 = np.where(finite, np.rint(disp * 16.0), -16).astype(np.int16)
    cv2.filterSpeckles(d16, -16, int(max_size), 16)
    return np.where(d16 == -16, np.float32(np.nan), disp).astype(np.float32)

