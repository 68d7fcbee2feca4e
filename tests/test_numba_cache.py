"""A numba cache that cannot be written costs a compile, never the run."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

# a kernel module of its own (numba caches per source file) and a process whose writes stop at 4 kB: the
# cache's index and machine code (tens of kB) cannot be written, as on a full disk
_SCRIPT = textwrap.dedent("""
    import logging, resource, signal, sys
    sys.path.insert(0, sys.argv[1])
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(message)s")
    if sys.argv[2] == "tolerant":
        from prismstereo.numba_cache import tolerate_cache_write_errors
        tolerate_cache_write_errors()
        tolerate_cache_write_errors()  # idempotent
    import kernel
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))
    print("sum", kernel.total(10), kernel.scaled(3.0))
""")

_KERNEL = textwrap.dedent("""
    from numba import njit

    @njit(cache=True)
    def total(n):
        s = 0
        for i in range(n):
            s += i
        return s

    @njit(cache=True)
    def scaled(x):
        return 2.0 * x
""")


def _run(tmp: Path, mode: str) -> subprocess.CompletedProcess[str]:
    (tmp / "kernel.py").write_text(_KERNEL)
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO / "src") + os.pathsep + env.get("PYTHONPATH", "")
    env["NUMBA_CACHE_DIR"] = str(tmp / "cache")
    return subprocess.run([sys.executable, "-c", _SCRIPT, str(tmp), mode], capture_output=True, text=True,
                          env=env, timeout=300)


def test_failed_cache_write_is_one_warning(tmp_path: Path) -> None:
    proc = _run(tmp_path, "tolerant")
    assert proc.returncode == 0, proc.stderr
    assert "sum 45 6.0" in proc.stdout
    warns = [line for line in proc.stderr.splitlines() if line.startswith("WARNING")]
    assert len(warns) == 1 and "numba cache not written" in warns[0], proc.stderr


def test_without_it_numba_fails_the_run(tmp_path: Path) -> None:
    # what the guard is for: numba raises from its cache write, after the kernel compiled
    proc = _run(tmp_path, "plain")
    assert proc.returncode != 0 and "sum" not in proc.stdout
    assert "OSError" in proc.stderr or "File too large" in proc.stderr, proc.stderr


def test_compilation_is_announced_once_and_only_on_a_compile() -> None:
    from numba import njit

    from prismstereo.numba_cache import compilation_notice

    calls: list[int] = []

    @njit
    def add(a, b):  # type: ignore[no-untyped-def]
        return a + b

    with compilation_notice(lambda: calls.append(1)):
        add(1, 2)
        add(1.0, 2.0)  # a second signature: compiled too, not announced again
    assert calls == [1]
    with compilation_notice(lambda: calls.append(2)):
        add(3, 4)  # compiled already: nothing to say
    assert calls == [1]
    add(1j, 2j)  # outside the block
    assert calls == [1]
