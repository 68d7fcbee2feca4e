"""Slope-sheared data-term volumes (coopcost.sheared_costs) and their use by the cooperative energy."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from prismstereo.errors import MatchingError
from prismstereo.matching.coop.coopcost import (
    CostParams,
    colour_term,
    keep_outside,
    raw_cost,
    raw_cost_from,
    shear_row_boxes,
    sheared_costs,
    sheared_inputs,
    sheared_row_boxes,
    sheared_row_costs_at,
)
from prismstereo.matching.coop.cooperative import build_segment_graph, total_energy
from prismstereo.matching.coop.pipeline import box_filter_volume
from prismstereo.matching.segments.planes import build_segment_index


def _steep_floor(slope: float = 1.0, seed: int = 5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Random-texture pair of a surface ``d = 4 + slope * y`` (integer disparities, exact warp)."""
    rng = np.random.default_rng(seed)
    h, w = 24, 80
    left = rng.integers(0, 256, size=(h, w, 3)).astype(np.uint8)
    right = rng.integers(0, 256, size=(h, w, 3)).astype(np.uint8)
    truth = np.rint(4 + slope * np.arange(h)).astype(int)
    for y in range(h):
        d = truth[y]
        right[y, : w - d] = left[y, d:]
    return left, right, truth


def test_slope_zero_is_the_boxed_raw_cost() -> None:
    left, right, _ = _steep_floor()
    vol = sheared_costs(left, right, max_disp=30, slopes=(0.0,), radius=1)
    ref = box_filter_volume(raw_cost(left, right, max_disp=30), 1)
    assert vol.shape == (1, *ref.shape)
    np.testing.assert_allclose(vol[0], ref, atol=1e-6)


def test_raw_cost_from_the_shared_colour_term_is_raw_cost_bit_for_bit() -> None:
    left, right, _ = _steep_floor()
    si = sheared_inputs(left, right, slopes=(-1.0, 0.0, 0.5))
    ad = colour_term(si, max_disp=30, min_disp=2)
    np.testing.assert_array_equal(raw_cost_from(si, ad, min_disp=2), raw_cost(left, right, max_disp=30, min_disp=2))
    np.testing.assert_array_equal(sheared_costs(left, right, max_disp=30, min_disp=2, slopes=si.slopes, inputs=si,
                                                ad=ad),
                                  sheared_costs(left, right, max_disp=30, min_disp=2, slopes=si.slopes))
    with pytest.raises(MatchingError):
        raw_cost_from(sheared_inputs(left, right, slopes=(0.5,)), ad, min_disp=2)


@pytest.mark.parametrize("slope", [-1.0, -0.5, 0.3, 1.0, 2.5])
def test_sheared_box_is_the_interpolated_row_mean_bit_for_bit(slope: float) -> None:
    # the kernel reads runs of disparities as contiguous slices; the sum must stay the per-tap formula's
    left, right, _ = _steep_floor()
    hb = sheared_costs(left, right, max_disp=30, slopes=(slope,), radius=1, vertical=False)[0]  # its census
    out = sheared_costs(left, right, max_disp=30, slopes=(slope,), radius=1)[0]
    h, _w, nd = hb.shape
    ref = np.zeros(hb.shape, np.float64)
    for dy in (-1, 0, 1):
        rows = hb[np.clip(np.arange(h) + dy, 0, h - 1)].astype(np.float64)
        kk = np.clip(np.arange(nd) + slope * dy, 0.0, nd - 1.0)
        k0 = kk.astype(int)
        f = kk - k0
        ref += (1.0 - f) * rows[:, :, k0] + f * rows[:, :, np.minimum(k0 + 1, nd - 1)]
    np.testing.assert_array_equal(out, (ref / 3).astype(np.float32))


def test_row_box_is_opencvs_box_of_the_raw_cost_bit_for_bit() -> None:
    left, right, _ = _steep_floor()
    for r in (0, 1, 2):
        vol = sheared_costs(left, right, max_disp=30, min_disp=2, slopes=(0.0,), radius=r, vertical=False)
        raw = raw_cost(left, right, max_disp=30, min_disp=2)
        ref = raw if r == 0 else cv2.boxFilter(raw, -1, (2 * r + 1, 1), borderType=cv2.BORDER_REFLECT)
        np.testing.assert_array_equal(vol[0], ref)


def test_row_costs_at_selected_pixels_only() -> None:
    left, right, _ = _steep_floor()
    slopes = (-1.0, 0.0, 0.5)
    full = sheared_costs(left, right, max_disp=30, slopes=slopes, radius=1, vertical=False)
    sel = np.random.default_rng(2).random(left.shape[:2]) < 0.3
    sel[:, 0] = sel[:, -1] = True  # the reflected borders
    out = np.full_like(full, -1.0)
    sheared_row_costs_at(left, right, sel, out, max_disp=30, slopes=slopes, radius=1)
    np.testing.assert_array_equal(out[:, sel], full[:, sel])
    assert (out[:, ~sel] == -1.0).all()


def test_row_costs_from_the_data_terms_inputs_fill_the_other_pixels() -> None:
    left, right, _ = _steep_floor()
    slopes = (-1.0, 0.0, 0.5)
    si = sheared_inputs(left, right, slopes=slopes)
    np.testing.assert_array_equal(sheared_costs(left, right, max_disp=30, slopes=slopes, radius=1, inputs=si),
                                  sheared_costs(left, right, max_disp=30, slopes=slopes, radius=1))
    full = sheared_costs(left, right, max_disp=30, slopes=slopes, radius=1, vertical=False)
    sel = np.random.default_rng(3).random(left.shape[:2]) < 0.4
    other = np.random.default_rng(4).random(full.shape).astype(np.float32)
    out = np.full_like(full, -1.0)
    sheared_row_costs_at(left, right, sel, out, max_disp=30, slopes=slopes, radius=1, inputs=si, fill=other)
    np.testing.assert_array_equal(out[:, sel], full[:, sel])
    np.testing.assert_array_equal(out[:, ~sel], other[:, ~sel])
    with pytest.raises(MatchingError, match="same params and slopes"):
        sheared_row_costs_at(left, right, sel, out, max_disp=30, slopes=(0.0, 0.5, 1.0), radius=1, inputs=si)
    with pytest.raises(MatchingError, match="same params and slopes"):
        sheared_costs(left, right, max_disp=30, slopes=slopes, params=CostParams(census_rx=3), inputs=si)


def test_row_boxes_are_the_row_only_volume_and_shear_into_the_sheared_volume_bit_for_bit() -> None:
    """The front end keeps the sheared volumes' first pass for the sweep's row-only volume: the same bits as
    ``sheared_costs(vertical=False)`` and, sheared, as ``sheared_costs``; the row-only volume at the selected
    pixels with the data term elsewhere is then ``sheared_row_costs_at(..., fill=)``."""
    left, right, _ = _steep_floor()
    slopes = (-1.0, -0.5, 0.0, 0.5, 1.0)
    si = sheared_inputs(left, right, slopes=slopes)
    ad = colour_term(si, max_disp=30, min_disp=2)
    for r in (1, 2):
        boxes = sheared_row_boxes(si, ad, min_disp=2, radius=r)
        np.testing.assert_array_equal(boxes, sheared_costs(left, right, max_disp=30, min_disp=2, slopes=slopes,
                                                           radius=r, vertical=False))
        data = sheared_costs(left, right, max_disp=30, min_disp=2, slopes=slopes, radius=r)
        np.testing.assert_array_equal(shear_row_boxes(boxes, slopes, radius=r), data)
        sel = np.random.default_rng(r).random(left.shape[:2]) < 0.4
        ref = np.empty_like(data)
        sheared_row_costs_at(left, right, sel, ref, max_disp=30, min_disp=2, slopes=slopes, radius=r, inputs=si,
                             fill=data)
        keep_outside(boxes, data, sel)
        np.testing.assert_array_equal(boxes, ref)
    with pytest.raises(MatchingError, match="one shape"):
        keep_outside(boxes, data[:2], sel)


def test_sheared_volume_prefers_the_true_steep_plane() -> None:
    left, right, truth = _steep_floor(1.0)
    vol = sheared_costs(left, right, max_disp=30, slopes=(0.0, 1.0), radius=1)
    h, w = left.shape[:2]
    ys, xs = np.mgrid[4:h - 4, 40:w - 2]  # away from the borders, every window inside the image
    at_truth = vol[:, ys, xs, truth[ys]]
    # the square window compares different surface points on a 1 px/row slant; the sheared one does not
    assert at_truth[1].mean() < 0.5 * at_truth[0].mean()
    wta = vol[1][ys, xs].argmin(axis=-1)
    assert np.mean(wta == truth[ys]) > 0.95
    assert np.mean(vol[0][ys, xs].argmin(axis=-1) == truth[ys]) < np.mean(wta == truth[ys])


def test_energy_reads_the_volume_of_the_nearest_slope() -> None:
    h, w, nd = 10, 12, 8
    labels = np.zeros((h, w), np.int32)
    index = build_segment_index(labels)
    graph = build_segment_graph(labels, np.zeros((h, w, 3), np.uint8))
    cost = np.stack([np.ones((h, w, nd), np.float32), np.zeros((h, w, nd), np.float32)])
    rel = np.ones((h, w), bool)
    flat = np.array([[0.0, 0.0, 3.0]])
    steep = np.array([[0.0, 0.4, 3.0]])  # nearest slope 0.5 -> the zero volume
    e_flat = total_energy(np.zeros(1, np.int32), flat, index, graph, cost, rel, slopes=(0.0, 0.5))
    e_steep = total_energy(np.zeros(1, np.int32), steep, index, graph, cost, rel, slopes=(0.0, 0.5))
    yy, xx = np.mgrid[0:h, 0:w]
    border = int((xx - (0.4 * yy + 3.0) < -0.5).sum())  # left of the right image: ω_border = 1 each
    assert 0 < border < h * w
    assert e_flat == pytest.approx(h * w)
    assert e_steep == pytest.approx(border)
    with pytest.raises(ValueError, match="one cost volume per slope"):
        total_energy(np.zeros(1, np.int32), flat, index, graph, cost, rel)


def _guided_filter_reference(guide: np.ndarray, vol: np.ndarray, r: int, eps: float) -> np.ndarray:
    """He et al.'s colour guided filter written with cv2.boxFilter and float32 numpy, slice by slice."""
    img = guide.astype(np.float32) / 255.0

    def box(a: np.ndarray) -> np.ndarray:
        return cv2.boxFilter(a, -1, (2 * r + 1, 2 * r + 1), borderType=cv2.BORDER_REFLECT)

    mean_i = box(img)
    sig = np.empty(img.shape[:2] + (3, 3))
    for i in range(3):
        for j in range(3):
            sig[:, :, i, j] = box(img[:, :, i] * img[:, :, j]) - mean_i[:, :, i] * mean_i[:, :, j]
    inv = np.linalg.inv(sig + eps * np.eye(3)).astype(np.float32)
    out = np.empty_like(vol)
    for k in range(vol.shape[2]):
        p = np.ascontiguousarray(vol[:, :, k])
        mp = box(p)
        cov = [box(p * img[:, :, c]) - mean_i[:, :, c] * mp for c in range(3)]
        a = [inv[:, :, i, 0] * cov[0] + inv[:, :, i, 1] * cov[1] + inv[:, :, i, 2] * cov[2] for i in range(3)]
        b = mp - a[0] * mean_i[:, :, 0] - a[1] * mean_i[:, :, 1] - a[2] * mean_i[:, :, 2]
        out[:, :, k] = box(b) + box(a[0]) * img[:, :, 0] + box(a[1]) * img[:, :, 1] + box(a[2]) * img[:, :, 2]
    return out


@pytest.mark.parametrize(("shape", "r"), [((23, 37, 11), 4), ((6, 5, 3), 9), ((19, 21, 9), 2), ((17, 16, 3), 1),
                                          ((12, 14, 5), 0), ((1, 9, 2), 3)])
def test_guided_filter_is_the_boxfilter_formulation_bit_for_bit(shape: tuple[int, int, int], r: int) -> None:
    from prismstereo.matching.coop.coopcost import guided_filter_volume

    rng = np.random.default_rng(sum(shape) + r)
    h, w, nd = shape
    guide = rng.integers(0, 256, size=(h, w, 3)).astype(np.uint8)
    vol = (2 * rng.random((h, w, nd)) ** 3).astype(np.float32)
    got = guided_filter_volume(guide, vol, radius=r, eps=1e-4)
    assert np.array_equal(got, _guided_filter_reference(guide, vol, r, 1e-4))
    # the right view's volume read in place: C_R(y, x, k) = C_L(y, x + min_disp + k, k), 2 outside the image
    for min_disp in (0, 2, -1):
        xl = np.arange(w)[:, None] + min_disp + np.arange(nd)[None, :]
        inside = (xl >= 0) & (xl < w)
        right = np.where(inside[None], vol[:, np.clip(xl, 0, w - 1), np.arange(nd)[None, :]], np.float32(2.0))
        got = guided_filter_volume(guide, vol, radius=r, eps=1e-4, right_of=min_disp)
        assert np.array_equal(got, _guided_filter_reference(guide, right, r, 1e-4))
