"""Captures without pixel-scale content: what a real camera's processing leaves, and the refinement for it.

A real capture is demosaiced (a Bayer mosaic records one colour per pixel) and usually JPEG-compressed; both
remove the image's finest scale, the sensor noise with it, and a lens adds defocus. The refinement's
defaults were chosen on renders that keep that scale (every pixel recording RGB, lossless): there an 11×11
window with a high ZNCC has a precise sub-pixel value. Without the finest scale the same window reaches the
same ZNCC on texture that pins its value less, and the wider window is the precise one.

:func:`pixel_noise` measures the grey levels of pixel-scale variation the capture shows (Immerkær's
estimator, the median form: texture edges do not raise it); below ``DepthConfig.refine_smoothed_below``
:func:`smoothed_config` gives the refinement its smoothed-capture profile: the wider window for every
match whose small window stayed below a ZNCC of 0.99 instead of 0.95 (its value taken where it is
confirmed), a third, 33-px window for the kept matches still below 0.95 (its value where it is
confirmed with a higher ZNCC; ``DepthConfig.refine_third_radius``), and the dense map's values filled where
the two windows agree within 1 px instead of 0.5.
"""

from __future__ import annotations

import dataclasses
import logging
from typing import TYPE_CHECKING

import cv2
import numpy as np

if TYPE_CHECKING:
    from prismstereo.depth.pipeline import DepthConfig

__all__ = ["pixel_noise", "smoothed_config"]

log = logging.getLogger(__name__)

# Immerkær's kernel: the difference of two Laplacians, blind to linear intensity ramps
_KERNEL = np.array([[1.0, -2.0, 1.0], [-2.0, 4.0, -2.0], [1.0, -2.0, 1.0]], dtype=np.float32)


def pixel_noise(image: np.ndarray) -> float:
    """Pixel-scale variation of a capture, grey levels: the median absolute response of Immerkær's
    noise kernel (sum of squared weights 36) over the grey image, as the standard deviation of white noise
    that would give it.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array
        The capture, 0..255.

    Returns
    -------
    float
        White noise of σ s reads ≈ s; a demosaiced or JPEG-compressed capture reads ≈ 0.25 (the 8-bit
        rounding), whatever noise its sensor had. NaN for an image smaller than 3×3.
    """
    a: np.ndarray = np.asarray(image, dtype=np.float32)
    if a.ndim == 3:
        a = np.asarray(cv2.cvtColor(a, cv2.COLOR_RGB2GRAY), dtype=np.float32)
    if a.shape[0] < 3 or a.shape[1] < 3:
        return float("nan")
    r = cv2.filter2D(a, -1, _KERNEL, borderType=cv2.BORDER_REPLICATE)[1:-1, 1:-1]
    # median of |N(0, 6 s)| is 0.6745 · 6 s
    return float(np.median(np.abs(r)) / (0.6745 * 6.0))


def smoothed_config(config: DepthConfig, image: np.ndarray) -> DepthConfig:
    """``config`` with the smoothed-capture refinement profile where ``image``'s :func:`pixel_noise` is
    below ``config.refine_smoothed_below``; ``config`` itself otherwise (or when that is None, or the
    refinement or its second window is off).

    The profile: ``refine_retry_below`` raised to ``refine_smoothed_retry_below`` (every match whose small
    window stayed below that ZNCC gets the wider window), and ``refine_fill_agree`` =
    ``refine_smoothed_fill_agree`` (the dense map's values where the two windows agree that well; only
    where the configuration fills with an agreement, not with ``refine_fill``), and the growth's
    ``refine_grow_fit``, ``refine_grow_agree`` and ``refine_grow_spread`` replaced by the
    ``refine_smoothed_grow_*`` ones that are not None, ``refine_third_radius`` =
    ``refine_smoothed_third_radius`` where that is not None, and the plane interpolation (``refine_interp_sigma``)
    off unless ``refine_smoothed_interp``."""
    below = config.refine_smoothed_below
    if below is None or not config.refine or config.refine_retry_radius is None \
            or config.refine_retry_radius == config.refine_radius:
        return config
    noise = pixel_noise(image)
    if not noise < below:
        return config
    fill_agree = config.refine_fill_agree
    if fill_agree is not None and config.refine_smoothed_fill_agree is not None:
        fill_agree = float(config.refine_smoothed_fill_agree)
    retry_below = max(float(config.refine_retry_below), float(config.refine_smoothed_retry_below))
    log.info("depth: pixel-scale noise %.2f grey levels < %.2f (a compressed / demosaiced capture): the %d-px "
             "window for every match below ZNCC %.2f", noise, below, 2 * config.refine_retry_radius + 1, retry_below)
    fit = config.refine_grow_fit if config.refine_smoothed_grow_fit is None else config.refine_smoothed_grow_fit
    agree = config.refine_grow_agree if config.refine_smoothed_grow_agree is None else \
        float(config.refine_smoothed_grow_agree)
    spread = config.refine_grow_spread if config.refine_smoothed_grow_spread is None else \
        float(config.refine_smoothed_grow_spread)
    # the plane interpolation's values on a smoothed capture cost the median more than the coverage they add
    interp = config.refine_interp_sigma if config.refine_smoothed_interp else None
    # the blurred weak texture pins a weak match's value only over more pixels: a third, wider window
    third = config.refine_third_radius if config.refine_smoothed_third_radius is None else \
        int(config.refine_smoothed_third_radius)
    return dataclasses.replace(config, refine_retry_below=retry_below, refine_fill_agree=fill_agree,
                               refine_third_radius=third,
                               refine_smoothed_below=None, refine_grow_fit=fit, refine_grow_agree=agree,
                               refine_grow_spread=spread, refine_interp_sigma=interp)
