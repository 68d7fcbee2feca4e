"""Table 7.2 reproduction on a tiny rig (smoke test of the measurement and the markdown)."""

from __future__ import annotations

from prismstereo.apps.tables.table7_2 import COLUMNS, measure, render_markdown


def test_table7_2_small():
    data = measure(scale=4)
    assert len(data["samples"]) == 8
    assert set(data["overall"]) == set(COLUMNS)
    exact = data["overall"]["exact"]
    assert exact["robot_median_rel_pct"] < 1.0 and exact["robot_points"] > 500
    md = render_markdown(data)
    assert "0.4839" in md and "0.62025" in md and "thesis construction (Q)" in md
