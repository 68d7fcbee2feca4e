"""A band of slices per row segment (issue 30): the banded BPASW aggregation and matcher against the whole volume's."""

from __future__ import annotations

import numpy as np
import pytest

from prismstereo.errors import MatchingError
from prismstereo.matching import get_matcher
from prismstereo.matching.local.aggregation import SegmentBand, aggregate_bpasw
from prismstereo.matching.local.costs import cost_s_ad_census


def _pair(h: int = 48, w: int = 90, d: int = 7, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    left = rng.integers(0, 256, size=(h, w, 3), dtype=np.uint8)
    left[:, w // 2:] //= 3  # two textures: the colour weights differ across the image
    right = np.roll(left, -d, axis=1)
    return left, right


def _random_band(h: int, nseg: int, nd: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    lo = rng.integers(0, nd, size=(h, nseg))
    hi = np.minimum(lo + rng.integers(0, 6, size=(h, nseg)), nd - 1)
    b = np.stack([lo, hi], axis=2).astype(np.int64)
    b[rng.random((h, nseg)) < 0.2] = (1, 0)  # empty segments
    b[:5] = (1, 0)  # empty rows above
    b[-3:] = (1, 0)  # and below
    return b


@pytest.mark.parametrize("segment", [8, 13, 90])
def test_banded_aggregation_equals_the_whole_volume_inside_the_band(segment: int) -> None:
    left, right = _pair()
    h, w = left.shape[:2]
    vol = cost_s_ad_census(left, right, max_disp=24, min_disp=2)
    full = aggregate_bpasw(vol, left, right, radius=6, dilation=2, min_disp=2)
    nseg = -(-w // segment)
    band = SegmentBand(bounds=_random_band(h, nseg, vol.shape[2], seed=segment), segment=segment)
    out = aggregate_bpasw(vol, left, right, radius=6, dilation=2, min_disp=2, band=band)
    idx = np.arange(vol.shape[2])[None, None, :]
    b = np.repeat(band.bounds, segment, axis=1)[:, :w]
    inside = (idx >= b[:, :, :1]) & (idx <= b[:, :, 1:])
    assert inside.any() and (~inside).any()
    np.testing.assert_array_equal(out[inside], full[inside])  # bit for bit
    assert np.isposinf(out[~inside]).all()
    assert band.pixels(h, w) == int(inside.sum())
    np.testing.assert_array_equal(band.mask(h, w), inside.any(axis=2))


def test_band_over_every_slice_is_the_matcher_itself() -> None:
    left, right = _pair(h=40, w=70)
    m = get_matcher("bpasw", radius=6)
    ref = m.compute(left, right, max_disp=15)
    band = SegmentBand(bounds=np.tile(np.array([0, 15], np.int64), (40, 3, 1)), segment=32)
    res = m.compute(left, right, max_disp=15, band=band)
    np.testing.assert_array_equal(res.valid, ref.valid)
    np.testing.assert_array_equal(res.disparity, ref.disparity)
    assert res.disparity_raw is not None and ref.disparity_raw is not None
    np.testing.assert_array_equal(res.disparity_raw, ref.disparity_raw)


def test_pixels_without_a_band_are_invalid_and_the_others_dense() -> None:
    left, right = _pair(h=40, w=70)
    m = get_matcher("bpasw", radius=6, subpixel=True)
    b = np.tile(np.array([3, 12], np.int64), (40, 3, 1))
    b[:10] = (1, 0)
    b[:, 2] = (1, 0)  # columns 64..69
    res = m.compute(left, right, max_disp=15, band=SegmentBand(bounds=b, segment=32))
    assert not res.valid[:10].any() and not res.valid[:, 64:].any()
    assert np.isnan(res.disparity[:10]).all() and np.isnan(res.disparity[:, 64:]).all()
    inner = res.disparity[10:, 20:64]
    assert np.isfinite(inner).all() and (inner >= 3).all() and (inner <= 12).all()
    # the shift is 7: matched inside the band, away from the left border where x - d < 0
    assert np.mean(np.abs(res.disparity[10:, 20:64][res.valid[10:, 20:64]] - 7) <= 1) > 0.95


def test_band_is_checked_and_refused_where_not_supported() -> None:
    left, right = _pair(h=20, w=40)
    with pytest.raises(MatchingError, match="shape"):
        SegmentBand(bounds=np.zeros((20, 2), np.int64), segment=32)
    band = SegmentBand(bounds=np.zeros((20, 3, 2), np.int64), segment=32)
    with pytest.raises(MatchingError, match="segments"):
        get_matcher("bpasw", radius=4).compute(left, right, max_disp=8, band=band)
    with pytest.raises(MatchingError, match="no band"):
        get_matcher("sad").compute(left, right, max_disp=8, band=band)
    assert get_matcher("bpasw").supports_band and not get_matcher("bpasw", continuity=True).supports_band
    assert not get_matcher("sad").supports_band


def test_pixel_cost_inside_a_band_equals_the_whole_volume_and_is_zero_outside() -> None:
    left, right = _pair()
    h, w = left.shape[:2]
    full = cost_s_ad_census(left, right, max_disp=24, min_disp=2, tau_color=20.0, tau_gradient=8.0,
                            census_weight=0.5)
    band = SegmentBand(bounds=_random_band(h, -(-w // 13), full.shape[2], seed=5), segment=13)
    out = cost_s_ad_census(left, right, max_disp=24, min_disp=2, tau_color=20.0, tau_gradient=8.0,
                           census_weight=0.5, band=band)
    idx = np.arange(full.shape[2])[None, None, :]
    b = np.repeat(band.bounds, 13, axis=1)[:, :w]
    inside = (idx >= b[:, :, :1]) & (idx <= b[:, :, 1:])
    np.testing.assert_array_equal(out[inside], full[inside])  # bit for bit
    assert (out[~inside] == 0.0).all() and (full[~inside] != 0.0).any()


@pytest.mark.parametrize(("rows", "cols", "segment"), [(3, 5, 8), (0, 0, 8), (6, 20, 8), (2, 13, 13)])
def test_dilated_band_holds_every_slice_within_its_reach(rows: int, cols: int, segment: int) -> None:
    h, w = 30, 61
    nseg = -(-w // segment)
    band = SegmentBand(bounds=_random_band(h, nseg, 20, seed=rows + cols), segment=segment)
    out = band.dilated(rows=rows, cols=cols, height=h, width=w).check(h, w)
    b = band.bounds
    for y in range(h):
        for s in range(nseg):
            # the segments with a column within ``cols`` of one of this segment's columns
            c0, c1 = s * segment, min(w, (s + 1) * segment) - 1
            near = [t for t in range(nseg) if t * segment <= c1 + cols and min(w, (t + 1) * segment) - 1 >= c0 - cols]
            src = [(b[yy, t, 0], b[yy, t, 1]) for yy in range(max(0, y - rows), min(h, y + rows + 1)) for t in near
                   if b[yy, t, 0] <= b[yy, t, 1]]
            if not src:
                assert out[y, s, 0] > out[y, s, 1]
            else:
                assert out[y, s, 0] <= min(a for a, _ in src) and out[y, s, 1] >= max(c for _, c in src)
