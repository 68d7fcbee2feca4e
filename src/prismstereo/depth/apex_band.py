"""The apex band in a depth run: where the lens aperture sees through two faces, the views mix.

A pixel whose beam (the lens aperture's cone, :mod:`prismstereo.optics.lens`) meets the prism across an
edge between two faces collects light through both: its colour is a blend of two views and is neither.
When the rig's camera gives its ``f_number`` and ``focus_distance`` (docs/rig.md), those pixels are left out
of the search region (rectified left view) and no match may land on them in the rectified right view;
the self-calibration leaves them out of its features the same way
(:func:`prismstereo.calibration.from_scene.match_faces`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from prismstereo.config import Rig
from prismstereo.optics.lens import apex_band_mask, apex_band_width_px
from prismstereo.rectify.rectification import RectifiedPair

__all__ = ["apex_band_info", "apex_band_real", "apex_band_views"]


def apex_band_real(rig: Rig) -> np.ndarray | None:
    """(H, W) bool mask of the real pixels in the apex band, None when the camera has no lens data."""
    cam = rig.camera
    if cam.f_number is None or cam.focus_distance is None:
        return None
    return apex_band_mask(rig, f_number=cam.f_number, focus_distance=cam.focus_distance)


def apex_band_views(rig: Rig, pair: RectifiedPair) -> tuple[np.ndarray, np.ndarray] | None:
    """The apex band in the rectified left and right views ((h, w) bool each: a pixel whose bilinear
    sample touches a band pixel), None when the camera has no lens data."""
    band = apex_band_real(rig)
    if band is None:
        return None
    left, right = pair.rectify_images(band.astype(np.float32))
    return np.asarray(left) > 0.0, np.asarray(right) > 0.0


def apex_band_info(rig: Rig) -> dict[str, Any] | None:
    """What ``run.json`` records: the lens and the band's modelled width, px; None without lens data."""
    cam = rig.camera
    if cam.f_number is None or cam.focus_distance is None:
        return None
    width = apex_band_width_px(rig, f_number=cam.f_number, focus_distance=cam.focus_distance)
    return {"f_number": float(cam.f_number), "focus_distance_mm": float(cam.focus_distance),
            "width_px": round(float(width), 2)}
