"""Reproduction of the thesis's tables: ours re-measured beside the thesis's own numbers.

Each table lives in its own module that defines::

    def reproduce(*, data_dir: Path | None, quick: bool = False) -> TableResult

The modules are imported lazily, so a table's heavy dependencies cost nothing to the others.
"""

from __future__ import annotations

import importlib
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from prismstereo.errors import ConfigError
from prismstereo.io.atomic import atomic_write_text, check_output_dir, output_dir
from prismstereo.io.jsonio import write_json
from prismstereo.progress import progress_bar

#: table name -> module that implements it
TABLE_MODULES: dict[str, str] = {
    "table3.4": "prismstereo.apps.tables.table3_4",
    "table4.3": "prismstereo.apps.tables.table4_3",
    "table5.1": "prismstereo.apps.tables.table5_1",
    "table6.1": "prismstereo.apps.tables.table6_1",
    "table6.2": "prismstereo.apps.tables.table6_2",
    "table7.1": "prismstereo.apps.tables.table7_1",
    "table7.2": "prismstereo.apps.tables.table7_2",
}


@dataclass(frozen=True)
class TableResult:
    """A reproduced table: a markdown rendering (ours beside the thesis) and the raw numbers."""

    name: str
    markdown: str
    data: dict[str, Any] = field(default_factory=dict)


def available_tables() -> list[str]:
    return sorted(TABLE_MODULES)


def reproduce_table(name: str, out_dir: str | os.PathLike[str], *, data_dir: Path | None = None,
                    quick: bool = False) -> TableResult:
    """Run one table's reproduction and write ``<name>.md`` and ``<name>.json`` into ``out_dir``."""
    key = name.lower().replace("table", "table").strip()
    if not key.startswith("table"):
        key = "table" + key
    if key not in TABLE_MODULES:
        raise ConfigError(f"expected one of {', '.join(available_tables())}, got {name!r}")
    try:
        module = importlib.import_module(TABLE_MODULES[key])
    except ModuleNotFoundError as exc:
        if exc.name == TABLE_MODULES[key]:
            raise ConfigError(f"{key} is not implemented yet") from None
        raise
    out = Path(out_dir)
    check_output_dir(out)  # before the (long) measurement

    # one step per table (the modules do not report their inner progress): on a terminal the bar names the
    # table being measured and its elapsed time when done
    with progress_bar(total=1, desc=f"reproduce {key}", unit="table", leave=False) as bar:
        result: TableResult = module.reproduce(data_dir=data_dir, quick=quick)
        bar.update(1)
    with output_dir(out) as stage:  # the .md and the .json appear together
        atomic_write_text(stage / f"{key}.md", result.markdown)
        write_json(stage / f"{key}.json", {"table": key, "settings": {"quick": quick, "data": data_dir},
                                           **result.data})
    return result
