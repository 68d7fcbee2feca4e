"""Choose the prism for a camera and a job: predicted depth resolution, a search over prisms, verification
on rendered captures (docs/design.md).

* :func:`predict` — per depth: baseline, disparity, common field, expected depth error, sub-image sizes.
* :func:`search` — ranked candidates for a camera, a depth range and constraints (:class:`Design`).
* :func:`verify` — predicted against measured error on rendered planes through a rig.
* :data:`GLASSES` — real glasses with their refractive index and Abbe number; :func:`parse_glass`.
* :data:`DISPARITY_PRECISION` — the matchers' measured disparity precision per preset.
"""

from __future__ import annotations

from prismstereo.design.geometry import GlassSize, SubImage, size_prism
from prismstereo.design.glass import GLASSES, Glass, parse_glass, parse_glasses
from prismstereo.design.precision import DEFAULT_PRESET, DISPARITY_PRECISION, disparity_precision_of
from prismstereo.design.predict import DepthPrediction, Prediction, predict
from prismstereo.design.search import CHECKS, Candidate, Design, Request, assess, search
from prismstereo.design.verify import Measurement, VerifyRow, measure_at_depth, verify, verify_scene

__all__ = ["CHECKS", "DEFAULT_PRESET", "DISPARITY_PRECISION", "GLASSES", "Candidate", "DepthPrediction", "Design",
           "Glass", "GlassSize", "Measurement", "Prediction", "Request", "SubImage", "VerifyRow", "assess",
           "disparity_precision_of", "measure_at_depth", "parse_glass", "parse_glasses", "predict", "search",
           "size_prism", "verify", "verify_scene"]
