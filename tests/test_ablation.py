"""The coop ablation (``benchmarks/ablation_coop.py``) at CI's reduced setting: it runs, and its table says
that the plane support test earns its place."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]


def test_quick_ablation_runs_and_the_support_test_earns_its_place(middlebury_dir: Path, tmp_path: Path) -> None:
    extra = middlebury_dir.parent / "middlebury-extra"
    if not extra.is_dir() or not any(p.is_dir() for p in extra.iterdir()):
        pytest.skip(f"validation scenes not found at {extra}")
    out = tmp_path / "ablation.json"
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT / "src")}
    proc = subprocess.run(
        [sys.executable, str(REPO_ROOT / "benchmarks" / "ablation_coop.py"), "--quick", "--steps", "full,split",
         "--v2", str(middlebury_dir), "--validation", str(extra), "--json", str(out)],
        capture_output=True, text=True, env=env, timeout=900, check=False)
    assert proc.returncode == 0, proc.stderr[-2000:]
    rows = json.loads(out.read_text())
    assert set(rows) == {"full", "split"}
    assert set(rows["full"]["v2"]) == {"tsukuba"} and len(rows["full"]["validation"]) == 1
    for row in rows.values():
        for scene in (*row["v2"].values(), *row["validation"].values()):
            assert 0.0 <= scene["nonocc"] <= scene["all"] <= 100.0
    # the first validation scene (books) has large repetitive segments: without the support test their single
    # planes are wrong (measured 13.2 vs 8.5 bad > 1 px nonocc)
    assert rows["full"]["val_avg_nonocc"] < rows["split"]["val_avg_nonocc"] - 2.0
    assert rows["full"]["v2_avg12"] <= 3.3  # Tsukuba alone: measured 2.91 (nonocc / all / disc 1.32 / 1.72 / 5.69)
