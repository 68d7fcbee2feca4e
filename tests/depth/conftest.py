"""Small simulated captures shared by the depth tests (half-resolution thesis bi-prism rig)."""

from __future__ import annotations

import pytest

from prismstereo.apps.demo import demo_rig, plane_scene


@pytest.fixture(scope="session")
def plane_capture():
    """(rig, scene, capture): a textured plane at 1.2 m turned 25°, seen by the demo rig (512×384)."""
    from prismstereo.simulate import render_capture

    rig = demo_rig()
    scene = plane_scene(1200.0, tilt_deg=25.0)
    return rig, scene, render_capture(rig, scene)


@pytest.fixture(scope="session")
def _plane_evaluated(plane_capture):
    import dataclasses

    from prismstereo.depth import DepthConfig, run_depth
    from prismstereo.evaluation.depth_metrics import evaluate_depth, ground_truth_for_run

    rig, scene, cap = plane_capture
    res = run_depth(rig, cap.image, config=DepthConfig())
    gt = ground_truth_for_run(res, scene=scene)
    return dataclasses.replace(res, accuracy=evaluate_depth(res, gt=gt)), gt


@pytest.fixture(scope="session")
def plane_run(_plane_evaluated):
    """The default depth run on :func:`plane_capture`, with its accuracy against the scene."""
    return _plane_evaluated[0]


@pytest.fixture(scope="session")
def plane_gt(_plane_evaluated):
    """The ground truth of :func:`plane_run` on its grid (a ``DepthGroundTruth``)."""
    return _plane_evaluated[1]
