"""Wall and CPU seconds of ``coop`` per scene against OpenCV SGBM-3WAY timed in the same process.

Usage::

    PYTHONPATH=src NUMBA_CACHE_DIR=.numba_cache .venv/bin/python benchmarks/time_coop.py \\
        --data ../shared/data/middlebury-2014 [--scenes Pipes,Piano] [--runs 2] [--check DIR]

For every scene: ``coop_match`` with the default parameters (what ``--method coop`` runs below 4 MP) and then
OpenCV's StereoSGBM in ``MODE_SGBM_3WAY`` (block 5, P1 = 8·3·25, P2 = 32·3·25, the reference of
``bench_scale.py``), alternated ``--runs`` times; printed: the min wall and CPU seconds (``time.process_time``,
all threads) of each, the ratio, and the load average before and after the scene. A warm-up on a tiny pair
loads numba's cache first (not counted). ``--save DIR`` writes the first run's maps as ``coop_maps.py save``
does; ``--check DIR``: compare the final, initial and plane maps of the first
run with ``benchmarks/coop_maps.py save DIR`` files (``np.array_equal``, NaN equal), a last line
``ALL BIT-IDENTICAL`` or how many differ.
"""

from __future__ import annotations

import argparse
import math
import os
import pathlib
import resource
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from prismstereo.evaluation.middlebury import list_scenes, load_scene  # noqa: E402
from prismstereo.matching.coop import coop_match  # noqa: E402


def _sgbm(left: np.ndarray, right: np.ndarray, max_disp: int) -> tuple[float, float]:
    n = int(math.ceil((max_disp + 1) / 16.0)) * 16
    b = 5
    sgbm = cv2.StereoSGBM_create(minDisparity=0, numDisparities=n, blockSize=b, P1=8 * 3 * b * b,  # type: ignore[attr-defined]
                                 P2=32 * 3 * b * b, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    t, c = time.perf_counter(), time.process_time()
    sgbm.compute(left, right)
    return time.perf_counter() - t, time.process_time() - c


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=None, help="scene folder (default: the Middlebury v2 scenes)")
    ap.add_argument("--scenes", default=None, help="comma-separated subset (default: every scene)")
    ap.add_argument("--runs", type=int, default=2)
    ap.add_argument("--check", type=pathlib.Path, default=None, help="coop_maps.py folder to compare with")
    ap.add_argument("--save", type=pathlib.Path, default=None, help="write the maps there as coop_maps.py save")
    args = ap.parse_args()
    names = args.scenes.split(",") if args.scenes else list_scenes(args.data)
    warm = np.random.default_rng(0).integers(0, 255, (40, 56, 3), dtype=np.uint8)
    coop_match(warm, np.roll(warm, -3, axis=1), max_disp=6)
    differ = 0
    print("| scene | NDISP | size | coop wall s | coop CPU s | SGBM-3WAY wall s | SGBM CPU s | coop/SGBM wall "
          "| load before-after |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name in names:
        sc = load_scene(name, args.data)
        l0 = os.getloadavg()[0]
        cw = cc = sw = scpu = math.inf
        first = None
        for _ in range(max(1, args.runs)):
            t, c = time.perf_counter(), time.process_time()
            r = coop_match(sc.left, sc.right, max_disp=sc.max_disp)
            cw, cc = min(cw, time.perf_counter() - t), min(cc, time.process_time() - c)
            if first is None:
                first = r
            w_, c_ = _sgbm(sc.left, sc.right, sc.max_disp)
            sw, scpu = min(sw, w_), min(scpu, c_)
        l1 = os.getloadavg()[0]
        h, w = sc.left.shape[:2]
        print(f"| {name} | {sc.max_disp + 1} | {w}x{h} | {cw:.2f} | {cc:.2f} | {sw:.3f} | {scpu:.3f} | "
              f"{cw / sw:.1f}x | {l0:.1f}-{l1:.1f} |", flush=True)
        maps = {} if first is None else {"": first.disparity, "_init": first.initial, "_plane": first.plane_map}
        if args.save is not None:
            args.save.mkdir(parents=True, exist_ok=True)
            for suffix, m in maps.items():
                np.save(args.save / f"{name}{suffix}.npy", m)
        if args.check is not None:
            for suffix, m in maps.items():
                ref = np.load(args.check / f"{name}{suffix}.npy")
                if not (ref.shape == m.shape and np.array_equal(ref, m, equal_nan=True)):
                    differ += 1
                    print(f"  {name}{suffix}: DIFFERS", flush=True)
    print(f"peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20:.2f} GiB")
    if args.check is not None:
        print("ALL BIT-IDENTICAL" if differ == 0 else f"{differ} maps differ")
    return 0 if differ == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
