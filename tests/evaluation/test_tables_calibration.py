"""Tables 3.4 and 4.3 (calibration baseline) in quick mode: they run, and the geometric models transfer
correspondences better than the thesis's lab numbers; the thesis's numbers are printed beside ours."""

from __future__ import annotations

import numpy as np
import pytest

from prismstereo.apps.reproduce import reproduce_table
from prismstereo.config import thesis_biprism
from prismstereo.rectify.baseline import (
    ZHANG_MODELS,
    detect_corners,
    exact_correspondence,
    transfer_at_depth,
    zhang_calibration,
)


def test_table3_4_quick(tmp_path) -> None:  # type: ignore[no-untyped-def]
    res = reproduce_table("table3.4", tmp_path, quick=True)
    assert (tmp_path / "table3.4.md").is_file() and (tmp_path / "table3.4.json").is_file()
    assert "6.78" in res.markdown and "10.75" in res.markdown
    summary = res.data["experiment"].summary
    assert summary["geometric (fitted model)"]["mean"] < 0.5
    assert summary["geometric (thesis construction)"]["mean"] < 6.78
    assert np.isfinite(summary["Zhang (k1,k2,p1,p2,k3)"]["mean"])


def test_table4_3_quick(tmp_path) -> None:  # type: ignore[no-untyped-def]
    res = reproduce_table("table4.3", tmp_path, quick=True)
    assert "7.50" in res.markdown and "12.88" in res.markdown
    summary = res.data["experiment"].summary
    assert summary["geometric (thesis construction)"]["mean"] < 7.5
    assert len(res.data["experiment"].table_points["exact"]) == 8


def test_zhang_recovers_a_pinhole_pair_from_exact_corners() -> None:
    """Zhang calibration (no distortion) on noiseless corners fits them and transfers within 15 px."""
    rig = thesis_biprism(6.4)
    det = detect_corners(rig, [1, 0], n_poses=12, source="exact", noise_px=0.0)
    z = zhang_calibration(rig, det, [1, 0], flags=ZHANG_MODELS["none"])
    assert z.rms_px[1] < 0.5
    pa = np.array([[200.0, 300.0], [300.0, 400.0]])
    _, pb, ok = exact_correspondence(rig, 1, 0, pa, np.array([1500.0, 1500.0]))
    assert ok.all()
    pred = transfer_at_depth(z.cameras[1], z.cameras[0], pa, np.array([1500.0, 1500.0]))
    assert np.linalg.norm(pred - pb, axis=1).max() == pytest.approx(0.0, abs=15.0)
