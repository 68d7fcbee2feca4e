"""Library errors name the parameter, never a command-line flag; the CLI prints its flags (issue 28)."""

from __future__ import annotations

import ast
import logging
import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from prismstereo.apps.cli import _CliFormatter, build_parser, cli_message, cli_warning
from prismstereo.cli import main
from prismstereo.depth.search_range import depth_warnings
from prismstereo.matching.diagnostics import limit_warnings

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "prismstereo"


def _raised_texts(text: str) -> Iterator[tuple[int, str]]:
    """(line, literal text) of the string parts of every ``raise X(...)`` message in a module's source."""
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, ast.Raise) and isinstance(node.exc, ast.Call):
            for arg in node.exc.args:
                for sub in ast.walk(arg):
                    if isinstance(sub, ast.Constant) and isinstance(sub.value, str):
                        yield node.lineno, sub.value


def test_the_scanner_sees_flags_in_f_strings() -> None:
    body = 'def f(x):\n    raise ValueError(f"--views: expected {x}, got " "it")\n'
    assert [t for _, t in _raised_texts(body)] == ["--views: expected ", ", got it"]


def test_no_library_error_message_speaks_the_command_line() -> None:
    """Outside the commands (``apps/``, ``cli``) no raised message holds a ``--flag``."""
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE)
        if rel.parts[0] in ("apps", "cli.py", "__main__.py"):
            continue
        for line, text in _raised_texts(path.read_text(encoding="utf-8")):
            if re.search(r"(^|[\s(])--[a-z]", text):
                found.append(f"{rel}:{line}: {text!r}")
    assert not found, "library errors that name a flag instead of the parameter:\n" + "\n".join(found)


def _non_doc_strings(text: str) -> Iterator[tuple[int, str]]:
    """(line, text) of every string constant of a module that is not a docstring."""
    tree = ast.parse(text)
    docs = {id(n.body[0].value) for n in ast.walk(tree)
            if isinstance(n, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and n.body
            and isinstance(n.body[0], ast.Expr) and isinstance(n.body[0].value, ast.Constant)}
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docs:
            yield node.lineno, node.value


def test_no_library_text_speaks_the_command_line() -> None:
    """Outside the commands no library string (a verdict, a figure label, a warning) holds a ``--flag``; the
    one exception is the benchmark command a measured table records (``benchmarks/...py --presets``)."""
    found = [f"{path.relative_to(PACKAGE)}:{line}: {text!r}" for path in sorted(PACKAGE.rglob("*.py"))
             if path.relative_to(PACKAGE).parts[0] not in ("apps", "cli.py", "__main__.py")
             for line, text in _non_doc_strings(path.read_text(encoding="utf-8"))
             if re.search(r"(^|[\s(])--[a-z]", text) and "benchmarks/" not in text]
    assert not found, "library texts that name a flag instead of the parameter:\n" + "\n".join(found)
    assert [t for _, t in _non_doc_strings('"""doc"""\nX = "see --verify"\n')] == ["see --verify"]


@pytest.mark.parametrize(("command", "message", "printed"), [
    ("depth", "DepthConfig.min_confidence: expected a number in [0, 1], got 5",
     "--min-confidence: expected a number in [0, 1], got 5"),
    ("depth", "DepthConfig.depth_range: expected (min, max) mm", "--depth-range: expected (min, max) mm"),
    ("depth", "views: expected face indices", "--views: expected face indices"),
    ("depth", "ground_truth: expected a 512×384 depth map", "--gt: expected a 512×384 depth map"),
    ("depth", "DepthConfig.refine_iterations: expected 1..50", "DepthConfig.refine_iterations: expected 1..50"),
    ("depth", "rig: expected a Rig", "rig: expected a Rig"),
    ("batch", "workers: expected a positive number, got 0", "--workers: expected a positive number, got 0"),
    ("calibrate-prism", "board: expected inner corners", "--board: expected inner corners"),
    ("simulate", "supersample: expected an integer in 1..16", "--supersample: expected an integer in 1..16"),
    ("match", "expected a 3x3 image", "expected a 3x3 image"),
])
def test_the_cli_prints_its_flags(command: str, message: str, printed: str) -> None:
    assert cli_message(build_parser(), command, message) == printed


def test_the_depth_warnings_name_the_parameter() -> None:
    """The library's warnings say ``DepthConfig.depth_range``; the commands print their flag instead."""
    saturated = np.full((8, 8), 30.0, np.float32)  # every match at the nearest searched disparity
    lines = [*depth_warnings(points=0, region_pixels=64, matched=0, confident=None, disparity=None, valid=None,
                             disparity_range=(2, 30), depth_range=(800.0, 1500.0)),
             *depth_warnings(points=64, region_pixels=64, matched=64, confident=None, disparity=saturated,
                             valid=None, disparity_range=(2, 30), depth_range=(800.0, 1500.0))]
    assert len(lines) == 2 and all("DepthConfig.depth_range" in t and "--" not in t for t in lines), lines
    assert cli_warning("depth", lines[1]).endswith("(widen --depth-range)")
    assert cli_warning("batch", lines[0]).count("--depth-range") == 1
    assert cli_warning("match", lines[1]) == lines[1]  # match has no --depth-range
    assert cli_warning("depth", "DepthConfig.refine_iterations: no such flag") == (
        "DepthConfig.refine_iterations: no such flag")
    record = logging.LogRecord("prismstereo.depth", logging.WARNING, "", 0, "%s", (lines[1],), None)
    assert _CliFormatter("depth").format(record) == f"prismstereo depth: warning: {cli_warning('depth', lines[1])}"
    limits = limit_warnings(np.full((8, 8), np.nan, np.float32), None, min_disp=0, max_disp=16)
    assert limits and "min_disp/max_disp" in limits[0] and "--" not in limits[0], limits


def test_a_bad_option_is_one_line_naming_the_flag(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rig = tmp_path / "rig.toml"
    rig.write_text("[camera]\nwidth = 64\nheight = 48\nfocal_length = 25.0\npixel_size = 0.0744\n"
                   "[prism]\nfaces = 2\ncorner_angle = 6.4\nrefractive_index = 1.5\napex_distance = 210.0\n"
                   "back_distance = 215.6\n")
    code = main(["depth", str(rig), str(tmp_path / "none.png"), "-o", str(tmp_path / "out"), "--min-confidence",
                 "5"])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("prismstereo depth: error: --min-confidence: expected"), err
    assert not (tmp_path / "out").exists()
