"""Shared fixtures: the thesis rigs and the optional Middlebury folder."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from prismstereo.config import Rig, pyramid_rig, thesis_biprism, thesis_triprism

REPO_ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session")
def biprism() -> Rig:
    return thesis_biprism()


@pytest.fixture(scope="session")
def triprism() -> Rig:
    return thesis_triprism()


@pytest.fixture(scope="session")
def pyramid4() -> Rig:
    return pyramid_rig(4)


@pytest.fixture(scope="session")
def middlebury_dir() -> Path:
    env = os.environ.get("PRISMSTEREO_MIDDLEBURY")
    path = Path(env) if env else REPO_ROOT.parent / "shared" / "data" / "middlebury"
    if not (path / "tsukuba" / "left.png").is_file():
        pytest.skip(f"Middlebury data not found at {path}")
    return path
