"""CPU profile of one ``coop`` match: where the seconds go, by function (numba kernels included).

Usage::

    NUMBA_CACHE_DIR=.numba_cache .venv/bin/python benchmarks/profile_coop.py [--scene teddy] [--top 30]
    ... profile_coop.py --data ../shared/data/middlebury-extra --scene books

Runs ``coop_match`` once to warm numba's cache (not counted), then once under :mod:`cProfile` timed with
``time.process_time``: each function's seconds are the CPU seconds of all threads while it ran, so a parallel
kernel is charged its whole CPU cost, and the table reads right on loaded, shared cores (wall time there
does not). Prints the ``--top`` functions by own time and by cumulative time, a per-stage table (cumulative
CPU seconds of the pipeline's pieces), the total CPU and wall seconds and the load average; then runs
``sgbm``, ``sgm`` and ``coop`` once each unprofiled (after a warm-up run each), timed the same way, and prints
their CPU seconds and the ratios to OpenCV SGBM's.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import os
import pstats
import time

# prismstereo sets this on import; numpy is imported first here, and reads it then
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from prismstereo.evaluation.middlebury import load_scene  # noqa: E402
from prismstereo.matching import match  # noqa: E402
from prismstereo.matching.coop import coop_match  # noqa: E402

# the pieces of coop_match whose cumulative CPU seconds make the per-stage table (function name, label)
STAGES = (("bpasw_volume", "BPASW volume"), ("raw_cost", "pixel cost"), ("aggregated_costs", "guided filter x2"),
          ("initial_disparity", "WTA + check"), ("mean_shift_segment", "segmentation"),
          ("fit_planes_splitting", "plane fits"), ("sheared_costs", "sheared volumes"),
          ("step_optimise", "optimise"), ("step_refit", "refit"), ("step_bpasw_planes", "bpasw_planes"),
          ("step_sweep", "sweep"), ("segment_sweep_candidates", "  sweep candidates"),
          ("row_box", "  row-only volume"), ("step_group_moves", "group_moves"), ("step_fine", "fine"),
          ("step_boundary", "boundary"), ("step_occlusion", "occlusion"), ("step_median", "median"),
          ("step_fallback", "fallback"), ("cooperative_optimize", "(all cooperative_optimize)"))


def _stage_table(stats: pstats.Stats) -> list[tuple[str, float]]:
    cum: dict[str, float] = {}
    for (_file, _line, name), row in stats.stats.items():  # type: ignore[attr-defined]
        cum[name] = cum.get(name, 0.0) + row[3]
    return [(label, cum.get(name, 0.0)) for name, label in STAGES]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=None, help="scene folder (default: the Middlebury v2 scenes)")
    ap.add_argument("--scene", default="teddy")
    ap.add_argument("--top", type=int, default=30)
    args = ap.parse_args()
    sc = load_scene(args.scene, args.data)
    lo = int(getattr(sc, "min_disp", 0))
    coop_match(sc.left, sc.right, max_disp=sc.max_disp, min_disp=lo)
    prof = cProfile.Profile(time.process_time)
    c, t = time.process_time(), time.perf_counter()
    prof.enable()
    res = coop_match(sc.left, sc.right, max_disp=sc.max_disp, min_disp=lo)
    prof.disable()
    cpu, wall = time.process_time() - c, time.perf_counter() - t
    for key in ("tottime", "cumulative"):
        buf = io.StringIO()
        pstats.Stats(prof, stream=buf).sort_stats(key).print_stats(args.top)
        print(f"--- by {key} (CPU seconds) ---")
        print("\n".join(line for line in buf.getvalue().splitlines() if line.strip())[:20000])
    print("\n| stage | CPU s |\n|---|---|")
    for label, sec in _stage_table(pstats.Stats(prof)):
        print(f"| {label} | {sec:.2f} |")
    print(f"\n{args.scene}: {cpu:.2f} s CPU, {wall:.2f} s wall (profiled); stages (wall s) "
          + ", ".join(f"{k} {v:.2f}" for k, v in res.timings.items())
          + f"; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    # unprofiled, in this process: coop against OpenCV SGBM and sgm (CPU seconds; ratios hold on a loaded host)
    cpu_of = {}
    for name in ("sgbm", "sgm", "coop"):
        match(sc.left, sc.right, max_disp=sc.max_disp, min_disp=lo, method=name)  # warm (numba, OpenCV)
        c = time.process_time()
        match(sc.left, sc.right, max_disp=sc.max_disp, min_disp=lo, method=name)
        cpu_of[name] = time.process_time() - c
    print("unprofiled CPU s: " + ", ".join(f"{k} {v:.2f}" for k, v in cpu_of.items())
          + f"; coop / sgbm {cpu_of['coop'] / cpu_of['sgbm']:.1f}x, sgm / sgbm {cpu_of['sgm'] / cpu_of['sgbm']:.1f}x"
          + f"; load average {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
