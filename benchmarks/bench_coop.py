"""Accuracy and speed of the ``coop`` matcher on the four Middlebury v2 scenes (thesis Table 6.2).

Usage::

    NUMBA_CACHE_DIR=.numba_cache .venv/bin/python benchmarks/bench_coop.py [--scenes tsukuba,venus]
    ... bench_coop.py --data ../shared/data/middlebury-extra      # the validation scenes

Prints per scene the bad > 1 px rates (nonocc / all / disc) of the initial map, the plane map and the final
map, then a table: wall and CPU seconds (all threads) of the whole match, the per-stage wall seconds, OpenCV
SGBM's wall seconds on the same pair in this process and the ratio; the 12-number average beside the thesis
and the peak resident memory. A warm-up on a tiny pair loads numba's cache first (not counted). On shared
cores trust the CPU column: wall time there grows with the load (printed).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import time

# prismstereo sets this on import; numpy is imported first here, and reads it then
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from prismstereo.evaluation.middlebury import evaluate_disparity, list_scenes, load_scene  # noqa: E402
from prismstereo.matching import match  # noqa: E402
from prismstereo.matching.coop import coop_match  # noqa: E402

THESIS = {"tsukuba": (0.89, 1.21, 5.84), "venus": (0.21, 0.57, 1.72), "teddy": (4.02, 6.51, 11.24),
          "cones": (2.73, 6.89, 7.04)}


def _bad(d: np.ndarray, scene: object) -> tuple[float, float, float]:
    b = evaluate_disparity(d, scene, thresholds=(1.0,))["bad"]["1.0"]  # type: ignore[arg-type]
    return b["nonocc"], b["all"], b["disc"]


def _sgbm_seconds(left: np.ndarray, right: np.ndarray, max_disp: int, min_disp: int) -> float:
    best = np.inf
    for _ in range(3):
        t = time.perf_counter()
        match(left, right, max_disp=max_disp, min_disp=min_disp, method="sgbm")
        best = min(best, time.perf_counter() - t)
    return float(best)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=None, help="scene folder (default: the Middlebury v2 scenes)")
    ap.add_argument("--scenes", default=None, help="comma-separated subset (default: every scene in --data)")
    ap.add_argument("--json", default="")
    args = ap.parse_args()
    names = args.scenes.split(",") if args.scenes else list_scenes(args.data)
    warm = np.random.default_rng(0).integers(0, 255, (40, 56, 3), dtype=np.uint8)
    coop_match(warm, np.roll(warm, -3, axis=1), max_disp=6)
    match(warm, warm, max_disp=4, method="sgbm")
    rows = {}
    for name in names:
        sc = load_scene(name, args.data)
        lo = int(getattr(sc, "min_disp", 0))
        c, t = time.process_time(), time.perf_counter()
        res = coop_match(sc.left, sc.right, max_disp=sc.max_disp, min_disp=lo)
        total, cpu = time.perf_counter() - t, time.process_time() - c
        sgbm = _sgbm_seconds(sc.left, sc.right, sc.max_disp, lo)
        rows[name] = {"initial": _bad(res.initial, sc), "planes": _bad(res.plane_map, sc),
                      "final": _bad(res.disparity, sc), "timings": res.timings, "total_s": total, "cpu_s": cpu,
                      "sgbm_s": sgbm, "info": res.info}
        r = rows[name]
        thesis = f"  (thesis {'/'.join(map(str, THESIS[name]))})" if name in THESIS else ""
        print(f"{name:9s} init {'/'.join(f'{v:.2f}' for v in r['initial'])}  "
              f"planes {'/'.join(f'{v:.2f}' for v in r['planes'])}  "
              f"final {'/'.join(f'{v:.2f}' for v in r['final'])}{thesis}", flush=True)
    stages = list(next(iter(rows.values()))["timings"]) if rows else []
    print(f"\nload average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores; seconds per pair, warm\n")
    print("| scene | wall s | CPU s | " + " | ".join(stages) + " | SGBM s | × SGBM |")
    print("|---" * (len(stages) + 5) + "|")
    for name, r in rows.items():
        st = " | ".join(f"{r['timings'].get(s, 0.0):.2f}" for s in stages)
        print(f"| {name} | {r['total_s']:.2f} | {r['cpu_s']:.2f} | {st} | {r['sgbm_s']:.3f} | "
              f"{r['total_s'] / r['sgbm_s']:.0f} |")
    finals = [v for r in rows.values() for v in r["final"]]
    nonocc = [r["final"][0] for r in rows.values()]
    print(f"\naverage of {len(finals)}: {np.mean(finals):.3f} (thesis 4.07 on v2); nonocc average "
          f"{np.mean(nonocc):.3f}; slowest pair {max(r['total_s'] for r in rows.values()):.2f} s wall, "
          f"{max(r['cpu_s'] for r in rows.values()):.2f} s CPU; peak RSS "
          f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)


if __name__ == "__main__":
    main()
