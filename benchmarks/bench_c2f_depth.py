"""Coarse-to-fine against the full search in the depth pipeline on a rendered capture (issue 30), one process.

For a capture folder written by ``prismstereo simulate`` (``rig.toml``, ``capture.png``, ``depth_gt.pfm``) the
set-up is prepared once per mode (``prepare_depth``) and one frame run (``run_depth_frame``) with
``DepthConfig(method=METHOD, depth_range=..., coarse_to_fine=MODE)`` for each mode given, in that order.
Printed per run (JSON lines): the rectified size, disparity range, the match step's wall and CPU seconds, the
median relative depth error and the coverage against the ground truth, ``run.json``'s ``matching`` record, the
process's peak RSS so far (run the mode whose peak you want first) and the load average.

    PYTHONPATH=src NUMBA_CACHE_DIR=.numba_cache .venv/bin/python benchmarks/bench_c2f_depth.py OUT/robot2k \\
        --method sgm --depth-range 1052,2675 --modes auto,off,auto
    ... --preset balanced --modes auto,auto,auto,auto --bands tile,segment   # band A/B, interleaved

``--bands`` sets :class:`~prismstereo.matching.scale.ScaleParams`'s ``band`` of each run (cycled along ``--modes``);
``--preset`` applies a preset's profile over ``--method`` (the depth range and mode kept). Printed besides: the
frame's wall and CPU seconds and the match's stages (``match_timings``).
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import resource
import time

from prismstereo.config import load_rig
from prismstereo.depth import pipeline
from prismstereo.depth.pipeline import DepthConfig, prepare_depth, run_depth_frame
from prismstereo.depth.presets import apply_preset
from prismstereo.evaluation.depth_metrics import evaluate_depth, read_depth_gt
from prismstereo.io import read_image
from prismstereo.matching.scale import ScaleParams


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("folder")
    ap.add_argument("--method", default="sgm")
    ap.add_argument("--depth-range", required=True, help="MIN,MAX mm (e.g. a full run's run.json depth_range_mm)")
    ap.add_argument("--modes", default="auto,off")
    ap.add_argument("--bands", default="segment",
                    help="ScaleParams.band per run, cycled with the modes (e.g. segment,tile,segment,tile)")
    ap.add_argument("--preset", default=None, help="apply this preset's profile (fast, balanced, accurate)")
    args = ap.parse_args()
    rig = load_rig(f"{args.folder}/rig.toml")
    img = read_image(f"{args.folder}/capture.png")
    gt = read_depth_gt(f"{args.folder}/depth_gt.pfm", rig)
    lo, hi = (float(v) for v in args.depth_range.split(","))
    modes = args.modes.split(",")
    bands = args.bands.split(",")
    for i, mode in enumerate(modes):
        band = bands[i % len(bands)]
        cfg = DepthConfig(method=args.method, depth_range=(lo, hi), coarse_to_fine=mode)
        if args.preset:
            cfg = apply_preset(cfg, args.preset, given=["depth_range", "coarse_to_fine"])
        # the pipeline builds its ScaleParams itself: the band is the benchmark's A/B switch
        pipeline.ScaleParams = functools.partial(ScaleParams, band=band)  # type: ignore[misc]
        t, c = time.perf_counter(), time.process_time()
        res = run_depth_frame(prepare_depth(rig, config=cfg), img)
        frame_wall, frame_cpu = time.perf_counter() - t, time.process_time() - c
        acc = evaluate_depth(res, depth_gt=gt)
        s = res.summary()
        print(json.dumps({"mode": mode, "band": band, "method": cfg.method, "size": s["rectified_size"],
                          "range": s["disparity_range"],
                          "match_wall": round(res.timings["match"], 2), "match_cpu": round(res.cpu_timings["match"], 2),
                          "frame_wall": round(frame_wall, 2), "frame_cpu": round(frame_cpu, 2),
                          "match_stages": {k: round(v, 2) for k, v in res.match_timings.items()},
                          "median_rel_pct": round(100 * acc["median_rel"], 4),
                          "coverage_pct": round(100 * acc["coverage"], 2),
                          "matching": s["matching"],
                          "maxrss_gb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20, 2),
                          "load": round(os.getloadavg()[0], 1)}), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
