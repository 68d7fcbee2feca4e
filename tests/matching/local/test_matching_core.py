"""Matching core: costs, aggregation, selection and every registered local method on synthetic truth."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from prismstereo.errors import ConfigError, ImageError, MatchingError
from prismstereo.matching import available_matchers, get_matcher, match
from prismstereo.matching.local import costs, selection
from prismstereo.matching.local.aggregation import (
    aggregate_box,
    aggregate_bpasw,
    to_lab,
    weber_fechner_weight,
    window_offsets,
)

METHODS = ("sad", "ssd", "ncc", "shd", "bpasw", "sgbm")
FAST = {"bpasw": {"radius": 6, "dilation": 2}}


def _texture(h: int, w: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    base = rng.uniform(0, 255, size=(h // 2 + 1, w // 2 + 1, 3)).astype(np.float32)
    import cv2

    img = cv2.resize(base, (w, h), interpolation=cv2.INTER_LINEAR)
    return np.clip(img, 0, 255).astype(np.uint8)


def _shifted_pair(d: int, h: int = 40, w: int = 64, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Right view of a fronto-parallel texture at disparity d: right(x) = left(x + d)."""
    big = _texture(h, w + d, seed)
    left = big[:, :w]
    right = big[:, d:d + w]
    return np.ascontiguousarray(left), np.ascontiguousarray(right)


def _two_plane_pair(h: int = 48, w: int = 80) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Background at d=3, a foreground box (rows 12..35, cols 30..59) at d=9; right rendered from left.

    The two surfaces are textured in different hues (bluish background, reddish box), the premise of
    colour-adaptive support weights.
    """
    bg = (_texture(h, w + 20, seed=1) * np.array([0.3, 0.5, 1.0])).astype(np.uint8)
    fg = (_texture(h, w + 20, seed=2) * np.array([1.0, 0.5, 0.3])).astype(np.uint8)
    gt = np.full((h, w), 3.0, dtype=np.float32)
    gt[12:36, 30:60] = 9.0
    right = np.empty((h, w, 3), dtype=np.uint8)
    left = np.empty((h, w, 3), dtype=np.uint8)
    for x in range(w):  # test fixture, small
        left[:, x] = bg[:, x + 10]
        right[:, x] = bg[:, x + 10 + 3]
    left[12:36, 30:60] = fg[12:36, 30:60]
    right[12:36, 21:51] = fg[12:36, 30:60]
    return left, right, gt


# ------------------------------------------------------------------------------------------- costs
@pytest.mark.parametrize("fn", [costs.cost_ad, costs.cost_gradient, costs.cost_s_ad, costs.cost_census,
                                costs.cost_sad_window, costs.cost_ssd, costs.cost_ncc])
def test_cost_volume_shape_dtype_and_minimum(fn) -> None:
    left, right = _shifted_pair(5)
    vol = fn(left, right, max_disp=12, min_disp=2)
    assert vol.shape == (40, 64, 11) and vol.dtype == np.float32
    assert np.isfinite(vol).all()
    # interior pixels: the true disparity (index 5 - 2) is the minimum
    idx = np.argmin(vol[10:30, 20:50], axis=2)
    assert (idx == 3).mean() > 0.9


def test_out_of_range_cost_is_worst() -> None:
    left, right = _shifted_pair(2)
    vol = costs.cost_ad(left, right, max_disp=8)
    assert np.all(vol[:, 0, 1:] == 255.0)
    cen = costs.cost_census(left, right, max_disp=8, window=(5, 5))
    assert np.all(cen[:, 3, 4:] == 24.0)


@pytest.mark.parametrize(("kw", "gray"), [({"tau_color": 20.0, "tau_gradient": 8.0, "census_weight": 0.5}, False),
                                          ({"omega": 0.2, "census_weight": 1.0}, True),
                                          ({"omega": 1.0, "tau_gradient": 4.0}, False)])
def test_fused_s_ad_census_equals_the_composed_costs(kw: dict, gray: bool) -> None:
    left, right = _shifted_pair(4)
    if gray:
        left, right = left[:, :, 1], right[:, :, 1]
    ref = costs.cost_s_ad(left, right, max_disp=9, min_disp=1, omega=kw.get("omega", 0.5),
                          tau_color=kw.get("tau_color"), tau_gradient=kw.get("tau_gradient"))
    if kw.get("census_weight", 0.0) > 0:
        ref += np.float32(kw["census_weight"]) * costs.cost_census(left, right, max_disp=9, min_disp=1)
    got = costs.cost_s_ad_census(left, right, max_disp=9, min_disp=1, **kw)
    assert got.dtype == np.float32 and np.array_equal(got, ref)


def test_census_window_checked() -> None:
    with pytest.raises(MatchingError, match="expected an odd census window"):
        costs.census_transform(np.zeros((5, 5)), window=(9, 9))


# ------------------------------------------------------------------------------------- aggregation
def test_weber_fechner_weight_is_clipped_and_monotone() -> None:
    s = np.linspace(0.0, 100.0, 1001)
    w = weber_fechner_weight(s, s0=50.0, s_min=1.0)
    assert np.all(np.diff(w) <= 1e-12)
    assert w[0] == 1.0 and w[s <= 1.0].min() == 1.0
    assert np.all(w[s >= 50.0] == 0.0) and np.all(w >= 0.0)
    with pytest.raises(MatchingError):
        weber_fechner_weight(1.0, s0=1.0, s_min=2.0)


def test_bpasw_respects_colour_edges() -> None:
    """Near the box's edges BPASW keeps each side's disparity (0 errors); a box window smears them."""
    left, right, gt = _two_plane_pair()
    vol = costs.cost_s_ad(left, right, max_disp=15, tau_color=20.0, tau_gradient=8.0)
    d_box = selection.winner_take_all(aggregate_box(vol, radius=6))
    d_asw = selection.winner_take_all(aggregate_bpasw(vol, left, right, radius=6, dilation=1))
    near_edges = np.zeros_like(gt, dtype=bool)
    near_edges[8:40, 26:64] = True
    near_edges[16:32, 34:56] = False
    near_edges[12:36, 24:30] = False  # background occluded by the box in the right view
    err_box = (np.abs(d_box - gt) > 1)[near_edges].mean()
    err_asw = (np.abs(d_asw - gt) > 1)[near_edges].mean()
    assert err_box > 0.03
    assert err_asw < 0.01


def _bpasw_reference(cost: np.ndarray, left: np.ndarray, right: np.ndarray | None, radius: int,
                     dilation: int) -> np.ndarray:
    """Eq. 5.14 term by term in float64: every weight evaluated for its own pixel pair."""
    h, w, nd = cost.shape
    lab_l = to_lab(left).astype(np.float64)
    lab_r = to_lab(right).astype(np.float64) if right is not None else None
    dys, dxs, dist = window_offsets(radius, dilation)
    prox = weber_fechner_weight(dist, s0=np.sqrt(2.0) * radius + 1.0)

    def wgt(lab: np.ndarray, p: tuple[int, int], q: tuple[int, int]) -> float:
        return float(weber_fechner_weight(np.sqrt(((lab[p] - lab[q]) ** 2).sum()), s0=28.0))

    out = cost.astype(np.float64).copy()
    for y in range(h):
        for x in range(w):
            for i in range(min(nd, x + 1)):
                num = den = 0.0
                for dy, dx, pk in zip(dys, dxs, prox, strict=True):
                    qy, qx = y + dy, x + dx
                    if not (0 <= qy < h and 0 <= qx < w):
                        continue
                    ww = wgt(lab_l, (y, x), (qy, qx)) * pk
                    if lab_r is not None:
                        ww *= (wgt(lab_r, (y, x - i), (qy, qx - i)) * pk) if qx - i >= 0 else 0.0
                    num += ww * cost[qy, qx, i]
                    den += ww
                if den > 0:
                    out[y, x, i] = num / den
    return out


@pytest.mark.parametrize("symmetric", [True, False])
def test_bpasw_equals_the_weights_evaluated_pair_by_pair(symmetric: bool) -> None:
    # the kernel evaluates each weight once for both pixels of a pair and runs rows in bands: 40 rows give
    # several bands, whose first rows read weights their band computed first
    rng = np.random.default_rng(4)
    left = (rng.integers(0, 6, size=(40, 14, 3)) * 40).astype(np.uint8)
    right = np.roll(left, -2, axis=1)
    cost = rng.random((40, 14, 4)).astype(np.float32)
    got = aggregate_bpasw(cost, left, right if symmetric else None, radius=2, dilation=1)
    ref = _bpasw_reference(cost, left, right if symmetric else None, 2, 1)
    np.testing.assert_allclose(got, ref, rtol=2e-5, atol=1e-6)


# --------------------------------------------------------------------------------------- selection
def test_wta_cross_check_subpixel_fill() -> None:
    vol = np.ones((2, 6, 4), dtype=np.float32)
    vol[:, :, 2] = 0.0
    disp = selection.winner_take_all(vol, min_disp=1)
    assert disp.dtype == np.float32 and np.all(disp == 3.0)
    dr = selection.right_disparity(vol, min_disp=1)
    assert dr.shape == (2, 6)
    ok = selection.cross_check(disp, np.full((2, 6), 3.0, np.float32))
    assert ok[:, 3:].all() and not ok[:, :3].any()  # x - 3 < 0 cannot be checked
    bad = selection.cross_check(disp, np.full((2, 6), 1.0, np.float32), tolerance=1.0)
    assert not bad.any()
    # parabola through 1, 0, 1 -> no offset; through 1, 0, 0.5 -> shift towards d+1
    vol2 = np.array([[[1.0, 0.0, 0.5]]], dtype=np.float32)
    sp = selection.subpixel_refine(vol2, np.array([[1.0]], np.float32))
    assert 1.0 < sp[0, 0] < 1.5
    raw = np.array([[np.nan, 5.0, np.nan, np.nan, 2.0, np.nan]], np.float32)
    filled = selection.fill_holes(raw, np.isfinite(raw))
    np.testing.assert_array_equal(filled, [[5.0, 5.0, 2.0, 2.0, 2.0, 2.0]])


def test_right_disparity_matches_flipped_matching() -> None:
    left, right = _shifted_pair(4)
    vol = costs.cost_sad_window(left, right, max_disp=10, radius=3)
    dr = selection.right_disparity(vol)
    assert (dr[5:35, 5:50] == 4).mean() > 0.95


def test_right_winner_is_the_argmin_of_the_right_volume() -> None:
    rng = np.random.default_rng(3)
    vol = rng.integers(0, 6, size=(7, 19, 9)).astype(np.float32)  # small integers: many equal minima
    for md in (0, 2):
        ref = selection.right_cost_volume(vol, min_disp=md).argmin(axis=2)
        np.testing.assert_array_equal(selection.right_winner(vol, min_disp=md), ref)
    vol[2, 5:, :] = np.nan  # NaN never selected; a pixel whose every entry is NaN has none
    dr = selection.right_disparity(vol, min_disp=1)
    ref = selection.winner_take_all(selection.right_cost_volume(vol, min_disp=1), min_disp=1)
    np.testing.assert_array_equal(dr, ref)  # NaN in the same places
    assert np.isnan(dr[2, 4:10]).all() and np.isnan(dr).sum() == 6  # x + 1 + k in 5..18: NaN for every k


# ---------------------------------------------------------------------------------- whole methods
def test_registry_lists_methods() -> None:
    names = available_matchers()
    for m in METHODS:
        assert m in names
    with pytest.raises(ConfigError, match="expected a method among"):
        get_matcher("nope")
    with pytest.raises(ConfigError, match="expected parameters"):
        get_matcher("sad", window_size=3)
    with pytest.raises(ConfigError, match="to be int"):
        get_matcher("sad", radius="abc")
    with pytest.raises(ConfigError, match=r"^BPASWMatcher.radius: expected an integer in \[0, 100\], got -1$"):
        get_matcher("bpasw", radius=-1)
    assert get_matcher("bpasw", similarity_s0=30).similarity_s0 == 30  # type: ignore[attr-defined]


@pytest.mark.parametrize("method", METHODS)
def test_recovers_constant_shift(method: str) -> None:
    left, right = _shifted_pair(6, h=48, w=80)
    res = match(left, right, max_disp=15, method=method, **FAST.get(method, {}))
    d = res.disparity
    assert d.dtype == np.float32 and d.shape == (48, 80)
    assert res.valid.dtype == bool and res.valid.shape == d.shape
    inner = d[8:40, 20:70]
    assert (np.abs(inner - 6.0) <= 1.0).mean() > 0.95


@pytest.mark.parametrize("method", ("sad", "ncc", "shd", "bpasw", "sgbm"))
def test_two_plane_scene(method: str) -> None:
    left, right, gt = _two_plane_pair()
    res = match(left, right, max_disp=15, method=method, **FAST.get(method, {}))
    inner = np.zeros_like(gt, dtype=bool)
    inner[6:42, 15:75] = True
    assert (np.abs(res.disparity - gt) <= 1.0)[inner].mean() > 0.85


@pytest.mark.parametrize("method", METHODS)
def test_identical_images_give_zero(method: str) -> None:
    img = _texture(32, 48, seed=3)
    res = match(img, img, max_disp=8, method=method, **FAST.get(method, {}))
    assert np.all(np.isfinite(res.disparity))
    assert np.nanmax(np.abs(res.disparity)) <= 0.5


@pytest.mark.parametrize("method", METHODS)
def test_one_pixel_wide_image(method: str) -> None:
    img = _texture(20, 4, seed=4)[:, :1]
    res = match(img, img, max_disp=0, method=method, **FAST.get(method, {}))
    assert res.disparity.shape == (20, 1)
    assert np.all(res.disparity == 0.0)
    with pytest.raises(MatchingError, match="expected max_disp < image width"):
        match(img, img, max_disp=1, method=method)


@pytest.mark.parametrize("method", METHODS)
def test_error_paths(method: str) -> None:
    a = _texture(20, 30)
    with pytest.raises(ImageError, match="same size"):
        match(a, a[:, :20], max_disp=4, method=method)
    with pytest.raises(MatchingError, match="expected max_disp < image width"):
        match(a, a, max_disp=30, method=method)
    with pytest.raises(MatchingError, match="min_disp >= 0"):
        match(a, a, max_disp=4, min_disp=-1, method=method)
    with pytest.raises(MatchingError, match="max_disp >= min_disp"):
        match(a, a, max_disp=2, min_disp=3, method=method)
    with pytest.raises(MatchingError, match="integer"):
        match(a, a, max_disp=2.5, method=method)  # type: ignore[arg-type]


def test_image_validation() -> None:
    a = _texture(10, 12).astype(np.float32)
    bad = a.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(ImageError, match="finite"):
        match(bad, a, max_disp=3, method="sad")
    with pytest.raises(ImageError, match="H×W or H×W×3"):
        match(np.zeros((4, 5, 2)), np.zeros((4, 5, 2)), max_disp=1, method="sad")
    with pytest.raises(ImageError, match="dtype"):
        match(np.zeros((4, 5), bool), np.zeros((4, 5), bool), max_disp=1, method="sad")


@pytest.mark.parametrize("method", METHODS)
def test_min_disp_offset_and_gray_input(method: str) -> None:
    left, right = _shifted_pair(9, h=40, w=72)
    gl = left.mean(axis=2).astype(np.float32)
    gr = right.mean(axis=2).astype(np.float32)
    res = match(gl, gr, max_disp=14, min_disp=5, method=method, **FAST.get(method, {}))
    assert (np.abs(res.disparity[8:32, 25:65] - 9.0) <= 1.0).mean() > 0.95
    assert np.nanmin(res.disparity) >= 5.0


def test_post_processing_switches() -> None:
    left, right, _ = _two_plane_pair()
    res = match(left, right, max_disp=15, method="sad", cross_check=False, fill=False, keep_cost=True)
    assert res.valid.all() and res.disparity_raw is None and res.extras["cost"].shape == (48, 80, 16)
    res2 = match(left, right, max_disp=15, method="sad")
    assert res2.disparity_raw is not None and np.isnan(res2.disparity_raw).any()
    assert np.isfinite(res2.disparity).all()
    assert np.all(np.isnan(res2.disparity_raw[~res2.valid]))


def test_float_unit_range_is_rescaled() -> None:
    left, right = _shifted_pair(6, h=48, w=80)
    a = match(left, right, max_disp=15, method="bpasw", **FAST["bpasw"]).disparity
    b = match(left / 255.0, right / 255.0, max_disp=15, method="bpasw", **FAST["bpasw"]).disparity
    assert (np.abs(a - b) <= 1.0).mean() > 0.99


@settings(max_examples=12, deadline=None)
@given(d=st.integers(min_value=0, max_value=10), seed=st.integers(min_value=0, max_value=10_000),
       method=st.sampled_from(["sad", "ncc", "shd", "sgbm"]))
def test_any_shift_is_recovered(d: int, seed: int, method: str) -> None:
    left, right = _shifted_pair(d, h=32, w=56, seed=seed)
    res = match(left, right, max_disp=12, method=method)
    inner = res.disparity[6:26, 14:50]
    assert (np.abs(inner - d) <= 1.0).mean() > 0.9
