"""Parsers of command-line values shared by the subcommands' argument modules."""

from __future__ import annotations

from prismstereo.errors import ConfigError

__all__ = ["parse_pair"]


def parse_pair(text: str, name: str, *, example: str = "800,5000") -> tuple[float, float]:
    """``"800,5000"`` -> ``(800.0, 5000.0)``; a malformed value names the flag ``name`` in one line."""
    try:
        a, b = (float(v) for v in text.split(","))
    except ValueError:
        raise ConfigError(f"{name}: expected two numbers like {example}, got {text!r}") from None
    return a, b
