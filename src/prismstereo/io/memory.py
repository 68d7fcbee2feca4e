"""Refuse work that cannot fit in memory before allocating it (one clear line instead of a crash)."""

from __future__ import annotations

import os

from prismstereo.errors import PrismStereoError

__all__ = ["available_memory_bytes", "check_fits_in_memory"]


def available_memory_bytes() -> int | None:
    """Memory available to new allocations now (``MemAvailable`` on Linux, else the free pages), or None."""
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None


def _human(n: float) -> str:
    for unit in ("B", "KB", "MB", "GB", "TB"):
        if n < 1024 or unit == "TB":
            return f"{n:.1f} {unit}" if unit != "B" else f"{int(n)} B"
        n /= 1024
    return f"{n:.1f} TB"


def check_fits_in_memory(needed_bytes: int, *, what: str, hint: str,
                         error: type[PrismStereoError] = PrismStereoError) -> None:
    """Raise ``error`` when ``needed_bytes`` exceed the memory available now.

    ``what`` names the thing ("a 20000×20000 image"), ``hint`` what to do instead.
    """
    avail = available_memory_bytes()
    if avail is not None and needed_bytes > avail:
        raise error(f"expected {what} to fit in memory, got about {_human(needed_bytes)} needed and "
                    f"{_human(avail)} available ({hint})")
