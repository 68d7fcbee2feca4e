"""The plane-label steps shared by ``coop`` and the global multi-view method: parameters, order, each step off."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from prismstereo.errors import ConfigError
from prismstereo.matching import get_matcher
from prismstereo.matching.coop.steps import STEP_NAMES, STEPS, StepParams, SweepParams


def test_every_named_step_has_one_function_in_the_order_of_the_sequence() -> None:
    assert tuple(STEPS) == STEP_NAMES
    assert STEP_NAMES[0] == "optimise" and STEP_NAMES[-1] == "fallback"


@pytest.mark.parametrize("steps", [{"sweep": {"frac": 1.5}}, {"sweep": {"keep": 0}}, {"boundary": {"agree": 3}},
                                   {"fine": {"levels": [[0.0, 10]]}}, {"median": {"radius": -1}},
                                   {"refit": {"rounds": -1}}, {"bpasw_planes": {"rounds": 4}}, {"swep": {}},
                                   {"sweep": {"fraction": 0.3}}, {"sweep": 0.3}, {"fine": {"check": -1}}])
def test_bad_step_parameters_fail_when_the_matcher_is_built(steps: dict) -> None:
    # the registry builds the matcher (and so validates every step) before any image is read
    with pytest.raises(ConfigError):
        get_matcher("coop", steps=steps)


def test_step_parameters_from_the_cli_mapping() -> None:
    m = get_matcher("coop", steps={"sweep": {"frac": 0.3, "slopes": [0, 1]}, "fine": {"levels": [[2, 5]]}},
                    data={"radius": 2})
    assert m.steps.sweep == SweepParams(frac=0.3, slopes=(0.0, 1.0))  # type: ignore[attr-defined]
    assert m.steps.fine.levels == ((2.0, 5),)  # type: ignore[attr-defined]
    assert m.steps.boundary == StepParams().boundary  # type: ignore[attr-defined]


def test_without_switches_each_step_off_and_refuses_unknown_names() -> None:
    off = StepParams().without(*STEP_NAMES[1:])
    assert off.refit.rounds == 0 and off.bpasw_planes.rounds == 0 and off.sweep.frac == 0
    assert not off.group_moves.enabled and off.fine.levels == () and off.boundary.radius == 0
    assert not off.occlusion.enabled and off.median.radius == 0 and not off.fallback.enabled
    assert not off.curved.enabled
    with pytest.raises(ConfigError):
        StepParams().without("optimise")


def test_each_step_off_still_recovers_the_synthetic_scene() -> None:
    """Every step is optional: with any one off, coop still recovers a piecewise-planar pair (the steps pass
    a consistent state on), and with all of them off the optimisation alone does too."""
    from test_coop import _synthetic_pair  # the test module beside this one (pytest puts its folder on the path)

    from prismstereo.matching.coop.pipeline import coop_match

    left, right, gt = _synthetic_pair()
    visible = np.ones(gt.shape, bool)
    visible[:, :20] = False
    for off in (("sweep", "group_moves"), ("fine", "boundary"), STEP_NAMES[1:]):
        res = coop_match(left, right, max_disp=20, steps=StepParams().without(*off), keep_stages=True)
        assert (np.abs(res.disparity - gt) > 1.0)[visible].mean() < 0.03, off
        assert set(STEP_NAMES) <= set(res.stages)


def test_the_global_multiview_method_takes_the_same_steps_with_its_own_defaults() -> None:
    from prismstereo.multiview.globalmv import MULTIVIEW_STEPS, GlobalMultiViewParams

    p = GlobalMultiViewParams(steps={"sweep": {"frac": 0.2}})
    assert p.steps.sweep.frac == 0.2 and p.steps.sweep.min_px == MULTIVIEW_STEPS.sweep.min_px
    assert p.steps.fine == MULTIVIEW_STEPS.fine
    with pytest.raises(ConfigError):
        GlobalMultiViewParams(steps={"median": {"radius": -2}})


def test_curved_step_follows_the_evidence_of_a_curved_segment_on_its_own_plane_pixels_only() -> None:
    """The ``curved`` step on a fold of cloth (one segment, its plane up to 1.3 px off at the ends): with the
    step on, the segment takes the quadric of the evidence (the mean of both cross-checked initial maps where
    they agree) and is within 1 px everywhere; pixels another step set are kept; off, nothing changes."""
    from prismstereo.matching.coop.pipeline import PairMaps, PairSetup, _PairEvidence
    from prismstereo.matching.coop.steps import CurvedParams, PlaneLabels, step_curved
    from prismstereo.matching.segments.planes import build_segment_index, fit_planes

    h, w = 40, 60
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    true = 30.0 + 0.05 * yy + 0.002 * (xx - w / 2) ** 2
    labels = np.zeros((h, w), np.int32)
    index = build_segment_index(labels)
    planes, _ = fit_planes(index, true, np.ones((h, w), bool))
    state = PlaneLabels(labels=labels, index=index, graph=None,  # type: ignore[arg-type]
                        assign=np.zeros(1, np.int32), planes=planes, own=np.full((1, 2), -1, np.int64),
                        parent=np.zeros(1, np.int64), pairs=np.zeros((0, 2), np.int32))
    plane = state.render()
    assert (np.abs(plane - true) > 1.0).mean() > 0.05
    final = plane.copy()
    final[:5, :5] = 40.0  # set by another step (boundary or occlusion)
    rng = np.random.default_rng(1)
    initial = (true + rng.normal(0.0, 0.2, (h, w))).astype(np.float32)
    bdisp = (true + rng.normal(0.0, 0.2, (h, w))).astype(np.float32)
    ok = rng.random((h, w)) < 0.7
    maps = PairMaps(data=np.zeros((1, 1, 1), np.float32), reliable=ok, initial=initial,
                    bvol=np.zeros((1, 1, 1), np.float32), bdisp=bdisp, brel=ok, nonplanar=np.zeros((h, w), bool),
                    evidence=ok)
    params = PairSetup(coop=None, segmentation=None, planes=None, cost=None, slopes=None)  # type: ignore[arg-type]
    ev = _PairEvidence(np.zeros((h, w, 3), np.uint8), np.zeros((h, w, 3), np.uint8), min_disp=0, max_disp=64,
                       maps=maps, params=params)
    s = dataclasses.replace(state, disparity=final)
    out = step_curved(s, ev, StepParams()).disparity
    assert out is not None
    np.testing.assert_array_equal(out[:5, :5], final[:5, :5])
    rest = np.ones((h, w), bool)
    rest[:5, :5] = False
    assert np.abs(out - true)[rest].max() < 0.5
    off = step_curved(s, ev, StepParams(curved=CurvedParams(enabled=False))).disparity
    np.testing.assert_array_equal(off, final)
