"""Residual vertical disparity of rectified pairs on exact correspondences (issue 5, item 4).

Run: .venv/bin/python benchmarks/bench_rectify.py [--quick]
Prints a markdown table: rig, pair, model (fit/thesis), remap (model/exact), depth range, RMS, p95, max.
"""

from __future__ import annotations

import argparse
import time
from itertools import combinations

from prismstereo.cameras import calibrate_rig
from prismstereo.config import Rig, pyramid_rig, thesis_biprism, thesis_triprism
from prismstereo.errors import GeometryError
from prismstereo.rectify import (
    common_depth_range,
    rectify_pair,
    true_correspondences,
    vertical_residual,
    view_regions,
)
from prismstereo.rectify.verify import DEPTH_RANGE_MM


def rigs() -> list[tuple[str, Rig]]:
    return [("bi-prism 6.4°", thesis_biprism(6.4)), ("bi-prism 10°", thesis_biprism(10.0)),
            ("bi-prism 20°", thesis_biprism(20.0)), ("tri-prism", thesis_triprism()),
            ("4-face", pyramid_rig(4))]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--n", type=int, default=4000)
    args = ap.parse_args()
    n = 800 if args.quick else args.n
    print("| rig | pair (L,R) | model | remap | depths used (mm) | n | RMS px | p95 px | max px |")
    print("|---|---|---|---|---|---|---|---|---|")
    t0 = time.time()
    for name, rig in rigs():
        regions = view_regions(rig)
        for method in ("fit", "thesis"):
            views = calibrate_rig(rig, method=method)
            for a, b in combinations(range(rig.prism.faces), 2):
                for remap in ("model", "exact"):
                    try:
                        pair = rectify_pair(rig, views[a], views[b], remap=remap, regions=regions)  # type: ignore[arg-type]
                    except GeometryError as exc:
                        print(f"| {name} | {a},{b} | {method} | {remap} | – | 0 | {exc} | | |")
                        continue
                    rng = DEPTH_RANGE_MM
                    try:
                        corr = true_correspondences(rig, pair.left_face, pair.right_face, n=n, depth_range=rng,
                                                    regions=regions)
                    except GeometryError:
                        lo, hi = common_depth_range(pair)
                        rng = (max(lo, rig.prism.back_distance + 50.0), min(hi, 2500.0))
                        corr = true_correspondences(rig, pair.left_face, pair.right_face, n=n, depth_range=rng,
                                                    regions=regions)
                    res, _ = vertical_residual(pair, corr)
                    print(f"| {name} | {pair.left_face},{pair.right_face} | {method} | {remap} | "
                          f"{res.depth_range[0]:.0f}–{res.depth_range[1]:.0f} | {res.n} | {res.rms:.3f} | "
                          f"{res.p95:.3f} | {res.max:.3f} |", flush=True)
    print(f"\n{time.time() - t0:.0f} s")


if __name__ == "__main__":
    main()
