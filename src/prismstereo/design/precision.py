"""The disparity precision of the matchers, measured on rendered captures (not assumed).

:data:`DISPARITY_PRECISION` is the median absolute disparity error (px) of the depth pipeline's refined
disparities with each preset's matcher, measured by ``benchmarks/bench_design.py`` on fronto-parallel textured
planes (:func:`~prismstereo.design.verify.verify_scene`) rendered through several prisms at several depths
(the table's numbers: docs/EXPERIMENTS.md, issue 29). The command that measured them:

    PYTHONPATH=src NUMBA_CACHE_DIR=.numba_cache python benchmarks/bench_design.py --presets balanced,fast
    PYTHONPATH=src NUMBA_CACHE_DIR=.numba_cache python benchmarks/bench_design.py --presets accurate --depths 1500,900

It holds for well-textured surfaces facing the camera with the simulator's sensor noise of 1 grey level; slanted
surfaces, depth edges, weak texture and real optics raise it (docs/design.md, limits).
"""

from __future__ import annotations

from prismstereo.errors import ConfigError

__all__ = ["DEFAULT_PRESET", "DISPARITY_PRECISION", "MEASURED_WITH", "disparity_precision_of"]

#: median |δd| in px per preset (``fast`` = sgm, ``balanced`` = bpasw, ``accurate`` = coop), pooled over the
#: rigs and depths of ``benchmarks/bench_design.py``
DISPARITY_PRECISION: dict[str, float] = {"fast": 0.0147, "balanced": 0.0147, "accurate": 0.0144}
#: the command that measured :data:`DISPARITY_PRECISION`
MEASURED_WITH = "PYTHONPATH=src NUMBA_CACHE_DIR=.numba_cache python benchmarks/bench_design.py --presets balanced,fast"
#: the preset a prediction assumes unless told otherwise (the depth command's default matcher, bpasw)
DEFAULT_PRESET = "balanced"


def disparity_precision_of(value: float | str) -> tuple[float, str | None]:
    """(median |δd| px, preset name or None) for a preset name or a number of pixels."""
    if isinstance(value, str):
        key = value.strip().lower()
        if key not in DISPARITY_PRECISION:
            raise ConfigError(f"disparity_precision: expected a preset among {', '.join(DISPARITY_PRECISION)} or "
                              f"a number of pixels, got {value!r}")
        return DISPARITY_PRECISION[key], key
    if isinstance(value, bool) or not isinstance(value, int | float) or not 0 < float(value) < 10:
        raise ConfigError(f"disparity_precision: expected a positive number of pixels (< 10), got {value!r}")
    return float(value), None
