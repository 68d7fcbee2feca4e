"""The plane-label steps shared by ``coop`` and the global multi-view method: parameters, order, each step off."""

from __future__ import annotations

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
                                   {"sweep": {"fraction": 0.3}}, {"sweep": 0.3}])
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
