"""The colour-weighted median (:func:`selection.weighted_median_filter`): a plain-Python reference, the row and the
pixel paths of its kernel, the mask and non-finite neighbours."""

from __future__ import annotations

import numpy as np
import pytest

from prismstereo.matching.local import selection
from prismstereo.matching.local._wmf import _LUT_MAX, _LUT_STEP
from prismstereo.matching.local.aggregation import to_lab


def _reference(disp: np.ndarray, image: np.ndarray, mask: np.ndarray, radius: int, gamma_c: float,
               gamma_d: float) -> np.ndarray:
    """The weighted median pixel by pixel in Python, float32 weights and sums added in the window's row-major
    order (the kernel's definition)."""
    lab = to_lab(image)
    h, w = disp.shape
    fin = disp[np.isfinite(disp)]
    dmin = float(np.floor(fin.min()))
    nbins = int(np.ceil(fin.max())) - int(dmin) + 2
    nlut = int(_LUT_MAX * _LUT_STEP) + 1
    lut = np.exp(-(np.arange(nlut) / _LUT_STEP) / gamma_c).astype(np.float32)
    out = disp.copy()
    for y in range(h):
        for x in range(w):
            if not mask[y, x]:
                continue
            hist = np.zeros(nbins, np.float32)
            total = np.float32(0.0)
            for yy in range(max(0, y - radius), min(h, y + radius + 1)):
                for xx in range(max(0, x - radius), min(w, x + radius + 1)):
                    v = disp[yy, xx]
                    if not np.isfinite(v):
                        continue
                    diff = lab[y, x] - lab[yy, xx]
                    k = int(np.sqrt(np.float32(np.dot(diff, diff))) * _LUT_STEP + 0.5)
                    if k >= nlut:
                        continue
                    sp = np.float32(np.exp(-np.sqrt(float((yy - y) ** 2 + (xx - x) ** 2)) / gamma_d))
                    wt = np.float32(lut[k] * sp)
                    bi = min(max(int(np.floor(v - dmin + 0.5)), 0), nbins - 1)
                    hist[bi] = np.float32(hist[bi] + wt)
                    total = np.float32(total + wt)
            if total <= 0:
                continue
            acc = np.float32(0.0)
            for bi in range(nbins):
                acc = np.float32(acc + hist[bi])
                if acc >= np.float32(0.5) * total:
                    out[y, x] = dmin + bi
                    break
    return out


def _scene(h: int = 26, w: int = 40, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """A two-region image (the left half darker) and a noisy step map with outliers."""
    rng = np.random.default_rng(seed)
    img = np.full((h, w, 3), 60.0, np.float32)
    img[:, w // 2:] = (200.0, 150.0, 90.0)
    img += rng.normal(0.0, 6.0, img.shape).astype(np.float32)
    disp = np.where(np.arange(w)[None, :] < w // 2, 12.0, 30.0) + rng.integers(-1, 2, (h, w))
    out = rng.random((h, w)) < 0.08
    disp[out] = rng.integers(0, 45, int(out.sum()))
    return disp.astype(np.float32), np.clip(img, 0, 255)


@pytest.mark.parametrize("density", [1.0, 0.3])
def test_weighted_median_matches_python_reference(density: float) -> None:
    # density 1: every row runs whole; 0.3: every row pixel by pixel
    disp, img = _scene()
    mask = np.random.default_rng(1).random(disp.shape) < density
    got = selection.weighted_median_filter(disp, img, mask=mask, radius=3)
    want = _reference(disp, img, mask, 3, 10.0, 9.0)
    np.testing.assert_array_equal(got, want)
    # the outliers inside a region are replaced by the region's value
    assert np.abs(got[mask] - np.where(np.arange(disp.shape[1])[None, :] < 20, 12.0, 30.0)
                  .repeat(disp.shape[0], 0)[mask]).max() <= 1.0


def test_row_and_pixel_paths_agree() -> None:
    disp, img = _scene(40, 64, seed=5)
    full = selection.weighted_median_filter(disp, img, radius=9)
    rng = np.random.default_rng(2)
    # dense rows (whole-row path) on the top half, sparse rows (pixel path) on the bottom half
    mask = np.zeros(disp.shape, bool)
    mask[:20] = rng.random((20, 64)) < 0.9
    mask[20:] = rng.random((20, 64)) < 0.2
    part = selection.weighted_median_filter(disp, img, mask=mask, radius=9)
    np.testing.assert_array_equal(part[mask], full[mask])
    np.testing.assert_array_equal(part[~mask], disp[~mask])  # only the mask is changed


def test_non_finite_neighbours_give_no_weight() -> None:
    disp, img = _scene()
    holes = np.zeros(disp.shape, bool)
    holes[5:9, 3:12] = True
    holes[15:18, 25:33] = True
    with_nan = np.where(holes, np.float32(np.nan), disp).astype(np.float32)
    for density in (1.0, 0.3):
        mask = (np.random.default_rng(4).random(disp.shape) < density) | holes
        got = selection.weighted_median_filter(with_nan, img, mask=mask, radius=3)
        np.testing.assert_array_equal(got, _reference(with_nan, img, mask, 3, 10.0, 9.0))
        assert np.isfinite(got[holes]).all()  # a hole with finite neighbours gets their median
    assert np.isnan(selection.weighted_median_filter(with_nan, img, mask=~holes, radius=3)[holes]).all()
