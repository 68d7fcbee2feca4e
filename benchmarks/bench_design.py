"""Measure the disparity precision behind ``prismstereo design`` (issue 29): rendered fronto-parallel textured
planes through several prisms at several depths, the depth pipeline per preset, the median absolute disparity
error and its relation to the depth error (:mod:`prismstereo.design.verify`).

    PYTHONPATH=src NUMBA_CACHE_DIR=.numba_cache python benchmarks/bench_design.py --presets fast,balanced,accurate

Prints one row per (rig, depth, preset) and the pooled median |δd| per preset, the values of
``prismstereo.design.precision.DISPARITY_PRECISION``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

from prismstereo.config import Rig, thesis_biprism, thesis_triprism
from prismstereo.design import search
from prismstereo.design.verify import measure_at_depth


def rigs() -> dict[str, tuple[Rig, tuple[float, ...]]]:
    """name -> (rig, depths mm)."""
    out: dict[str, tuple[Rig, tuple[float, ...]]] = {
        "thesis bi-prism 6.4°": (thesis_biprism(), (1200.0, 1500.0, 1800.0)),
        "thesis tri-prism (0,1)": (thesis_triprism(), (600.0, 900.0)),
    }
    cam = thesis_biprism().camera
    best = search(cam, near=1200.0, far=1800.0, faces=(2,), glass="n=1.5", disparity_precision=0.02).best
    out[f"designed bi-prism {best.rig.prism.corner_angle:g}° apex {best.rig.prism.apex_distance:g}"] = (
        best.rig, (1200.0, 1500.0, 1800.0))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--presets", default="fast,balanced", help="comma-separated presets (fast, balanced, accurate)")
    ap.add_argument("--rigs", default=None, help="comma-separated substrings of the rig names to run (default all)")
    ap.add_argument("--depths", default=None, help="comma-separated depths (mm) to keep of each rig's (default all)")
    ap.add_argument("--json", default=None, help="write the rows to this JSON file")
    args = ap.parse_args(argv)
    presets = [p.strip() for p in args.presets.split(",") if p.strip()]
    print(f"load average {os.getloadavg()[0]:.2f}", flush=True)
    print(f"{'rig':<36} {'Z mm':>6} {'preset':>9} {'med rel %':>10} {'|dd| px':>8} {'bias px':>8} "
          f"{'model %':>9} {'ratio':>6} {'cover':>6} {'B mm':>6} {'t s':>6}", flush=True)
    rows = []
    chosen = rigs()
    if args.rigs:
        keys = [k.strip() for k in args.rigs.split(",")]
        chosen = {n: v for n, v in chosen.items() if any(k in n for k in keys)}
    for name, (rig, depths) in chosen.items():
        keep = None if args.depths is None else {float(v) for v in args.depths.split(",")}
        for z in depths:
            if keep is not None and z not in keep:
                continue
            for preset in presets:
                t = time.perf_counter()
                m = measure_at_depth(rig, z, preset=preset)
                dt = time.perf_counter() - t
                rows.append({"rig": name, **m.to_dict()})
                print(f"{name:<36} {z:>6.0f} {preset:>9} {100 * m.median_rel:>10.4f} {m.median_abs_disparity_px:>8.4f} "
                      f"{m.disparity_bias_px:>8.4f} {100 * m.model_rel:>9.4f} {m.model_ratio:>6.3f} "
                      f"{m.coverage:>6.3f} {m.baseline_mm:>6.2f} {dt:>6.1f}", flush=True)
    print("\npooled median |dd| per preset (DISPARITY_PRECISION):")
    for preset in presets:
        vals = [r["median_abs_disparity_px"] for r in rows if r["preset"] == preset]
        print(f"  {preset:<9} {float(np.median(vals)):.4f} px  (per run {min(vals):.4f}-{max(vals):.4f}, "
              f"{len(vals)} runs)")
    print(f"load average {os.getloadavg()[0]:.2f}")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(rows, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
