"""Signs that a disparity map is not to be trusted: matches piled at the search limits, few consistent ones.

A scene that extends beyond the searched disparity range does not fail loudly: the matcher returns the
nearest allowed value, so the pixels of every object outside the range pile up at ``max_disp`` (objects
nearer than the range) or ``min_disp`` (farther), and the left–right check rejects many of the rest.
These checks turn that into warnings (docs/cli.md, "Warnings").
"""

from __future__ import annotations

import numpy as np

__all__ = ["LIMIT_SHARE", "MIN_VALID_SHARE", "limit_shares", "limit_warnings"]

#: share of consistent matches within half a pixel of a search limit that triggers a warning (chosen
#: between a range that holds the scene and one that cuts it: docs/EXPERIMENTS.md)
LIMIT_SHARE = 0.02
#: share of the image's pixels (black rectification borders excluded) passing the left–right check below
#: which a map is reported as unreliable (docs/EXPERIMENTS.md)
MIN_VALID_SHARE = 0.7


def limit_shares(disparity: np.ndarray, valid: np.ndarray | None, *, min_disp: float,
                 max_disp: float) -> tuple[float, float, int]:
    """Shares of the consistent matches at the low and the high search limit.

    Parameters
    ----------
    disparity : (H, W) float, px, NaN invalid.
    valid : (H, W) bool or None
        Matches that passed the left–right check (None: every finite disparity).
    min_disp, max_disp : the searched range, px.

    Returns
    -------
    (share at min_disp, share at max_disp, number of matches considered).
    """
    d = np.asarray(disparity, dtype=np.float64)
    ok = np.isfinite(d)
    if valid is not None:
        ok &= np.asarray(valid, dtype=bool)
    v = d[ok]
    if v.size == 0:
        return 0.0, 0.0, 0
    at_lo = float(np.mean(v <= min_disp + 0.5))
    at_hi = float(np.mean(v >= max_disp - 0.5))
    return at_lo, at_hi, int(v.size)


def limit_warnings(disparity: np.ndarray, valid: np.ndarray | None, *, min_disp: float, max_disp: float,
                   region: np.ndarray | None = None, hint: str = "min_disp/max_disp") -> list[str]:
    """One-line warnings when the map looks cut by its search range or mostly inconsistent.

    ``region`` (bool, H×W) are the pixels that could match (e.g. not the black border of a rectified
    view); default all.
    """
    lines: list[str] = []
    at_lo, at_hi, n = limit_shares(disparity, valid, min_disp=min_disp, max_disp=max_disp)
    d = np.asarray(disparity)
    total = int(np.count_nonzero(region)) if region is not None else d.size
    if region is not None and valid is not None:
        n_region = int(np.count_nonzero(np.asarray(valid, dtype=bool) & np.asarray(region, dtype=bool)))
    else:
        n_region = n
    if n == 0:
        return [f"no pixel passed the left–right check: the images may not be a rectified pair, or the scene "
                f"lies outside the searched disparities {min_disp:g}–{max_disp:g} px (widen {hint})"]
    if at_hi > LIMIT_SHARE:
        lines.append(f"{100 * at_hi:.1f} % of the matches sit at the largest searched disparity {max_disp:g} px: "
                     f"parts of the scene are probably nearer than the range reaches (raise the maximum, {hint})")
    if at_lo > LIMIT_SHARE and min_disp > 0:
        lines.append(f"{100 * at_lo:.1f} % of the matches sit at the smallest searched disparity {min_disp:g} px: "
                     f"parts of the scene are probably farther than the range reaches (lower the minimum, {hint})")
    share = n_region / max(total, 1)
    if valid is not None and share < MIN_VALID_SHARE:
        lines.append(f"only {100 * share:.1f} % of the pixels passed the left–right check: the result is "
                     f"unreliable (images not a rectified pair, too little texture, or a disparity range "
                     f"{min_disp:g}–{max_disp:g} px that misses the scene)")
    return lines
