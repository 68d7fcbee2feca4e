"""The ``prismstereo`` console entry point; the commands live in :mod:`prismstereo.apps.cli`."""

from prismstereo.apps.cli import build_parser, main

__all__ = ["build_parser", "main"]
