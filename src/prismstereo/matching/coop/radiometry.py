"""Radiometric compensation of the right view for ``coop``'s colour costs (an addition to thesis §5.2).

``coop``'s pixel cost adds a truncated colour difference (AD) to the census distance (Mei et al. 2011). AD
assumes both views record a surface with the same intensities; a different exposure of one view (Middlebury
2014 ``MotorcycleE``), a different light (``ArtL``, ``PianoL``) or, through a prism, a different glass path and
vignetting per face break that, and AD then prefers wrong disparities whose colours happen to agree. Census
(a rank order) is unaffected by any monotone change of intensity.

The compensation uses census alone to find correspondences: census Hamming costs on the pair reduced by
``scale`` (area average), box-aggregated, winner-take-all, cross-checked and unique. At those matched pixels
(the same surface points in both views) each colour channel's transfer from the right view to the left is
estimated as the monotone quantile map of the right samples onto the left samples, and applied to the full
right view by a 256-entry table. Without a radiometric difference the table is near the identity; it is applied
only when it lowers the median colour difference of the matched pixels by at least ``min_gain`` grey levels,
or (``min_offset`` > 0, off by default) when the matched pixels show a systematic brightness offset (median
signed difference of at least ``min_offset`` levels) that the table reduces; otherwise the right view is
returned unchanged, bit for bit.
The offset matters on weak texture: on a wall whose intensity varies by a level or two over many pixels, an
offset of 1-2 levels between the views moves the minimum of any colour-difference cost to a wrong disparity
where the slope of the wall's shading cancels it, while the median absolute difference, dominated by noise and
texture, hardly changes. The offset trigger is off by default because the same offsets occur on scenes where
removing them changes coop's maps for the worse as often as for the better (docs/EXPERIMENTS.md, issue 27,
branch h-mb27).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from prismstereo.errors import ConfigError
from prismstereo.matching.local.costs import cost_census

log = logging.getLogger(__name__)

__all__ = ["RadiometryParams", "compensate_right"]

U8 = npt.NDArray[np.uint8]


@dataclass(frozen=True, kw_only=True)
class RadiometryParams:
    """Parameters of :func:`compensate_right`.

    Attributes
    ----------
    enabled : bool
        False: the right view is used as given.
    scale : int
        Reduction factor of the census matching (>= 1); the transfer is a function of intensity, so coarse
        matches of smooth colours suffice.
    radius : int
        Box radius of the census cost aggregation at the reduced scale.
    uniqueness : float
        A match counts when its aggregated cost is below ``(1 - uniqueness)`` times the second best's outside
        a 1-level neighbourhood.
    min_samples : int
        Fewest matched pixels to estimate the transfer from.
    min_gain : float
        Grey levels by which the median colour difference of the matched pixels must drop for the table to be
        applied.
    min_offset : float
        The table is applied too when the magnitude of the matched pixels' median signed colour difference
        (left minus right, mean over the channels) is at least this many grey levels and the table reduces it
        without raising their median colour difference or leaving it above ``max_residual`` (0: off, the
        default; 1.0 is the value measured in docs/EXPERIMENTS.md).
    max_residual : float
        When the matched pixels' median colour difference stays above this many grey levels after the mapping
        (a change of light that no function of intensity undoes), ``info["radiometry_census_only"]`` is 1: the
        caller should drop its colour terms and match on census alone.
    """

    enabled: bool = True
    scale: int = 2
    radius: int = 3
    uniqueness: float = 0.1
    min_samples: int = 500
    min_gain: float = 3.0
    min_offset: float = 0.0
    max_residual: float = 8.0

    def __post_init__(self) -> None:
        """Validate the fields; implementation helper with no thesis equation of its own."""
        if not (self.scale >= 1 and self.radius >= 0 and 0.0 <= self.uniqueness < 1.0 and self.min_samples >= 16
                and self.min_gain >= 0 and self.min_offset >= 0 and self.max_residual >= 0):
            raise ConfigError(f"expected radiometry.scale >= 1, radius >= 0, uniqueness in [0, 1), min_samples "
                              f">= 16, min_gain, min_offset and max_residual >= 0, got {self.scale!r}, "
                              f"{self.radius!r}, {self.uniqueness!r}, {self.min_samples!r}, {self.min_gain!r}, "
                              f"{self.min_offset!r}, {self.max_residual!r}")


def _census_matches(left: U8, right: U8, *, max_disp: int, radius: int,
                    uniqueness: float) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp], npt.NDArray[np.intp]]:
    """Rows, left columns and right columns of the unique, cross-checked census WTA matches of a pair.

    An addition to thesis §5.2 (module docstring) with no thesis equation of its own; the cross-check is that of
    Eq. 6.7.
    """
    h, w = left.shape[:2]
    vol = cost_census(left, right, max_disp=max_disp, min_disp=0, window=(7, 7))
    if radius > 0:
        k = 2 * radius + 1
        for i in range(vol.shape[2]):
            vol[:, :, i] = cv2.boxFilter(vol[:, :, i], -1, (k, k), borderType=cv2.BORDER_REFLECT)
    nd = vol.shape[2]
    dl = vol.argmin(axis=2)
    best = np.take_along_axis(vol, dl[..., None], 2)[..., 0]
    far = vol.copy()
    for off in (-1, 0, 1):
        np.put_along_axis(far, np.clip(dl + off, 0, nd - 1)[..., None], np.inf, 2)
    second = far.min(axis=2)
    unique = best < (1.0 - uniqueness) * second
    # the right view's winners: right pixel xr matches left pixel xr + d
    xs = np.arange(w)
    rv = np.full((h, w, nd), np.inf, np.float32)
    for i in range(nd):
        if i < w:
            rv[:, : w - i, i] = vol[:, i:, i]
    dr = rv.argmin(axis=2)
    xr = xs[None, :] - dl
    inside = xr >= 0
    back = np.take_along_axis(dr, np.clip(xr, 0, w - 1), axis=1)
    ok = inside & unique & (back == dl) & (dl < nd - 1)
    ys, xl = np.nonzero(ok)
    return ys, xl, xl - dl[ys, xl]


def _quantile_table(src: npt.NDArray[np.float64], ref: npt.NDArray[np.float64]) -> npt.NDArray[np.uint8]:
    """256-entry monotone table mapping the distribution of ``src`` samples onto that of ``ref`` samples.

    An addition to thesis §5.2 (module docstring) with no thesis equation of its own.
    """
    q = np.linspace(0.0, 1.0, 101)
    qs = np.quantile(src, q)
    qr = np.quantile(ref, q)
    qs, idx = np.unique(qs, return_index=True)  # strictly increasing abscissae for interp
    lut = np.interp(np.arange(256, dtype=np.float64), qs, qr[idx])
    return np.clip(np.rint(lut), 0, 255).astype(np.uint8)


def compensate_right(left: U8, right: U8, *, max_disp: int,
                     params: RadiometryParams | None = None) -> tuple[U8, dict[str, float]]:
    """The right view with its colours mapped to the left view's radiometry (see the module docstring).

    An addition to thesis §5.2 (module docstring) with no thesis equation of its own.

    Parameters
    ----------
    left, right : (H, W, 3) uint8
        Rectified pair; disparity ``d = x_left - x_right`` in ``[0, max_disp]``.
    max_disp : int, keyword-only
        Largest disparity (px at full size).
    params : RadiometryParams, keyword-only

    Returns
    -------
    right : (H, W, 3) uint8
        The compensated right view, or ``right`` itself (the same array) when the compensation is off, has too
        few matches, or does not lower the matched pixels' median colour difference by ``min_gain``.
    info : dict
        ``radiometry_samples``, ``radiometry_ad_before``, ``radiometry_ad_after`` (median mean-channel absolute
        difference of the matched pixels, grey levels), ``radiometry_offset_before``, ``radiometry_offset_after``
        (their median mean-channel signed difference, left minus right), ``radiometry_applied``,
        ``radiometry_offset_only`` (applied by the ``min_offset`` rule alone) and ``radiometry_census_only``
        (0 / 1, see :class:`RadiometryParams`).
    """
    p = params or RadiometryParams()
    info = {"radiometry_applied": 0.0, "radiometry_census_only": 0.0}
    if not p.enabled:
        return right, info
    s = int(p.scale)
    h, w = left.shape[:2]
    size = (max(1, w // s), max(1, h // s))
    ls: U8 = np.asarray(cv2.resize(left, size, interpolation=cv2.INTER_AREA) if s > 1 else left, np.uint8)
    rs: U8 = np.asarray(cv2.resize(right, size, interpolation=cv2.INTER_AREA) if s > 1 else right, np.uint8)
    md = max(1, min(int(np.ceil(max_disp / s)), size[0] - 1))
    ys, xl, xr = _census_matches(ls, rs, max_disp=md, radius=p.radius, uniqueness=p.uniqueness)
    info["radiometry_samples"] = float(ys.size)
    if ys.size < p.min_samples:
        return right, info
    lv = ls[ys, xl].astype(np.float64)
    rv = rs[ys, xr].astype(np.float64)
    luts = [_quantile_table(rv[:, c], lv[:, c]) for c in range(left.shape[2])]
    mapped = np.stack([luts[c][rs[ys, xr, c]] for c in range(left.shape[2])], axis=1).astype(np.float64)
    before = float(np.median(np.abs(lv - rv).mean(axis=1)))
    after = float(np.median(np.abs(lv - mapped).mean(axis=1)))
    off_before = float(np.median((lv - rv).mean(axis=1)))
    off_after = float(np.median((lv - mapped).mean(axis=1)))
    info.update(radiometry_ad_before=before, radiometry_ad_after=after, radiometry_offset_before=off_before,
                radiometry_offset_after=off_after)
    # a systematic offset is read by the colour costs as texture on weakly textured surfaces (module docstring)
    offset = (p.min_offset > 0 and abs(off_before) >= p.min_offset and abs(off_after) < abs(off_before)
              and after <= min(before, p.max_residual))
    applied = before - after >= p.min_gain or offset
    info["radiometry_offset_only"] = float(applied and before - after < p.min_gain)
    if (after if applied else before) > p.max_residual:  # what the costs will see still disagrees
        info["radiometry_census_only"] = 1.0
    if not applied:
        return right, info
    out = np.empty_like(right)
    for c in range(right.shape[2]):
        out[:, :, c] = cv2.LUT(np.ascontiguousarray(right[:, :, c]), luts[c])
    info["radiometry_applied"] = 1.0
    log.info("coop: right view's colours mapped to the left's (matched median AD %.1f -> %.1f, offset %.1f -> "
             "%.1f, %d samples)", before, after, off_before, off_after, ys.size)
    return np.ascontiguousarray(out), info
