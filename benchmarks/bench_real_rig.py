"""Calibration of a real (misaligned, distorting) rig from simulated captures, and the depth it gives (issue 15).

Run: .venv/bin/python benchmarks/bench_real_rig.py [--captures 10] [--quick]

The "true" rig is the thesis bi-prism (α = 6.4°) rotated 1.4°, tilted (1.0°, −0.8°), decentred (1.0, −0.5) mm,
on a lens with k1 = −0.10, k2 = 0.12. Every image is rendered by the simulator through that rig with sensor
noise (σ = 1 grey level), 20 % vignetting and 8-bit rounding. The workflow of docs/real-rigs.md:

1. ``calibrate_camera`` on 12 photos of the 8×6-corner, 3 mm board taken without the prism (0.25–0.4 m);
2. ``calibrate_prism`` on board captures through the prism (0.6–1.2 m), starting from the nominal prism and
   the camera of step 1;
3. depth of a textured plane at 1.2 m (turned 25°) computed with the nominal rig (what a user gets without
   calibrating), the calibrated rig, and the true rig.

Depth accuracy is measured against the truth: every reconstructed rectified pixel is mapped to its real pixel
(a pure resampling, exact whatever rig was used), whose ray through the TRUE rig hits the scene.
``--quick`` renders at half resolution (faster, coarser).
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import time

import numpy as np

from prismstereo.calibration import Board, calibrate_camera, calibrate_prism
from prismstereo.config import Rig, thesis_biprism
from prismstereo.depth import DepthConfig, run_depth
from prismstereo.depth.demo import plane_scene, scaled_rig
from prismstereo.evaluation.depth_metrics import evaluate_depth
from prismstereo.simulate import render_capture
from prismstereo.simulate.checkerboard import camera_board_poses, checkerboard_poses


def true_rig(nominal: Rig) -> Rig:
    cam = dataclasses.replace(nominal.camera, distortion=(-0.10, 0.12, 0.0, 0.0, 0.0))
    return dataclasses.replace(nominal, camera=cam, name="true").with_prism(
        rotation=1.4, tilt=(1.0, -0.8), decenter=(1.0, -0.5))


def _sensor(scene, seed: int):
    return dataclasses.replace(scene, noise=1.0, vignetting=0.2, seed=seed)


def depth_row(name: str, rig: Rig, true: Rig, image: np.ndarray, scene) -> dict:
    t0 = time.perf_counter()
    res = run_depth(rig, image, config=DepthConfig())
    secs = time.perf_counter() - t0
    judged = copy.copy(res)
    judged.rig = true  # the truth: the real pixels' rays through the true prism
    acc = evaluate_depth(judged, scene=scene)
    return {"rig": name, **acc, "seconds": secs}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--captures", type=int, default=10)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    nominal = thesis_biprism()
    if args.quick:
        nominal = scaled_rig(nominal, 2)
    true = true_rig(nominal)
    board = Board(8, 6, 3.0)

    t0 = time.perf_counter()
    cam_poses = camera_board_poses(true, n_poses=12, squares=(9, 7), square_mm=3.0, seed=0)
    photos = [render_capture(true, _sensor(p.scene, i), supersample=2, prism=False).image
              for i, p in enumerate(cam_poses)]
    t1 = time.perf_counter()
    cam = calibrate_camera(photos, board)
    t2 = time.perf_counter()
    print(f"camera: rendered {len(photos)} photos in {t1 - t0:.0f} s, calibrated in {t2 - t1:.1f} s")
    print(cam.summary().splitlines()[-1])
    print(f"true: fx = fy = {true.camera.focal_px:.2f}, c = {true.camera.center}, k1 -0.10, k2 0.12")

    poses = checkerboard_poses(true, n_poses=args.captures, squares=(9, 7), square_mm=3.0,
                               distance_range=(600.0, 1200.0), seed=1)
    caps = [render_capture(true, _sensor(p.scene, 100 + i), supersample=2).image for i, p in enumerate(poses)]
    start = dataclasses.replace(nominal, camera=cam.camera, name="start")
    t3 = time.perf_counter()
    pc = calibrate_prism(start, caps, board)
    t4 = time.perf_counter()
    print(f"\nprism: {len(caps)} captures rendered; calibrate_prism {t4 - t3:.1f} s")
    print(pc.summary())
    truth = {"rotation": 1.4, "tilt_x": 1.0, "tilt_y": -0.8, "decenter_x": 1.0, "decenter_y": -0.5}
    print("\n| parameter | true | fitted | error | std |\n|---|---|---|---|---|")
    for k, v in pc.estimates.items():
        print(f"| {k} | {truth[k]:g} | {v:.4f} | {v - truth[k]:+.4f} | {pc.std[k]:.4f} |")

    scene = _sensor(plane_scene(1200.0, tilt_deg=25.0), 7)
    image = render_capture(true, scene).image
    rows = [depth_row("nominal (uncalibrated)", nominal, true, image, scene),
            depth_row("calibrated", pc.rig, true, image, scene),
            depth_row("true", true, true, image, scene)]
    print("\n| rig | median rel % | p95 rel % | within 1 % | coverage | points | depth s |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['rig']} | {100 * r['median_rel']:.3f} | {100 * r['p95_rel']:.3f} | "
              f"{100 * r['within_1pct']:.1f} | {100 * r['coverage']:.1f} | {r['n_points']} | {r['seconds']:.0f} |")


if __name__ == "__main__":
    main()
