"""Multi-view matching (thesis chapter 7).

* :func:`match_multiview` — collinear rectified views with signed baseline ratios: the local
  multi-baseline method (§7.1.1, Eqs. 7.3–7.8) and the global method (§7.1.2, Eqs. 7.9–7.18).
* :func:`depth_all_views` — every virtual view of an N-face prism capture: plane sweep along the
  reference view's exact rays, then multi-ray exact triangulation.
"""

from __future__ import annotations

from prismstereo.multiview.api import match_multiview
from prismstereo.multiview.prism import depth_all_views

__all__ = ["depth_all_views", "match_multiview"]
