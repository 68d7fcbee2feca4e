"""prismstereo: depth from a single camera and a prism.

The pipeline follows Wang (2012), *Depth recovery with rectification using single-lens prism based
stereovision system*: optics-based virtual cameras, rectification, segment-based stereo matching with
cooperative optimisation, multi-view matching and triangulation.

The library in one call per task (:mod:`prismstereo.api`, docs/api.md)::

    import prismstereo
    result = prismstereo.depth("rig.toml", "capture.png")   # .depth, .disparity, .confidence, .points(), .save()

``load_rig``, ``depth``, ``simulate``, ``calibrate_prism`` and ``DepthResult`` are loaded on first use, so that
``import prismstereo`` stays light (the command line's start-up). Importing the package sets two thread
variables unless they are set already (below; README "The first run"), and the package's logger has a
:class:`logging.NullHandler`: the library logs, the application decides what is shown.
"""

from __future__ import annotations

import importlib
import logging
import os
import sys
import types
from typing import Any

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

logging.getLogger(__name__).addHandler(logging.NullHandler())

#: the one-call functions of :mod:`prismstereo.api`, loaded when first used
_API = ("load_rig", "depth", "simulate", "calibrate_prism", "DepthResult")


class _EntryPoint:
    """``prismstereo.depth`` and ``prismstereo.simulate``: a function of :mod:`prismstereo.api` that shares its
    name with a subpackage. Calling it runs the function; its attributes are the subpackage's
    (``prismstereo.depth.pipeline`` still works)."""

    def __init__(self, name: str) -> None:
        self._name = name

    @property
    def __wrapped__(self) -> Any:  # inspect.signature and help() show the function's
        return getattr(importlib.import_module("prismstereo.api"), self._name)

    @property
    def __doc__(self) -> str | None:  # type: ignore[override]
        return self.__wrapped__.__doc__

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        return self.__wrapped__(*args, **kwargs)

    def __getattr__(self, attr: str) -> Any:
        if attr.startswith("__"):
            raise AttributeError(attr)
        return getattr(importlib.import_module(f"prismstereo.{self._name}"), attr)

    def __repr__(self) -> str:
        return f"<function prismstereo.{self._name} (and the subpackage prismstereo.{self._name})>"


_ENTRY: dict[str, _EntryPoint] = {"depth": _EntryPoint("depth"), "simulate": _EntryPoint("simulate")}


class _Package(types.ModuleType):
    """The package module: ``depth`` and ``simulate`` stay the entry points after their subpackages are
    imported (the import system binds a loaded subpackage as an attribute of its parent)."""

    depth = property(lambda self: _ENTRY["depth"], lambda self, value: None)
    simulate = property(lambda self: _ENTRY["simulate"], lambda self, value: None)


sys.modules[__name__].__class__ = _Package


def __dir__() -> list[str]:
    return sorted({*globals(), *_API, "depth", "simulate"})


def __getattr__(name: str) -> Any:
    if name in _API:
        return getattr(importlib.import_module("prismstereo.api"), name)
    raise AttributeError(f"module 'prismstereo' has no attribute {name!r}")


__all__ = [
    "ConfigError",
    "GeometryError",
    "ImageError",
    "MatchingError",
    "OutputError",
    "PrismStereoError",
    "DepthResult",
    "__version__",
    "calibrate_prism",
    "depth",
    "load_rig",
    "simulate",
]
