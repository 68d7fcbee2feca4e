"""The temporal prior of a stream: per-pixel bands from the previous frame and the check of a banded frame."""

from __future__ import annotations

import numpy as np
import pytest

from prismstereo.errors import ConfigError
from prismstereo.matching.temporal import TemporalPrior, band_failed, band_limit_share, prior_band


def test_band_is_the_neighbourhood_min_max_with_the_margin_and_full_where_nothing_is_known() -> None:
    prev = np.full((40, 60), np.nan, dtype=np.float32)
    prev[:, 10:30] = 20.4
    prev[:, 30:40] = 31.0
    b = prior_band(prev, min_disp=5, max_disp=60, radius=2, wide_radius=4, margin=3)
    assert (b.lo[5, 15], b.hi[5, 15]) == (17, 24) and (b.lo[:, 15] == 17).all()
    # near the edge between the two: both values
    assert (b.lo[5, 29], b.hi[5, 29]) == (17, 34)
    # no value within 2 px, one within 4 px: the wide window's; none within 4 px: the whole range
    assert (b.lo[5, 43], b.hi[5, 43]) == (28, 34) and not b.full[5, 43]
    assert (b.lo[5, 50], b.hi[5, 50]) == (5, 60) and b.full[5, 50]
    assert b.full_share == pytest.approx(float(b.full.mean())) and 7 < b.mean_width < 56
    clipped = prior_band(np.full((4, 4), 59.0, np.float32), min_disp=5, max_disp=60, margin=3)
    assert (clipped.lo.min(), clipped.hi.max()) == (56, 60)
    nothing = prior_band(np.full((4, 4), np.nan, np.float32), min_disp=5, max_disp=60)
    assert nothing.full.all() and nothing.full_share == 1.0


def test_a_frame_outside_its_bands_fails_the_check_and_one_inside_passes() -> None:
    prev = np.full((30, 30), 20.0, dtype=np.float32)
    band = prior_band(prev, min_disp=0, max_disp=50, radius=2, margin=3)
    rules = TemporalPrior()
    inside = prev + np.float32(0.6)
    assert band_limit_share(inside, band, min_disp=0, max_disp=50) == 0.0
    assert band_failed(inside, band, min_disp=0, max_disp=50, reference_matches=900, rules=rules) == ""
    cut = np.full_like(prev, 23.0)  # the scene moved beyond the band: its winners at the limit
    assert band_limit_share(cut, band, min_disp=0, max_disp=50) == 1.0
    assert "band limit" in band_failed(cut, band, min_disp=0, max_disp=50, reference_matches=900, rules=rules)
    sparse = np.where(np.arange(900).reshape(30, 30) % 2 == 0, inside, np.float32(np.nan))
    assert "matches against" in band_failed(sparse, band, min_disp=0, max_disp=50, reference_matches=900,
                                            rules=rules)
    # a limit that is the search range's own is no sign of a cut
    edge = prior_band(np.full((5, 5), 1.0, np.float32), min_disp=0, max_disp=50, margin=3)
    assert band_limit_share(np.zeros((5, 5), np.float32), edge, min_disp=0, max_disp=50) == 0.0


def test_rules_are_checked() -> None:
    with pytest.raises(ConfigError, match="keyframe_every"):
        TemporalPrior(keyframe_every=0)
    with pytest.raises(ConfigError, match="max_limit_share"):
        TemporalPrior(max_limit_share=2.0)
    assert TemporalPrior().to_dict()["radius"] == 8
