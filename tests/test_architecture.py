"""The package's layers: every import, and the depth command's data path, go downward.

The layer order is written here, lowest first. A package may import from its own layer (its own modules,
or a package listed beside it) and from the layers below, never from a layer above; a new package must be
placed in :data:`LAYERS` before it can be imported. Imports are read with ``ast`` from the source, at module
level AND inside functions (a function-level import that dodges a cycle is still an upward import). Outside
the commands (``apps/``) imports sit at module level, and no module imports another's underscore names.

The one-call API (``prismstereo.depth``, ``load_rig``, ``simulate``, ``calibrate_prism``) is the module
:mod:`prismstereo.api`, a layer of its own just below the commands (which call it). The top-level package
names these functions but loads :mod:`prismstereo.api` only when one is first used (by name, through
``importlib``, never an ``import`` statement): ``import prismstereo`` loads nothing but the bottom layer.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
PACKAGE = SRC / "prismstereo"

#: lowest first; "" is the top-level package itself (prismstereo/__init__.py, its version)
LAYERS: tuple[frozenset[str], ...] = (
    frozenset({"", "errors", "checks", "progress", "numba_cache"}),
    frozenset({"io"}),  # files, atomic writes, JSON
    frozenset({"config"}),  # the rig (TOML) and the thesis's rigs
    frozenset({"optics"}),  # refraction through the prism, exact projection
    frozenset({"cameras"}),  # pinhole and virtual cameras of the faces
    frozenset({"simulate"}),  # renders captures through optics and cameras
    frozenset({"rectify"}),  # rectification (its conventional baseline renders checkerboards)
    frozenset({"viz"}),  # colourised maps, reports, epipolar figures of rectified pairs
    frozenset({"matching"}),  # two-view matchers on rectified images
    frozenset({"multiview"}),  # collinear multi-baseline matching, the all-view plane sweep
    frozenset({"depth"}),  # the depth pipeline: cameras -> rectify -> match -> triangulate
    frozenset({"calibration"}),  # camera and prism calibration from boards
    frozenset({"evaluation"}),  # metrics against ground truth (Middlebury, simulated depth)
    frozenset({"design"}),  # choose a prism for a camera and a job: predict, search, verify on renders
    frozenset({"batch"}),  # depth of many frames on Dask
    frozenset({"api"}),  # one call per task: load_rig, depth, simulate, calibrate_prism (docs/api.md)
    frozenset({"apps", "cli", "__main__"}),  # the commands, demo, warm-up and thesis tables
)
RANK = {name: i for i, layer in enumerate(LAYERS) for name in layer}


def _package_of(module: str) -> str:
    """``prismstereo.depth.pipeline`` -> ``depth``; ``prismstereo`` -> ``""``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def _module_name(path: Path) -> str:
    rel = path.relative_to(SRC).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _imports(path: Path) -> Iterator[tuple[int, str]]:
    """(line, imported prismstereo module) of every import in a file, at any depth."""
    yield from _imports_in(path.read_text(encoding="utf-8"), _module_name(path), is_package=path.name == "__init__.py")


def _imports_in(text: str, here: str, *, is_package: bool = False) -> Iterator[tuple[int, str]]:
    """(line, imported prismstereo module) of every import in the source of module ``here``."""
    tree = ast.parse(text)
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == "prismstereo":
                    yield node.lineno, alias.name
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: resolve against this module's package
                base = here.split(".")
                if not is_package:
                    base = base[:-1]
                base = base[: len(base) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.split(".")[0] != "prismstereo":
                continue
            if target == "prismstereo":  # "from prismstereo import x": x may be a subpackage
                for alias in node.names:
                    sub = f"prismstereo.{alias.name}"
                    yield node.lineno, sub if alias.name in RANK else target
            else:
                yield node.lineno, target


def _sources() -> list[Path]:
    return sorted(PACKAGE.rglob("*.py"))


#: function-level prismstereo imports allowed outside ``apps/`` ("path relative to src:line" -> why); the
#: commands in ``apps/`` import their algorithms lazily to keep the CLI's start-up short
LAZY_IMPORTS_ALLOWED: dict[str, str] = {}


def _function_level_imports(text: str, here: str, *, is_package: bool = False) -> Iterator[tuple[int, str]]:
    """(line, imported prismstereo module) of every import inside a function body of module ``here``."""
    inside = {sub.lineno for node in ast.walk(ast.parse(text))
              if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
              for sub in ast.walk(node) if isinstance(sub, (ast.Import, ast.ImportFrom))}
    for line, target in _imports_in(text, here, is_package=is_package):
        if line in inside:
            yield line, target


def _private_names_imported(text: str) -> Iterator[tuple[int, str]]:
    """(line, "module.name") of every underscore name (dunders aside) imported from a prismstereo module."""
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, ast.ImportFrom) and (node.level or (node.module or "").split(".")[0] == "prismstereo"):
            for alias in node.names:
                if alias.name.startswith("_") and not alias.name.endswith("__"):
                    yield node.lineno, f"{'.' * node.level}{node.module or ''}.{alias.name}"


def test_every_package_has_a_layer() -> None:
    packages = {_package_of(_module_name(p)) for p in _sources()}
    unplaced = sorted(packages - set(RANK))
    assert not unplaced, f"place these packages in LAYERS of tests/test_architecture.py: {unplaced}"


def test_imports_go_downward() -> None:
    upward = []
    for path in _sources():
        src_pkg = _package_of(_module_name(path))
        for line, target in _imports(path):
            dst_pkg = _package_of(target)
            if src_pkg in RANK and dst_pkg in RANK and RANK[dst_pkg] > RANK[src_pkg]:
                upward.append(f"{path.relative_to(SRC)}:{line}: {src_pkg or 'prismstereo'} -> {target}")
    assert not upward, "imports from a lower layer to a higher one:\n" + "\n".join(upward)


def test_the_reader_sees_imports_hidden_in_functions() -> None:
    """The reader catches upward imports inside a function, relative ones included (the test can fail)."""
    body = ("def f():\n    from prismstereo.depth.pipeline import run_depth\n    return run_depth\n"
            "def g():\n    from ..apps import cli\n    return cli\n")
    found = list(_imports_in(body, "prismstereo.optics.fake"))
    assert found == [(2, "prismstereo.depth.pipeline"), (5, "prismstereo.apps")]
    assert all(RANK[_package_of(m)] > RANK["optics"] for _, m in found)


def test_no_function_level_imports_outside_apps() -> None:
    """Imports sit at module level (a lazy import hides a cycle); only the commands in ``apps/`` stay lazy."""
    lazy = []
    for path in _sources():
        rel = path.relative_to(SRC)
        if rel.parts[1] == "apps":
            continue
        text = path.read_text(encoding="utf-8")
        for line, target in _function_level_imports(text, _module_name(path), is_package=path.name == "__init__.py"):
            if f"{rel}:{line}" not in LAZY_IMPORTS_ALLOWED:
                lazy.append(f"{rel}:{line}: {target}")
    assert not lazy, "function-level imports (hoist them; break a cycle by moving code down):\n" + "\n".join(lazy)


def test_the_lazy_import_check_can_fail() -> None:
    body = ("from prismstereo.errors import ConfigError\n"
            "def f():\n    from prismstereo.optics import trace_pixels\n    return trace_pixels\n"
            "class C:\n    def m(self):\n        from . import sibling\n        return sibling\n")
    assert list(_function_level_imports(body, "prismstereo.cameras.fake")) == [
        (3, "prismstereo.optics"), (7, "prismstereo.cameras")]


def test_no_private_names_imported_across_modules() -> None:
    """A helper another module needs is public (documented, no underscore)."""
    private = [f"{path.relative_to(SRC)}:{line}: {name}" for path in _sources()
               for line, name in _private_names_imported(path.read_text(encoding="utf-8"))]
    assert not private, "underscore names imported from another module (make them public):\n" + "\n".join(private)


def test_the_private_import_check_can_fail() -> None:
    body = ("from prismstereo import __version__\n"
            "from prismstereo.matching.local._sgm import sgm_kernel\n"
            "from prismstereo.calibration.prism import PARAMETERS, _helper\n"
            "def f():\n    from .planes import _fit\n    return _fit\n")
    assert list(_private_names_imported(body)) == [(3, "prismstereo.calibration.prism._helper"), (5, ".planes._fit")]


#: coop's optimiser must stay readable (issue 28): at most this many parameters per function, and tuples of at
#: most this many values returned (more travel as a named structure: a NamedTuple in numba, a dataclass elsewhere)
MAX_PARAMS, MAX_RETURNED = 12, 4
READABLE = PACKAGE / "matching" / "coop"


def _unreadable_functions(text: str) -> Iterator[tuple[int, str]]:
    """``(line, why)`` of each function of ``text`` with more than :data:`MAX_PARAMS` parameters (``self`` and
    ``cls`` not counted) or returning a tuple of more than :data:`MAX_RETURNED` values (a ``return`` of a tuple
    display, or a ``tuple[...]`` return annotation)."""
    for node in ast.walk(ast.parse(text)):
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            continue
        a = node.args
        names = [x.arg for x in (*a.posonlyargs, *a.args, *a.kwonlyargs, a.vararg, a.kwarg) if x is not None]
        if names and names[0] in ("self", "cls"):
            names = names[1:]
        name = getattr(node, "name", "<lambda>")
        if len(names) > MAX_PARAMS:
            yield node.lineno, f"{name} takes {len(names)} parameters"
        returned = [len(r.value.elts) for r in ast.walk(node) if isinstance(r, ast.Return)
                    and isinstance(r.value, ast.Tuple) and not any(isinstance(e, ast.Starred) for e in r.value.elts)]
        ann = getattr(node, "returns", None)
        if (isinstance(ann, ast.Subscript) and isinstance(ann.value, ast.Name) and ann.value.id == "tuple"
                and isinstance(ann.slice, ast.Tuple) and not any(isinstance(e, ast.Constant) and e.value is ...
                                                                 for e in ann.slice.elts)):
            returned.append(len(ann.slice.elts))
        if returned and max(returned) > MAX_RETURNED:
            yield node.lineno, f"{name} returns a tuple of {max(returned)}"


def test_coop_functions_are_small() -> None:
    """No function of ``matching/coop/`` takes more than 12 parameters or returns a tuple of more than 4."""
    found = [f"{path.relative_to(SRC)}:{line}: {why}" for path in sorted(READABLE.rglob("*.py"))
             for line, why in _unreadable_functions(path.read_text(encoding="utf-8"))]
    assert not found, "group these into named structures:\n" + "\n".join(found)


def test_the_function_size_check_can_fail() -> None:
    body = ("def f(a, b, c, d, e, f, g, h, i, j, k, l):\n    return a, b, c, d\n"
            "def g(a, b, c, d, e, f, g, h, i, j, k, *, l, m):\n    return a\n"
            "class C:\n    def m(self, a):\n        return (a, a, a, a, a)\n"
            "def h(x) -> tuple[int, int, int, int, int]:\n    return x\n"
            "def ok(x) -> tuple[int, ...]:\n    return (*x, 1, 2, 3, 4)\n")
    assert sorted(_unreadable_functions(body)) == [(3, "g takes 13 parameters"), (6, "m returns a tuple of 5"),
                                                 (8, "h returns a tuple of 5")]


def test_importing_the_pipeline_loads_nothing_above_it() -> None:
    """``import prismstereo.depth.pipeline`` loads only its own layer and the layers below."""
    code = ("import sys, prismstereo.depth.pipeline\n"
            "print('\\n'.join(m for m in sys.modules if m == 'prismstereo' or m.startswith('prismstereo.')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env={"PYTHONPATH": str(SRC), "PATH": "/usr/bin:/bin"}).stdout.split()
    above = sorted(m for m in out if RANK.get(_package_of(m), 0) > RANK["depth"])
    assert not above, f"the depth pipeline pulls in higher layers: {above}"


def test_importing_the_package_loads_only_the_bottom_layer() -> None:
    """``import prismstereo`` names the API's functions without loading them (or numpy); the first use does."""
    code = ("import sys, prismstereo\n"
            "before = sorted(m for m in sys.modules if m.startswith('prismstereo.') or m == 'numpy')\n"
            "prismstereo.load_rig\n"
            "print(' '.join(before), '|', 'prismstereo.api' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env={"PYTHONPATH": str(SRC), "PATH": "/usr/bin:/bin"}).stdout.split("|")
    loaded = out[0].split()
    assert all(RANK[_package_of(m)] == 0 for m in loaded) and "numpy" not in loaded, loaded
    assert out[1].strip() == "True"


#: a module of the bottom layer whose only calls upward are the callbacks a caller passed it
CALLBACK_ONLY = "prismstereo.numba_cache"


@pytest.mark.slow
def test_depth_command_data_path_goes_downward(capture_folder: Path, tmp_path: Path) -> None:
    """Every call made while ``prismstereo depth`` runs goes to the caller's layer or below (no climbs back up)."""
    from prismstereo.cli import main

    climbs: set[str] = set()
    packages_seen: set[str] = set()

    def pkg(frame: object) -> str | None:
        name = getattr(frame, "f_globals", {}).get("__name__", "")
        return _package_of(name) if name == "prismstereo" or name.startswith("prismstereo.") else None

    def profile(frame: object, event: str, arg: object) -> None:
        if event != "call":
            return
        callee = pkg(frame)
        caller_frame = getattr(frame, "f_back", None)
        caller = pkg(caller_frame) if caller_frame is not None else None
        if callee is None or caller is None:
            return
        packages_seen.add(callee)
        # numba_cache calls back only the notice it was handed (the CLI's "compiling" line on a cold cache)
        if RANK[callee] > RANK[caller] and getattr(caller_frame, "f_globals", {}).get("__name__") != CALLBACK_ONLY:
            code = getattr(frame, "f_code", None)
            climbs.add(f"{caller} -> {callee}.{getattr(code, 'co_name', '?')}")

    argv = ["depth", str(capture_folder / "rig.toml"), str(capture_folder / "capture.png"), "-o",
            str(tmp_path / "out"), "--method", "sad", "--roi", "60,60,80,80", "--depth-range", "1200,2200",
            "--gt", str(capture_folder / "depth_gt.pfm"), "-q"]
    sys.setprofile(profile)
    try:
        code = main(argv)
    finally:
        sys.setprofile(None)
    assert code == 0
    assert {"apps", "depth", "rectify", "matching", "cameras", "optics", "evaluation"} <= packages_seen
    assert not climbs, f"calls from a lower layer back up to a higher one: {sorted(climbs)}"
