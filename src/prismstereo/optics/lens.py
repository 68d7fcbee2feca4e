"""A thin lens in front of the prism: its aperture, and the apex band where one pixel sees two faces.

A thin lens of focal length f (mm) at f-number N has an entrance pupil of diameter D = f / N at the optical
centre (z = 0). Focused at distance F, the pixel whose chief ray (through the lens centre) has normalised
direction (x, y, 1) collects the rays from every aperture point a = (a_x, a_y, 0), |a| ≤ D/2, toward its
in-focus point P = F · (x, y, 1); at depth z such a ray is at ``a·(1 − z/F) + P·z/F``, so the pixel's beam
is a disc of radius (D/2)·|1 − z/F| around its chief ray. Where that disc at the prism (z ≈ apex distance
a) straddles an edge between two faces, part of the pixel's light comes through each face: the two views
mix in a band around the edge's image (the apex line of a bi-prism) whose width is

    w = f_px · D · |1/a − 1/F|   px

(half-width f_px·(D/2)·|1 − a/F| / a on each side). The thesis bi-prism (f = 25 mm, 4.65 µm pixels, so
f_px ≈ 5376, apex 210 mm) at f/8 focused at 1.4 m: w = 5376 · 3.125 · (1/210 − 1/1400) ≈ 68 px.
"""

from __future__ import annotations

import math

import numpy as np

from prismstereo.config import Rig
from prismstereo.errors import ConfigError
from prismstereo.optics.prism import rays_from_pixels

__all__ = ["aperture_diameter", "aperture_points", "apex_band_mask", "apex_band_width_px"]

_GOLDEN = math.pi * (3.0 - math.sqrt(5.0))


def _check(f_number: float, focus_distance: float) -> None:
    for key, v in (("f_number", f_number), ("focus_distance", focus_distance)):
        if isinstance(v, bool) or not isinstance(v, int | float | np.floating) or not math.isfinite(v) or v <= 0:
            raise ConfigError(f"{key}: expected a positive number, got {v!r}")


def aperture_diameter(rig: Rig, *, f_number: float) -> float:
    """Entrance pupil diameter D = f / N, mm (f the camera's focal length in mm).

    Raises
    ------
    ConfigError
        If the f-number is not positive, or the rig's camera has no focal length in mm (give
        ``focal_length``, or ``pixel_size`` with ``fx``/``fy``).
    """
    _check(f_number, 1.0)
    cam = rig.camera
    if cam.focal_length is not None:
        f_mm = float(cam.focal_length)
    elif cam.pixel_size is not None:
        f_mm = cam.focal_px * float(cam.pixel_size)
    else:
        raise ConfigError("[camera]: a thin lens needs the focal length in mm; give focal_length, or pixel_size "
                          "with fx and fy")
    return f_mm / float(f_number)


def aperture_points(n: int, diameter: float) -> np.ndarray:
    """(n, 2) points (x, y) spread evenly over a disc of ``diameter`` mm (Vogel's golden-angle spiral:
    point k at radius (D/2)·√((k + ½)/n), angle k·137.5°), each standing for an equal share of its area."""
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
        raise ConfigError(f"samples: expected a positive integer, got {n!r}")
    k = np.arange(int(n), dtype=np.float64)
    r = 0.5 * float(diameter) * np.sqrt((k + 0.5) / n)
    return np.stack([r * np.cos(k * _GOLDEN), r * np.sin(k * _GOLDEN)], axis=1)


def apex_band_width_px(rig: Rig, *, f_number: float, focus_distance: float) -> float:
    """Width in px of the band around the image of each prism edge (the apex line) where a pixel's beam
    meets two faces: ``f_px · D · |1/a − 1/F|`` with D = f/N, a the apex distance, F the focus distance (mm).

    Parameters
    ----------
    rig : Rig
    f_number : float
        N (> 0).
    focus_distance : float
        F, mm from the optical centre along the axis (> 0).

    Returns
    -------
    float, px (0 when the lens is focused on the apex).
    """
    _check(f_number, focus_distance)
    a = rig.prism.apex_distance
    return float(rig.camera.focal_px * aperture_diameter(rig, f_number=f_number)
                 * abs(1.0 / a - 1.0 / float(focus_distance)))


def apex_band_mask(rig: Rig, *, f_number: float, focus_distance: float) -> np.ndarray:
    """(H, W) bool: pixels whose beam at the apex plane (a disc of radius (D/2)·|1 − a/F| around the chief
    ray's point) reaches an edge between two faces, i.e. whose colour mixes two views.

    The edges are the half-lines from the apex (moved by the prism's ``decenter``) between neighbouring faces,
    at angles rotation + 360°·(k + ½)/N in the plane z = a; the prism's tilt is neglected here. Lens
    distortion is taken into account through each pixel's chief ray.
    """
    _check(f_number, focus_distance)
    cam, prism = rig.camera, rig.prism
    a = prism.apex_distance
    radius = 0.5 * aperture_diameter(rig, f_number=f_number) * abs(1.0 - a / float(focus_distance))
    vv, uu = np.mgrid[0:cam.height, 0:cam.width].astype(np.float64)
    d = rays_from_pixels(np.stack([uu, vv], axis=-1), cam.K, cam.distortion if cam.has_distortion else None)
    with np.errstate(divide="ignore", invalid="ignore"):
        qx = d[..., 0] / d[..., 2] * a - prism.decenter[0]
        qy = d[..., 1] / d[..., 2] * a - prism.decenter[1]
    dist = np.full(qx.shape, np.inf)
    n = prism.faces
    for k in range(n):
        phi = math.radians(prism.rotation + 360.0 * (k + 0.5) / n)
        bx, by = math.cos(phi), math.sin(phi)
        along = qx * bx + qy * by
        across = np.abs(qx * by - qy * bx)
        dist = np.minimum(dist, np.where(along >= 0, across, np.hypot(qx, qy)))
    return np.asarray(dist <= radius)
