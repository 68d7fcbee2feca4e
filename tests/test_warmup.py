"""``prismstereo warmup`` (issue 19): compiles the kernels of the chosen matchers, reports the cache folder."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from prismstereo.apps.warmup import warmup
from prismstereo.cli import main
from prismstereo.errors import ConfigError

SRC = Path(__file__).resolve().parents[1] / "src"


def test_warmup_selected_methods() -> None:
    rep = warmup(["sgm", "SAD"], parts=(), jobs=1)
    assert list(rep.seconds) == ["match sgm", "match sad"]
    assert f"numba cache: {rep.cache}" in rep.summary()


_STATS = """
import json, sys, numba
from prismstereo.apps.warmup import numba_cache_location, warmup
rep = warmup(["sad"], parts=(), jobs=1)
hits = misses = 0
for name, mod in list(sys.modules.items()):
    if name.startswith("prismstereo."):
        for obj in vars(mod).values():
            if isinstance(obj, numba.core.dispatcher.Dispatcher) and obj.overloads:
                hits += sum(obj.stats.cache_hits.values())
                misses += sum(obj.stats.cache_misses.values())
print(json.dumps({"cache": rep.cache, "where": numba_cache_location(), "hits": hits, "misses": misses}))
"""


def _warm_process(cache: Path | None) -> dict[str, object]:
    env = {"PYTHONPATH": str(SRC), "PATH": "/usr/bin:/bin", "HOME": os.environ.get("HOME", "/tmp")}
    if cache is not None:
        env["NUMBA_CACHE_DIR"] = str(cache)
    out = subprocess.run([sys.executable, "-c", _STATS], env=env, capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stderr
    return dict(json.loads(out.stdout.strip().splitlines()[-1]))


@pytest.mark.slow
def test_warmup_fills_the_cache_that_the_next_process_loads(tmp_path: Path) -> None:
    """Into an empty ``NUMBA_CACHE_DIR`` the warm-up compiles and writes the kernels; a second process
    compiles nothing: every kernel it runs comes from that cache."""
    cache = tmp_path / "numba"
    first = _warm_process(cache)
    assert first["cache"] == first["where"] == str(cache)
    assert first["misses"] and not first["hits"]
    assert list(cache.rglob("*.nbi")) and list(cache.rglob("*.nbc"))
    second = _warm_process(cache)
    assert second["hits"] and not second["misses"], second


def test_the_cache_location_follows_numba() -> None:
    env = {"PYTHONPATH": str(SRC), "PATH": "/usr/bin:/bin"}
    code = "from prismstereo.apps.warmup import numba_cache_location; print(numba_cache_location())"
    mine = subprocess.run([sys.executable, "-c", code], env={**env, "NUMBA_CACHE_DIR": "/tmp/x-cache"},
                          capture_output=True, text=True, check=True).stdout.strip()
    assert mine == "/tmp/x-cache"
    default = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                             check=True).stdout.strip()
    assert default.startswith("__pycache__ folders under ") and default.split()[3] == str(SRC / "prismstereo")


@pytest.mark.parametrize(("methods", "parts"), [(["nope"], ()), (["sad"], ("gpu",))])
def test_warmup_rejects_unknown(methods, parts) -> None:
    with pytest.raises(ConfigError):
        warmup(methods, parts=parts)


def test_warmup_cli(capsys) -> None:
    assert main(["warmup", "--methods", "sgm"]) == 0
    out = capsys.readouterr().out
    assert "match sgm" in out and "depth" in out and "numba cache" in out
    assert main(["warmup", "--methods", "nope"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "nope" in err
