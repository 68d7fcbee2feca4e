"""The epipolar curves of a rectified tri-prism pair: the table's row offsets agree with exact projection."""

from __future__ import annotations

import numpy as np
import pytest

from prismstereo.apps.demo import scaled_rig
from prismstereo.cameras import calibrate_rig
from prismstereo.config import thesis_triprism
from prismstereo.optics import project_exact, trace_pixels
from prismstereo.rectify import rectify_pair
from prismstereo.rectify.epipolar import EpipolarTable, epipolar_table


@pytest.fixture(scope="module")
def triprism_pair():  # type: ignore[no-untyped-def]
    rig = scaled_rig(thesis_triprism(), 2)
    views = calibrate_rig(rig, method="fit")
    return rectify_pair(rig, views[1], views[0])


def _exact_matches(pair, n: int, seed: int):  # type: ignore[no-untyped-def]
    """Random left pixels of the pair's left view at random depths: (ys, xs, d, dy) of their exact matches
    (left ray traced through the left face, the point projected through the right face, into the rectified
    right view by the model's inverse: another path than the table's)."""
    rng = np.random.default_rng(seed)
    vl, vr = pair.valid_masks()
    ys, xs = np.nonzero(vl)
    pick = rng.choice(ys.size, n, replace=False)
    px = np.stack([xs[pick] + rng.random(n), ys[pick] + rng.random(n)], axis=1)
    z = rng.uniform(800.0, 2500.0, n)
    rays = trace_pixels(pair.rig, pair.rectified_to_real(px, "left"), face=int(pair.left_face), bounded=False)
    pr, ok = project_exact(pair.rig, rays.point_at_depth(z), face=int(pair.right_face))
    r = pair.real_to_rectified(pr, "right")
    h, w = vr.shape
    ri, ci = np.rint(r[:, 1]).astype(np.int64), np.rint(r[:, 0]).astype(np.int64)
    ok &= (ri >= 0) & (ri < h) & (ci >= 0) & (ci < w)
    ok[ok] &= vr[ri[ok], ci[ok]]
    return px[ok, 1], px[ok, 0], px[ok, 0] - r[ok, 0], r[ok, 1] - px[ok, 1]


def test_row_offsets_agree_with_exact_projection(triprism_pair) -> None:  # type: ignore[no-untyped-def]
    pair = triprism_pair
    table = epipolar_table(pair)
    ys, xs, d, dy = _exact_matches(pair, 3000, seed=4)
    assert ys.size > 300
    # the tri-prism's pinholes leave matches off the row by a tenth of a pixel and more
    assert np.percentile(np.abs(dy), 95) > 0.1
    err = table.row_offset(ys, xs, d) - dy
    assert np.percentile(np.abs(err), 95) < 0.01
    assert np.abs(err).max() < 0.03


def test_row_offset_map_and_arrays_round_trip(triprism_pair) -> None:  # type: ignore[no-untyped-def]
    table = epipolar_table(triprism_pair, step=32, n_layers=8)
    disp = np.full((20, 30), np.nan, dtype=np.float32)
    disp[5:15, 10:20] = 60.0
    rows = table.row_offset_map(disp)
    assert np.array_equal(np.isfinite(rows), np.isfinite(disp))
    ys, xs = np.nonzero(np.isfinite(disp))
    np.testing.assert_allclose(rows[ys, xs], table.row_offset(ys, xs, np.full(ys.size, 60.0)), atol=1e-6)
    back = EpipolarTable.from_arrays(table.to_arrays())
    assert np.array_equal(back.offsets, table.offsets)
    assert (back.step, back.d_start, back.d_step) == (table.step, table.d_start, table.d_step)


def test_resampling_is_np_interp_per_column() -> None:
    from prismstereo.rectify.epipolar import _resample

    rng = np.random.default_rng(0)
    d = np.sort(rng.uniform(0.0, 300.0, (32, 200)), axis=0)[::-1]
    dy = rng.normal(size=d.shape)
    ok = rng.random(d.shape) > 0.3
    ok[:, :3] = False  # columns without a sample
    layers = np.linspace(-5.0, 310.0, 48)
    got = _resample(d, dy, ok, layers)
    assert np.all(np.isnan(got[:, :3]))
    for j in range(3, d.shape[1]):
        m = ok[:, j]
        order = np.argsort(d[m, j])
        np.testing.assert_allclose(got[:, j], np.interp(layers, d[m, j][order], dy[m, j][order]), atol=1e-12)


def test_lookup_is_scipy_trilinear_with_nearest_edges() -> None:
    """The numba lookup is scipy's ``map_coordinates(order=1, mode="nearest")`` on the table (in and beyond it)."""
    from scipy.ndimage import map_coordinates

    rng = np.random.default_rng(3)
    table = EpipolarTable(offsets=rng.normal(size=(12, 9, 14)).astype(np.float32), step=16, d_start=-3.0,
                          d_step=7.5)
    n = 5000
    ys, xs, d = rng.uniform(-20, 160, n), rng.uniform(-20, 240, n), rng.uniform(-30, 110, n)
    d[::7] = np.nan
    k = (np.nan_to_num(d, nan=table.d_start) - table.d_start) / table.d_step
    ref = map_coordinates(table.offsets.astype(np.float64), [k, ys / table.step, xs / table.step], order=1,
                          mode="nearest")
    got = table.row_offset(ys, xs, d)
    assert np.array_equal(np.isnan(got), np.isnan(d))
    np.testing.assert_allclose(got[np.isfinite(d)], ref[np.isfinite(d)], rtol=0, atol=1e-12)
