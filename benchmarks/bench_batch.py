"""Batch depth on Dask: throughput with 1 and 2 workers, CPU use and memory per worker, and the overhead of batch
over plain depth runs (issue 18).

Run: .venv/bin/python benchmarks/bench_batch.py [--quick] [--frames 8] [--method bpasw] [--scale 2] [--repeat 2]

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

Per worker process and batch run: frames, busy seconds (its tasks' wall time) and busy share of the run's
wall time, CPU seconds (``psutil``, the whole process) and CPU / wall, peak RSS. On an idle machine a
worker whose CPU / wall is near 100 % is never waiting for the scheduler or for the client; on a shared
machine CPU / wall is the worker's share of the cores. The *CPU-bound estimate* of the speed-up is what the
wall times would be if every process had a core of its own and nothing else ran: (set-up CPU + the CPU of
the busiest worker's frames, summed over its tasks) of the 1-worker run over that of the 2-worker run.

Every frame runs with ``--numba-threads`` (default 1) numba threads, in the depth runs and in the batch
tasks alike, so that the comparisons measure the batch machinery and the scaling over workers, not
numba's threading; an extra row (not with ``--quick``) has one worker with ``run_batch``'s default rule
(numba on all cores). The best of ``--repeat`` runs is kept for each. ``--quick`` (about 1–2 min on an idle
2-core machine): one repeat and no extra row; the default takes about 3–4 min.
"""

from __future__ import annotations

import argparse
import logging
import os
import shutil
import tempfile
import time
from dataclasses import dataclass, field
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


def _worker_usage(client) -> dict[str, tuple[float, float]]:
    """Worker address -> (CPU seconds of its process so far, its RSS in MB now)."""

    def usage() -> tuple[float, float]:
        import psutil

        proc = psutil.Process()
        t = proc.cpu_times()
        return float(t.user + t.system), proc.memory_info().rss / 2**20

    return client.run(usage)


@dataclass
class BatchRun:
    """The best of the repeats of one batch configuration."""

    wall: float = float("inf")
    cpu: float = float("inf")  # client (with the scheduler) + worker processes
    client_cpu: float = 0.0
    start: float = 0.0  # cluster start-up
    workers: list[dict] = field(default_factory=list)  # per worker of the best run

    def cpu_bound(self, setup_cpu: float) -> float:
        """Wall time if every process had its own core and nothing else ran: the set-up on the client, then
        the busiest worker's frames back to back (their CPU seconds in the tasks). Unlike the processes'
        CPU, this leaves out Dask's periodic work, which grows with the wall time of a loaded machine."""
        return setup_cpu + max((w["task_cpu"] for w in self.workers), default=0.0)


def _batch(rig, paths: list[Path], warm: list[Path], config: DepthConfig, out: Path, workers: int, repeat: int,
           outputs: str, numba_threads: int | None = None) -> BatchRun:
    from distributed import Client

    logging.getLogger("distributed").setLevel(logging.WARNING)
    best = BatchRun()
    t = time.perf_counter()
    with local_cluster(workers, dashboard_address=None) as cl, Client(cl) as client:
        best.start = time.perf_counter() - t
        run_batch(rig, warm, out / "warm", config=config, client=client, outputs=outputs, progress=False,
                  numba_threads=numba_threads)
        for r in range(repeat):
            dest = out / f"run{r}"
            u0, c0 = _worker_usage(client), time.process_time()
            t = time.perf_counter()
            s = run_batch(rig, paths, dest, config=config, client=client, outputs=outputs, progress=False,
                          numba_threads=numba_threads)
            wall = time.perf_counter() - t
            client_cpu = time.process_time() - c0  # the scheduler runs in this process too
            u1 = _worker_usage(client)
            assert s.exit_code == 0, s.text()
            if wall < best.wall:
                per = []
                for addr, (cpu1, rss_now) in u1.items():
                    pid = client.run(os.getpid, workers=[addr])[addr]
                    rows = [x for x in s.rows if int(str(x["worker"]).rsplit(":", 1)[1]) == pid]
                    busy = sum(float(x["t_total_s"]) for x in rows)
                    per.append({"frames": len(rows), "busy": busy, "cpu": cpu1 - u0[addr][0],
                                "task_cpu": sum(float(x["cpu_s"]) for x in rows),
                                "rss": max([rss_now] + [float(x["rss_mb"]) for x in rows])})
                best = BatchRun(wall=wall, cpu=client_cpu + sum(w["cpu"] for w in per), client_cpu=client_cpu,
                                start=best.start, workers=per)
            shutil.rmtree(dest)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--method", default="bpasw")
    ap.add_argument("--scale", type=int, default=2, help="1/scale of the thesis rig's 1024×768 sensor")
    ap.add_argument("--repeat", type=int, default=None, help="runs per configuration, best kept (default 2; 1 "
                    "with --quick)")
    ap.add_argument("--quick", action="store_true", help="one repeat, no extra numba row")
    ap.add_argument("--outputs", default="depth.pfm,points.ply")
    ap.add_argument("--numba-threads", type=int, default=1,
                    help="numba threads of the depth runs and of each batch task (the extra row: the default rule)")
    args = ap.parse_args()
    repeat = args.repeat if args.repeat is not None else (1 if args.quick else 2)
    rig = scaled_rig(thesis_biprism(), args.scale)
    # a batch searches every depth at which the views share a field (the rig's range: one frame says nothing
    # of the next's), while a lone depth run narrows the range to what its image shows; both get the rig's
    # range here, so that the two do the same work and the difference is the batch's own cost
    config = DepthConfig(method=args.method,
                         depth_range=prepare_depth(rig, config=DepthConfig(method=args.method)).depth_range)
    load0 = os.getloadavg()[0]
    t_all, c_all = time.perf_counter(), time.process_time()
    tmp = Path(tempfile.mkdtemp(prefix="bench-batch-"))
    try:
        paths = _render(rig, args.frames + 2, tmp)
        paths, warm = paths[:args.frames], paths[args.frames:]
        run_depth(rig, read_image(warm[0]), config=config, progress=False)  # numba warm-up in this process
        nt = args.numba_threads
        runs = [_depth_runs(rig, paths, config, tmp / "depth", nt) for _ in range(repeat)]
        depth_sum, setup = min(r[0] for r in runs), min(r[1] for r in runs)
        depth_cpu, setup_cpu = min(r[2] for r in runs), min(r[3] for r in runs)
        reference = depth_sum - (args.frames - 1) * setup
        reference_cpu = depth_cpu - (args.frames - 1) * setup_cpu
        b1 = _batch(rig, paths, warm, config, tmp / "b1", 1, repeat, args.outputs, nt)
        b2 = _batch(rig, paths, warm, config, tmp / "b2", 2, repeat, args.outputs, nt)
        b1a = None if args.quick else _batch(rig, paths, warm, config, tmp / "b1a", 1, repeat, args.outputs, None)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    n = args.frames
    print(f"batch benchmark ({nt} numba thread(s) per frame): {n} frames {rig.camera.width}x{rig.camera.height}, "
          f"method {args.method}, outputs {args.outputs}, {machine_cores()} cores, load average before "
          f"{load0:.1f} (best of {repeat}{', quick' if args.quick else ''})")
    print("| run | wall s | frames/s | wall vs reference | CPU s | CPU vs reference | CPU-bound s (idle estimate) | "
          "cluster start s |")
    print("|---|---|---|---|---|---|---|---|")
    print(f"| {n} depth runs (sum) | {depth_sum:.2f} | {n / depth_sum:.2f} | {depth_sum / reference:.3f} | "
          f"{depth_cpu:.2f} | {depth_cpu / reference_cpu:.3f} | {depth_cpu:.2f} | - |")
    print(f"| reference = sum − {n - 1} × set-up ({setup:.3f} s, {setup_cpu:.3f} CPU s) | {reference:.2f} | "
          f"{n / reference:.2f} | 1.000 | {reference_cpu:.2f} | 1.000 | {reference_cpu:.2f} | - |")
    named = [("batch, 1 worker", b1), ("batch, 2 workers", b2)]
    if b1a is not None:
        named.insert(1, (f"batch, 1 worker, numba threads = cores ({machine_cores()})", b1a))
    for name, b in named:
        print(f"| {name} | {b.wall:.2f} | {n / b.wall:.2f} | {b.wall / reference:.3f} | {b.cpu:.2f} | "
              f"{b.cpu / reference_cpu:.3f} | {b.cpu_bound(setup_cpu):.2f} | {b.start:.1f} |")
    print("\nPer worker process (best run of each):")
    print("| run | worker | frames | busy s | busy / wall | CPU s | CPU / wall | frames' CPU s | peak RSS MB |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, b in named:
        print(f"| {name} | client + scheduler | - | - | - | {b.client_cpu:.2f} | "
              f"{100 * b.client_cpu / b.wall:.0f} % | - | - |")
        for i, w in enumerate(b.workers):
            print(f"| {name} | {i} | {w['frames']} | {w['busy']:.2f} | {100 * w['busy'] / b.wall:.0f} % | "
                  f"{w['cpu']:.2f} | {100 * w['cpu'] / b.wall:.0f} % | {w['task_cpu']:.2f} | {w['rss']:.0f} |")
    print(f"\noverhead of batch (1 worker) over the reference: wall {100 * (b1.wall / reference - 1):+.1f} %, "
          f"CPU {100 * (b1.cpu / reference_cpu - 1):+.1f} % (target <= 10 %)")
    print(f"throughput: 1 worker {n / b1.wall:.3f} frames/s, 2 workers {n / b2.wall:.3f} frames/s; speed-up 2 workers "
          f"vs 1 ({nt} numba thread each): {b1.wall / b2.wall:.2f}x measured (target >= 1.7x), "
          f"{b1.cpu_bound(setup_cpu) / b2.cpu_bound(setup_cpu):.2f}x CPU-bound estimate (set-up + the busiest "
          f"worker's frames, each process on its own core)")
    if b1a is not None:
        print(f"2 workers vs 1 worker with numba on all cores: {b1a.wall / b2.wall:.2f}x")
    print(f"benchmark total: {time.perf_counter() - t_all:.0f} s wall, {time.process_time() - c_all:.0f} CPU s in "
          f"this process; load average after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
