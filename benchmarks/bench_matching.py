"""Speed and memory of every registered matcher on the Middlebury v2 scenes.

Prints a markdown table of seconds per scene (best of ``--repeat`` runs, after one warm-up run on a
small image so that loading numba's cached kernels is not counted), the ratio to OpenCV StereoSGBM
timed in the same process, the peak traced memory (tracemalloc, numpy buffers included) and bad-1.0
nonocc for context. Cold whole-command times are a separate matter: time ``prismstereo match`` itself.

    NUMBA_CACHE_DIR=.numba_cache .venv/bin/python benchmarks/bench_matching.py [--data DIR] [--repeat 3]
    ... bench_matching.py --cold      # whole `prismstereo match` commands on Teddy, wall and CPU seconds
    ... bench_matching.py --weights   # does the Weber–Fechner reading weight the right neighbours?
    ... bench_matching.py --sgm-speed [--sets 2014] [--pairs DIR,DIR]   # sgm's stages against SGBM

``--sgm-speed``: ``sgm`` (the ``fast`` preset's matcher, defaults) stage by stage (cost, the path costs with
the selection of the winners, the speckle filter, fill + median) in CPU seconds (``time.process_time``, every
thread) and wall seconds, min of ``--repeat``, beside OpenCV StereoSGBM-3WAY (block 5, P1 = 8·3·25,
P2 = 32·3·25, as bench_scale) and the registered ``sgbm`` matcher (OpenCV MODE_HH, holes filled: issue 27's
baseline) timed alternately in the same process, on the Middlebury 2014 Q scenes at their NDISP and on
rectified pairs saved as ``left.npy``, ``right.npy`` and ``range.json`` (``[lo, hi]``) in each folder of
``--pairs`` (e.g. the rectified robot captures of ``bench_scale.py``). The load average is printed on every row.
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import time
import tracemalloc
from functools import partial
from typing import Any

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


def _sgm_stages(left: np.ndarray, right: np.ndarray, lo: int, hi: int) -> tuple[dict[str, tuple[float, float]],
                                                                                np.ndarray]:
    """``SGMMatcher().compute`` stage by stage: {stage: (CPU s, wall s)} and the dense map (checked against
    ``compute``'s by the caller)."""
    from prismstereo.matching.local import costs, selection
    from prismstereo.matching.local.sgm import SGMMatcher, _speckle_filter, sgm_aggregate_select

    m = SGMMatcher()
    out: dict[str, tuple[float, float]] = {}
    clock = [time.process_time(), time.perf_counter()]

    def lap(name: str) -> None:
        c, t = time.process_time(), time.perf_counter()
        out[name] = (c - clock[0], t - clock[1])
        clock[:] = [c, t]

    vol = m.cost_volume(left, right, max_disp=hi, min_disp=lo)
    lap("cost")
    disp, _ = sgm_aggregate_select(vol, costs.to_gray(left), p1=m.p1, p2=m.p2, p2_gamma=m.p2_gamma, min_disp=lo,
                                   uniqueness=m.uniqueness, tolerance=m.tolerance, subpixel=m.subpixel)
    del vol
    lap("paths + WTA")
    disp = _speckle_filter(disp, window=min(m.speckle_window, disp.size // 20), max_diff=m.speckle_range)
    lap("speckles")
    valid = np.isfinite(disp)
    dense = selection.fill_holes(disp, valid, median_radius=0)
    dense = selection.weighted_median_filter(dense, left, radius=m.median_radius)
    lap("fill")
    return out, dense


def _sgbm3way(left: np.ndarray, right: np.ndarray, lo: int, hi: int) -> None:
    import cv2

    b = 5
    n = int(np.ceil((hi - lo + 1) / 16.0)) * 16
    cv2.StereoSGBM_create(minDisparity=int(lo), numDisparities=n, blockSize=b, P1=8 * 3 * b * b,  # type: ignore[attr-defined]
                          P2=32 * 3 * b * b, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY).compute(left, right)


def _timed(fn: Any) -> tuple[float, float]:
    c, t = time.process_time(), time.perf_counter()
    fn()
    return time.process_time() - c, time.perf_counter() - t


def sgm_speed(pairs: list[tuple[str, np.ndarray, np.ndarray, int, int]], *, repeat: int) -> None:
    """Print sgm's stages (CPU / wall s, min of ``repeat``) against SGBM-3WAY and the ``sgbm`` matcher."""
    from prismstereo.matching.local.sgbm import _as_uint8
    from prismstereo.matching.local.sgm import SGMMatcher

    stages = ("cost", "paths + WTA", "speckles", "fill")
    print(f"sgm (defaults) against OpenCV SGBM-3WAY and the registered `sgbm` (MODE_HH, filled), one process, "
          f"min of {repeat} alternated; CPU s = time.process_time (all threads); {os.cpu_count()} cores\n")
    print("| pair | size, disparities | sgm CPU s (" + " / ".join(stages) + ") | sgm CPU | sgm wall | "
          "3WAY CPU / wall | × 3WAY CPU / wall | sgbm CPU / wall | × sgbm CPU / wall | load |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    tot = {"sgm": [0.0, 0.0], "3way": [0.0, 0.0], "sgbm": [0.0, 0.0]}
    for name, left, right, lo, hi in pairs:
        match(left, right, max_disp=hi, min_disp=lo, method="sgm")  # warm (numba's cache, the allocator)
        best = {k: (np.inf, np.inf) for k in stages}
        ref = {"3way": (np.inf, np.inf), "sgbm": (np.inf, np.inf)}
        l8, r8 = _as_uint8(left), _as_uint8(right)
        dense = None
        for _ in range(repeat):
            st, dense = _sgm_stages(left, right, lo, hi)
            best = {k: (min(best[k][0], st[k][0]), min(best[k][1], st[k][1])) for k in stages}
            for k, fn in (("3way", partial(_sgbm3way, l8, r8, lo, hi)),
                          ("sgbm", partial(match, left, right, max_disp=hi, min_disp=lo, method="sgbm"))):
                c, w = _timed(fn)
                ref[k] = (min(ref[k][0], c), min(ref[k][1], w))
        res = SGMMatcher().compute(left, right, max_disp=hi, min_disp=lo)
        if dense is None or not np.array_equal(dense, res.disparity, equal_nan=True):
            raise SystemExit(f"{name}: the staged sgm differs from SGMMatcher.compute")
        cpu = sum(best[k][0] for k in stages)
        wall = sum(best[k][1] for k in stages)
        for k, v in (("sgm", (cpu, wall)), ("3way", ref["3way"]), ("sgbm", ref["sgbm"])):
            tot[k][0] += v[0]
            tot[k][1] += v[1]
        h, w = left.shape[:2]
        print(f"| {name} | {w}×{h}, {hi - lo + 1} | " + " / ".join(f"{best[k][0]:.3f}" for k in stages)
              + f" | {cpu:.3f} | {wall:.3f} | {ref['3way'][0]:.3f} / {ref['3way'][1]:.3f} | "
              f"{cpu / ref['3way'][0]:.1f}× / {wall / ref['3way'][1]:.1f}× | {ref['sgbm'][0]:.3f} / "
              f"{ref['sgbm'][1]:.3f} | {cpu / ref['sgbm'][0]:.2f}× / {wall / ref['sgbm'][1]:.2f}× | "
              f"{os.getloadavg()[0]:.1f} |", flush=True)
    print(f"| **total** | | | {tot['sgm'][0]:.3f} | {tot['sgm'][1]:.3f} | {tot['3way'][0]:.3f} / "
          f"{tot['3way'][1]:.3f} | {tot['sgm'][0] / tot['3way'][0]:.1f}× / {tot['sgm'][1] / tot['3way'][1]:.1f}× | "
          f"{tot['sgbm'][0]:.3f} / {tot['sgbm'][1]:.3f} | {tot['sgm'][0] / tot['sgbm'][0]:.2f}× / "
          f"{tot['sgm'][1] / tot['sgbm'][1]:.2f}× | {os.getloadavg()[0]:.1f} |")


def _speed_pairs(sets: str, pairs: str) -> list[tuple[str, np.ndarray, np.ndarray, int, int]]:
    import json
    from pathlib import Path

    from prismstereo.evaluation.middlebury import list_scenes

    root = Path(__file__).resolve().parents[1].parent / "shared" / "data"
    folders = {"2014": "middlebury-2014", "v2": "middlebury", "validation": "middlebury-extra"}
    out = []
    for key in [s for s in sets.split(",") if s]:
        data = root / folders[key]
        for s in list_scenes(data):
            sc = load_scene(s, data)
            out.append((s, sc.left, sc.right, 0, sc.max_disp))
    for f in [Path(p) for p in pairs.split(",") if p]:
        lo, hi = json.loads((f / "range.json").read_text())
        out.append((f.name, np.load(f / "left.npy"), np.load(f / "right.npy"), int(lo), int(hi)))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=None, help="Middlebury folder")
    ap.add_argument("--methods", default=",".join(DEFAULT_METHODS))
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--weights", action="store_true", help="only the BPASW weight-purity check")
    ap.add_argument("--cold", action="store_true", help="only whole-command timings on Teddy")
    ap.add_argument("--sgm-speed", action="store_true", help="only sgm's stages against SGBM (see above)")
    ap.add_argument("--sets", default="2014", help="with --sgm-speed: Middlebury sets (2014,v2,validation)")
    ap.add_argument("--pairs", default="", help="with --sgm-speed: folders of rectified pairs (see above)")
    args = ap.parse_args(argv)
    if args.sgm_speed:
        sgm_speed(_speed_pairs(args.sets, args.pairs), repeat=args.repeat)
        return 0
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
