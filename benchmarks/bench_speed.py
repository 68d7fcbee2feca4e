"""Speed against accuracy of every matcher and preset, timed beside OpenCV SGBM in the same process (issue 19).

For each Middlebury v2 scene (Tsukuba, Venus, Teddy, Cones) and each validation scene (Books, Reindeer,
Bowling1, Cloth3, Wood2; ``../shared/data/middlebury-extra``) every method runs on the scene's search
range (its ``manifest.json``), best of ``--repeat`` runs after a warm-up on a tiny pair (numba's cache
loaded, not compiled, is not counted). Printed: seconds per scene, the ratio to OpenCV SGBM timed in the
same process, bad > 1 px nonocc per scene and the averages of each set, and the presets.

Then ``depth --preset fast`` (and the other presets with ``--depth-methods``) on the 512×384 demo capture
(the built-in robot scene): seconds per stage and frames/s, warm, both for the whole ``run_depth`` (what one
``prismstereo depth`` call does after its imports) and, where the pipeline has it, for the video path that
prepares the cameras and rectification once (``prepare_depth`` + ``run_depth_frame``); also the sum of
``run_depth``'s per-frame stages (match, refine, speckles, triangulate).

    NUMBA_CACHE_DIR=.numba_cache .venv/bin/python benchmarks/bench_speed.py [--methods sad,bpasw,sgbm,sgm]
    ... bench_speed.py --methods sad,bpasw,sgbm,sgm,coop --repeat 1      # coop: ~10-50 s per scene
    ... bench_speed.py --no-stereo          # only the depth frames/s
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("NUMBA_CACHE_DIR", os.path.join(os.path.dirname(__file__), "..", ".numba_cache"))
# prismstereo sets this on import; numpy is imported first here, and reads it then
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from prismstereo.evaluation.middlebury import bad_pixel_rate  # noqa: E402
from prismstereo.io import read_image  # noqa: E402
from prismstereo.matching import PRESETS, available_matchers, match  # noqa: E402

V2 = ("tsukuba", "venus", "teddy", "cones")
VALIDATION = ("books", "reindeer", "bowling1", "cloth3", "wood2")
DEFAULT_METHODS = "sad,bpasw,sgbm,sgm"
#: OpenCV SGBM baselines quoted in the issue (bad > 1 px nonocc averages)
SGBM_QUOTED = {"v2": 5.44, "validation": 8.52}
#: per-rig stages a video path computes once (the rest of run_depth's stages run per frame)
_SETUP_STAGES = ("validate", "cameras", "rectify", "total")
_SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"


@dataclass(frozen=True)
class Scene:
    name: str
    group: str
    left: np.ndarray
    right: np.ndarray
    gt: np.ndarray
    nonocc: np.ndarray
    max_disp: int
    min_disp: int


def load_folder(folder: Path, group: str) -> Scene:
    """A scene folder of the shared layout (left, right, disp_left, nonocc PNGs + manifest.json)."""
    man = json.loads((folder / "manifest.json").read_text())
    raw = read_image(folder / "disp_left.png", gray=True).astype(np.float32)
    gt = np.where(raw > 0, raw / np.float32(man["ground_truth"]["scale_factor"]), np.nan).astype(np.float32)
    rng = man["disparity_search_range"]
    return Scene(folder.name, group, read_image(folder / "left.png"), read_image(folder / "right.png"), gt,
                 read_image(folder / "nonocc.png", gray=True) == 255, int(rng["max"]), int(rng.get("min", 0)))


def _time(fn, repeat: int) -> tuple[float, float, object]:  # type: ignore[no-untyped-def]
    """Best wall seconds of ``repeat`` runs, the CPU seconds (all threads) of that run, the result."""
    best, best_cpu, out = np.inf, np.inf, None
    for _ in range(max(1, repeat)):
        c, t = time.process_time(), time.perf_counter()
        out = fn()
        wall = time.perf_counter() - t
        if wall < best:
            best, best_cpu = wall, time.process_time() - c
    return best, best_cpu, out


def stereo(scenes: list[Scene], methods: list[str], repeat: int, slow: set[str]) -> None:
    if "sgbm" not in methods:
        methods = ["sgbm", *methods]
    warm = np.random.default_rng(0).integers(0, 255, (32, 48, 3), dtype=np.uint8)
    for m in methods:
        match(warm, warm, max_disp=4, method=m)
    secs: dict[str, dict[str, float]] = {m: {} for m in methods}
    cpus: dict[str, dict[str, float]] = {m: {} for m in methods}
    bad: dict[str, dict[str, float]] = {m: {} for m in methods}
    for sc in scenes:
        for m in methods:
            reps = 1 if m in slow else repeat
            t, c, res = _time(lambda m=m, sc=sc: match(sc.left, sc.right, max_disp=sc.max_disp,  # type: ignore[misc]
                                                         min_disp=sc.min_disp, method=m), reps)
            secs[m][sc.name] = t
            cpus[m][sc.name] = c
            bad[m][sc.name] = bad_pixel_rate(res.disparity, sc.gt, sc.nonocc, threshold=1.0)  # type: ignore[attr-defined]
            print(f"  {sc.name:9s} {m:6s} {t:7.3f} s  bad1 nonocc {bad[m][sc.name]:6.2f}", file=sys.stderr,
                  flush=True)
    groups = [(g, [s.name for s in scenes if s.group == g]) for g in ("v2", "validation")]
    groups = [(g, names) for g, names in groups if names]
    print(f"\nCPU cores: {os.cpu_count()}; load average {os.getloadavg()[0]:.1f}; best of {repeat} "
          f"(1 for {', '.join(sorted(slow)) or '-'}); in-process seconds, numba cache warm\n")
    for g, names in groups:
        print(f"### {g}: seconds per pair (× OpenCV SGBM in this process)\n")
        print("| method | " + " | ".join(names) + " | total s | × SGBM (total) | × SGBM (worst pair) |")
        print("|---" * (len(names) + 4) + "|")
        ref = secs["sgbm"]
        for m in methods:
            cells = " | ".join(f"{secs[m][n]:.3f} ({secs[m][n] / ref[n]:.1f}×)" for n in names)
            total = sum(secs[m][n] for n in names)
            worst = max(secs[m][n] / ref[n] for n in names)
            print(f"| {m} | {cells} | {total:.2f} | {total / sum(ref[n] for n in names):.2f} | {worst:.2f} |")
        print(f"\n### {g}: CPU seconds per pair, all threads (× OpenCV SGBM's CPU seconds)\n")
        print("| method | " + " | ".join(names) + " | total s | × SGBM (total) |")
        print("|---" * (len(names) + 3) + "|")
        cref = cpus["sgbm"]
        for m in methods:
            cells = " | ".join(f"{cpus[m][n]:.3f} ({cpus[m][n] / max(cref[n], 1e-6):.1f}×)" for n in names)
            total = sum(cpus[m][n] for n in names)
            print(f"| {m} | {cells} | {total:.2f} | {total / max(sum(cref[n] for n in names), 1e-6):.2f} |")
        print(f"\n### {g}: bad > 1 px nonocc (%)\n")
        print("| method | " + " | ".join(names) + " | avg | × SGBM here | × SGBM quoted |")
        print("|---" * (len(names) + 4) + "|")
        ref_avg = float(np.mean([bad["sgbm"][n] for n in names]))
        for m in methods:
            avg = float(np.mean([bad[m][n] for n in names]))
            cells = " | ".join(f"{bad[m][n]:.2f}" for n in names)
            print(f"| {m} | {cells} | {avg:.2f} | {avg / ref_avg:.2f} | {avg / SGBM_QUOTED[g]:.2f} |")
        print()
    print("### presets\n\n| preset | method | " + " | ".join(f"{g} s | {g} bad1" for g, _ in groups) + " |")
    print("|---|---|" + "---|---|" * len(groups))
    for p, m in PRESETS.items():
        if m not in methods:
            print(f"| {p} | {m} | " + " | ".join("- | -" for _ in groups) + " |")
            continue
        cells = " | ".join(f"{sum(secs[m][n] for n in names):.2f} | {np.mean([bad[m][n] for n in names]):.2f}"
                           for _, names in groups)
        print(f"| {p} | {m} | {cells} |")


def depth_fps(presets: list[str], frames: int) -> None:
    # CPU seconds per step (all threads, DepthRun.cpu_timings): on idle cores a serial step takes about its
    # CPU time and a parallel one less, so 1 / (CPU s of the per-frame steps) estimates frames/s when the
    # cores are shared
    cpu: dict[str, float] = {}
    _depth_rows(presets, frames, cpu)


def _depth_rows(presets: list[str], frames: int, cpu: dict[str, float]) -> None:
    from prismstereo.depth import DepthConfig, run_depth
    from prismstereo.depth import pipeline as pl
    from prismstereo.evaluation.depth_metrics import evaluate_depth
    from prismstereo.simulate import render_capture, robot_scene

    rig, scene = robot_scene(width=512)
    cap = render_capture(rig, scene)
    video = hasattr(pl, "prepare_depth") and hasattr(pl, "run_depth_frame")
    try:
        from prismstereo.depth.setup_cache import cache_folder
        folder = cache_folder()
        cache = f"set-up cache {folder}" if folder is not None else "set-up cache off (PRISMSTEREO_CACHE=0)"
    except ImportError:
        cache = "no set-up cache in this version"
    print(f"\n### depth on the {cap.image.shape[1]}×{cap.image.shape[0]} demo capture (robot scene), warm, "
          f"{frames} frames; load average {os.getloadavg()[0]:.1f}; {cache}\n")
    print("| preset | method | whole run_depth s/frame | frames/s | its CPU s/frame | 1/CPU | "
          "stages after set-up s/frame | frames/s | their CPU s/frame | 1/CPU | video path s/frame | frames/s | "
          "its CPU s/frame | 1/CPU | stages of one frame (s) | median rel. depth error | coverage |")
    print("|---" * 17 + "|")
    for p in presets:
        m = PRESETS[p]
        cfg = DepthConfig(method=m)
        res = run_depth(rig, cap.image, config=cfg, progress=False)  # warm-up (numba cache, OpenCV)
        t, c = time.perf_counter(), time.process_time()
        per_frame = []
        cpu.clear()
        for _ in range(frames):
            res = run_depth(rig, cap.image, config=cfg, progress=False)
            per_frame.append(sum(v for k, v in res.timings.items() if k not in _SETUP_STAGES))
            for k, v in res.cpu_timings.items():
                cpu[k] = cpu.get(k, 0.0) + v
        whole = (time.perf_counter() - t) / frames
        whole_cpu = (time.process_time() - c) / frames
        rest = float(np.mean(per_frame))
        rest_cpu = sum(v for k, v in cpu.items() if k not in _SETUP_STAGES) / frames
        vid, vfps, vid_cpu, stages = float("nan"), float("nan"), float("nan"), res.timings
        if video:
            setup = pl.prepare_depth(rig, config=cfg)
            pl.run_depth_frame(setup, cap.image)
            t, c = time.perf_counter(), time.process_time()
            for _ in range(frames):
                res = pl.run_depth_frame(setup, cap.image)
            vid = (time.perf_counter() - t) / frames
            vid_cpu = (time.process_time() - c) / frames
            vfps = 1.0 / vid
            stages = res.timings
        acc = evaluate_depth(res, scene=scene)
        st = ", ".join(f"{k} {v:.2f}" for k, v in stages.items() if k not in ("total", "validate") and v >= 0.005)
        print(f"| {p} | {m} | {whole:.2f} | {1.0 / whole:.2f} | {whole_cpu:.2f} | {1.0 / whole_cpu:.2f} | "
              f"{rest:.2f} | {1.0 / rest:.2f} | {rest_cpu:.2f} | "
              f"{1.0 / rest_cpu:.2f} | {vid:.2f} | "
              f"{vfps:.2f} | {vid_cpu:.2f} | {1.0 / vid_cpu:.2f} | {st} | "
              f"{100 * acc['median_rel']:.3f} % | {100 * acc['coverage']:.1f} % |")
    if not video:
        print("\n(the video path, prepare_depth + run_depth_frame, is not in this pipeline version; 'stages after "
              "set-up' sums run_depth's per-frame stages: match, refine, speckles, triangulate — the per-frame "
              "remap of the capture is inside its rectify stage and not counted)")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=str(_SHARED / "middlebury"), help="Middlebury v2 folder")
    ap.add_argument("--extra", default=str(_SHARED / "middlebury-extra"), help="validation scenes folder")
    ap.add_argument("--methods", default=DEFAULT_METHODS, help="comma-separated (add coop for the accurate preset)")
    ap.add_argument("--repeat", type=int, default=3, help="best of N runs (coop and bpasw: 1)")
    ap.add_argument("--scenes", default=None, help="comma-separated subset of the scenes")
    ap.add_argument("--no-stereo", action="store_true", help="skip the Middlebury table")
    ap.add_argument("--no-depth", action="store_true", help="skip depth frames/s")
    ap.add_argument("--depth-presets", default="fast", help="presets for the depth frames/s (fast,balanced,...)")
    ap.add_argument("--frames", type=int, default=5, help="frames timed per preset for frames/s")
    args = ap.parse_args(argv)
    methods = [m for m in args.methods.split(",") if m]
    unknown = sorted(set(methods) - set(available_matchers()))
    if unknown:
        print(f"unknown methods {unknown}; available: {available_matchers()}", file=sys.stderr)
        return 2
    presets = [p for p in args.depth_presets.split(",") if p]
    if set(presets) - set(PRESETS):
        print(f"unknown presets {presets}; available: {list(PRESETS)}", file=sys.stderr)
        return 2
    if not args.no_stereo:
        want = set(args.scenes.split(",")) if args.scenes else set(V2) | set(VALIDATION)
        scenes = []
        for root, names, group in ((Path(args.data), V2, "v2"), (Path(args.extra), VALIDATION, "validation")):
            for n in names:
                if n in want and (root / n / "manifest.json").is_file():
                    scenes.append(load_folder(root / n, group))
        if not scenes:
            print(f"no scenes found under {args.data} / {args.extra}", file=sys.stderr)
            return 2
        stereo(scenes, methods, args.repeat, slow={"coop", "bpasw"})
    if not args.no_depth:
        depth_fps(presets, args.frames)
    return 0


if __name__ == "__main__":
    sys.exit(main())
