"""Multi-view matching (thesis chapter 7).

* :func:`match_multiview` — collinear rectified views with signed baseline ratios: the local
  multi-baseline method (§7.1.1, Eqs. 7.3–7.8) and the global method (§7.1.2, Eqs. 7.9–7.18).
* :func:`depth_all_views` — every virtual view of an N-face prism capture: plane sweep along the
  reference view's exact rays, then multi-ray exact triangulation.

Heavy modules load lazily on first use.
"""

from __future__ import annotations

from typing import Any

__all__ = ["depth_all_views", "match_multiview"]


def match_multiview(*args: Any, **kwargs: Any) -> Any:
    """See :func:`prismstereo.multiview.api.match_multiview`."""
    from prismstereo.multiview.api import match_multiview as impl

    return impl(*args, **kwargs)


def depth_all_views(*args: Any, **kwargs: Any) -> Any:
    """See :func:`prismstereo.multiview.prism.depth_all_views`."""
    from prismstereo.multiview.prism import depth_all_views as impl

    return impl(*args, **kwargs)
