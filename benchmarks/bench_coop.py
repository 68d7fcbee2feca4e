"""Accuracy and speed of the ``coop`` matcher on the four Middlebury v2 scenes (thesis Table 6.2).

Usage::

    NUMBA_CACHE_DIR=.numba_cache .venv/bin/python benchmarks/bench_coop.py [--scenes tsukuba,venus]

Prints per scene the bad > 1 px rates (nonocc / all / disc) of the initial map, the plane map and the final
map, the per-stage timings, the peak resident memory, and the 12-number average beside the thesis.
"""

from __future__ import annotations

import argparse
import json
import resource
import time

import numpy as np

from prismstereo.evaluation.middlebury import SCENES, evaluate_disparity, load_scene
from prismstereo.matching.coop.pipeline import coop_match

THESIS = {"tsukuba": (0.89, 1.21, 5.84), "venus": (0.21, 0.57, 1.72), "teddy": (4.02, 6.51, 11.24),
          "cones": (2.73, 6.89, 7.04)}


def _bad(d: np.ndarray, scene: object) -> tuple[float, float, float]:
    b = evaluate_disparity(d, scene, thresholds=(1.0,))["bad"]["1.0"]  # type: ignore[arg-type]
    return b["nonocc"], b["all"], b["disc"]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--json", default="")
    args = ap.parse_args()
    rows = {}
    for name in args.scenes.split(","):
        sc = load_scene(name)
        t = time.perf_counter()
        res = coop_match(sc.left, sc.right, max_disp=sc.max_disp)
        total = time.perf_counter() - t
        rows[name] = {"initial": _bad(res.initial, sc), "planes": _bad(res.plane_map, sc),
                      "final": _bad(res.disparity, sc), "timings": res.timings, "total_s": total,
                      "info": res.info}
        f = rows[name]["final"]
        print(f"{name:8s} init {'/'.join(f'{v:.2f}' for v in rows[name]['initial'])}  "
              f"planes {'/'.join(f'{v:.2f}' for v in rows[name]['planes'])}  "
              f"final {f[0]:.2f}/{f[1]:.2f}/{f[2]:.2f}  (thesis {'/'.join(map(str, THESIS[name]))})  "
              f"{total:.2f}s " + " ".join(f"{k}={v:.2f}" for k, v in res.timings.items()), flush=True)
    finals = [v for r in rows.values() for v in r["final"]]
    print(f"average of {len(finals)}: {np.mean(finals):.2f}  (thesis 4.07)   peak RSS "
          f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)


if __name__ == "__main__":
    main()
