"""Progress bars for long steps: tqdm on a terminal only, off with ``--quiet`` (``TQDM_DISABLE=1``)."""

from __future__ import annotations

import os
from collections.abc import Iterable
from typing import Any

__all__ = ["progress_bar"]


def progress_bar(iterable: Iterable[Any] | None = None, **kwargs: Any) -> Any:
    """A ``tqdm`` bar drawn only when stderr is a terminal and ``TQDM_DISABLE`` is not set.

    tqdm reads ``TQDM_DISABLE`` only for arguments it is not given, and ``disable=None`` (hide when not a
    terminal) must be given explicitly, so the variable is honoured here.
    """
    from tqdm import tqdm

    quiet = os.environ.get("TQDM_DISABLE", "").strip().lower() in ("1", "true", "yes")
    return tqdm(iterable, disable=True if quiet else None, **kwargs)
