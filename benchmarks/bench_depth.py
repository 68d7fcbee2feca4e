"""Depth accuracy of the pipeline on simulated captures, for each triangulation (issue 6).

Run: .venv/bin/python benchmarks/bench_depth.py [--quick] [--method bpasw]

For each scene the capture is rendered with the simulator, the depth pipeline runs once (fitted virtual
cameras, the matcher, sub-pixel refinement) and the same matches are triangulated with every method:
``exact`` (exact refractive rays), ``q`` (Eq. 7.23 of the fitted rectified pair), ``midpoint`` (Eq. 7.19 on
the fitted cameras' rays) and ``dlt``. The thesis's own construction is a second run (thesis virtual
cameras for rectification, Q). Accuracy is against the simulator's exact ground truth (see
:mod:`prismstereo.evaluation.depth_metrics`): median and 95th-percentile relative depth error, share of
points within 1 %, coverage of the common view. ``--quick`` uses the rigs at half resolution.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import numpy as np

from prismstereo.apps.demo import demo_scene, plane_scene, robot_scene, scaled_rig
from prismstereo.config import Rig, pyramid_rig, thesis_biprism, thesis_triprism
from prismstereo.depth import DepthConfig, run_depth, triangulate_matches
from prismstereo.evaluation.depth_metrics import DepthGroundTruth, depth_accuracy, evaluate_depth, ground_truth_for_run
from prismstereo.simulate import render_capture


def _acc_of(res: Any, method: str, gt: DepthGroundTruth) -> dict[str, Any]:
    ys, xs = np.nonzero(res.valid)
    d = res.disparity[ys, xs].astype(np.float64)
    tri = triangulate_matches(res.rig, res.pair, ys, xs, d, method=method, views=res.views)
    depth = np.full(res.valid.shape, np.nan)
    depth[ys[tri.valid], xs[tri.valid]] = tri.points[tri.valid, 2]
    return depth_accuracy(depth, np.isfinite(depth), gt)


def _row(scene: str, rig: str, tri: str, acc: dict[str, Any], secs: float) -> str:
    return (f"| {scene} | {rig} | {tri} | {100 * acc['median_rel']:.3f} | {100 * acc['p95_rel']:.3f} | "
            f"{100 * acc['within_1pct']:.1f} | {100 * acc['coverage']:.1f} | {acc['n_points']} | {secs:.1f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="rigs at half resolution")
    ap.add_argument("--method", default="bpasw")
    ap.add_argument("--no-thesis", action="store_true", help="skip the thesis-construction runs")
    args = ap.parse_args()
    f = 2 if args.quick else 1

    def rig_of(r: Rig) -> Rig:
        return r if f == 1 else scaled_rig(r, f)

    bi = rig_of(thesis_biprism())
    from prismstereo.simulate import robot_scene as builtin_robot

    ex_rig, ex_scene = builtin_robot(width=1024 // f)  # examples/biprism_robot.toml (demo scene)
    cases: list[tuple[str, Rig, str, Any]] = [
        ("examples robot (1.2–2.2 m)", ex_rig, "bi-prism", ex_scene),
        ("demo (1.25–1.9 m)", bi, "bi-prism", demo_scene()),
        ("robot (1.5 m)", bi, "bi-prism", robot_scene()),
        ("plane 1.0 m, 30°", bi, "bi-prism", plane_scene(1000.0, tilt_deg=30.0)),
        ("plane 1.5 m, −20°", bi, "bi-prism", plane_scene(1500.0, tilt_deg=-20.0, seed=7)),
        ("plane 2.0 m, 40°", bi, "bi-prism", plane_scene(2000.0, tilt_deg=40.0, seed=9)),
        ("demo (1.25–1.9 m)", rig_of(thesis_triprism()), "tri-prism", demo_scene()),
        ("demo (1.25–1.9 m)", rig_of(pyramid_rig(4)), "4-face", demo_scene()),
    ]
    w, h = bi.camera.width, bi.camera.height
    print(f"# Depth accuracy on simulated captures ({w}×{h} bi-prism; matcher {args.method}; refined)\n")
    print("| scene | rig | triangulation | median % | p95 % | within 1 % | coverage % | points | s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, rig, rig_name, scene in cases:
        cap = render_capture(rig, scene)
        t = time.perf_counter()
        res = run_depth(rig, cap.image, config=DepthConfig(method=args.method), progress=False)
        secs = time.perf_counter() - t
        gt = ground_truth_for_run(res, scene=scene)
        exact = evaluate_depth(res, gt=gt)
        for tri in ("exact", "q", "midpoint", "dlt"):
            print(_row(name, rig_name, tri, exact if tri == "exact" else _acc_of(res, tri, gt), secs), flush=True)
        if not args.no_thesis and rig_name == "bi-prism":
            t = time.perf_counter()
            th = run_depth(rig, cap.image, config=DepthConfig(method=args.method, calibration="thesis",
                                                             triangulation="q"), progress=False)
            secs = time.perf_counter() - t
            print(_row(name, rig_name, "thesis construction (Q)", evaluate_depth(th, scene=scene), secs),
                  flush=True)


if __name__ == "__main__":
    main()
