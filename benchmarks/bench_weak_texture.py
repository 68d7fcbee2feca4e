"""Coverage on weak texture (issue 26 item 4): which rule of the refine/confidence/speckle steps drops
matches that the matcher had right.

Run: PYTHONPATH=src NUMBA_CACHE_DIR=.numba_cache python benchmarks/bench_weak_texture.py [--quick]
     [--rigs biprism,triprism] [--methods bpasw,coop] [--data ../shared/data/middlebury-extra]

Captures rendered by the simulator through the thesis bi-prism (1024×768) and tri-prism, sensor noise
σ 1.5 grey levels, with the failure modes of the issue-26 table built from the simulator's own objects:

- ``toy``: a weakly textured toy (a sphere and boxes of pale low-contrast smooth noise) in front of a
  photo-textured wall (a Baby-like scene);
- ``pots``: terracotta pots (spheres, a box) of low-contrast texture standing on a plain floor (almost no
  texture) before a photo-textured wall;
- ``rich``: the same layout with strong textures (the control: no loss of accuracy there).

For every capture the matcher runs once (``run_depth`` without refinement and filters); then the
pipeline's own ``refine`` step (:func:`~prismstereo.depth.confidence.confident_matches`) and speckle
filter are applied with the configuration given, and each matched pixel whose matcher disparity is
*correct* (triangulated depth within 1 % of the simulator's exact ground truth) is attributed to the first
rule that drops it (from the cross-checked matches alone, as before ``refine_fill``): not confirmed by the
refinement (off a view, or moved by ``max_shift`` or more), the texture test, the sub-pixel left–right
check, the confidence threshold, the speckle filter. The last table runs ``run_depth`` end to end with the
default configuration, with ``refine_fill`` off and on: coverage of the common view, median error, share
within 1 %.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from prismstereo.config import Rig, thesis_biprism, thesis_triprism
from prismstereo.depth import DepthConfig, run_depth, triangulate_matches
from prismstereo.depth.confidence import confident_matches, remove_speckles
from prismstereo.evaluation.depth_metrics import ground_truth_for_run
from prismstereo.rectify.epipolar import epipolar_table
from prismstereo.simulate import Box, ImageTexture, NoiseTexture, Plane, Rectangle, Scene, Sphere, render_capture
from prismstereo.simulate.scene import rotation_from_normal

DEFAULT_DATA = next((p for p in (Path(__file__).resolve().parents[k] / "shared" / "data" / "middlebury-extra"
                     for k in (1, 2, 3)) if p.is_dir()), Path("../shared/data/middlebury-extra"))


def _wall(data: Path, name: str, seed: int) -> Any:
    p = data / name / "left.png"
    if p.is_file():
        from prismstereo.io import read_image

        return ImageTexture(path=f"{name}/left.png", image=read_image(p), size=(360.0, 288.0))
    return NoiseTexture(scale=90.0, octaves=6, persistence=0.7, contrast=2.0, seed=seed)


def toy_scene(data: Path, *, rich: bool = False) -> Scene:
    """A pale, weakly textured toy (head, body, arms) before a photo wall, 1.2–1.9 m."""
    skin = NoiseTexture(scale=30.0, octaves=6, persistence=0.7, contrast=2.2, seed=71) if rich else \
        NoiseTexture(scale=45.0, octaves=3, persistence=0.45, contrast=0.22, seed=71)
    cloth = NoiseTexture(scale=20.0, octaves=6, persistence=0.75, contrast=2.4, seed=72) if rich else \
        NoiseTexture(scale=35.0, octaves=3, persistence=0.5, contrast=0.3, seed=72)
    return Scene(objects=(
        Plane(center=(0.0, 0.0, 1900.0), texture=_wall(data, "cloth3", 73), name="wall"),
        Sphere(center=(2.0, -38.0, 1400.0), radius=24.0, texture=skin, name="head"),
        Box(center=(0.0, 18.0, 1440.0), size=(52.0, 60.0, 36.0), rotation=(0.0, 15.0, 0.0), texture=cloth,
            name="body"),
        Sphere(center=(-40.0, 8.0, 1385.0), radius=13.0, texture=skin, name="arm-l"),
        Sphere(center=(42.0, 12.0, 1405.0), radius=13.0, texture=skin, name="arm-r"),
    ), noise=1.5, shading=0.3, seed=7, supersample=2, name="toy" + ("-rich" if rich else ""))


def pots_scene(data: Path, *, rich: bool = False) -> Scene:
    """Terracotta pots on a plain floor (a faint fine grain, seen from 15° above at 1.35–2 m), photo wall at 2 m."""
    floor = NoiseTexture(scale=50.0, octaves=5, persistence=0.7, contrast=2.0, seed=81) if rich else \
        NoiseTexture(scale=12.0, octaves=3, persistence=0.5, contrast=0.3, seed=81)
    pot = NoiseTexture(scale=25.0, octaves=6, persistence=0.7, contrast=2.0, seed=82) if rich else \
        NoiseTexture(scale=30.0, octaves=4, persistence=0.55, contrast=0.6, seed=82)
    return Scene(objects=(
        Plane(center=(0.0, 0.0, 2000.0), texture=_wall(data, "books", 83), name="wall"),
        Rectangle(center=(0.0, 43.2, 1500.0), size=(500.0, 1400.0),
                  rotation=rotation_from_normal((0.0, -0.966, -0.259)), texture=floor,
                  name="floor"),
        Sphere(center=(-30.0, 36.0, 1450.0), radius=20.0, texture=pot, name="pot-1"),
        Sphere(center=(32.0, 0.0, 1600.0), radius=16.0, texture=pot, name="pot-2"),
        Box(center=(0.0, -42.0, 1750.0), size=(36.0, 36.0, 36.0), rotation=(0.0, 30.0, 0.0), texture=pot,
            name="pot-3"),
    ), noise=1.5, shading=0.3, seed=8, supersample=2, name="pots" + ("-rich" if rich else ""))


@dataclass(frozen=True)
class Case:
    name: str
    rig: Rig
    scene: Scene


def cases(data: Path, rigs: list[str], quick: bool) -> list[Case]:
    makers = {"biprism": thesis_biprism, "triprism": thesis_triprism}
    out = []
    for r in rigs:
        rig = makers[r]()
        out += [Case(f"{r}: toy", rig, toy_scene(data)), Case(f"{r}: pots", rig, pots_scene(data))]
        if not quick:
            out += [Case(f"{r}: toy (rich)", rig, toy_scene(data, rich=True)),
                    Case(f"{r}: pots (rich)", rig, pots_scene(data, rich=True))]
    return out


def _rel_error(res: Any, gt: Any, disp: np.ndarray) -> np.ndarray:
    ys, xs = np.nonzero(np.isfinite(disp))
    tri = triangulate_matches(res.rig, res.pair, ys, xs, disp[ys, xs].astype(np.float64), method="exact",
                              views=res.views)
    err = np.full(disp.shape, np.nan)
    z = gt.depth[ys, xs]
    ok = tri.valid & (tri.points[:, 2] > res.rig.prism.back_distance)
    err[ys[ok], xs[ok]] = np.abs(tri.points[ok, 2] - z[ok]) / z[ok]
    return err


def loss_table(res: Any, gt: Any, cfg: DepthConfig) -> dict[str, float]:
    """Shares of the common view: matched, matched-and-correct, and where the correct ones were lost."""
    common = gt.common & np.isfinite(gt.depth)
    n = int(common.sum())
    vl, vr = res.pair.valid_masks()
    raw = res.disparity
    err0 = _rel_error(res, gt, raw)
    correct = common & (err0 <= 0.01)
    disp, zncc = confident_matches(res.left, res.right, raw, radius=cfg.refine_radius,
                                   iterations=cfg.refine_iterations, max_shift=cfg.refine_max_shift,
                                   min_texture=cfg.refine_min_texture, min_confidence=None,
                                   max_lr_gap=None, valid_left=vl, valid_right=vr,
                                   epipolar=epipolar_table(res.pair), prefilter=cfg.refine_prefilter)
    disp_c, conf_c = confident_matches(res.left, res.right, raw, radius=cfg.refine_radius,
                                       iterations=cfg.refine_iterations, max_shift=cfg.refine_max_shift,
                                       min_texture=cfg.refine_min_texture, min_confidence=None,
                                       max_lr_gap=cfg.refine_max_lr_gap, valid_left=vl, valid_right=vr,
                                       epipolar=epipolar_table(res.pair), prefilter=cfg.refine_prefilter)
    # zncc = 0 here where refine_disparity gave NaN (not refined / hit the bound); split those two by texture
    from prismstereo.depth.refine import refine_disparity

    _, zr = refine_disparity(res.left, res.right, raw, radius=cfg.refine_radius, iterations=cfg.refine_iterations,
                             max_shift=cfg.refine_max_shift, min_texture=0.0, valid_left=vl, valid_right=vr,
                             min_pixels=49, row_offset=epipolar_table(res.pair).row_offset_map(raw),
                             prefilter=cfg.refine_prefilter)
    thr = cfg.min_confidence if cfg.min_confidence is not None else 0.0
    # unconfirmed (confidence 0 before the check): still unrefined without the texture test = off a view or
    # moved by max_shift or more; refined without it = the texture test
    not_refined = correct & (zncc == 0) & ~np.isfinite(zr)
    low_tex = correct & (zncc == 0) & np.isfinite(zr)
    lr = correct & (zncc > 0) & (conf_c == 0)
    low_conf = correct & (conf_c > 0) & (conf_c < thr)
    kept = np.where(np.isfinite(disp_c) & (conf_c >= thr) & (conf_c > 0 if thr > 0 else True), disp_c, np.nan)
    size = max(20, int((cfg.speckle_fraction or 0.0) * int(res.roi_mask.sum())))
    desp = remove_speckles(kept, max_size=size) if cfg.speckle_fraction is not None else kept
    speck = correct & np.isfinite(kept) & ~np.isfinite(desp)
    err1 = _rel_error(res, gt, desp)
    k = common & np.isfinite(err1)
    e = err1[k]
    return {"matched": np.isfinite(raw)[common].mean(), "correct": correct.sum() / n,
            "off-view/bound": not_refined.sum() / n, "low-tex": low_tex.sum() / n,
            "lr-check": lr.sum() / n, "conf<thr": low_conf.sum() / n, "speckles": speck.sum() / n,
            "kept": k.sum() / n, "kept-correct": (k & (err1 <= 0.01)).sum() / n,
            "median": float(np.median(e)) if e.size else np.nan, "within1": float(np.mean(e <= 0.01)) if e.size else 0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="weak scenes only")
    ap.add_argument("--rigs", default="biprism", help="comma list of biprism, triprism")
    ap.add_argument("--methods", default="bpasw", help="comma list of matchers (presets: sgm bpasw coop)")
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA)
    ap.add_argument("--loss", action="store_true", help="the per-rule loss table too")
    args = ap.parse_args()
    todo = cases(args.data, args.rigs.split(","), args.quick)
    d = DepthConfig()
    for method in args.methods.split(","):
        print(f"\n## matcher {method}\n")
        if args.loss:
            print("| capture | matched | matched & correct | lost: off view / bound | lost: texture | lost: lr check |"
                  " lost: conf | lost: speckles | kept | kept & correct | median % | within 1 % |")
            print("|---|---|---|---|---|---|---|---|---|---|---|---|")
            for case in todo:
                cap = render_capture(case.rig, case.scene)
                base = DepthConfig(method=method, refine=False, min_confidence=None, speckle_fraction=None)
                res = run_depth(case.rig, cap.image, config=base, progress=False)
                gt = ground_truth_for_run(res, scene=case.scene)
                m = loss_table(res, gt, replace(d, method=method))
                print(f"| {case.name} | " + " | ".join(
                    f"{100 * m[k]:.1f}" for k in ("matched", "correct", "off-view/bound", "low-tex", "lr-check",
                                                  "conf<thr", "speckles", "kept", "kept-correct"))
                      + f" | {100 * m['median']:.3f} | {100 * m['within1']:.1f} |", flush=True)
        print("\n| capture | refine_fill | coverage % | median % | within 1 % | depth s wall (CPU) |")
        print("|---|---|---|---|---|---|")
        for case, fill in ((c, f) for c in todo for f in (False, True)):
            cap = render_capture(case.rig, case.scene)
            t, c = time.perf_counter(), time.process_time()
            res = run_depth(case.rig, cap.image, config=replace(d, method=method, refine_fill=fill), progress=False)
            secs, cpu = time.perf_counter() - t, time.process_time() - c
            gt = ground_truth_for_run(res, scene=case.scene)
            common = gt.common & np.isfinite(gt.depth)
            err = np.abs(res.depth - gt.depth) / gt.depth
            k = common & res.valid & np.isfinite(err)
            e = err[k]
            print(f"| {case.name} | {'on' if fill else 'off'} | {100 * k.sum() / common.sum():.1f} | "
                  f"{100 * np.median(e):.3f} | {100 * np.mean(e <= 0.01):.1f} | {secs:.1f} ({cpu:.1f}) |", flush=True)


if __name__ == "__main__":
    main()
