"""Self-calibration of a misaligned prism from one ordinary capture, and rectified rows at the working depth.

Run: .venv/bin/python benchmarks/bench_self_calibration.py [--no-pipeline]

1. The "true" rig is the thesis bi-prism (α = 6.4°) rotated 1.4°, tilted (1.0°, −0.8°), decentred (1.0, −0.5)
   mm, on a lens with k1 = −0.10, k2 = 0.12 (the lens is known: ``calibrate-camera``). One 1024×768 capture of
   three textured planes (1.1–1.8 m) is rendered through it with sensor noise (σ = 1 grey level), 20 %
   vignetting and 8-bit rounding. ``calibrate_from_scene`` refines the NOMINAL prism (centred, same apex
   distance and index) from that capture alone.
2. Rows: |y_left − y_right| of SIFT matches between the rectified views (``row_misalignment``) under the
   nominal, refined and true rigs.
3. Depth: true correspondences (left pixel, the right pixel that sees the same scene point through the true
   prism) triangulated with each rig; and the depth pipeline (bpasw) on the capture, judged against the truth
   (``--no-pipeline`` skips it).
4. The 20° bi-prism at its working depth: a textured plane at 300 mm (and planes at 260 / 330 mm; its views
   share a field only at ~225–330 mm), no misalignment: rectified size and rows |dy| on SIFT matches.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import time

import numpy as np

from prismstereo.calibration.drift import row_misalignment
from prismstereo.calibration.from_scene import calibrate_from_scene
from prismstereo.config import Rig, thesis_biprism
from prismstereo.errors import PrismStereoError
from prismstereo.simulate import NoiseTexture, Plane, Rectangle, Scene, render_capture


def rigs() -> tuple[Rig, Rig]:
    nominal = thesis_biprism()
    cam = dataclasses.replace(nominal.camera, distortion=(-0.10, 0.12, 0.0, 0.0, 0.0))
    nominal = dataclasses.replace(nominal, camera=cam, name="nominal")
    true = dataclasses.replace(nominal, name="true").with_prism(rotation=1.4, tilt=(1.0, -0.8), decenter=(1.0, -0.5))
    return nominal, true


def planes_scene(seed: int = 5) -> Scene:
    return Scene(objects=(
        Plane(center=(0.0, 0.0, 1800.0), rotation=(0.0, 15.0, 0.0), texture=NoiseTexture(scale=30.0, seed=1),
              name="wall"),
        Rectangle(center=(-30.0, -40.0, 1300.0), size=(120.0, 90.0), rotation=(10.0, -25.0, 0.0),
                  texture=NoiseTexture(scale=20.0, seed=2), name="panel a"),
        Rectangle(center=(30.0, 50.0, 1100.0), size=(110.0, 80.0), rotation=(-15.0, 20.0, 0.0),
                  texture=NoiseTexture(scale=15.0, seed=3), name="panel b"),
    ), supersample=2, noise=1.0, vignetting=0.2, seed=seed, name="planes")


def correspondence_row(rig: Rig, true: Rig, capture, left: int = 1, right: int = 0) -> dict:
    """True correspondences triangulated with ``rig`` (exact rays): median relative depth error."""
    from prismstereo.depth.triangulation import triangulate_exact
    from prismstereo.optics import project_exact

    vv, uu = np.nonzero((capture.faces == left) & np.isfinite(capture.depth))
    pick = np.arange(0, vv.size, max(1, vv.size // 4000))
    pl = np.stack([uu[pick], vv[pick]], axis=1).astype(np.float64)
    X = capture.points[vv[pick], uu[pick]]
    pr, ok = project_exact(true, X, face=right, tolerance_px=1e-9)
    w, h = true.camera.width, true.camera.height
    ok &= (pr[:, 0] >= 0) & (pr[:, 0] <= w - 1) & (pr[:, 1] >= 0) & (pr[:, 1] <= h - 1)
    tri = triangulate_exact(rig, pl[ok], pr[ok])
    rel = np.abs(tri.points[:, 2] - X[ok, 2]) / X[ok, 2]
    return {"median_rel": float(np.nanmedian(rel)), "p95_rel": float(np.nanpercentile(rel, 95)),
            "n": int(ok.sum())}


def pipeline_row(rig: Rig, true: Rig, image: np.ndarray, scene: Scene) -> dict:
    from prismstereo.depth import DepthConfig, run_depth
    from prismstereo.evaluation.depth_metrics import evaluate_depth

    t0 = time.perf_counter()
    res = run_depth(rig, image, config=DepthConfig())
    secs = time.perf_counter() - t0
    judged = copy.copy(res)
    judged.rig = true  # the truth: the real pixels' rays through the true prism
    return {**evaluate_depth(judged, scene=scene), "seconds": secs}


def working_depth_rows() -> None:
    from prismstereo.cameras import calibrate_rig
    from prismstereo.rectify import rectify_pair

    rig = dataclasses.replace(thesis_biprism(20.0), name="biprism-20")
    views = calibrate_rig(rig)
    pair = rectify_pair(rig, views[0], views[1])
    print(f"\n20° bi-prism: rectified pair {pair.size[0]}×{pair.size[1]} px, fit RMS "
          f"{', '.join(f'{v.rms_px:.3f}' for v in views)} px")
    print("| scene | matches | median |dy| px | p95 |dy| px |\n|---|---|---|---|")
    for z in (260.0, 300.0, 330.0):
        scene = Scene(objects=(Plane(center=(0.0, 0.0, z), rotation=(0.0, 10.0, 0.0),
                                     texture=NoiseTexture(scale=6.0, seed=11), name="plane"),),
                      supersample=2, noise=1.0, seed=3, name=f"plane-{z:g}")
        img = render_capture(rig, scene).image
        try:
            c = row_misalignment(rig, img)
        except PrismStereoError as exc:
            print(f"| plane at {z:g} mm | refused: {exc} | | |")
            continue
        print(f"| plane at {z:g} mm | {c.n_matches} | {c.median_px:.3f} | {c.p95_px:.3f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--no-pipeline", action="store_true", help="skip the depth pipeline runs")
    ap.add_argument("--only-working-depth", action="store_true", help="only part 4 (the 20° bi-prism)")
    args = ap.parse_args()
    if args.only_working_depth:
        working_depth_rows()
        return
    nominal, true = rigs()
    scene = planes_scene()
    t0 = time.perf_counter()
    capture = render_capture(true, scene)
    print(f"rendered the misaligned capture in {time.perf_counter() - t0:.0f} s")
    t0, c0 = time.perf_counter(), time.process_time()
    cal = calibrate_from_scene(nominal, [capture.image])
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    print(cal.summary())
    print(f"calibrate_from_scene (matching included): {wall:.1f} s wall, {cpu:.1f} s CPU (this process)")
    truth = {"rotation": 1.4, "tilt_x": 1.0, "tilt_y": -0.8}
    print("| parameter | true | fitted ± std | error |\n|---|---|---|---|")
    for k, v in cal.estimates.items():
        print(f"| {k} | {truth[k]:g} | {v:.4f} ± {cal.std[k]:.4f} | {v - truth[k]:+.4f} |")

    print("\n| rig | rows: matches | median |dy| px | p95 |dy| px | true corr.: median rel % | p95 rel % |")
    print("|---|---|---|---|---|---|")
    for name, rig in (("nominal", nominal), ("refined (from scene)", cal.rig), ("true", true)):
        c = row_misalignment(rig, capture.image)
        d = correspondence_row(rig, true, capture)
        print(f"| {name} | {c.n_matches} | {c.median_px:.3f} | {c.p95_px:.3f} | {100 * d['median_rel']:.3f} | "
              f"{100 * d['p95_rel']:.3f} |")
    if not args.no_pipeline:
        print("\nDepth pipeline (bpasw, exact triangulation) on the capture, against the truth:")
        print("| rig | median rel % | p95 rel % | within 1 % | coverage % | points | s |")
        print("|---|---|---|---|---|---|---|")
        for name, rig in (("refined (from scene)", cal.rig), ("true", true)):
            r = pipeline_row(rig, true, capture.image, scene)
            print(f"| {name} | {100 * r['median_rel']:.3f} | {100 * r['p95_rel']:.3f} | {100 * r['within_1pct']:.1f} "
                  f"| {100 * r['coverage']:.1f} | {r['n_points']} | {r['seconds']:.0f} |")
    working_depth_rows()


if __name__ == "__main__":
    main()
