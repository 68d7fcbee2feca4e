"""Depth density vs accuracy on rendered captures with textures the matcher was not tuned on (issue 14).

Run: PYTHONPATH=src .venv/bin/python benchmarks/bench_density.py [--quick] [--data ../shared/data/middlebury-extra]

Every capture is rendered with the simulator; its objects carry textures of other statistics than the
noise textures the pipeline was developed on: photos (the left views of the Middlebury validation scenes in
``--data``, never the v2 scenes the matchers were tuned on), sparse random dots, sums of gratings,
low-contrast few-octave noise, fine checkers. The captures are split in two:

- ``tune``: the captures the defaults were chosen on;
- ``held-out``: other photos, other procedural textures, other seeds and other rigs (the tri-prism, the
  thesis bi-prism at full resolution), looked at only to report.

The matcher runs once per capture (``run_depth`` without refinement and filters); every setting of the
grid then applies the depth pipeline's own steps (:func:`prismstereo.depth.confidence.confident_matches`
along the pair's epipolar curves unless a row says ``rows``,
:func:`~prismstereo.depth.confidence.remove_speckles`) to those matches and triangulates them
(exact rays). Reported per setting: coverage of the common view (share with a point), median / p90
relative depth error, share within 1 %, share of gross errors (> 5 %), against the simulator's exact
ground truth (:mod:`prismstereo.evaluation.depth_metrics`). The last table runs ``run_depth`` with the
default :class:`~prismstereo.depth.DepthConfig` end to end on every capture.

``--quick``: one tune and one held-out capture, a reduced grid (about 3 min on an idle 2-core machine).
"""

from __future__ import annotations

import argparse
import itertools
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from prismstereo.apps.demo import demo_rig, scaled_rig
from prismstereo.config import Rig, thesis_biprism, thesis_triprism
from prismstereo.depth import DepthConfig, run_depth, triangulate_matches
from prismstereo.depth.confidence import confident_matches, remove_speckles
from prismstereo.evaluation.depth_metrics import ground_truth_for_run
from prismstereo.rectify.epipolar import epipolar_table
from prismstereo.simulate import (
    Box,
    CheckerTexture,
    ImageTexture,
    NoiseTexture,
    Plane,
    Rectangle,
    Scene,
    Sphere,
    render_capture,
)

DEFAULT_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "middlebury-extra"


# --------------------------------------------------------------------------- held-out textures
def dots_image(seed: int, n: int = 256) -> np.ndarray:
    """Sparse 2×2 random-colour dots on a flat grey: mostly texture-free windows between sharp features."""
    rng = np.random.default_rng(seed)
    img = np.full((n, n, 3), 0.55)
    k = n * n // 40
    ys, xs = rng.integers(0, n, k), rng.integers(0, n, k)
    cols = rng.random((k, 3))
    for dy, dx in itertools.product(range(2), range(2)):
        img[(ys + dy) % n, (xs + dx) % n] = cols
    return np.asarray(img * 255.0, dtype=np.uint8)


def grating_image(seed: int, n: int = 256) -> np.ndarray:
    """A sum of four random sinusoidal gratings (near-periodic, low contrast)."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:n, 0:n] / n
    img = np.zeros((n, n, 3))
    for _ in range(4):
        f = rng.uniform(3.0, 14.0, 2)
        phase = rng.uniform(0.0, 2 * np.pi)
        img += np.sin(2 * np.pi * (f[0] * x + f[1] * y) + phase)[..., None] * rng.uniform(0.3, 1.0, 3)
    return np.asarray(np.clip(0.5 + 0.12 * img, 0.0, 1.0) * 255.0, dtype=np.uint8)


def _photo(data: Path, name: str, size: tuple[float, float]) -> ImageTexture:
    from prismstereo.io import read_image

    return ImageTexture(path=f"{name}/left.png", image=read_image(data / name / "left.png"), size=size)


def _image(img: np.ndarray, size: tuple[float, float]) -> ImageTexture:
    return ImageTexture(image=img, size=size)


def demo_layout(wall: Any, box: Any, ball: Any, panel: Any, name: str) -> Scene:
    """The demo scene's objects (box, ball, slanted panel at 1.25–1.6 m, wall at 1.9 m) with other textures."""
    return Scene(objects=(
        Plane(center=(0.0, 0.0, 1900.0), texture=wall, name="wall"),
        Box(center=(-22.0, -45.0, 1420.0), size=(50.0, 55.0, 50.0), rotation=(10.0, 30.0, 0.0), texture=box,
            name="box"),
        Sphere(center=(28.0, 5.0, 1250.0), radius=26.0, texture=ball, name="ball"),
        Rectangle(center=(-10.0, 62.0, 1600.0), size=(90.0, 55.0), rotation=(0.0, -25.0, 0.0), texture=panel,
                  name="panel"),
    ), supersample=2, name=name)


@dataclass(frozen=True)
class Case:
    name: str
    split: str  # "tune" or "held-out"
    rig: Rig
    scene: Scene


def cases(data: Path, *, quick: bool) -> list[Case]:
    """The rendered captures (module docstring); photos only where ``data`` has them."""
    have = data.is_dir() and all((data / n / "left.png").is_file()
                                 for n in ("books", "bowling1", "cloth3", "reindeer", "wood2"))

    def ph(name: str, size: tuple[float, float], fallback: Any) -> Any:
        return _photo(data, name, size) if have else fallback

    out = [
        Case("photos + dots (books, cloth3)", "tune", demo_rig(), demo_layout(
            ph("books", (260.0, 208.0), NoiseTexture(scale=60.0, octaves=3, persistence=0.5, contrast=1.0, seed=301)),
            ph("cloth3", (60.0, 52.0), _image(grating_image(302), (60.0, 60.0))),
            NoiseTexture(scale=10.0, octaves=3, persistence=0.5, contrast=1.5, seed=303),
            _image(dots_image(304), (60.0, 60.0)), "tune-1")),
        Case("photos + gratings (bowling1, wood2, reindeer)", "held-out", demo_rig(), demo_layout(
            ph("bowling1", (300.0, 240.0), NoiseTexture(scale=80.0, octaves=4, persistence=0.6, contrast=1.2,
                                                         seed=401)),
            ph("wood2", (70.0, 60.0), _image(dots_image(402), (50.0, 50.0))),
            _image(grating_image(403), (70.0, 70.0)),
            ph("reindeer", (90.0, 72.0), NoiseTexture(scale=12.0, octaves=4, persistence=0.4, contrast=1.5,
                                                       seed=404)), "held-out-1")),
    ]
    if quick:
        return out
    out += [
        Case("procedural (low-contrast noise, dots, fine checker, grating)", "tune", demo_rig(), demo_layout(
            NoiseTexture(scale=40.0, octaves=4, persistence=0.6, contrast=1.2, seed=201),
            _image(dots_image(5), (60.0, 60.0)),
            CheckerTexture(square=3.0, colors=((0.2, 0.25, 0.3), (0.8, 0.7, 0.6))),
            _image(grating_image(3), (80.0, 80.0)), "tune-2")),
        Case("tri-prism, photos + dots (reindeer, wood2)", "held-out", scaled_rig(thesis_triprism(), 2), demo_layout(
            ph("reindeer", (250.0, 200.0), NoiseTexture(scale=50.0, octaves=5, persistence=0.5, contrast=1.0,
                                                         seed=501)),
            _image(dots_image(502), (40.0, 40.0)),
            CheckerTexture(square=2.5, colors=((0.7, 0.3, 0.2), (0.3, 0.6, 0.7))),
            ph("wood2", (100.0, 80.0), _image(grating_image(504), (90.0, 90.0))), "held-out-2")),
        Case("full-res bi-prism, photos + noise (wood2, bowling1)", "held-out", thesis_biprism(), demo_layout(
            ph("wood2", (400.0, 320.0), NoiseTexture(scale=90.0, octaves=5, persistence=0.55, contrast=1.3,
                                                      seed=601)),
            ph("bowling1", (80.0, 64.0), _image(dots_image(602), (60.0, 60.0))),
            NoiseTexture(scale=8.0, octaves=4, persistence=0.4, contrast=1.0, seed=603),
            _image(grating_image(604), (90.0, 90.0)), "held-out-3")),
    ]
    return out


# --------------------------------------------------------------------------- measuring
@dataclass(frozen=True)
class Setting:
    radius: int
    min_texture: float
    min_confidence: float | None
    speckles: bool = True
    border: bool = True  # windows cut by a view's edge refined on their pixels inside (at least 7×7 worth)
    lr_gap: float | None = None  # sub-pixel left–right check, px
    curves: bool = True  # right windows along the exact epipolar curves (False: on the left pixel's rows)
    prefilter: float | None = None  # low-pass along the rows before the refinement, σ px

    def label(self) -> str:
        c = "all" if self.min_confidence is None else f"{self.min_confidence:g}"
        lr = "-" if self.lr_gap is None else f"{self.lr_gap:g}"
        pf = "-" if self.prefilter is None else f"{self.prefilter:g}"
        return (f"r={self.radius} tex={self.min_texture:g} conf≥{c} edges={'cut' if self.border else '-'} "
                f"lr={lr} lowpass={pf} speckles={'on' if self.speckles else 'off'}" + ("" if self.curves else " rows"))


def _metrics(err: np.ndarray, keep: np.ndarray, common: np.ndarray) -> dict[str, float]:
    m = keep & common & np.isfinite(err)
    e = err[m]
    n = int(common.sum())
    if e.size == 0:
        return {"coverage": 0.0, "median": float("nan"), "p90": float("nan"), "within1": 0.0, "gross": 0.0}
    return {"coverage": float(m.sum() / n), "median": float(np.median(e)), "p90": float(np.percentile(e, 90)),
            "within1": float(np.mean(e <= 0.01)), "gross": float(np.mean(e > 0.05))}


def _rel_error(res: Any, gt: Any, disp: np.ndarray) -> np.ndarray:
    ys, xs = np.nonzero(np.isfinite(disp))
    tri = triangulate_matches(res.rig, res.pair, ys, xs, disp[ys, xs].astype(np.float64), method="exact",
                              views=res.views)
    err = np.full(disp.shape, np.nan)
    z = gt.depth[ys, xs]
    ok = tri.valid & (tri.points[:, 2] > res.rig.prism.back_distance)
    err[ys[ok], xs[ok]] = np.abs(tri.points[ok, 2] - z[ok]) / z[ok]
    return err


def measure_case(case: Case, grid: list[Setting]) -> dict[Setting, dict[str, float]]:
    """Metrics of every setting on one capture (the matcher runs once)."""
    cap = render_capture(case.rig, case.scene)
    base = DepthConfig(refine=False, min_confidence=None, speckle_fraction=None)
    res = run_depth(case.rig, cap.image, config=base, progress=False)
    gt = ground_truth_for_run(res, scene=case.scene)
    vl, vr = res.pair.valid_masks()
    assert res.disparity is not None and res.roi_mask is not None
    speckle_size = max(20, int((DepthConfig().speckle_fraction or 0.0) * int(res.roi_mask.sum())))
    epipolar = epipolar_table(res.pair)
    out: dict[Setting, dict[str, float]] = {}
    for (radius, tex, border, lr, curves, pf), group in itertools.groupby(
            grid, key=lambda s: (s.radius, s.min_texture, s.border, s.lr_gap, s.curves, s.prefilter)):
        disp, conf = confident_matches(res.left, res.right, res.disparity, radius=radius, min_texture=tex,
                                       min_confidence=None, border_radius=3 if border else None,
                                       max_lr_gap=lr, valid_left=vl, valid_right=vr,
                                       epipolar=epipolar if curves else None, prefilter=pf)
        err = _rel_error(res, gt, disp)
        for s in group:
            kept = disp if s.min_confidence is None else np.where(conf >= s.min_confidence, disp, np.nan)
            if s.speckles:
                kept = remove_speckles(kept, max_size=speckle_size)
            out[s] = _metrics(err, np.isfinite(kept), gt.common)
    return out


def _fmt(m: dict[str, float]) -> str:
    return (f"{100 * m['coverage']:.1f} | {100 * m['median']:.3f} | {100 * m['p90']:.3f} | "
            f"{100 * m['within1']:.1f} | {100 * m['gross']:.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="two captures, a reduced grid (about 3 min idle)")
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA,
                    help="Middlebury validation scenes whose left views become photo textures")
    args = ap.parse_args()
    d = DepthConfig()
    lr, pf = d.refine_max_lr_gap, d.refine_prefilter
    if args.quick:
        grid = [Setting(3, 1.0, 0.8, border=False), Setting(3, 1.0, None, border=False)]
        grid += [Setting(d.refine_radius, d.refine_min_texture, 0.5, border=False)]
        grid += [Setting(d.refine_radius, d.refine_min_texture, 0.5, lr_gap=None)]
        grid += [Setting(d.refine_radius, d.refine_min_texture, c, lr_gap=lr) for c in (None, 0.5, 0.7)]
        grid += [Setting(d.refine_radius, d.refine_min_texture, 0.5, lr_gap=lr, curves=False)]
        grid += [Setting(d.refine_radius, d.refine_min_texture, c, lr_gap=lr, prefilter=pf) for c in (None, 0.5, 0.7)]
    else:
        old = [Setting(3, 1.0, c, sp, border=False) for c in (None, 0.5, 0.8, 0.9) for sp in (True, False)]
        grid = old + [Setting(r, t, c, sp, b, g) for r, t, b, g in (
                          (3, 0.01, False, None), (3, 0.01, True, None), (5, 1.0, False, None),
                          (5, 0.05, False, None), (5, 0.01, False, None), (5, 0.01, True, None),
                          (5, 0.01, True, 1.0), (5, 0.01, True, 0.5), (5, 0.01, True, lr), (5, 0.01, True, 0.3),
                          (7, 0.01, True, lr))
                      for c in (None, 0.5, 0.6, 0.7, 0.8) for sp in ((True, False) if c == 0.5 else (True,))]
        grid += [Setting(5, 0.01, c, True, True, lr, curves=False) for c in (None, 0.5)]
        grid += [Setting(5, 0.01, c, sp, True, g, prefilter=p) for g, p in ((0.5, pf), (lr, 0.5), (lr, pf), (lr, 1.0))
                 for c in (None, 0.5, 0.7) for sp in ((True, False) if c == 0.5 else (True,))]
    todo = cases(args.data, quick=args.quick)
    print(f"# Depth density on rendered captures with held-out textures ({len(todo)} captures; matcher "
          f"{d.method}; default: r={d.refine_radius} tex={d.refine_min_texture:g} conf≥{d.min_confidence} "
          f"edges=cut lr={d.refine_max_lr_gap} lowpass={d.refine_prefilter} speckles={d.speckle_fraction})\n")
    results: dict[str, dict[Setting, dict[str, float]]] = {}
    for case in todo:
        t, c = time.perf_counter(), time.process_time()
        results[case.name] = measure_case(case, grid)
        print(f"- {case.split}: {case.name} ({case.rig.camera.width}×{case.rig.camera.height}, "
              f"{case.rig.prism.faces} faces): {time.perf_counter() - t:.0f} s wall, "
              f"{time.process_time() - c:.0f} s CPU", flush=True)
    print()
    for split in ("tune", "held-out"):
        names = [c.name for c in todo if c.split == split]
        print(f"## {split} captures: worst coverage / worst median over {len(names)}; then each capture "
              "(coverage % | median % | p90 % | within 1 % | gross > 5 %)\n")
        print("| setting | worst cov % | worst median % | " + " | ".join(names) + " |")
        print("|---|---|---|" + "---|" * len(names))
        for s in grid:
            ms = [results[n][s] for n in names]
            worst_cov = min(m["coverage"] for m in ms)
            worst_med = max(m["median"] for m in ms)
            print(f"| {s.label()} | {100 * worst_cov:.1f} | {100 * worst_med:.3f} | "
                  + " | ".join(_fmt(m) for m in ms) + " |", flush=True)
        print()
    print("## default DepthConfig, run_depth end to end\n")
    print("| capture | split | coverage % | median % | p90 % | within 1 % | gross > 5 % | depth s (CPU s) |")
    print("|---|---|---|---|---|---|---|---|")
    for case in todo:
        cap = render_capture(case.rig, case.scene)
        t, c = time.perf_counter(), time.process_time()
        res = run_depth(case.rig, cap.image, config=replace(d), progress=False)
        secs, cpu = time.perf_counter() - t, time.process_time() - c
        gt = ground_truth_for_run(res, scene=case.scene)
        assert res.depth is not None and res.valid is not None
        err = np.abs(res.depth - gt.depth) / gt.depth
        print(f"| {case.name} | {case.split} | {_fmt(_metrics(err, res.valid, gt.common))} | "
              f"{secs:.1f} ({cpu:.1f}) |", flush=True)


if __name__ == "__main__":
    main()
