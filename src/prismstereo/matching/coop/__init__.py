"""``coop``: segment-based stereo with cooperative optimisation (thesis chapters 5-6).

:mod:`~prismstereo.matching.coop.pipeline` runs the two-view pipeline; :mod:`~prismstereo.matching.coop.cooperative`
is the optimiser of the plane labels, :mod:`~prismstereo.matching.coop.coopcost` its costs and
:mod:`~prismstereo.matching.coop.slanted` the slanted-window plane costs.
"""

from __future__ import annotations

from prismstereo.matching.coop.pipeline import (
    CoopMatcher,
    CoopResult,
    FineSegments,
    boundary_pixel_planes,
    bpasw_candidate_rounds,
    coop_match,
    initial_disparity,
    occlusion_background_fill,
    refine_fine_segments,
    segment_sweep_candidates,
)

__all__ = ["CoopMatcher", "CoopResult", "FineSegments", "boundary_pixel_planes", "bpasw_candidate_rounds",
           "coop_match", "initial_disparity", "occlusion_background_fill", "refine_fine_segments",
           "segment_sweep_candidates"]
