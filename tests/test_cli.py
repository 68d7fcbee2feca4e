from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from prismstereo import __version__
from prismstereo.cli import main
from prismstereo.config import thesis_biprism


def test_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert __version__ in capsys.readouterr().out


def test_calibrate_end_to_end(tmp_path, capsys):
    rig_path = tmp_path / "rig.toml"
    thesis_biprism().save(rig_path)
    out = tmp_path / "cameras.json"
    assert main(["calibrate", str(rig_path), "-o", str(out), "--method", "fit"]) == 0
    text = capsys.readouterr().out
    assert "right" in text and "left" in text and "rms px" in text
    data = json.loads(out.read_text())
    assert data["method"] == "fit"
    assert all(v["rms_px"] < 0.5 for v in data["views"])


def test_bad_rig_is_one_line_exit_2(tmp_path):
    rig_path = tmp_path / "rig.toml"
    rig_path.write_text(thesis_biprism().to_toml().replace("refractive_index = 1.5", "refractive_index = 0.9"))
    out = tmp_path / "cameras.json"
    proc = subprocess.run([sys.executable, "-m", "prismstereo", "calibrate", str(rig_path), "-o", str(out)],
                          capture_output=True, text=True)
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and "refractive_index" in proc.stderr
    assert "Traceback" not in proc.stderr
    assert not out.exists()


def test_quiet_does_not_leak_into_later_calls(monkeypatch, tmp_path) -> None:  # type: ignore[no-untyped-def]
    import os

    from prismstereo.cli import main

    monkeypatch.delenv("TQDM_DISABLE", raising=False)
    rig = Path(__file__).resolve().parents[1] / "examples" / "rigs" / "biprism.toml"
    assert main(["calibrate", str(rig), "-o", str(tmp_path / "cams.json"), "--quiet"]) == 0
    assert "TQDM_DISABLE" not in os.environ
    monkeypatch.setenv("TQDM_DISABLE", "0")
    assert main(["calibrate", str(rig), "-o", str(tmp_path / "cams2.json"), "--quiet"]) == 0
    assert os.environ["TQDM_DISABLE"] == "0"
