"""Speed and memory of every registered matcher on the Middlebury v2 scenes.

Prints a markdown table of seconds per scene (best of ``--repeat`` runs, after one warm-up run on a
small image so that loading numba's cached kernels is not counted), the ratio to OpenCV StereoSGBM
timed in the same process, the peak traced memory (tracemalloc, numpy buffers included) and bad-1.0
nonocc for context. Cold whole-command times are a separate matter: time ``prismstereo match`` itself.

    NUMBA_CACHE_DIR=.numba_cache .venv/bin/python benchmarks/bench_matching.py [--data DIR] [--repeat 3]
    ... bench_matching.py --cold      # whole `prismstereo match` commands on Teddy, wall and CPU seconds
    ... bench_matching.py --weights   # does the Weber–Fechner reading weight the right neighbours?
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import time
import tracemalloc

import numpy as np

os.environ.setdefault("NUMBA_CACHE_DIR", os.path.join(os.path.dirname(__file__), "..", ".numba_cache"))

from prismstereo.evaluation.middlebury import SCENES, evaluate_disparity, load_scene  # noqa: E402
from prismstereo.matching import available_matchers, match  # noqa: E402

DEFAULT_METHODS = ("sad", "ssd", "ncc", "shd", "bpasw", "sgbm")


def weight_purity(data: str | None, *, samples: int = 3000, radius: int = 16, dilation: int = 2) -> None:
    """Do BPASW's Weber–Fechner weights favour neighbours on the centre's surface? (data check)

    For pixels of the ``disc`` mask (near depth edges) the share of support weight given to window
    neighbours whose ground truth is within 1 px of the centre's, for: a box window, the literal
    ``-ln(S)`` reading (negative and infinite weights; reported as the share of negative mass), the
    clipped Weber–Fechner weights used by BPASW (several S0), and Yoon–Kweon's exp weights.
    """
    from prismstereo.matching.local.aggregation import to_lab, weber_fechner_weight, window_offsets

    dy, dx, dist = window_offsets(radius, dilation)
    rng = np.random.default_rng(0)
    rows = []
    for s in SCENES:
        sc = load_scene(s, data)
        lab = to_lab(sc.left).astype(np.float64)
        h, w = sc.gt.shape
        ys, xs = np.nonzero(sc.masks["disc"] & np.isfinite(sc.gt))
        pick = rng.choice(len(ys), size=min(samples, len(ys)), replace=False)
        y0, x0 = ys[pick][:, None], xs[pick][:, None]
        qy, qx = y0 + dy[None, :], x0 + dx[None, :]
        inside = (qy >= 0) & (qy < h) & (qx >= 0) & (qx < w)
        qy, qx = np.clip(qy, 0, h - 1), np.clip(qx, 0, w - 1)
        gq = sc.gt[qy, qx]
        same = inside & np.isfinite(gq) & (np.abs(gq - sc.gt[y0, x0]) <= 1.0)
        known = inside & np.isfinite(gq)
        dc = np.sqrt(((lab[qy, qx] - lab[y0, x0][:, :, :]) ** 2).sum(axis=2))
        prox_w = weber_fechner_weight(dist, s0=np.sqrt(2) * radius + 1)[None, :]

        def share(wt: np.ndarray, known: np.ndarray = known, same: np.ndarray = same) -> float:
            wt = np.where(known, wt, 0.0)
            return float((wt * same).sum() / wt.sum())

        # literal Eqs. 5.10-5.13 with S0 = 1: -ln(dist) * -ln(dissimilarity); the centre (dist 0) and equal
        # colours (dissimilarity 0) give infinite weights and are left out here
        ok = known & (dc > 0) & (dist[None, :] > 0)
        lit = np.where(ok, np.log(np.where(ok, dc, 1.0)) * np.log(np.maximum(dist, 1e-9))[None, :], 0.0)
        row = {"scene": s, "box": share(np.ones_like(dc)),
               "literal share": share(lit, ok),
               "literal w<0 %": float(100.0 * (lit[ok] < 0).mean())}
        for s0 in (10.0, 28.0, 50.0, 100.0):
            row[f"weber S0={s0:g}"] = share(prox_w * weber_fechner_weight(dc, s0=s0))
        row["exp (YK)"] = share(np.exp(-dist / 17.5)[None, :] * np.exp(-dc / 7.0))
        rows.append(row)
    keys = [k for k in rows[0] if k != "scene"]
    print("| scene | " + " | ".join(keys) + " |")
    print("|---" * (len(keys) + 1) + "|")
    for r in rows:
        print(f"| {r['scene']} | " + " | ".join(f"{r[k]:.3f}" for k in keys) + " |")


def cold_commands(data: str | None, methods: list[str], scene: str = "teddy") -> None:
    """Wall and CPU seconds of whole ``prismstereo match`` runs (new process each, numba disk cache warm)."""
    import subprocess
    import tempfile
    from pathlib import Path

    from prismstereo.evaluation.middlebury import resolve_data_dir

    folder = resolve_data_dir(data) / scene
    sc = load_scene(scene, data)
    exe = Path(sys.executable).with_name("prismstereo")
    print(f"whole `prismstereo match` runs on {scene} ({sc.left.shape[1]}x{sc.left.shape[0]}, "
          f"{sc.max_disp + 1} disparities); load average before: {os.getloadavg()[0]:.1f}\n")
    print("| method | wall s | CPU s (user+sys) |\n|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for m in methods:
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            t = time.perf_counter()
            subprocess.run([str(exe), "match", str(folder / "left.png"), str(folder / "right.png"), "-o",
                            str(Path(tmp) / f"{m}.pfm"), "--max-disp", str(sc.max_disp), "--method", m],
                           check=True, capture_output=True)
            wall = time.perf_counter() - t
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
            print(f"| {m} | {wall:.2f} | {cpu:.2f} |")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=None, help="Middlebury folder")
    ap.add_argument("--methods", default=",".join(DEFAULT_METHODS))
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--weights", action="store_true", help="only the BPASW weight-purity check")
    ap.add_argument("--cold", action="store_true", help="only whole-command timings on Teddy")
    args = ap.parse_args(argv)
    if args.cold:
        cold_commands(args.data, [m for m in args.methods.split(",") if m])
        return 0
    if args.weights:
        weight_purity(args.data)
        return 0
    methods = [m for m in args.methods.split(",") if m]
    for m in methods:
        if m not in available_matchers():
            print(f"unknown method {m!r}; available: {available_matchers()}", file=sys.stderr)
            return 2
    scenes = {s: load_scene(s, args.data) for s in SCENES}
    warm = np.random.default_rng(0).integers(0, 255, (24, 40, 3), dtype=np.uint8)
    for m in methods:
        match(warm, warm, max_disp=4, method=m)
    secs: dict[str, dict[str, float]] = {m: {} for m in methods}
    peak: dict[str, float] = {}
    bad: dict[str, dict[str, float]] = {m: {} for m in methods}
    for m in methods:
        peak_m = 0.0
        for s, sc in scenes.items():
            best = np.inf
            for _ in range(args.repeat):
                t = time.perf_counter()
                res = match(sc.left, sc.right, max_disp=sc.max_disp, method=m)
                best = min(best, time.perf_counter() - t)
            secs[m][s] = best
            bad[m][s] = evaluate_disparity(res.disparity, sc, thresholds=(1.0,))["bad"]["1.0"]["nonocc"]
            tracemalloc.start()
            match(sc.left, sc.right, max_disp=sc.max_disp, method=m)
            peak_m = max(peak_m, tracemalloc.get_traced_memory()[1] / 2**20)
            tracemalloc.stop()
        peak[m] = peak_m
    ref = secs.get("sgbm")
    print(f"CPU cores available: {os.cpu_count()}; best of {args.repeat}; seconds per scene "
          "(in-process, warm numba cache)\n")
    head = "| method | " + " | ".join(scenes) + " | total s | × SGBM | peak MiB | bad1 nonocc avg |"
    print(head)
    print("|---" * (len(scenes) + 5) + "|")
    for m in methods:
        total = sum(secs[m].values())
        ratio = total / sum(ref.values()) if ref else float("nan")
        cells = " | ".join(f"{secs[m][s]:.3f}" for s in scenes)
        print(f"| {m} | {cells} | {total:.3f} | {ratio:.1f} | {peak[m]:.0f} | "
              f"{np.mean(list(bad[m].values())):.2f} |")
    print(f"\nprocess max RSS: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
