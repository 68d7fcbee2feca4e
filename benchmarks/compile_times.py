"""Numba compile time of one coop match into the current ``NUMBA_CACHE_DIR`` (issue 32).

Run into an empty cache to see what a clean clone's first coop call compiles, per kernel and signature::

    rm -rf /tmp/cc && PYTHONPATH=src NUMBA_CACHE_DIR=/tmp/cc python benchmarks/compile_times.py

Times per kernel are wall seconds of numba's ``numba:compile`` events, inclusive of the kernels each one calls.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from numba.core import event

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "matching" / "coop"))


def main() -> None:
    from test_coop import _synthetic_pair

    from prismstereo.matching.coop.pipeline import coop_match

    left, right, _ = _synthetic_pair()
    with event.install_recorder("numba:compile") as rec:
        t0, c0 = time.perf_counter(), time.process_time()
        coop_match(left, right, max_disp=20)
        t1, c1 = time.perf_counter(), time.process_time()
    starts: dict[tuple[str, str], float] = {}
    per: dict[str, list[float]] = {}
    for ts, ev in rec.buffer:
        key = (ev.data["dispatcher"].py_func.__qualname__, str(ev.data["args"]))
        if ev.is_start:
            starts[key] = ts
        else:
            per.setdefault(key[0], []).append(ts - starts.pop(key))
    print(f"coop_match: {t1 - t0:.1f} s wall, {c1 - c0:.1f} s CPU, {sum(map(len, per.values()))} compiles")
    for name, secs in sorted(per.items(), key=lambda kv: -sum(kv[1])):
        print(f"{sum(secs):7.2f} s  {len(secs)}x  {name}")


if __name__ == "__main__":
    main()
