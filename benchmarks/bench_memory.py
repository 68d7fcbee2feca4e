"""Peak memory of a depth run per step, against the estimate printed before the images are read (issue 30).

One child process per (capture, preset): ``run_depth`` once (set-up computed and cached, numba's kernels
loaded), then the measured second run. Each step of the second run starts by resetting the process's
high-water mark (``/proc/self/clear_refs`` ← 5) and ends by reading it (``VmHWM``), so every step's own peak
resident memory is known, not only the run's. The child also reports the whole-run estimate of
:func:`prismstereo.depth.pipeline.estimate_depth_memory` made from the rig and configuration alone.

    NUMBA_CACHE_DIR=.numba_cache PYTHONPATH=src .venv/bin/python benchmarks/bench_memory.py \\
        FOLDER[,FOLDER...] --presets fast,balanced,accurate [--max-memory 8G] [--limit-gb 11]

``FOLDER`` holds ``capture.png``, ``rig.toml`` (and ``depth_gt.pfm``: accuracy too), as
``benchmarks/bench_scale.py`` renders them. ``--limit-gb`` caps each child's address space
(``RLIMIT_AS``), so a run that would grow past it fails instead of taking the shared machine's memory.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any

os.environ.setdefault("NUMBA_CACHE_DIR", os.path.join(os.path.dirname(__file__), "..", ".numba_cache"))


def _hwm() -> int:
    with open("/proc/self/status", encoding="ascii") as fh:
        for line in fh:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024
    return 0


def _reset_hwm() -> None:
    with open("/proc/self/clear_refs", "w", encoding="ascii") as fh:
        fh.write("5")


def _child(folder: Path, preset: str, max_memory: int | None, c2f: str, runs: int) -> dict[str, Any]:
    import logging

    logging.basicConfig(level=logging.INFO, format="%(relativeCreated)8.0f ms %(name)s: %(message)s")
    import numpy as np

    from prismstereo.config import load_rig
    from prismstereo.depth import pipeline
    from prismstereo.depth.memory import estimate_depth_memory, resident_bytes
    from prismstereo.depth.pipeline import DepthConfig, run_depth, validate_config
    from prismstereo.evaluation.depth_metrics import evaluate_depth, read_depth_gt
    from prismstereo.io import read_image
    from prismstereo.matching import PRESETS

    rig = load_rig(folder / "rig.toml")
    cfg = DepthConfig(method=PRESETS[preset], max_memory=max_memory, coarse_to_fine=c2f)
    resolved = validate_config(rig, cfg)
    est_uncached = estimate_depth_memory(rig, resolved)
    img = read_image(folder / "capture.png")
    steps: dict[str, int] = {}
    first_steps: dict[str, int] = {}
    overall = [_hwm()]
    orig = pipeline._Clock.step
    into = [first_steps]

    @contextmanager
    def step(self: Any, name: str) -> Any:
        overall[0] = max(overall[0], _hwm())
        _reset_hwm()
        with orig(self, name):
            yield
        peak = _hwm()
        into[0][name] = max(into[0].get(name, 0), peak)
        overall[0] = max(overall[0], peak)

    pipeline._Clock.step = step  # type: ignore[method-assign]
    t = time.perf_counter()
    if runs > 1:
        run_depth(rig, img, config=cfg, progress=False)
        into[0] = steps
    first = time.perf_counter() - t
    plan = estimate_depth_memory(rig, resolved)  # the set-up is cached now: its size and range
    est = plan.peak
    base = resident_bytes()
    res = run_depth(rig, img, config=cfg, progress=False)
    pipeline._Clock.step = orig  # type: ignore[method-assign]
    overall[0] = max(overall[0], _hwm())
    out: dict[str, Any] = {
        "folder": str(folder), "preset": preset, "estimate": est, "plan": plan.describe(),
        "estimate_uncached": est_uncached.peak, "plan_uncached": est_uncached.describe(),
        "first_run_s": round(first, 2),
        "timings": {k: round(v, 3) for k, v in res.timings.items()},
        "cpu": {k: round(v, 3) for k, v in res.cpu_timings.items()},
        "rss_before_run": base, "step_peaks": steps, "first_run_step_peaks": first_steps, "run_peak": overall[0],
        "process_peak_ru": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024,
        "rectified": list(res.left.shape[:2]), "disparity_range": list(res.disparity_range),
        "match_info": {k: v for k, v in res.match_info.items() if not isinstance(v, (list, dict))},
        "load": open("/proc/loadavg").read().split()[:3]}
    if (folder / "depth_gt.pfm").is_file():
        acc = evaluate_depth(res, depth_gt=read_depth_gt(folder / "depth_gt.pfm", rig))
        out.update({k: float(acc[k]) for k in ("median_rel", "within_1pct", "coverage")})
    del res
    _ = np
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folders")
    ap.add_argument("--presets", default="fast,balanced,accurate")
    ap.add_argument("--max-memory", default=None)
    ap.add_argument("--coarse-to-fine", default="auto")
    ap.add_argument("--limit-gb", type=float, default=11.0)
    ap.add_argument("--json", default=None)
    ap.add_argument("--runs", type=int, default=2, help="2: the second run measured (set-up cached, kernels "
                                                        "loaded); 1: one run (a set-up cached already)")
    ap.add_argument("--child", nargs=2, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    from prismstereo.matching.scale import parse_memory

    mm = parse_memory(args.max_memory)
    if args.child is not None:
        print(json.dumps(_child(Path(args.child[0]), args.child[1], mm, args.coarse_to_fine, args.runs)))
        return
    gb = 2**30
    rows = []
    print("| capture | preset | estimate GB | measured peak GB | peak / estimate | step peaks (GB) | s per frame | "
          "median err | coverage | load |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for folder in args.folders.split(","):
        for preset in args.presets.split(","):
            lim = int(args.limit_gb * gb)

            def cap(lim: int = lim) -> None:
                resource.setrlimit(resource.RLIMIT_AS, (lim, lim))

            cmd = [sys.executable, __file__, args.folders, "--child", folder, preset,
                   "--coarse-to-fine", args.coarse_to_fine, "--runs", str(args.runs)]
            if args.max_memory:
                cmd += ["--max-memory", args.max_memory]
            p = subprocess.run(cmd, capture_output=True, text=True, preexec_fn=cap)
            Path(f"{folder}-{preset}.stderr").write_text(p.stderr)
            if p.returncode != 0:
                tail = (p.stderr.strip().splitlines() or [f"exit {p.returncode}"])[-1]
                print(f"| {Path(folder).name} | {preset} | failed (exit {p.returncode}): {tail} |", flush=True)
                rows.append({"folder": folder, "preset": preset, "error": tail, "exit": p.returncode})
                continue
            r = json.loads(p.stdout.strip().splitlines()[-1])
            rows.append(r)
            sp = ", ".join(f"{k} {v / gb:.2f}" for k, v in r["step_peaks"].items())
            fp = max(r["first_run_step_peaks"].items(), key=lambda kv: kv[1], default=("-", 0))
            sp += f"; first run's largest: {fp[0]} {fp[1] / gb:.2f}"
            acc = (f"{100 * r['median_rel']:.4f} % | {100 * r['coverage']:.2f} %" if "coverage" in r else " | ")
            print(f"| {Path(folder).name} | {preset} | {r['estimate'] / gb:.2f} | {r['run_peak'] / gb:.2f} | "
                  f"{r['run_peak'] / r['estimate']:.2f} | {sp} | {r['timings']['total']:.1f} | {acc} | "
                  f"{' '.join(r['load'])} |", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
