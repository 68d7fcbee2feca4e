"""Residual vertical disparity of rectified pairs on exact correspondences (issue 5, item 4).

Run: .venv/bin/python benchmarks/bench_rectify.py [--quick] [--figures DIR]

``--figures DIR`` also renders a textured scene through each rig and runs ``prismstereo rectify`` on it,
writing the rectified images and the before/after epipolar figures into ``DIR/<rig>/``.

For each rig and each pair of faces, true correspondences (a real pixel of one face traced exactly to a
random depth, the point projected exactly through the other face) are mapped into the rectified pair; the
table gives RMS and 95th percentile of y_left − y_right (px) for the virtual camera models ``fit`` and
``thesis`` and the two remap constructions (``model``: through the camera model; ``exact``: through exact
refraction at a reference depth). Depths are 0.8–2.5 m where the two faces share a view there, else the
depths where they do (noted). Where the working depths differ from the 0.5–3 m the ``fit`` model was fitted
on, a row refits it there and puts the exact remap's reference depth in the middle.
"""

from __future__ import annotations

import argparse
import time
from itertools import combinations
from pathlib import Path

import numpy as np

from prismstereo.cameras import VirtualView, calibrate_rig, fit_camera, reprojection_error
from prismstereo.config import Rig, pyramid_rig, thesis_biprism, thesis_triprism
from prismstereo.errors import GeometryError
from prismstereo.rectify import (
    common_depth_range,
    rectify_pair,
    rectify_views,
    true_correspondences,
    vertical_residual,
    view_regions,
)
from prismstereo.rectify.verify import DEPTH_RANGE_MM


def rigs() -> list[tuple[str, Rig]]:
    return [("bi-prism 6.4°", thesis_biprism(6.4)), ("bi-prism 10°", thesis_biprism(10.0)),
            ("bi-prism 20°", thesis_biprism(20.0)), ("tri-prism", thesis_triprism()),
            ("4-face", pyramid_rig(4))]


def _cell(rig: Rig, views: list[VirtualView], a: int, b: int, remap: str, regions, n: int,  # type: ignore[no-untyped-def]
          depth: tuple[float, float] | None, ref_depth: float = 1500.0):
    pair = rectify_pair(rig, views[a], views[b], remap=remap, regions=regions,  # type: ignore[arg-type]
                        reference_depth_mm=ref_depth)
    rng = DEPTH_RANGE_MM if depth is None else depth
    try:
        corr = true_correspondences(rig, pair.left_face, pair.right_face, n=n, depth_range=rng, regions=regions)
        if corr.points.shape[0] < 100 and depth is None:
            raise GeometryError("too few")
    except GeometryError:
        lo, hi = common_depth_range(pair)
        rng = (max(lo, rig.prism.back_distance + 50.0), min(hi, 2500.0))
        corr = true_correspondences(rig, pair.left_face, pair.right_face, n=n, depth_range=rng, regions=regions)
    res, _ = vertical_residual(pair, corr)
    return pair, res


def figures(out: Path) -> None:
    """Render a box in front of a textured wall through each rig and rectify it (DESIGN.md §5 ``rectify``)."""
    from prismstereo.apps.rectify_folder import rectify_to_folder
    from prismstereo.io import write_image
    from prismstereo.simulate import Box, NoiseTexture, Plane, Scene, render_capture

    # (name, rig, box depth, wall depth): the 20° bi-prism's views meet only at 0.27-0.35 m
    setups = [("biprism6.4", thesis_biprism(6.4), 1400.0, 2500.0), ("biprism10", thesis_biprism(10.0), 1400.0, 2500.0),
              ("biprism20", thesis_biprism(20.0), 300.0, 340.0), ("triprism", thesis_triprism(), 500.0, 700.0),
              ("4face", pyramid_rig(4), 500.0, 800.0)]
    for name, rig, zb, zp in setups:
        k = zb / 1400.0
        scene = Scene(objects=(Plane(center=(0.0, 0.0, zp), texture=NoiseTexture(scale=80.0 * k)),
                               Box(center=(0.0, 0.0, zb), size=(60 * k, 60 * k, 60 * k), rotation=(10.0, 30.0, 0.0))),
                      supersample=2)
        d = out / name
        d.mkdir(parents=True, exist_ok=True)
        rig.save(d / "rig.toml")
        write_image(d / "capture.png", render_capture(rig, scene).image)
        print(rectify_to_folder(d / "rig.toml", d / "capture.png", d / "rectified").summary(), flush=True)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--figures", type=Path, default=None, help="also write rectified captures and figures here")
    args = ap.parse_args()
    if args.figures is not None:
        figures(args.figures)
    n = 800 if args.quick else 4000
    print("| rig | pair L,R | depths (mm) | n | fit/model RMS, p95 | fit/exact | thesis/model | thesis/exact |")
    print("|---|---|---|---|---|---|---|---|")
    t0 = time.time()
    for name, rig in rigs():
        regions = view_regions(rig)
        allviews = {m: calibrate_rig(rig, method=m) for m in ("fit", "thesis")}
        for a, b in combinations(range(rig.prism.faces), 2):
            cells, depth, info = [], None, ""
            for m in ("fit", "thesis"):
                for remap in ("model", "exact"):
                    try:
                        pair, res = _cell(rig, allviews[m], a, b, remap, regions, n, depth)
                    except GeometryError as exc:
                        cells.append(f"– ({exc})")
                        continue
                    depth = depth or res.depth_range
                    lo_, hi_ = res.depth_range
                    info = f"{pair.left_face},{pair.right_face} | {lo_:.0f}–{hi_:.0f} | {res.n}"
                    cells.append(f"{res.rms:.3f}, {res.p95:.3f}")
            print(f"| {name} | {info} | " + " | ".join(cells) + " |", flush=True)
            if depth is not None and (depth[0] > DEPTH_RANGE_MM[1] - 1 or depth[1] < DEPTH_RANGE_MM[0] + 400):
                # working depths far from the fit's 0.5-3 m: refit there, exact remap referenced mid-range
                lo, hi = depth
                refit = [VirtualView(face=v.face, name=v.name, method="fit",
                                     camera=(c := fit_camera(rig, v.face, depth_range=(lo, hi))),
                                     rms_px=reprojection_error(c, rig, v.face, depth_range=(lo, hi))[0], max_px=0.0)
                         for v in allviews["fit"]]
                mid = float(2.0 / (1.0 / lo + 1.0 / hi))
                c1 = _cell(rig, refit, a, b, "model", regions, n, depth)[1]
                c2 = _cell(rig, refit, a, b, "exact", regions, n, depth, ref_depth=mid)[1]
                print(f"| {name} (fit refitted at {lo:.0f}–{hi:.0f} mm, exact ref. {mid:.0f} mm) | {info} | "
                      f"{c1.rms:.3f}, {c1.p95:.3f} | {c2.rms:.3f}, {c2.p95:.3f} | | |", flush=True)
        if rig.prism.faces >= 3:
            rv = rectify_views(rig, allviews["fit"], pairs=False)
            for fl, fr in rv.horizontal_pairs:
                corr = true_correspondences(rig, fl, fr, n=n, regions=regions,
                                            depth_range=(rig.prism.back_distance + 50.0, 2500.0))
                dy = rv.real_to_rectified(corr.pixels_a, fl)[:, 1] - rv.real_to_rectified(corr.pixels_b, fr)[:, 1]
                print(f"| {name} shared orientation (R = I, §4.2) | {fl},{fr} | "
                      f"{corr.points[:, 2].min():.0f}–{corr.points[:, 2].max():.0f} | {dy.size} | "
                      f"{np.sqrt(np.mean(dy**2)):.3f}, {np.percentile(np.abs(dy), 95):.3f} | | | |", flush=True)
    print(f"\n{time.time() - t0:.0f} s")


if __name__ == "__main__":
    main()
