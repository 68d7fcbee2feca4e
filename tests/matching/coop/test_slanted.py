"""Slanted-support-window cost (PatchMatch Stereo's cost, Bleyer et al. 2011) on a synthetic slanted plane."""

from __future__ import annotations

import cv2
import numpy as np

from prismstereo.matching.coop.slanted import plane_cost

A, B, C = 0.3, 0.15, 4.0  # d = A x + B y + C


def _pair(h: int = 64, w: int = 96) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(3)
    tex = rng.uniform(0, 255, (h, w, 3)).astype(np.float32)
    left = cv2.GaussianBlur(tex, (0, 0), 1.0)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    # right(y, xr) = left(y, x) with xr = x - (A x + B y + C)  =>  x = (xr + B y + C) / (1 - A)
    mx = (xx + B * yy + C) / (1.0 - A)
    right = cv2.remap(left, mx, yy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    return np.clip(left, 0, 255).astype(np.uint8), np.clip(right, 0, 255).astype(np.uint8)


def test_true_slanted_plane_beats_every_fronto_parallel_hypothesis() -> None:
    left, right = _pair()
    h, w = left.shape[:2]
    true = plane_cost(left, right, (A, B, C))
    fronto = np.stack([plane_cost(left, right, (0.0, 0.0, float(d))) for d in range(0, 50)], axis=2)
    yy, xx = np.mgrid[0:h, 0:w]
    inner = (yy >= 16) & (yy < h - 16) & (xx >= 40) & (xx < w - 16)
    # the slanted window's cost of the true plane is below the best fronto-parallel window at (almost) every pixel
    assert (true[inner] < fronto.min(axis=2)[inner]).mean() > 0.95
    # and the fronto-parallel hypotheses cannot tell a slanted plane from its fronto-parallel tangent: both have
    # the same fronto-parallel cost, while the slanted cost prefers the true plane
    d_int = np.rint(A * xx + B * yy + C).astype(int)
    tangent = np.take_along_axis(fronto, d_int[..., None], 2)[..., 0]
    assert np.median(true[inner]) < 0.5 * np.median(tangent[inner])


def test_sweep_costs_equal_the_plane_costs_of_the_same_planes() -> None:
    """The sweep kernel (contiguous reads, shared border costs) gives segment_plane_costs' numbers for every
    plane of the sweep, including matches that leave the right image on either side."""
    from prismstereo.matching.coop.slanted import SlantedParams, segment_plane_costs, segment_sweep_costs

    left, right = _pair(40, 60)
    labels = np.zeros((40, 60), np.int32)
    labels[:, 20:] = 1
    labels[20:, 40:] = 2
    labels[:8, 52:] = 3
    active = np.array([True, True, False, True])
    avals = np.array([[0.0, np.nan], [0.0, 0.2], [0.0, 0.1], [0.0, -0.3]])
    centres = np.array([[9.5, 19.5], [30.0, 15.0], [50.0, 30.0], [56.0, 3.5]])
    slopes = (-0.5, 0.0, 0.5)
    lo, hi = -3, 12
    for census in (0.5, 0.0):
        win = SlantedParams(step=2, census=census)
        got = segment_sweep_costs(left, right, labels, active, avals, centres, slopes, min_disp=lo, max_disp=hi,
                                  window=win)
        dcs = np.arange(lo, hi + 1, dtype=np.float64)
        nd = dcs.size
        assert got.shape == (4, 2 * len(slopes) * nd)
        planes, cand = [], np.full(got.shape, -1, np.int64)
        for s in np.flatnonzero(active):
            for ia in range(2):
                if np.isnan(avals[s, ia]):
                    continue
                for ib, b in enumerate(slopes):
                    a = avals[s, ia]
                    j = (ia * len(slopes) + ib) * nd
                    cand[s, j:j + nd] = len(planes) + np.arange(nd)
                    planes += [(a, b, dc - a * centres[s, 0] - b * centres[s, 1]) for dc in dcs]
        want = segment_plane_costs(left, right, labels, cand, np.asarray(planes), min_disp=lo, max_disp=hi,
                                   window=win)
        assert np.array_equal(np.isinf(got), np.isinf(want))
        fin = np.isfinite(want)
        assert fin.sum() == 5 * len(slopes) * nd
        np.testing.assert_allclose(got[fin], want[fin], rtol=1e-5, atol=1e-4)
