"""One-call multi-view matching (``prismstereo multiview`` is :mod:`prismstereo.apps.multiview_command`)."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

from prismstereo.errors import ConfigError
from prismstereo.matching.registry import MatchResult
from prismstereo.multiview.globalmv import GlobalMultiViewParams, match_multiview_global
from prismstereo.multiview.local import LocalMultiViewParams, match_multibaseline

log = logging.getLogger(__name__)

__all__ = ["METHODS", "match_multiview"]

#: the multi-view methods by name
METHODS = ("local", "global")


def match_multiview(reference: Any, views: Sequence[Any], *, ratios: Sequence[float], max_disp: int,
                    method: str = "global", **params: Any) -> MatchResult:
    """Disparity of ``reference`` for the unit baseline from several collinear views (thesis §7.1).

    Parameters
    ----------
    reference : (H, W, 3) or (H, W) image, 0..255
    views : sequence of images of the same size, rectified with the reference (horizontal baselines)
    ratios : sequence of float, keyword-only
        Signed baseline ratio of each view (``+1`` = the standard right view; negative = left of the
        reference, matched at ``x + |δ| d``).
    max_disp : int, keyword-only
        Largest disparity of the unit baseline.
    method : {"global", "local"}, keyword-only
        ``"local"``: multi-baseline BPASW sum + WTA (§7.1.1, Eq. 7.8,
        :func:`~prismstereo.multiview.local.match_multibaseline`); ``"global"``: joint planes + cooperative
        optimisation of the summed energy (§7.1.2, :func:`~prismstereo.multiview.globalmv.match_multiview_global`).
    **params
        Fields of :class:`~prismstereo.multiview.local.LocalMultiViewParams` or
        :class:`~prismstereo.multiview.globalmv.GlobalMultiViewParams`.

    Returns
    -------
    MatchResult
    """
    key = str(method).lower()
    if key == "local":

        try:
            lp = LocalMultiViewParams(**params)
        except TypeError as exc:
            raise ConfigError(f"expected parameters of LocalMultiViewParams, got {sorted(params)}: {exc}") from None
        return match_multibaseline(reference, views, ratios=ratios, max_disp=max_disp, params=lp)
    if key == "global":

        try:
            gp = GlobalMultiViewParams(**params)
        except TypeError as exc:
            raise ConfigError(f"expected parameters of GlobalMultiViewParams, got {sorted(params)}: {exc}") from None
        return match_multiview_global(reference, views, ratios=ratios, max_disp=max_disp, params=gp)
    raise ConfigError(f"expected a multi-view method among {', '.join(METHODS)}, got {method!r}")
