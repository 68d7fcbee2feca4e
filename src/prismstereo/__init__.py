"""prismstereo: depth from a single camera and a prism.

The pipeline follows Wang (2012), *Depth recovery with rectification using single-lens prism based
stereovision system*: optics-based virtual cameras, rectification, segment-based stereo matching with
cooperative optimisation, multi-view matching and triangulation.
"""

from __future__ import annotations

import os

__version__ = "0.1.0"

# numba's parallel kernels run on OpenMP, whose threads spin while they wait for work by default. When
# the cores are shared (other processes, Dask workers, a laptop doing something else) every parallel
# call then waits for spinning threads to be scheduled: tens of milliseconds per call, measured 0.12 s
# against 0.001 s for a tiny sgm match. Passive waiting costs microseconds on idle cores. A user's own
# setting wins; it must be set before OpenMP is loaded, which happens at the first parallel call.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
# OpenBLAS (numpy's BLAS) threads spin the same way, and the library's products are thin ((N, 3) @ (3, 3)
# point transforms) that a second thread cannot speed up: on shared cores one projection of 150 000 points
# measured 67 ms CPU / 200 ms wall with OpenBLAS's threads against 5 ms / 14 ms with one. It is read when
# numpy is first imported, so it only takes effect when prismstereo is imported first (the CLI does).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

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
