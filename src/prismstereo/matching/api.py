"""One-call stereo matching: :func:`match` validates its inputs, then runs a registered method."""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from prismstereo.errors import ConfigError, ImageError, MatchingError
from prismstereo.io.images import as_image
from prismstereo.matching.registry import MatchResult, get_matcher
from prismstereo.matching.scale import match_scaled

log = logging.getLogger(__name__)

__all__ = ["match", "validate_pair", "validate_range"]


def _check_image(img: Any, name: str, unit: bool | None) -> np.ndarray:
    """uint8 kept (H×W×1 squeezed), anything else float32 on the 0..255 scale (:func:`~prismstereo.io.images.
    as_image`)."""
    arr = np.asarray(img)
    return as_image(arr, name=name, dtype=np.uint8 if arr.dtype == np.uint8 else np.float32, unit=unit)


def validate_pair(left: Any, right: Any) -> tuple[np.ndarray, np.ndarray]:
    """Check a stereo pair (same size, H×W or H×W×3, uint8 or finite float) and return it as arrays.

    Float pairs whose values all lie in [0, 1] (scikit-image convention) are rescaled to 0..255, the
    scale the matching costs are tuned for.
    """
    la, ra = np.asarray(left), np.asarray(right)
    # scikit-image convention: float images in [0, 1], decided for the pair
    unit = None
    if la.dtype.kind == "f" and ra.dtype.kind == "f" and la.size and ra.size:
        with np.errstate(invalid="ignore"):
            unit = bool(max(float(np.nanmax(la)), float(np.nanmax(ra))) <= 1.0)
    lt, rt = _check_image(la, "left", unit), _check_image(ra, "right", unit)
    if lt.shape[:2] != rt.shape[:2]:
        raise ImageError(f"expected left and right images of the same size, got {lt.shape[1]}×{lt.shape[0]} "
                         f"and {rt.shape[1]}×{rt.shape[0]} (W×H)")
    if lt.ndim != rt.ndim:
        lt = lt if lt.ndim == 3 else np.repeat(lt[:, :, None], 3, axis=2)
        rt = rt if rt.ndim == 3 else np.repeat(rt[:, :, None], 3, axis=2)
    return lt, rt


def validate_range(width: int, *, max_disp: Any, min_disp: Any = 0) -> tuple[int, int]:
    """Check ``0 <= min_disp <= max_disp < width`` (integers) and return them."""
    for name, v in (("max_disp", max_disp), ("min_disp", min_disp)):
        if isinstance(v, bool) or not isinstance(v, int | np.integer):
            raise MatchingError(f"expected an integer {name}, got {v!r}")
    lo, hi = int(min_disp), int(max_disp)
    if lo < 0:
        raise MatchingError(f"expected min_disp >= 0, got {lo}")
    if hi < lo:
        raise MatchingError(f"expected max_disp >= min_disp ({lo}), got {hi}")
    if hi >= width:
        raise MatchingError(f"expected max_disp < image width ({width}), got {hi}")
    return lo, hi


def match(left: Any, right: Any, *, max_disp: int, min_disp: int = 0, method: str = "bpasw",
          scale: Any = None, band: Any = None, **params: Any) -> MatchResult:
    """Disparity of ``left`` against ``right`` with a registered method.

    Inputs are validated before any work.

    Parameters
    ----------
    left, right : ndarray, (H, W) or (H, W, 3)
        Rectified pair, RGB, uint8 or float on the 0..255 scale (uint16 and float pairs within
        [0, 1] are rescaled to it);
        ``d = x_left - x_right >= 0``.
    max_disp, min_disp : int
        Inclusive search range, ``0 <= min_disp <= max_disp < W`` (a single level is allowed, so a
        1-pixel-wide image is matched with ``max_disp=0``).
    method : str
        A name from :func:`~prismstereo.matching.registry.available_matchers`.
    scale : ScaleParams or None (typed Any: a matcher parameter in ``**params`` may be a bool)
        Coarse-to-fine and memory-bounded tiling (:func:`~prismstereo.matching.scale.match_scaled`); None
        runs the matcher once on the whole pair.
    band : (lo, hi) of (H, W) int arrays, optional (typed Any, as ``scale``)
        Each pixel's own disparities ``lo .. hi`` (inclusive, within the range), for a matcher that searches
        per-pixel bands (``compute_banded``: ``sgm``); the match then runs untiled (``scale`` unused) and costs
        pixels × band (:mod:`prismstereo.matching.temporal`).
    **params
        The method's keyword tuning parameters.

    Returns
    -------
    MatchResult
        ``disparity`` float32 (H, W), NaN invalid; ``valid``; ``timings``; ...

    Raises
    ------
    ImageError, MatchingError, ConfigError
    """
    lt, rt = validate_pair(left, right)
    lo, hi = validate_range(lt.shape[1], max_disp=max_disp, min_disp=min_disp)
    matcher = get_matcher(method, **params)
    log.debug("match %s: %dx%d, d in [%d, %d]", method, lt.shape[1], lt.shape[0], lo, hi)
    if band is not None:
        banded = getattr(matcher, "compute_banded", None)
        if banded is None:
            raise ConfigError(f"band: expected a matcher that searches per-pixel bands (sgm), got {method!r}")
        return banded(lt, rt, max_disp=hi, min_disp=lo, band_lo=band[0], band_hi=band[1])  # type: ignore[no-any-return]
    if scale is not None:
        return match_scaled(lt, rt, max_disp=hi, min_disp=lo, method=method, params=params, scale=scale)
    return matcher.compute(lt, rt, max_disp=hi, min_disp=lo)
