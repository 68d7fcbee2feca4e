"""Coarse-to-fine against the full search in the depth pipeline on a rendered capture (issue 30), one process.

For a capture folder written by ``prismstereo simulate`` (``rig.toml``, ``capture.png``, ``depth_gt.pfm``) the
set-up is prepared once per mode (``prepare_depth``) and one frame run (``run_depth_frame``) with
``DepthConfig(method=METHOD, depth_range=..., coarse_to_fine=MODE)`` for each mode given, in that order.
Printed per run (JSON lines): the rectified size, disparity range, the match step's wall and CPU seconds, the
median relative depth error and the coverage against the ground truth, ``run.json``'s ``matching`` record, the
process's peak RSS so far (run the mode whose peak you want first) and the load average.

    PYTHONPATH=src NUMBA_CACHE_DIR=.numba_cache .venv/bin/python benchmarks/bench_c2f_depth.py OUT/robot2k \\
        --method sgm --depth-range 1052,2675 --modes auto,off,auto
"""

from __future__ import annotations

import argparse
import json
import os
import resource

from prismstereo.config import load_rig
from prismstereo.depth.pipeline import DepthConfig, prepare_depth, run_depth_frame
from prismstereo.evaluation.depth_metrics import evaluate_depth, read_depth_gt
from prismstereo.io import read_image


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("folder")
    ap.add_argument("--method", default="sgm")
    ap.add_argument("--depth-range", required=True, help="MIN,MAX mm (e.g. a full run's run.json depth_range_mm)")
    ap.add_argument("--modes", default="auto,off")
    args = ap.parse_args()
    rig = load_rig(f"{args.folder}/rig.toml")
    img = read_image(f"{args.folder}/capture.png")
    gt = read_depth_gt(f"{args.folder}/depth_gt.pfm", rig)
    lo, hi = (float(v) for v in args.depth_range.split(","))
    for mode in args.modes.split(","):
        cfg = DepthConfig(method=args.method, depth_range=(lo, hi), coarse_to_fine=mode)
        res = run_depth_frame(prepare_depth(rig, config=cfg), img)
        acc = evaluate_depth(res, depth_gt=gt)
        s = res.summary()
        print(json.dumps({"mode": mode, "size": s["rectified_size"], "range": s["disparity_range"],
                          "match_wall": round(res.timings["match"], 2), "match_cpu": round(res.cpu_timings["match"], 2),
                          "median_rel_pct": round(100 * acc["median_rel"], 4),
                          "coverage_pct": round(100 * acc["coverage"], 2),
                          "matching": s["matching"],
                          "maxrss_gb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20, 2),
                          "load": round(os.getloadavg()[0], 1)}), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
