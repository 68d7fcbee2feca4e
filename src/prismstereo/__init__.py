"""prismstereo: depth from a single camera and a prism.

The pipeline follows Wang (2012), *Depth recovery with rectification using single-lens prism based
stereovision system*: optics-based virtual cameras, rectification, segment-based stereo matching with
cooperative optimisation, multi-view matching and triangulation.
"""

from __future__ import annotations

__version__ = "0.1.0"

from prismstereo.errors import (
    ConfigError,
    GeometryError,
    ImageError,
    MatchingError,
    OutputError,
    PrismStereoError,
)

__all__ = [
    "ConfigError",
    "GeometryError",
    "ImageError",
    "MatchingError",
    "OutputError",
    "PrismStereoError",
    "__version__",
]
