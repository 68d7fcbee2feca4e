"""Shared fixtures: the thesis rigs and the optional Middlebury folder."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from prismstereo.config import Rig, pyramid_rig, thesis_biprism, thesis_triprism

REPO_ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session", autouse=True)
def _setup_cache(tmp_path_factory: pytest.TempPathFactory):
    """The depth set-up cache of the test session (and of the CLI processes it starts): a fresh folder, not
    the user's."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("PRISMSTEREO_CACHE_DIR", str(tmp_path_factory.mktemp("setup_cache")))
        yield


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


@pytest.fixture(scope="session")
def capture_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A simulated capture folder like ``prismstereo simulate`` writes: capture.png, depth_gt.pfm, rig.toml.

    The demo bi-prism looking at a plane 1.6 m away, tilted by 20°; read-only for the tests that use it.
    """
    from prismstereo.apps.demo import demo_rig, plane_scene
    from prismstereo.io import write_image, write_pfm
    from prismstereo.simulate import render_capture

    folder = tmp_path_factory.mktemp("capture")
    rig = demo_rig()
    cap = render_capture(rig, plane_scene(1600.0, tilt_deg=-20.0, seed=5))
    write_image(folder / "capture.png", cap.image)
    write_pfm(folder / "depth_gt.pfm", cap.depth)
    rig.save(folder / "rig.toml")
    return folder
