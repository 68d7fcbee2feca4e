"""Save or compare ``coop``'s maps on the Middlebury scenes: the check behind an exact (bit-identical) speed-up.

Usage::

    NUMBA_CACHE_DIR=.numba_cache .venv/bin/python benchmarks/coop_maps.py save DIR     # on the reference code
    NUMBA_CACHE_DIR=.numba_cache .venv/bin/python benchmarks/coop_maps.py check DIR    # on the changed code
    ... coop_maps.py save DIR --data ../shared/data/middlebury-2014 [--scenes Pipes,Piano]  # other scene sets

For every v2 scene and every validation scene (``../shared/data/middlebury-extra``) ``coop_match`` runs with the
default parameters; ``save`` writes its final, initial and plane maps to ``DIR/<scene>{,_init,_plane}.npy``,
``check`` compares them with ``np.array_equal`` (NaN equal to NaN) and prints per map ``same`` or the number of
pixels that differ and the largest difference, the wall and CPU seconds of each match, and a last line
``ALL BIT-IDENTICAL`` or how many maps differ (exit status 1 then). Run ``check`` twice after a kernel's numba
cache was invalidated: a freshly compiled fast-math kernel may round differently on its first run.
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

import numpy as np

from prismstereo.evaluation.middlebury import list_scenes, load_scene
from prismstereo.matching.coop import coop_match

EXTRA = pathlib.Path(__file__).resolve().parents[1].parent / "shared" / "data" / "middlebury-extra"


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("mode", choices=("save", "check"))
    ap.add_argument("folder", type=pathlib.Path)
    ap.add_argument("--data", action="append", default=None,
                    help="a scene folder to run instead of v2 + validation (repeatable; e.g. the 2014 scenes)")
    ap.add_argument("--scenes", default=None, help="comma-separated subset of the scenes (default: all)")
    args = ap.parse_args()
    args.folder.mkdir(parents=True, exist_ok=True)
    differ = 0
    sources: list[str | None] = [None]
    if args.data:
        sources = list(args.data)
    elif EXTRA.is_dir():
        sources.append(str(EXTRA))
    else:
        print(f"(no validation scenes at {EXTRA}: v2 scenes only)")
    wanted = set(args.scenes.split(",")) if args.scenes else None
    for data in sources:
        for name in list_scenes(data):
            if wanted is not None and name not in wanted:
                continue
            sc = load_scene(name, data)
            t, c = time.perf_counter(), time.process_time()
            r = coop_match(sc.left, sc.right, max_disp=sc.max_disp, min_disp=int(getattr(sc, "min_disp", 0)))
            wall, cpu = time.perf_counter() - t, time.process_time() - c
            maps = {"": r.disparity, "_init": r.initial, "_plane": r.plane_map}
            out = []
            for suffix, m in maps.items():
                path = args.folder / f"{name}{suffix}.npy"
                if args.mode == "save":
                    np.save(path, m)
                    out.append(f"{suffix.lstrip('_') or 'final'} saved")
                    continue
                ref = np.load(path)
                if ref.shape == m.shape and np.array_equal(ref, m, equal_nan=True):
                    out.append(f"{suffix.lstrip('_') or 'final'} same")
                    continue
                differ += 1
                if ref.shape != m.shape:
                    out.append(f"{suffix.lstrip('_') or 'final'} DIFFERS (shape {ref.shape} vs {m.shape})")
                    continue
                diff = np.abs(np.nan_to_num(ref) - np.nan_to_num(m))
                out.append(f"{suffix.lstrip('_') or 'final'} DIFFERS ({int((diff > 0).sum())} px, "
                           f"max {diff.max():.3g})")
            print(f"{name}: {', '.join(out)}  wall {wall:.2f} s, CPU {cpu:.2f} s", flush=True)
    if args.mode == "check":
        print("ALL BIT-IDENTICAL" if differ == 0 else f"{differ} maps differ")
    return 0 if differ == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
