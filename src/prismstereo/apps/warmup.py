"""Compile the numba kernels once, so that a user's first real run only loads them (``prismstereo warmup``).

Every numba kernel of the package is compiled with ``cache=True``: the first call in a fresh environment
compiles it (tens of seconds for ``coop``) and writes the machine code to numba's on-disk cache — the
folder ``$NUMBA_CACHE_DIR`` when set, else ``__pycache__`` beside the package's modules (or a per-user
cache folder when those are read-only). Later processes load the cached code in a fraction of that time.
:func:`warmup` pays the compilation up front by running each hot path on tiny inputs with the dtypes
and layouts of a real run (uint8 RGB pairs, the float32 images of the depth pipeline), so that the
cache holds the same signatures the real run asks for.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field

import numpy as np

import prismstereo
from prismstereo.apps.demo import demo_rig, plane_scene, scaled_rig
from prismstereo.depth import DepthConfig, run_depth
from prismstereo.errors import ConfigError
from prismstereo.matching import available_matchers, match
from prismstereo.matching.temporal import BANDED_MATCHERS
from prismstereo.multiview.api import match_multiview
from prismstereo.simulate import render_capture

log = logging.getLogger(__name__)

__all__ = ["WarmupReport", "numba_cache_location", "warmup"]

#: parts of the package warmed besides the matchers (by default)
PARTS: tuple[str, ...] = ("depth", "multiview")
#: every part :func:`warmup` knows: also ``"pipeline"``, the depth pipeline without the renderer (what a command
#: that reads a capture compiles; ``"depth"`` includes it)
ALL_PARTS: tuple[str, ...] = (*PARTS, "pipeline")


@dataclass(frozen=True)
class WarmupReport:
    """Seconds per warmed item (``"match coop"``, ``"depth"``, ...) and the numba cache folder."""

    seconds: dict[str, float] = field(default_factory=dict)
    cache: str = ""

    def summary(self) -> str:
        lines = [f"warmup: {name:<16s} {s:6.1f} s" for name, s in self.seconds.items()]
        lines.append(f"warmup: total {sum(self.seconds.values()):.1f} s; numba cache: {self.cache}")
        return "\n".join(lines)


def numba_cache_location() -> str:
    """Where numba writes its cache: ``$NUMBA_CACHE_DIR``, else beside the package's modules."""
    from numba.core import config

    cache_dir = getattr(config, "CACHE_DIR", "")  # set from $NUMBA_CACHE_DIR when numba loads
    if cache_dir:
        return str(cache_dir)
    return f"__pycache__ folders under {prismstereo.__path__[0]} (a per-user folder where read-only)"


def _pair(h: int = 48, w: int = 72, shift: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """A textured uint8 RGB pair, right(x) = left(x + shift)."""
    import cv2

    rng = np.random.default_rng(0)
    base = rng.uniform(0, 255, size=(h // 3 + 1, (w + shift) // 3 + 1, 3)).astype(np.float32)
    big = np.clip(cv2.resize(base, (w + shift, h), interpolation=cv2.INTER_CUBIC), 0, 255).astype(np.uint8)
    return np.ascontiguousarray(big[:, :w]), np.ascontiguousarray(big[:, shift:shift + w])


def _warm_item(item: tuple[str, str]) -> float:
    """Run one warm-up item (``("match", method)``, ``("depth", "")``, ``("pipeline", "")``, ``("multiview",
    "")``); its seconds."""
    kind, name = item
    t = time.perf_counter()
    if kind == "match":
        left, right = _pair()
        match(left, right, max_disp=8, method=name)
        if name in BANDED_MATCHERS:  # a stream's banded frames (the temporal prior) run its banded kernels
            lo = np.full(left.shape[:2], 2, dtype=np.int32)
            match(left, right, max_disp=8, method=name, band=(lo, lo + 4))
    elif kind == "depth":
        # the pipeline's own kernels (renderer, refinement, triangulation) with OpenCV's SGBM, which compiles
        # nothing: the matchers' kernels are the "match" items' (the pipeline calls them on contiguous uint8
        # RGB views, the tiny pair's types)
        rig = scaled_rig(demo_rig(), 4)
        cap = render_capture(rig, plane_scene(1600.0, tilt_deg=-20.0, seed=5))
        run_depth(rig, cap.image, config=DepthConfig(method="sgbm"), progress=False)
    elif kind == "pipeline":
        # the same run on a capture-sized random texture instead of a render: the renderer's kernels are not
        # compiled (a first ``depth`` reads its capture; it needs the pipeline's kernels only)
        rig = scaled_rig(demo_rig(), 4)
        left, _ = _pair(rig.camera.height, rig.camera.width, 0)
        run_depth(rig, left, config=DepthConfig(method="sgbm"), progress=False)
    else:
        left, right = _pair()
        far = _pair(shift=8)[1]
        for mv in ("local", "global"):
            match_multiview(left, [right, far], ratios=[1.0, 2.0], max_disp=6, method=mv)
    seconds = time.perf_counter() - t
    log.info("warmed %s %s in %.1f s", kind, name, seconds)
    return seconds


def warmup(methods: Sequence[str] | None = None, *, parts: Sequence[str] = PARTS,
           jobs: int | None = None) -> WarmupReport:
    """Run every matcher (and the depth pipeline and multi-view matching) once on tiny inputs.

    Parameters
    ----------
    methods : sequence of str, optional
        Matchers to warm (default: every registered one).
    parts : sequence of str
        Also warm ``"depth"`` (a 128×96 rendered capture through the depth pipeline, with OpenCV's SGBM: the
        renderer's and the pipeline's kernels; the matchers' are the methods'), ``"pipeline"`` (the same
        without the renderer: a random texture of the capture's size) and ``"multiview"`` (local and global
        matching of three views).
    jobs : int, optional
        Processes compiling at the same time (numba compiles on one core per process; every process writes
        the shared disk cache). Default: one per core, at most one per item; 1: in this process.

    Returns
    -------
    WarmupReport
        Seconds per item; a warm cache makes each of them small.

    Raises
    ------
    ConfigError
        Unknown method or part, or ``jobs`` < 1.
    """

    names = list(available_matchers()) if methods is None else [str(m).lower() for m in methods]
    unknown = sorted(set(names) - set(available_matchers()))
    if unknown:
        raise ConfigError(f"methods: expected methods among {', '.join(available_matchers())}, got {unknown}")
    bad_parts = sorted(set(parts) - set(ALL_PARTS))
    if bad_parts:
        raise ConfigError(f"parts: expected warmup parts among {', '.join(ALL_PARTS)}, got {bad_parts}")
    if jobs is not None and (isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1):
        raise ConfigError(f"jobs: expected a positive integer, got {jobs!r}")
    items = [("match", n) for n in names] + [(p, "") for p in ALL_PARTS if p in parts]
    labels = [f"match {n}" if k == "match" else k for k, n in items]
    workers = min(len(items), jobs if jobs is not None else (os.cpu_count() or 1))
    if workers <= 1:
        seconds = [_warm_item(it) for it in items]
    else:
        # fresh interpreters (spawn): a forked copy of a process that has run numba's threads is unsafe
        with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn")) as pool:
            seconds = list(pool.map(_warm_item, items))
    return WarmupReport(dict(zip(labels, seconds, strict=True)), numba_cache_location())
