"""``coop``: segment-based stereo with cooperative optimisation (thesis chapters 5-6).

:mod:`~prismstereo.matching.coop.pipeline` runs the two-view pipeline; :mod:`~prismstereo.matching.coop.cooperative`
is the optimiser of the plane labels, :mod:`~prismstereo.matching.coop.coopcost` its costs and
:mod:`~prismstereo.matching.coop.slanted` the slanted-window plane costs; :mod:`~prismstereo.matching.coop.steps`
the steps run after the front end and :mod:`~prismstereo.matching.coop.refine` the plane-label refinements they use.
"""

from __future__ import annotations

from prismstereo.matching.coop.pipeline import (
    CoopMatcher,
    CoopResult,
    coop_match,
    initial_disparity,
    occlusion_background_fill,
    segment_sweep_candidates,
)
from prismstereo.matching.coop.refine import (
    FineSegments,
    boundary_pixel_planes,
    bpasw_candidate_rounds,
    refine_fine_segments,
)

__all__ = ["CoopMatcher", "CoopResult", "FineSegments", "boundary_pixel_planes", "bpasw_candidate_rounds",
           "coop_match", "initial_disparity", "occlusion_background_fill", "refine_fine_segments",
           "segment_sweep_candidates"]
