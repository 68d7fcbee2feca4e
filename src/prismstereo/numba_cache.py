"""numba's on-disk cache of compiled kernels, made best-effort.

Every kernel is compiled with ``cache=True``: the first call writes the machine code to numba's cache
folder (``$NUMBA_CACHE_DIR``, else ``__pycache__`` beside the module). numba raises when that write fails
(disk full, a file-size limit, a read-only or missing folder), which would fail a run whose kernel compiled
fine. :func:`tolerate_cache_write_errors` turns such a failure into one logged warning per kernel: the run
goes on with the compiled kernel, and the next process compiles it again.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

log = logging.getLogger(__name__)

__all__ = ["compilation_notice", "has_cached_code", "tolerate_cache_write_errors"]

_MARK = "_prismstereo_tolerant"


def tolerate_cache_write_errors() -> None:
    """Log a warning instead of raising when numba cannot write a kernel to its cache (idempotent).

    Call before the first kernel compiles (the CLI does, before running a command; a batch worker, before
    a frame). Loading from the cache is unchanged.
    """
    from numba.core.caching import Cache

    if getattr(Cache.save_overload, _MARK, False):
        return
    save = Cache.save_overload
    failures: list[str] = []

    def save_overload(self: Any, sig: Any, data: Any) -> None:
        try:
            save(self, sig, data)
        except OSError as exc:
            # this kernel is not written again in this process; it is compiled again by the next one
            self.disable()
            reason = f"{exc.strerror or type(exc).__name__}" + (f": {exc.filename}" if exc.filename else "")
            failures.append(reason)
            # one warning per process (a fresh cache fails for every kernel), the others in the debug log
            level = logging.WARNING if len(failures) == 1 else logging.DEBUG
            log.log(level, "numba cache not written (%s): running without it, the kernels are compiled again "
                    "next time", reason)

    setattr(save_overload, _MARK, True)
    Cache.save_overload = save_overload  # type: ignore[method-assign]


@contextmanager
def compilation_notice(announce: Callable[[], None]) -> Iterator[None]:
    """Call ``announce()`` once, when the first kernel inside the ``with`` block must be compiled (not found
    in numba's cache: a first run in this environment, or after an upgrade), before that compilation starts.

    A warm cache never calls it: numba signals a compilation only on a cache miss.
    """
    from numba.core import event

    class _First(event.Listener):
        fired = False

        def on_start(self, ev: Any) -> None:
            if not self.fired:
                self.fired = True
                announce()

        def on_end(self, ev: Any) -> None:
            pass

    with event.install_listener("numba:compile", _First()):
        yield


def has_cached_code(dispatcher: Any) -> bool:
    """Whether numba's disk cache holds code of the ``cache=True`` kernel ``dispatcher`` (its index file exists;
    a stale entry, from changed sources, is compiled again when called)."""
    cache = getattr(dispatcher, "_cache", None)
    path = getattr(getattr(cache, "_cache_file", None), "_index_path", None)
    return isinstance(path, str) and os.path.exists(path)
