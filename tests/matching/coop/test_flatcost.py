"""The fallback's evidence for ``sgm``'s map: where BPASW's aggregated cost has no distinct minimum."""

from __future__ import annotations

import numpy as np
import pytest

from prismstereo.errors import ConfigError
from prismstereo.matching.coop.flatcost import contradicted_segments, flat_cost_segments, outvoted_segments, peak_ratio
from prismstereo.matching.coop.steps import FallbackParams


def test_peak_ratio_is_the_second_minimum_beyond_the_winners_neighbours() -> None:
    vol = np.array([[[4.0, 2.0, 1.0, 1.5, 3.0], [1.0, 1.1, 5.0, 5.0, 1.05]]], np.float32)  # (1, 2, 5)
    winner = vol.argmin(axis=2)
    r = peak_ratio(vol, winner, np.ones((1, 2), bool))
    # pixel 0: winner 2 (cost 1), levels 1..3 its own peak, next best 3.0; pixel 1: winner 0, next best 1.05
    np.testing.assert_allclose(r, [[2.0, 0.05]], rtol=1e-6)
    assert np.isinf(peak_ratio(vol, winner, np.array([[True, False]]))[0, 1])


def test_flat_segments_take_sgm_only_where_its_check_holds() -> None:
    labels = np.zeros((4, 30), np.int32)
    labels[:, 10:] = 1
    labels[:, 20:] = 2
    ratio = np.full((4, 30), 0.5, np.float32)
    ratio[:, 10:] = 0.01  # segments 1 and 2: a flat cost
    sgm = np.ones((4, 30), bool)
    sgm[:3, 20:] = False  # segment 2: sgm's check keeps a quarter
    bp = np.ones((4, 30), bool)
    where = np.ones((4, 30), bool)
    kw = {"max_ratio": 0.07, "min_support": 0.4, "support_margin": 0.3}
    flat = flat_cost_segments(labels, where, ratio, sgm, bp, **kw)
    assert not flat[labels == 0].any() and flat[labels == 1].all() and not flat[labels == 2].any()
    # sgm's share below BPASW's by more than the margin: BPASW's map stays
    bp2 = bp.copy()
    sgm2 = sgm.copy()
    sgm2[:2, 10:20] = False  # segment 1: sgm 0.5 against BPASW 1.0
    assert not flat_cost_segments(labels, where, ratio, sgm2, bp2, **kw)[labels == 1].any()
    assert not flat_cost_segments(labels, where, ratio, sgm, bp, **{**kw, "max_ratio": 0.0}).any()
    # only the replaced pixels count and are returned
    part = where.copy()
    part[:, 15:20] = False
    flat = flat_cost_segments(labels, part, ratio, sgm, bp, **kw)
    assert flat[:, 10:15].all() and not flat[:, 15:20].any()


def test_outvoted_segments_need_both_matchers_to_agree_far_from_the_plane() -> None:
    labels = np.zeros((10, 40), np.int32)
    labels[:, 20:] = 1
    labels[:2, 38:] = 2  # a small segment (4 px of 400)
    final = np.full((10, 40), 10.0, np.float32)
    bp = np.full((10, 40), 10.0, np.float32)
    bp[:1, :20] = 20.0  # segment 0: 20 of its 200 px are outvoted (both matchers at 20, checked)
    bp[:, 20:] = 30.0  # segment 1: BPASW far from the plane everywhere...
    bp[:2, 38:] = 30.0
    sgm = bp.copy()
    sgm[2:, 20:] = 10.0  # ... but sgm agrees with it on a few pixels only besides segment 2's
    sgm[:2, 20:38] = 30.5
    ok = np.ones((10, 40), bool)
    kw = {"tol": 7.0, "min_share": 0.05, "min_size": 0.02}
    out = outvoted_segments(labels, final, bp, ok, sgm, ok, **kw)
    assert out[labels == 0].all() and out[labels == 1].all() and not out[labels == 2].any()
    # within tol of the plane, unchecked, or the two maps apart: no vote
    assert not outvoted_segments(labels, final, bp, ok, sgm, ok, **{**kw, "tol": 25.0}).any()
    nochk = ok.copy()
    nochk[:2, :] = False
    assert not outvoted_segments(labels, final, bp, nochk, sgm, ok, **kw)[labels == 1].any()
    assert not outvoted_segments(labels, final, bp, ok, sgm + 2.0, ok, **kw).any()
    # a share threshold above the votes, or the rule off
    assert not outvoted_segments(labels, final, bp, ok, sgm, ok, **{**kw, "min_share": 0.2})[labels == 0].any()
    assert not outvoted_segments(labels, final, bp, ok, sgm, ok, **{**kw, "tol": 0.0}).any()
    # the small segment counts once it is large enough
    assert outvoted_segments(labels, final, bp, ok, sgm, ok, **{**kw, "min_size": 0.0})[labels == 2].all()


@pytest.mark.parametrize("kw", [{"flat_ratio": -0.1}, {"flat_min_support": 1.5}, {"flat_support_margin": -0.2},
                                {"outvoted_tol": -1.0}, {"outvoted_share": 1.5}, {"outvoted_min_size": -0.1},
                                {"contradicted_share": 1.5}, {"contradicted_min_size": -0.1}])
def test_bad_flat_parameters_name_the_fallback(kw: dict) -> None:
    with pytest.raises(ConfigError, match="fallback"):
        FallbackParams(**kw)


def test_contradicted_segments_need_both_checks_on_two_disparities() -> None:
    labels = np.zeros((10, 40), np.int32)
    labels[:, 20:] = 1
    labels[:2, 38:] = 2  # a small segment (4 px of 400)
    bp = np.full((10, 40), 10.0, np.float32)
    sgm = bp.copy()
    sgm[:5, :20] = 14.0  # segment 0: half its pixels 4 px apart
    sgm[:2, 20:] = 14.0  # segment 1: 36 of its 196 px apart; segment 2 all apart
    ok = np.ones((10, 40), bool)
    where = np.ones((10, 40), bool)
    kw = {"min_share": 0.4, "min_size": 0.02}
    out = contradicted_segments(labels, where, bp, ok, sgm, ok, **kw)
    assert out[labels == 0].all() and not out[labels == 1].any() and not out[labels == 2].any()
    # a check failing where the maps differ, the maps within 1 px, or the rule off: not contradicted
    nochk = ok.copy()
    nochk[:3, :20] = False
    assert not contradicted_segments(labels, where, bp, nochk, sgm, ok, **kw).any()
    assert not contradicted_segments(labels, where, bp, ok, sgm, nochk, **kw).any()
    assert not contradicted_segments(labels, where, bp, ok, np.minimum(sgm, 11.0), ok, **kw).any()
    assert not contradicted_segments(labels, where, bp, ok, sgm, ok, **{**kw, "min_share": 0.0}).any()
    # shares of the replaced pixels only, and only those are returned; the small segment once large enough
    part = where.copy()
    part[2:, 20:] = False  # segment 1: its 36 replaced pixels are all apart
    out = contradicted_segments(labels, part, bp, ok, sgm, ok, **{**kw, "min_size": 0.0})
    assert out[:2, 20:].all() and not out[2:, 20:].any()
    assert contradicted_segments(labels, where, bp, ok, sgm, ok, **{**kw, "min_size": 0.0})[labels == 2].all()
