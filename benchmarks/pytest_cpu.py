"""CPU seconds per test and numba compilations per worker: a pytest plugin, and its summary.

Wall seconds of a test run on the shared machine follow the others' load; CPU seconds do not (much). Load it
with ``-p pytest_cpu`` and ``benchmarks`` on ``PYTHONPATH``, e.g. (an empty numba cache: what a fresh clone
compiles)::

    PYTHONPATH=src:benchmarks NUMBA_CACHE_DIR=/tmp/nc PYTEST_CPU_OUT=/tmp/cpu.jsonl \\
        python -m pytest -p pytest_cpu -n 2 --dist loadfile
    python benchmarks/pytest_cpu.py /tmp/cpu.jsonl

Per test (one JSON line in ``$PYTEST_CPU_OUT``): the CPU seconds of the test process (all its threads:
``time.process_time``), of the child processes it waited for (``RUSAGE_CHILDREN``), its wall seconds, its
xdist worker. Per numba compilation (``$PYTEST_CPU_OUT.compiles``, in-process only): the function, its
argument types, the CPU seconds, the worker and the nesting depth (0: a compile started outside another).
A file's module fixtures count in its first test.
"""

from __future__ import annotations

import collections
import json
import os
import resource
import sys
import time
from collections.abc import Iterator
from typing import Any

import pytest

_OUT = os.environ.get("PYTEST_CPU_OUT", "/tmp/pytest_cpu.jsonl")


def _worker() -> str:
    return os.environ.get("PYTEST_XDIST_WORKER", "main")


def _cpu() -> tuple[float, float]:
    c = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time(), c.ru_utime + c.ru_stime


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> Iterator[None]:
    p0, c0 = _cpu()
    w0 = time.perf_counter()
    yield
    p1, c1 = _cpu()
    rec = {"id": item.nodeid, "worker": _worker(), "wall": time.perf_counter() - w0, "cpu": p1 - p0,
           "child": c1 - c0, "t_end": time.time(), "load": os.getloadavg()[0]}
    with open(_OUT, "a") as f:
        f.write(json.dumps(rec) + "\n")


def _listener() -> Any:
    from numba.core import event

    class Listener(event.Listener):  # type: ignore[misc]
        def __init__(self) -> None:
            self.open: dict[tuple[int, str], tuple[float, float]] = {}

        def on_start(self, ev: Any) -> None:
            self.open[id(ev.data.get("dispatcher")), str(ev.data.get("args"))] = (time.perf_counter(),
                                                                                   time.process_time())

        def on_end(self, ev: Any) -> None:
            key = id(ev.data.get("dispatcher")), str(ev.data.get("args"))
            if key not in self.open:
                return
            w0, p0 = self.open.pop(key)
            func = getattr(ev.data.get("dispatcher"), "py_func", None)
            rec = {"name": f"{getattr(func, '__module__', '?')}.{getattr(func, '__qualname__', '?')}",
                   "args": key[1], "wall": time.perf_counter() - w0, "cpu": time.process_time() - p0,
                   "worker": _worker(), "depth": len(self.open)}
            with open(_OUT + ".compiles", "a") as f:  # written at once: xdist workers end without unconfigure
                f.write(json.dumps(rec) + "\n")

    return Listener()


def pytest_configure(config: pytest.Config) -> None:
    from numba.core import event

    event.register("numba:compile", _listener())


def summary(path: str, top: int = 40) -> None:
    """Print CPU per worker and per file, and the project kernels compiled in more than one worker."""
    rows = [json.loads(line) for line in open(path)]
    by: dict[str, list[float]] = collections.defaultdict(lambda: [0.0, 0.0, 0.0, 0.0])
    workers: dict[str, float] = collections.defaultdict(float)
    for r in rows:
        b = by[r["id"].split("::")[0]]
        b[0] += r["cpu"]
        b[1] += r["child"]
        b[2] += r["wall"]
        b[3] += 1
        workers[r["worker"]] += r["cpu"] + r["child"]
    print(f"{len(rows)} tests, {sum(b[0] + b[1] for b in by.values()):.1f} CPU s")
    for w, c in sorted(workers.items()):
        print(f"  worker {w}: {c:.1f} CPU s")
    for name, b in sorted(by.items(), key=lambda kv: -(kv[1][0] + kv[1][1]))[:top]:
        print(f"{b[0] + b[1]:8.1f} CPU s ({b[1]:6.1f} in children), wall {b[2]:7.1f}, {int(b[3]):3d} tests  {name}")
    if os.path.exists(path + ".compiles"):
        comp = [json.loads(line) for line in open(path + ".compiles")]
        seen: dict[tuple[str, str], set[str]] = collections.defaultdict(set)
        for c in comp:
            if c["name"].startswith("prismstereo"):
                seen[c["name"], c["args"]].add(c["worker"])
        outer = sum(c["cpu"] for c in comp if c["depth"] == 0)
        twice = [k[0] for k, ws in seen.items() if len(ws) > 1]
        print(f"compiles: {outer:.1f} CPU s outermost; {len(seen)} project signatures, {len(twice)} compiled in "
              f"more than one worker {twice}")


if __name__ == "__main__":
    summary(sys.argv[1])
