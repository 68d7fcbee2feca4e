"""Render-time benchmark of the prism-capture simulator (issue 2: 1024x768 at 2x2 in under 5 s on 2 cores).

    NUMBA_CACHE_DIR=.numba_cache .venv/bin/python benchmarks/bench_render.py [--scene examples/biprism_robot.toml]
        [--supersample 2] [--repeat 5]

Prints a table: wall time per render (first call includes numba compilation or cache loading), the share
spent tracing rays through the prism (numpy, prismstereo.optics) and the ray-scene kernel (numba).
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numba
import numpy as np

from prismstereo.simulate import intersect_scene, load_scene, render_capture, sample_offsets
from prismstereo.simulate.kernels import compile_scene
from prismstereo.simulate.render import _trace

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default=str(ROOT / "examples" / "biprism_robot.toml"))
    ap.add_argument("--supersample", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    rig, scene = load_scene(args.scene)
    W, H, s = rig.camera.width, rig.camera.height, args.supersample
    print(f"scene {args.scene}: {W}x{H}, {s}x{s} samples + 1 centre ray per pixel "
          f"({W * H * (s * s + 1) / 1e6:.2f} M rays), numba threads {numba.get_num_threads()}")
    t0 = time.perf_counter()
    render_capture(rig, scene.__class__(objects=scene.objects[:1]), supersample=1)
    print(f"warm-up (1 object, 1 sample; numba compile or cache load): {time.perf_counter() - t0:.2f} s")
    t0 = time.perf_counter()
    render_capture(rig, scene, supersample=s)
    print(f"first full render: {time.perf_counter() - t0:.2f} s")
    times, cpu = [], []
    for _ in range(args.repeat):
        c0 = time.process_time()
        cap = render_capture(rig, scene, supersample=s)
        cpu.append(time.process_time() - c0)
        times.append(cap.seconds)
    print(f"render wall: best {min(times):.2f} s, median {statistics.median(times):.2f} s over {args.repeat} "
          f"(coverage {100 * cap.coverage:.1f}%)")
    # CPU time summed over all threads does not depend on other processes' load: on an idle machine the
    # wall time is at most this (and about half of it with 2 cores busy).
    print(f"render CPU (all threads): best {min(cpu):.2f} s, median {statistics.median(cpu):.2f} s")

    # breakdown on one block of rows, scaled to the image
    rows = 64
    vv, uu = np.meshgrid(np.arange(rows, dtype=float), np.arange(W, dtype=float), indexing="ij")
    px = (np.stack([uu, vv], -1)[:, :, None, :] + sample_offsets(s)).reshape(-1, 2)
    compiled = compile_scene(scene)
    t0 = time.perf_counter()
    chunks = [_trace(rig, px[i:i + 8192], True) for i in range(0, len(px), 8192)]
    t_trace = time.perf_counter() - t0
    o = np.concatenate([c[0] for c in chunks])
    d = np.concatenate([c[1] for c in chunks])
    t0 = time.perf_counter()
    intersect_scene(o, d, compiled, shading=scene.shading)
    t_kernel = time.perf_counter() - t0
    scale = H / rows * (s * s + 1) / (s * s)
    print(f"estimated per image: prism trace {t_trace * scale:.2f} s, scene kernel {t_kernel * scale:.2f} s")


if __name__ == "__main__":
    main()
