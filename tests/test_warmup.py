"""``prismstereo warmup`` (issue 19): compiles the kernels of the chosen matchers, reports the cache folder."""

from __future__ import annotations

import pytest

from prismstereo.apps.warmup import numba_cache_location, warmup
from prismstereo.cli import main
from prismstereo.errors import ConfigError


def test_warmup_selected_methods() -> None:
    rep = warmup(["sgm", "SAD"], parts=())
    assert list(rep.seconds) == ["match sgm", "match sad"]
    assert all(s >= 0.0 for s in rep.seconds.values())
    assert rep.cache == numba_cache_location()
    assert "numba cache" in rep.summary()


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
