"""CLI of the matching layer: match and evaluate, error paths, PFM round trip with NaN."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from prismstereo.cli import main
from prismstereo.io import read_pfm, write_image, write_pfm


def _pair(tmp_path: Path, d: int = 5) -> tuple[Path, Path]:
    rng = np.random.default_rng(0)
    big = rng.integers(0, 255, size=(30, 60 + d, 3), dtype=np.uint8)
    lp, rp = tmp_path / "l.png", tmp_path / "r.png"
    write_image(lp, big[:, :60])
    write_image(rp, big[:, d:d + 60])
    return lp, rp


def test_pfm_round_trip_with_nan(tmp_path: Path) -> None:
    d = np.array([[1.5, np.nan], [0.0, 3.25]], np.float32)
    write_pfm(tmp_path / "d.pfm", d)
    back = read_pfm(tmp_path / "d.pfm")
    assert back.shape == d.shape
    assert np.array_equal(np.isfinite(back), np.isfinite(d))
    np.testing.assert_array_equal(back[np.isfinite(d)], d[np.isfinite(d)])


@pytest.mark.parametrize("method", ["sad", "sgbm"])
def test_cli_match_writes_pfm_and_png(tmp_path: Path, method: str, capsys) -> None:
    lp, rp = _pair(tmp_path)
    out = tmp_path / "out" / "disp.pfm"
    out.parent.mkdir()
    rc = main(["match", str(lp), str(rp), "-o", str(out), "--max-disp", "12", "--method", method])
    assert rc == 0
    disp = read_pfm(out)
    assert disp.shape == (30, 60)
    assert (np.abs(disp[5:25, 20:55] - 5.0) <= 1.0).mean() > 0.9
    assert out.with_suffix(".png").is_file()
    assert "wrote" in capsys.readouterr().out


def test_cli_match_errors(tmp_path: Path, capsys) -> None:
    lp, rp = _pair(tmp_path)
    out = str(tmp_path / "d.pfm")
    assert main(["match", str(lp), str(rp), "-o", out, "--max-disp", "60"]) == 2
    assert "expected max_disp < image width" in capsys.readouterr().err
    # the method is checked before the images are read
    assert main(["match", "missing.png", "missing.png", "-o", out, "--max-disp", "4", "--method", "x"]) == 2
    assert "expected a method among" in capsys.readouterr().err
    assert main(["match", str(lp), str(rp), "-o", out, "--max-disp", "4", "-p", "radius"]) == 2
    assert "key=value" in capsys.readouterr().err
    assert main(["match", str(lp), str(rp), "-o", str(tmp_path / "d.png"), "--max-disp", "4"]) == 2
    assert not (tmp_path / "d.png").exists()


def test_cli_evaluate_missing_data(tmp_path: Path, capsys) -> None:
    rc = main(["evaluate", "middlebury", "--data", str(tmp_path / "none"), "--method", "sad",
               "-o", str(tmp_path / "o")])
    assert rc == 2
    assert "expected a Middlebury data folder" in capsys.readouterr().err


def test_cli_evaluate_tsukuba(middlebury_dir: Path, tmp_path: Path, capsys) -> None:
    rc = main(["evaluate", "middlebury", "--data", str(middlebury_dir), "--method", "ncc",
               "--scenes", "tsukuba", "-o", str(tmp_path)])
    assert rc == 0
    out = capsys.readouterr().out
    assert "tsukuba" in out and "average" in out
    assert (tmp_path / "results.json").is_file() and (tmp_path / "tsukuba.pfm").is_file()


def test_cli_reproduce_table5_1_quick(middlebury_dir: Path, tmp_path: Path, capsys) -> None:
    rc = main(["reproduce", "table5.1", "--data", str(middlebury_dir), "--quick", "-o", str(tmp_path)])
    assert rc == 0
    assert "BPASW" in capsys.readouterr().out
    assert (tmp_path / "table5.1.md").is_file() and (tmp_path / "table5.1.json").is_file()
