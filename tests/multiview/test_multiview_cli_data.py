"""``prismstereo multiview`` command and the Middlebury multi-view checks (skipped without the data)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from prismstereo.cli import main
from prismstereo.io import read_pfm, write_image


def _pair(tmp_path: Path) -> tuple[Path, Path]:
    rng = np.random.default_rng(0)
    big = rng.integers(0, 256, size=(32, 80, 3)).astype(np.uint8)
    ref, view = big[:, 8:56], big[:, 10:58]  # view at ratio +1 shows ref[x] at x - 2
    a, b = tmp_path / "ref.png", tmp_path / "v.png"
    write_image(a, ref)
    write_image(b, view)
    return a, b


@pytest.mark.parametrize("spec", ["v.png", "v.png:abc", "v.png:0", "v.png:nan"])
def test_cli_bad_ratio_exit_2(tmp_path: Path, spec: str, capsys: pytest.CaptureFixture[str]) -> None:
    a, _ = _pair(tmp_path)
    rc = main(["multiview", "--reference", str(a), "--view", str(tmp_path / spec), "--max-disp", "4",
               "-o", str(tmp_path / "o.pfm")])
    assert rc == 2
    err = capsys.readouterr().err
    assert "error" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o.pfm").exists()


def test_cli_bad_method_and_size_exit_2(tmp_path: Path) -> None:
    a, b = _pair(tmp_path)
    base = ["multiview", "--reference", str(a), "--view", f"{b}:1", "-o", str(tmp_path / "o.pfm")]
    assert main([*base, "--max-disp", "4", "--method", "sgm"]) == 2
    assert main([*base, "--max-disp", "400"]) == 2
    assert main(["multiview", "--reference", str(a), "--view", f"{b}:1", "--max-disp", "4",
                 "-o", str(tmp_path / "o.png")]) == 2


def test_cli_writes_pfm_and_png(tmp_path: Path) -> None:
    a, b = _pair(tmp_path)
    out = tmp_path / "d.pfm"
    rc = main(["multiview", "--reference", str(a), "--view", f"{b}:1", "--max-disp", "5", "--method", "local",
               "-o", str(out)])
    assert rc == 0
    d = read_pfm(out)
    assert d.shape == (32, 48)
    assert np.median(d[8:-8, 12:-12]) == pytest.approx(2.0, abs=0.25)
    assert out.with_suffix(".png").is_file()


def test_tsukuba_five_views_global_beats_two_view_coop(middlebury_dir: Path) -> None:
    from prismstereo.apps.tables.table7_1 import TSUKUBA_VIEWS
    from prismstereo.evaluation.middlebury import evaluate_disparity, load_scene
    from prismstereo.io import read_image
    from prismstereo.matching.api import match
    from prismstereo.multiview.api import match_multiview

    scene = load_scene("tsukuba", middlebury_dir)
    views = middlebury_dir / "tsukuba" / "views"
    ref = read_image(views / "col3.png")
    imgs = [read_image(views / f"{k}.png") for k in TSUKUBA_VIEWS]
    mv = match_multiview(ref, imgs, ratios=list(TSUKUBA_VIEWS.values()), max_disp=scene.max_disp)
    # the live two-view coop matcher on col3/col4 (the unit baseline), run here so the comparison tracks it
    two = match(ref, read_image(views / "col4.png"), max_disp=scene.max_disp, method="coop")
    b_mv = evaluate_disparity(mv.disparity, scene, thresholds=(1.0,))["bad"]["1.0"]
    b_two = evaluate_disparity(two.disparity, scene, thresholds=(1.0,))["bad"]["1.0"]
    # measured (v2 masks, bad > 1 px): five-view global 0.98 / 1.34 / 4.90, coop 1.35 / 1.79 / 6.21 (before the
    # depth-aware segmentation, aggregated data term and finer segment levels: global 1.24 / 1.60 / 5.87)
    # both are deterministic; margins of 0.1 on every mask keep the comparison meaningful
    for m in ("nonocc", "all", "disc"):
        assert b_mv[m] < b_two[m] - 0.1, (m, b_mv, b_two)
    # issue 7's target (nonocc <= 1.0 %, the thesis's global method 1.021)
    assert b_mv["nonocc"] <= 1.0 and b_mv["all"] < 1.45 and b_mv["disc"] < 5.5, b_mv
