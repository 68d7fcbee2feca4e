"""The sub-pixel check's numba passes against the numpy formulas they replace (bit for bit)."""

from __future__ import annotations

import numpy as np
import pytest

from prismstereo.depth import _lrcheck  # the private module under test


def _np_seen_from_right(disparity: np.ndarray) -> np.ndarray:
    d = np.asarray(disparity, dtype=np.float32)
    h, w = d.shape
    ys, xs = np.nonzero(np.isfinite(d))
    xr = np.rint(xs - d[ys, xs]).astype(np.int64)
    inside = (xr >= 0) & (xr < w)
    out = np.full((h, w), -np.inf, dtype=np.float32)
    np.maximum.at(out, (ys[inside], xr[inside]), d[ys[inside], xs[inside]])
    out[np.isneginf(out)] = np.nan
    return out


def _np_read_by_check(disparity: np.ndarray, where: np.ndarray) -> np.ndarray:
    h, w = disparity.shape
    ys, xs = np.nonzero(where & np.isfinite(disparity))
    x0 = np.floor(xs - disparity[ys, xs]).astype(np.int64)
    out = np.zeros((h, w), dtype=bool)
    for k in (0, 1):
        inside = (x0 + k >= 0) & (x0 + k < w)
        out[ys[inside], x0[inside] + k] = True
    return out


def _np_lr_gap(disparity: np.ndarray, disparity_right: np.ndarray) -> np.ndarray:
    h, w = disparity.shape
    gap = np.full((h, w), np.nan, dtype=np.float32)
    ys, xs = np.nonzero(np.isfinite(disparity))
    d = disparity[ys, xs]
    xq = xs - d
    x0 = np.floor(xq).astype(np.int64)
    inside = (x0 >= 0) & (x0 + 1 < w)
    ys, xs, d, xq, x0 = ys[inside], xs[inside], d[inside], xq[inside], x0[inside]
    t = (xq - x0).astype(np.float32)
    a, b = disparity_right[ys, x0], disparity_right[ys, x0 + 1]
    with np.errstate(invalid="ignore"):
        dr = np.where(np.isfinite(a) & np.isfinite(b), (1 - t) * a + t * b, np.where(np.isfinite(a), a, b))
    gap[ys, xs] = np.abs(d - dr)
    return gap


def _maps(seed: int, h: int = 23, w: int = 61) -> tuple[np.ndarray, np.ndarray]:
    """A disparity map with NaN / ±inf holes, values beyond both row ends, exact halves and integers (the
    rounding's and floor's ties), negative values and ties of several pixels landing on one; its right map."""
    rng = np.random.default_rng(seed)
    d = (rng.random((h, w)) * 30.0 - 4.0).astype(np.float32)
    d[rng.random((h, w)) < 0.15] = np.nan
    d[0, :5] = np.inf
    d[1, :5] = -np.inf
    d[2, ::3] = np.float32(7.5)  # x − d exactly a half: rint to even
    d[3, :] = np.float32(5.0)  # integers: floor(x − d) exact, every pixel its own right pixel
    d[4, 10:20] = np.float32(12.0) + np.arange(10, dtype=np.float32)  # ten pixels on one right pixel: equal
    d[5, :] = np.float32(-0.0)
    d[6, :] = np.float32(1e-7)
    d[7, :] = np.float32(w + 3.0)
    dr = (d + rng.normal(0.0, 0.3, (h, w))).astype(np.float32)
    dr[rng.random((h, w)) < 0.2] = np.nan
    return d, dr


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    return a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b, equal_nan=True) and \
        np.array_equal(np.signbit(a), np.signbit(b))


@pytest.mark.parametrize("seed", range(6))
def test_seen_from_right_equals_the_numpy_scatter(seed):
    d, _ = _maps(seed)
    assert _same(_lrcheck.seen_from_right(d), _np_seen_from_right(d))


@pytest.mark.parametrize("seed", range(6))
def test_read_by_check_equals_the_numpy_scatter(seed):
    d, _ = _maps(seed)
    where = np.random.default_rng(seed + 100).random(d.shape) < 0.7
    assert _same(_lrcheck.read_by_check(d, where), _np_read_by_check(d, where))


@pytest.mark.parametrize("seed", range(6))
def test_lr_gap_equals_the_numpy_interpolation(seed):
    d, dr = _maps(seed)
    assert _same(_lrcheck.lr_gap(d, dr), _np_lr_gap(d, dr))


def test_the_passes_on_an_empty_and_an_all_nan_map():
    for shape in ((0, 5), (4, 0), (3, 7)):
        d = np.full(shape, np.nan, dtype=np.float32)
        assert _same(_lrcheck.seen_from_right(d), _np_seen_from_right(d))
        assert _same(_lrcheck.read_by_check(d, np.ones(shape, bool)), _np_read_by_check(d, np.ones(shape, bool)))
        assert _same(_lrcheck.lr_gap(d, d), _np_lr_gap(d, d))


@pytest.mark.parametrize("dtype", [np.uint8, np.float32, np.bool_])
def test_mirror_equals_numpy_reversed_columns(dtype):
    rng = np.random.default_rng(3)
    for shape in ((9, 13), (9, 13, 3), (1, 1), (0, 4)):
        a = (rng.random(shape) * 255).astype(dtype)
        m = _lrcheck.mirror(a)
        assert m.flags.c_contiguous and _same(m, np.ascontiguousarray(a[:, ::-1]))
    view = (rng.random((8, 20, 3)) * 255).astype(dtype)[:, 3:17]  # not contiguous
    assert _same(_lrcheck.mirror(view), np.ascontiguousarray(view[:, ::-1]))
