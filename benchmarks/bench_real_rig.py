"""Calibration of a real (misaligned, distorting) rig from simulated captures, and the depth it gives (issue 15).

Run: .venv/bin/python benchmarks/bench_real_rig.py [--quick] [--seed 1] [--captures 10] [--scale 1]

The "true" rig is the thesis bi-prism (α = 6.4°) rotated 1.4°, tilted (1.0°, −0.8°), decentred (1.0, −0.5) mm,
on a lens with k1 = −0.10, k2 = 0.12. Every image is rendered by the simulator through that rig with sensor
noise (σ = 1 grey level), 20 % vignetting and 8-bit rounding. The workflow of docs/real-rigs.md:

1. ``calibrate_camera`` on 20 photos of the 8×6-corner, 3 mm board taken without the prism (0.25–0.4 m);
2. ``calibrate_prism`` on ``--captures`` board captures through the prism (0.6–1.2 m, poses drawn with
   ``--seed``), starting from the nominal prism and the camera of step 1;
3. depth of a textured plane at 1.2 m (turned 25°) computed with the nominal rig (what a user gets without
   calibrating), the calibrated rig, and the true rig.

Depth accuracy is measured against the truth: every reconstructed rectified pixel is mapped to its real pixel
(a pure resampling, exact whatever rig was used), whose ray through the TRUE rig hits the scene.

Modes. The full mode (about 12 min on an idle 2-core machine) also fits the prism alone on the
photo-calibrated camera and on the exact camera, and runs the depth pipeline with every rig. ``--quick``
(about 3 min) keeps the same scenario and the default fit, and runs the depth pipeline with the calibrated
rig only (the nominal and true rigs are in the geometry table, which is cheap). ``--scale 2`` renders a
half-resolution rig (a different scenario: squares of 6–13 px). Every step prints its wall and CPU seconds.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import time

import numpy as np

from prismstereo.apps.demo import plane_scene, scaled_rig
from prismstereo.calibration import Board, calibrate_camera, calibrate_prism
from prismstereo.config import Rig, thesis_biprism
from prismstereo.depth import DepthConfig, run_depth
from prismstereo.errors import PrismStereoError
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


def correspondence_row(name: str, rig: Rig, true: Rig, capture) -> dict:
    """Geometry alone: triangulate TRUE correspondences (left pixel, the right pixel that sees the same scene
    point through the true prism) with ``rig``; and how far apart their rectified rows are under ``rig``."""
    from prismstereo.cameras import calibrate_rig
    from prismstereo.depth.triangulation import triangulate_exact
    from prismstereo.optics import project_exact
    from prismstereo.rectify import rectify_pair

    left, right = 1, 0
    vv, uu = np.nonzero((capture.faces == left) & np.isfinite(capture.depth))
    pick = np.arange(0, vv.size, max(1, vv.size // 4000))
    pl = np.stack([uu[pick], vv[pick]], axis=1).astype(np.float64)
    X = capture.points[vv[pick], uu[pick]]
    pr, ok = project_exact(true, X, face=right, tolerance_px=1e-9)
    ok &= (pr[:, 0] >= 0) & (pr[:, 0] <= true.camera.width - 1) & (pr[:, 1] >= 0) & (pr[:, 1] <= true.camera.height - 1)
    pl, pr, X = pl[ok], pr[ok], X[ok]
    tri = triangulate_exact(rig, pl, pr)
    rel = np.abs(tri.points[:, 2] - X[:, 2]) / X[:, 2]
    views = calibrate_rig(rig)
    pair = rectify_pair(rig, views[left], views[right])
    rows = np.abs(pair.real_to_rectified(pl, "left")[:, 1] - pair.real_to_rectified(pr, "right")[:, 1])
    return {"rig": name, "median_rel": float(np.nanmedian(rel)), "within_1pct": float(np.nanmean(rel <= 0.01)),
            "rows_px": float(np.nanmedian(rows)), "n": int(pl.shape[0])}


class _Clock:
    """Wall and CPU seconds of each step (CPU of this process, all threads)."""

    def __init__(self) -> None:
        self.rows: list[tuple[str, float, float]] = []

    def __call__(self, name: str):  # noqa: ANN204 - a context manager
        import contextlib

        @contextlib.contextmanager
        def step():
            t, c = time.perf_counter(), time.process_time()
            yield
            self.rows.append((name, time.perf_counter() - t, time.process_time() - c))

        return step()

    def table(self) -> str:
        lines = ["| step | wall s | CPU s |", "|---|---|---|"]
        lines += [f"| {n} | {w:.1f} | {c:.1f} |" for n, w, c in self.rows]
        lines.append(f"| total | {sum(r[1] for r in self.rows):.1f} | {sum(r[2] for r in self.rows):.1f} |")
        return "\n".join(lines)


def main() -> None:
    import os

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--captures", type=int, default=10)
    ap.add_argument("--seed", type=int, default=1, help="seed of the board poses through the prism")
    ap.add_argument("--scale", type=int, default=1, help="1/scale of the thesis rig's 1024×768 sensor")
    ap.add_argument("--quick", action="store_true", help="default fit and the calibrated rig's depth only")
    args = ap.parse_args()
    clock = _Clock()
    load0 = os.getloadavg()[0]
    nominal = thesis_biprism()
    if args.scale != 1:
        nominal = scaled_rig(nominal, args.scale)
    true = true_rig(nominal)
    board = Board(8, 6, 3.0)

    with clock("render 20 camera photos"):
        cam_poses = camera_board_poses(true, n_poses=20, squares=(9, 7), square_mm=3.0, max_tilt=45.0, seed=0)
        photos = [render_capture(true, _sensor(p.scene, i), supersample=2, prism=False).image
                  for i, p in enumerate(cam_poses)]
    with clock("calibrate_camera"):
        cam = calibrate_camera(photos, board)
    print(cam.summary().splitlines()[-1])
    print(f"true: fx = fy = {true.camera.focal_px:.2f}, c = {true.camera.center}, k1 -0.10, k2 0.12")

    with clock(f"render {args.captures} board captures"):
        poses = checkerboard_poses(true, n_poses=args.captures, squares=(9, 7), square_mm=3.0,
                                   distance_range=(600.0, 1200.0), seed=args.seed)
        caps = [render_capture(true, _sensor(p.scene, 100 + i), supersample=2).image for i, p in enumerate(poses)]
    start = dataclasses.replace(nominal, camera=cam.camera, name="start")
    with clock("calibrate_prism (default --free)"):
        pc = calibrate_prism(start, caps, board)
    print(f"\nprism: {len(caps)} captures (pose seed {args.seed}); calibrate_prism {pc.seconds:.1f} s")
    print(pc.summary())
    fits = [("default (prism + focal)", pc)]
    pc_prism = pc_exact = None
    if not args.quick:
        # the prism alone (camera held at its photo calibration), and with the exact camera
        with clock("calibrate_prism (prism only, photo camera)"):
            try:
                pc_prism = calibrate_prism(start, caps, board, free="rotation,tilt,decenter")
            except PrismStereoError as exc:
                print(f"prism-only fit on the photo-calibrated camera refused: {exc}")
        with clock("calibrate_prism (prism only, exact camera)"):
            pc_exact = calibrate_prism(dataclasses.replace(nominal, camera=true.camera), caps, board,
                                       free="rotation,tilt,decenter")
        fits += [(n, f) for n, f in (("prism only", pc_prism), ("prism only, exact camera", pc_exact))
                 if f is not None]
    truth = {"rotation": 1.4, "tilt_x": 1.0, "tilt_y": -0.8, "decenter_x": 1.0, "decenter_y": -0.5,
             "fx": true.camera.focal_px, "fy": true.camera.focal_px}
    print("\n| parameter | true | " + " | ".join(f"{n}: fitted ± std (error)" for n, _ in fits) + " |")
    print("|---|---|" + "---|" * len(fits))
    for k in pc.estimates:
        cells = [f"{f.estimates[k]:.4f} ± {f.std[k]:.4f} ({f.estimates[k] - truth[k]:+.4f})" if k in f.estimates
                 else "held" for _, f in fits]
        print(f"| {k} | {truth[k]:g} | " + " | ".join(cells) + " |")
    print("calibrate_prism seconds: " + ", ".join(f"{n} {f.seconds:.1f}" for n, f in fits))
    errs = {k: pc.estimates[k] - truth[k] for k in ("rotation", "tilt_x", "tilt_y")}
    print(f"targets: rotation error {errs['rotation']:+.4f}° (within 0.1°: {abs(errs['rotation']) <= 0.1}), "
          f"tilt errors {errs['tilt_x']:+.4f}° ± {pc.std['tilt_x']:.4f}, {errs['tilt_y']:+.4f}° ± "
          f"{pc.std['tilt_y']:.4f} (within 0.2°: {max(abs(errs['tilt_x']), abs(errs['tilt_y'])) <= 0.2})")

    scene = _sensor(plane_scene(1200.0, tilt_deg=25.0), 7)
    with clock("render the depth scene"):
        capture = render_capture(true, scene)
    image = capture.image
    rigs = [("nominal (uncalibrated)", nominal), ("calibrated (prism + focal)", pc.rig)]
    if pc_prism is not None:
        rigs.append(("calibrated (prism only)", pc_prism.rig))
    if pc_exact is not None:
        rigs.append(("calibrated, exact camera", pc_exact.rig))
    rigs.append(("true", true))
    print("\nTrue correspondences triangulated with each rig (geometry only):")
    print("| rig | median rel % | within 1 % | rectified rows apart, px | points |\n|---|---|---|---|---|")
    with clock("geometry table"):
        for name, rig in rigs:
            try:
                c = correspondence_row(name, rig, true, capture)
            except PrismStereoError as exc:
                print(f"| {name} | failed: {exc} | | | |")
                continue
            print(f"| {name} | {100 * c['median_rel']:.3f} | {100 * c['within_1pct']:.1f} | {c['rows_px']:.2f} | "
                  f"{c['n']} |")
    rows = []
    depth_rigs = [r for r in rigs if r[0].startswith("calibrated (prism + focal)")] if args.quick else rigs
    with clock(f"depth pipeline x{len(depth_rigs)}"):
        for name, rig in depth_rigs:
            try:
                rows.append(depth_row(name, rig, true, image, scene))
            except PrismStereoError as exc:
                print(f"depth with {name} failed: {exc}")
    print("\nDepth pipeline (bpasw matcher, exact triangulation) on the capture, against the truth:")
    print("| rig | median rel % | p95 rel % | within 1 % | coverage | points | depth s |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['rig']} | {100 * r['median_rel']:.3f} | {100 * r['p95_rel']:.3f} | "
              f"{100 * r['within_1pct']:.1f} | {100 * r['coverage']:.1f} | {r['n_points']} | {r['seconds']:.0f} |")
    print(f"\n{'quick' if args.quick else 'full'} mode, load average before {load0:.1f}, after "
          f"{os.getloadavg()[0]:.1f} ({os.cpu_count()} CPUs)")
    print(clock.table())


if __name__ == "__main__":
    main()
