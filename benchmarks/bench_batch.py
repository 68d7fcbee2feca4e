"""Batch depth on Dask: throughput with 1 and 2 workers, and the overhead of batch over plain depth runs (issue 18).

Run: nice .venv/bin/python benchmarks/bench_batch.py [--frames 8] [--method bpasw] [--scale 2] [--repeat 2]

Frames: ``--frames`` rendered captures of a textured tilted plane at 1.1–1.8 m seen by the thesis bi-prism
rig at 1/``scale`` resolution (default 512×384). Every run writes ``depth.pfm`` and ``points.ply`` per
frame (``--outputs``).

1. *depth runs*: ``run_depth`` + writing the same files, frame by frame in this process (numba warm), and
   the set-up that each of them repeats (``prepare_depth``: virtual cameras, rectification maps, common
   view). Reference = sum of the depth runs − (frames − 1) × set-up: what one set-up plus the per-frame work
   costs without any batch machinery.
2. *batch, 1 worker*: ``run_batch`` on a running ``local_cluster`` of one single-threaded worker process
   (warmed up on other frames first, so numba's cache is loaded), wall time over all frames;
   overhead = batch / reference − 1 (target ≤ 10 %).
3. *batch, 2 workers*: the same with two worker processes; speed-up = 1-worker wall / 2-worker wall
   (target ≥ 1.7× on two cores).

Every frame runs with ``--numba-threads`` (default 1) numba threads, in the depth runs and in the batch
tasks alike, so that the comparisons measure the batch machinery and the scaling over workers, not
numba's threading; an extra row has one worker with ``run_batch``'s default rule (numba on all cores).
The best of ``--repeat`` runs is kept for each. The timings are wall clock on a machine that may be
shared: run it on an idle machine for numbers to quote; the CPU columns (client, scheduler and worker
processes) are less sensitive to other load.
"""

from __future__ import annotations

import argparse
import logging
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from prismstereo.apps.demo import plane_scene, scaled_rig
from prismstereo.batch import local_cluster, run_batch
from prismstereo.batch.runner import machine_cores
from prismstereo.config import thesis_biprism
from prismstereo.depth import DepthConfig, prepare_depth, run_depth
from prismstereo.io import read_image, write_image, write_pfm, write_ply
from prismstereo.simulate import render_capture


def _render(rig, n: int, folder: Path) -> list[Path]:
    paths = []
    for i, z in enumerate(np.linspace(1100.0, 1800.0, n)):
        p = folder / f"frame{i:03d}.png"
        write_image(p, render_capture(rig, plane_scene(float(z), tilt_deg=10.0 + 3 * i, seed=30 + i)).image)
        paths.append(p)
    return paths


def _depth_runs(rig, paths: list[Path], config: DepthConfig, out: Path, numba_threads: int
                ) -> tuple[float, float, float, float]:
    """(sum of run_depth + write over the frames, median prepare_depth time, the same two in CPU seconds)."""
    import numba

    numba.set_num_threads(numba_threads)
    total, cpu0 = 0.0, time.process_time()
    for i, p in enumerate(paths):
        t = time.perf_counter()
        res = run_depth(rig, read_image(p), config=config, progress=False)
        d = out / f"d{i}"
        d.mkdir(parents=True, exist_ok=True)
        write_pfm(d / "depth.pfm", res.depth)
        write_ply(d / "points.ply", *res.point_cloud())
        total += time.perf_counter() - t
    cpu = time.process_time() - cpu0
    setups, setups_cpu = [], []
    for _ in range(3):
        t, c = time.perf_counter(), time.process_time()
        prepare_depth(rig, config=config)
        setups.append(time.perf_counter() - t)
        setups_cpu.append(time.process_time() - c)
    return total, float(np.median(setups)), cpu, float(np.median(setups_cpu))


def _cpu_of_workers(client) -> float:
    import psutil

    def cpu() -> float:
        t = psutil.Process().cpu_times()
        return float(t.user + t.system)

    return sum(client.run(cpu).values())


def _batch(rig, paths: list[Path], warm: list[Path], config: DepthConfig, out: Path, workers: int, repeat: int,
           outputs: str, numba_threads: int | None = None) -> tuple[float, float, float, float]:
    """(best wall time of run_batch over paths, cluster start time, peak worker RSS MB, best CPU seconds)."""
    from distributed import Client

    logging.getLogger("distributed").setLevel(logging.WARNING)
    t = time.perf_counter()
    with local_cluster(workers, dashboard_address=None) as cl, Client(cl) as client:
        start = time.perf_counter() - t
        run_batch(rig, warm, out / "warm", config=config, client=client, outputs=outputs, progress=False,
                  numba_threads=numba_threads)
        best, best_cpu, rss = float("inf"), float("inf"), 0.0
        for r in range(repeat):
            dest = out / f"run{r}"
            w0, c0 = _cpu_of_workers(client), time.process_time()
            t = time.perf_counter()
            s = run_batch(rig, paths, dest, config=config, client=client, outputs=outputs, progress=False,
                          numba_threads=numba_threads)
            best = min(best, time.perf_counter() - t)
            # CPU of the client (scheduler included: it runs in this process) and of the worker processes
            best_cpu = min(best_cpu, time.process_time() - c0 + _cpu_of_workers(client) - w0)
            assert s.exit_code == 0, s.text()
            rss = max(rss, max(float(x["rss_mb"]) for x in s.rows))
            shutil.rmtree(dest)
    return best, start, rss, best_cpu


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--method", default="bpasw")
    ap.add_argument("--scale", type=int, default=2, help="1/scale of the thesis rig's 1024×768 sensor")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--outputs", default="depth.pfm,points.ply")
    ap.add_argument("--numba-threads", type=int, default=1,
                    help="numba threads of the depth runs and of each batch task (the extra row: the default rule)")
    args = ap.parse_args()
    rig = scaled_rig(thesis_biprism(), args.scale)
    config = DepthConfig(method=args.method)
    load0 = os.getloadavg()[0]
    tmp = Path(tempfile.mkdtemp(prefix="bench-batch-"))
    try:
        paths = _render(rig, args.frames + 2, tmp)
        paths, warm = paths[:args.frames], paths[args.frames:]
        run_depth(rig, read_image(warm[0]), config=config, progress=False)  # numba warm-up in this process
        nt = args.numba_threads
        runs = [_depth_runs(rig, paths, config, tmp / "depth", nt) for _ in range(args.repeat)]
        depth_sum, setup = min(r[0] for r in runs), min(r[1] for r in runs)
        depth_cpu, setup_cpu = min(r[2] for r in runs), min(r[3] for r in runs)
        reference = depth_sum - (args.frames - 1) * setup
        reference_cpu = depth_cpu - (args.frames - 1) * setup_cpu
        t1, start1, rss1, cpu1 = _batch(rig, paths, warm, config, tmp / "b1", 1, args.repeat, args.outputs, nt)
        t2, start2, rss2, cpu2 = _batch(rig, paths, warm, config, tmp / "b2", 2, args.repeat, args.outputs, nt)
        t1a, _, _, cpu1a = _batch(rig, paths, warm, config, tmp / "b1a", 1, args.repeat, args.outputs, None)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    n = args.frames
    print(f"batch benchmark ({args.numba_threads} numba thread(s) per frame): "
          f"{n} frames {rig.camera.width}x{rig.camera.height}, method {args.method}, outputs "
          f"{args.outputs}, {machine_cores()} cores, load average before {load0:.1f} (best of {args.repeat})")
    print("| run | wall s | frames/s | wall vs reference | CPU s | CPU vs reference | cluster start s | "
          "peak worker RSS MB |")
    print("|---|---|---|---|---|---|---|---|")
    print(f"| {n} depth runs (sum) | {depth_sum:.2f} | {n / depth_sum:.2f} | {depth_sum / reference:.3f} | "
          f"{depth_cpu:.2f} | {depth_cpu / reference_cpu:.3f} | - | - |")
    print(f"| reference = sum − {n - 1} × set-up ({setup:.3f} s, {setup_cpu:.3f} CPU s) | {reference:.2f} | "
          f"{n / reference:.2f} | 1.000 | {reference_cpu:.2f} | 1.000 | - | - |")
    print(f"| batch, 1 worker | {t1:.2f} | {n / t1:.2f} | {t1 / reference:.3f} | {cpu1:.2f} | "
          f"{cpu1 / reference_cpu:.3f} | {start1:.1f} | {rss1:.0f} |")
    print(f"| batch, 1 worker, numba threads = cores ({machine_cores()}) | {t1a:.2f} | {n / t1a:.2f} | "
          f"{t1a / reference:.3f} | {cpu1a:.2f} | {cpu1a / reference_cpu:.3f} | - | - |")
    print(f"| batch, 2 workers | {t2:.2f} | {n / t2:.2f} | {t2 / reference:.3f} | {cpu2:.2f} | "
          f"{cpu2 / reference_cpu:.3f} | {start2:.1f} | {rss2:.0f} |")
    print(f"overhead of batch (1 worker) over the reference: wall {100 * (t1 / reference - 1):+.1f} %, "
          f"CPU {100 * (cpu1 / reference_cpu - 1):+.1f} % (target <= 10 %)")
    print(f"speed-up 2 workers vs 1 ({nt} numba thread each): {t1 / t2:.2f}x (target >= 1.7x); 2 workers vs 1 worker "
          f"with numba on all cores: {t1a / t2:.2f}x; load average after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
