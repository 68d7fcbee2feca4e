"""Semi-global matching within per-pixel bands (``SGMMatcher.compute_banded``, issue 30's temporal prior)."""

from __future__ import annotations

import numpy as np
import pytest
from tests.matching.local.test_sgm import _slanted_pair

from prismstereo.errors import ConfigError
from prismstereo.matching import match
from prismstereo.matching.local.sgm import SGMMatcher
from prismstereo.matching.temporal import PriorBand, TemporalPrior, band_failed


@pytest.mark.parametrize(("lo", "hi"), [(0, 20), (3, 17)])
def test_whole_range_bands_give_the_full_search_bit_for_bit(lo: int, hi: int) -> None:
    left, right, _ = _slanted_pair(40, 72)
    m = SGMMatcher(fill=False)
    full = m.compute(left, right, max_disp=hi, min_disp=lo)
    shape = left.shape[:2]
    banded = m.compute_banded(left, right, max_disp=hi, min_disp=lo, band_lo=np.full(shape, lo),
                              band_hi=np.full(shape, hi))
    np.testing.assert_array_equal(full.disparity, banded.disparity)
    assert full.extras["rejected_lr"] == banded.extras["rejected_lr"]
    assert banded.extras["band_mean"] == hi - lo + 1


def test_bands_around_the_truth_keep_the_full_search_accuracy_and_search_less() -> None:
    left, right, gt = _slanted_pair(60, 96)
    m = SGMMatcher(fill=False)
    full = m.compute(left, right, max_disp=24, min_disp=0)
    # a different band per pixel, each holding the truth: narrow (± 2..4 px around it, uneven)
    rng = np.random.default_rng(3)
    lo = np.clip(np.floor(gt) - rng.integers(2, 5, gt.shape), 0, 24)
    hi = np.clip(np.ceil(gt) + rng.integers(2, 5, gt.shape), 0, 24)
    banded = m.compute_banded(left, right, max_disp=24, min_disp=0, band_lo=lo, band_hi=hi)
    inner = (slice(8, -8), slice(30, -8))  # away from the borders the right view does not see

    def err(d: np.ndarray) -> tuple[float, float]:
        e = np.abs(d[inner] - gt[inner])
        return float(np.mean(np.isfinite(e))), float(np.nanmedian(e))

    (cov_full, med_full), (cov_band, med_band) = err(full.disparity), err(banded.disparity)
    assert cov_band >= cov_full - 0.02 and med_band <= med_full + 0.05 and med_band < 0.3
    assert banded.extras["band_mean"] < 10


def test_a_band_that_misses_the_truth_fails_the_streams_check() -> None:
    """What the stream reads (:func:`~prismstereo.matching.temporal.band_failed`): a scene outside its bands
    (a cut) piles its winners at a band limit or loses its matches to the left–right check."""
    left, right, gt = _slanted_pair(60, 96)
    m = SGMMatcher(fill=False)
    full = m.compute(left, right, max_disp=30, min_disp=0)
    reference = int(np.isfinite(full.disparity).sum())
    for shift in (4, -10):
        lo = np.clip(np.ceil(gt) + shift, 0, 24).astype(np.int32)
        band = PriorBand(lo=lo, hi=lo + 6, full=np.zeros(lo.shape, bool))
        d = m.compute_banded(left, right, max_disp=30, min_disp=0, band_lo=band.lo, band_hi=band.hi).disparity
        assert band_failed(d, band, min_disp=0, max_disp=30, reference_matches=reference, rules=TemporalPrior())
    inside = PriorBand(lo=np.floor(gt).astype(np.int32) - 3, hi=np.ceil(gt).astype(np.int32) + 3,
                       full=np.zeros(gt.shape, bool))
    d = m.compute_banded(left, right, max_disp=30, min_disp=0, band_lo=inside.lo, band_hi=inside.hi).disparity
    assert band_failed(d, inside, min_disp=0, max_disp=30, reference_matches=reference, rules=TemporalPrior()) == ""


def test_bad_bands_are_refused() -> None:
    left, right, _ = _slanted_pair(20, 40)
    m = SGMMatcher()
    shape = left.shape[:2]
    with pytest.raises(ConfigError, match="band_lo/band_hi"):
        m.compute_banded(left, right, max_disp=10, band_lo=np.zeros((3, 3)), band_hi=np.zeros((3, 3)))
    with pytest.raises(ConfigError, match="band_lo/band_hi"):
        m.compute_banded(left, right, max_disp=10, band_lo=np.full(shape, 5), band_hi=np.full(shape, 4))
    with pytest.raises(ConfigError, match="band_lo/band_hi"):
        m.compute_banded(left, right, max_disp=10, band_lo=np.zeros(shape), band_hi=np.full(shape, 11))
    with pytest.raises(ConfigError, match="census"):
        SGMMatcher(cost="bpasw").compute_banded(left, right, max_disp=10, band_lo=np.zeros(shape),
                                                band_hi=np.full(shape, 10))
    with pytest.raises(ConfigError, match="per-pixel bands"):
        match(left, right, max_disp=10, method="sad", band=(np.zeros(shape, int), np.full(shape, 10)))
