"""Multi-baseline matching (thesis §7.1): ratio parsing, exact synthetic recovery, more views help."""

from __future__ import annotations

import numpy as np
import pytest

from prismstereo.errors import ConfigError, ImageError, MatchingError
from prismstereo.multiview.api import match_multiview
from prismstereo.multiview.baseline import check_views, parse_ratio, parse_view_spec, resample_to_unit
from prismstereo.multiview.local import LocalMultiViewParams, match_multibaseline

H, W, D_TRUE = 40, 72, 3
FAST_BPASW = {"radius": 4, "dilation": 2}


def _texture(h: int, w: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.integers(0, 256, size=(h, w, 3)).astype(np.float32)


def _views(ratios: list[float], d: float, *, noise: float = 0.0, seed: int = 1) -> tuple[np.ndarray, list]:
    """Reference = crop of a wide texture; view at ratio δ shows reference pixel x at x - δ d."""
    pad = 20
    big = _texture(H, W + 2 * pad)
    ref = big[:, pad:pad + W]
    rng = np.random.default_rng(seed)
    views = []
    for r in ratios:
        s = int(round(r * d))
        v = big[:, pad + s:pad + s + W].copy()  # v[x] = ref[x + δ d]  <=>  ref[x] = v[x - δ d]
        if noise:
            v = np.clip(v + rng.normal(0, noise, v.shape), 0, 255).astype(np.float32)
        views.append(v)
    if noise:
        ref = np.clip(ref + rng.normal(0, noise, ref.shape), 0, 255).astype(np.float32)
    return ref, views


@pytest.mark.parametrize("text, value", [("-2", -2.0), ("0.25", 0.25), ("+1", 1.0), ("-1/4", -0.25)])
def test_parse_ratio(text: str, value: float) -> None:
    assert parse_ratio(text) == pytest.approx(value)


@pytest.mark.parametrize("text", ["x", "", "0", "nan", "inf", "1/0"])
def test_parse_ratio_rejects(text: str) -> None:
    with pytest.raises(ConfigError):
        parse_ratio(text)


def test_parse_view_spec() -> None:
    assert parse_view_spec("a/b.png:-2") == ("a/b.png", -2.0)
    assert parse_view_spec("C:/x.png:0.5") == ("C:/x.png", 0.5)
    for bad in ("nocolon.png", ":1", "a.png:"):
        with pytest.raises(ConfigError):
            parse_view_spec(bad)


def test_check_views_errors() -> None:
    ref, views = _views([1.0, 2.0], D_TRUE)
    with pytest.raises(ConfigError, match="one baseline ratio per view"):
        check_views(ref, views, [1.0], max_disp=5)
    with pytest.raises(ConfigError, match="distinct"):
        check_views(ref, views, [1.0, 1.0], max_disp=5)
    with pytest.raises(ConfigError, match="at least one view"):
        check_views(ref, [], [], max_disp=5)
    with pytest.raises(ImageError, match="size"):
        check_views(ref, [views[0][:, :-1]], [1.0], max_disp=5)
    with pytest.raises(MatchingError):
        check_views(ref, views, [1.0, 2.0], max_disp=W)
    with pytest.raises(ConfigError, match="multi-view method"):
        match_multiview(ref, views, ratios=[1.0, 2.0], max_disp=5, method="nope")


@pytest.mark.parametrize("cost", ["bpasw", "guided"])
def test_local_recovers_shift_both_sides(cost: str) -> None:
    ratios = [-2.0, -1.0, 1.0, 2.0]
    ref, views = _views(ratios, D_TRUE)
    params = LocalMultiViewParams(cost=cost, cost_params=FAST_BPASW if cost == "bpasw" else {"radius": 3})
    res = match_multibaseline(ref, views, ratios=ratios, max_disp=8, params=params)
    inner = res.disparity[6:-6, 16:-16]
    assert np.all(np.abs(inner - D_TRUE) < 0.5), np.unique(np.rint(inner), return_counts=True)
    assert (np.rint(inner) == D_TRUE).mean() == 1.0


def test_local_fractional_ratio() -> None:
    ratios = [-0.5, 0.5, 1.0]
    d = 4.0  # shifts -2, 2, 4 px
    ref, views = _views(ratios, d)
    res = match_multibaseline(ref, views, ratios=ratios, max_disp=8,
                              params=LocalMultiViewParams(cost_params=FAST_BPASW))
    inner = res.disparity[6:-6, 16:-16]
    assert np.median(np.abs(inner - d)) < 0.25
    assert (np.abs(inner - d) < 0.5).mean() > 0.95


def test_resample_exact_for_integer_ratio() -> None:
    from prismstereo.multiview.baseline import PairCost

    rng = np.random.default_rng(0)
    vol = rng.random((4, 10, 9)).astype(np.float32)
    pc = PairCost(2.0, vol, np.zeros((4, 10), np.float32), np.ones((4, 10), bool))
    out, seen = resample_to_unit(pc, max_disp=3)
    np.testing.assert_array_equal(out, vol[:, :, [0, 2, 4, 6]])
    assert not seen[:, 0, 1].any() and seen[:, 9, 3].all()  # x - 2 d < 0 at the left border
    pc2 = PairCost(0.5, vol, np.zeros((4, 10), np.float32), np.ones((4, 10), bool))
    out2, _ = resample_to_unit(pc2, max_disp=3)
    np.testing.assert_allclose(out2[:, :, 1], 0.5 * (vol[:, :, 0] + vol[:, :, 1]), rtol=1e-6)


def test_more_views_lower_error_on_noise() -> None:
    ratios = [-2.0, -1.0, 1.0, 2.0]
    ref, views = _views(ratios, D_TRUE, noise=45.0, seed=3)
    p = LocalMultiViewParams(cost_params={"radius": 2, "dilation": 1})
    one = match_multibaseline(ref, [views[2]], ratios=[1.0], max_disp=8, params=p).disparity
    many = match_multibaseline(ref, views, ratios=ratios, max_disp=8, params=p).disparity
    err1 = (np.abs(one - D_TRUE)[6:-6, 16:-16] > 0.5).mean()
    errn = (np.abs(many - D_TRUE)[6:-6, 16:-16] > 0.5).mean()
    assert errn < err1 * 0.7, (err1, errn)


def test_global_recovers_plane() -> None:
    ratios = [-1.0, 1.0, 2.0]
    ref, views = _views(ratios, D_TRUE)
    res = match_multiview(ref, views, ratios=ratios, max_disp=8, method="global")
    inner = res.disparity[6:-6, 16:-16]
    assert (np.abs(inner - D_TRUE) < 1.0).mean() > 0.95
    assert res.disparity.dtype == np.float32 and res.disparity.shape == (H, W)


def test_resolve_occlusion() -> None:
    from prismstereo.multiview.baseline import resolve_occlusion

    assert resolve_occlusion("auto", [-2, -1, 1, 2]) == "sides"
    assert resolve_occlusion("auto", [(k - 2) / 4 for k in range(9) if k != 2]) == "sum"
    assert resolve_occlusion("auto", [1, 2]) == "sum"
    assert resolve_occlusion("sides", [1, 2]) == "sum"
    assert resolve_occlusion("sides", [-0.25, 2]) == "sides"
    with pytest.raises(ConfigError):
        resolve_occlusion("best", [1.0])


@pytest.mark.parametrize("params", [FAST_BPASW, {"radius": 3, "dilation": 1, "kernel": "exp"}])
def test_shared_bpasw_equals_pair_cost(params: dict) -> None:
    """The reference's weights computed once for all views give the pair-by-pair volumes (to 1 ulp: the
    compiler may vectorise the disparity loop's tail differently) and the same maps."""
    from prismstereo.multiview.baseline import pair_cost
    from prismstereo.multiview.sharedbpasw import bpasw_pair_costs

    ratios = [-2.0, -1.0, 0.5, 1.0, 2.0]
    ref, views = _views(ratios, D_TRUE, noise=20.0, seed=5)
    shared = bpasw_pair_costs(ref, views, ratios, max_disp=6, cost_params=params)
    for v, r, pc in zip(views, ratios, shared, strict=True):
        one = pair_cost(ref, v, r, max_disp=6, cost="bpasw", cost_params=params)
        assert pc.ratio == one.ratio and pc.step == one.step
        np.testing.assert_allclose(pc.cost, one.cost, rtol=3e-7, atol=0)
        # a 1-ulp difference may break an exact tie of the WTA at a pixel or two
        assert (np.abs(pc.disparity - one.disparity) <= 1e-5).mean() > 0.995
        assert (pc.reliable == one.reliable).mean() > 0.995


@pytest.mark.parametrize("cost", ["guided", "bpasw"])
def test_row_radius_keeps_the_row_boxed_raw(cost: str) -> None:
    """``row_radius`` keeps the same volume a second ``row_box`` pass over the pair computes."""
    from prismstereo.multiview.baseline import pair_cost

    ratios = [-1.0, 2.0]
    ref, views = _views(ratios, D_TRUE, noise=20.0, seed=6)
    cp = FAST_BPASW if cost == "bpasw" else {}
    for v, r in zip(views, ratios, strict=True):
        both = pair_cost(ref, v, r, max_disp=6, cost=cost, cost_params=cp, keep_raw=True, row_radius=1)
        sq = pair_cost(ref, v, r, max_disp=6, cost=cost, cost_params=cp, keep_raw=True)
        row = pair_cost(ref, v, r, max_disp=6, cost=cost, cost_params=cp, keep_raw=True, row_box=True)
        assert both.raw is not None and both.raw_row is not None and sq.raw is not None and row.raw is not None
        np.testing.assert_array_equal(both.raw, sq.raw)
        np.testing.assert_array_equal(both.raw_row, row.raw)
        assert sq.raw_row is None


def _layered_views(ratios: list[float], d_bg: float, d_fg: float) -> tuple[np.ndarray, list, np.ndarray]:
    """A textured square at disparity ``d_fg`` in front of a textured wall at ``d_bg``, seen from each ratio;
    returns the reference, the views and the reference's true disparity."""
    h, w, pad = 40, 72, 24
    # dark wall, bright card: the square's outline is a colour edge, as segment-based stereo assumes
    wall = _texture(h, w + 2 * pad, seed=5) * 0.45
    card = 140.0 + _texture(h, w + 2 * pad, seed=6) * 0.45
    y0, y1, x0, x1 = 12, 28, 28, 46  # the square in reference coordinates
    out = []
    for r in [0.0, *ratios]:
        v = wall[:, pad + int(round(r * d_bg)):pad + int(round(r * d_bg)) + w].copy()
        s = int(round(r * d_fg))
        v[y0:y1, x0 - s:x1 - s] = card[y0:y1, pad + x0:pad + x1]
        out.append(v)
    gt = np.full((h, w), d_bg, np.float32)
    gt[y0:y1, x0:x1] = d_fg
    return out[0], out[1:], gt


@pytest.mark.parametrize("overrides", [{}, {"data_agg": 0.0}, {"fine_extra": ()}])
def test_global_recovers_layered_scene_with_and_without_the_edge_steps(overrides: dict) -> None:
    from dataclasses import replace

    from prismstereo.multiview.globalmv import GlobalMultiViewParams, match_multiview_global

    ratios = [-1.0, 1.0, 2.0]
    ref, views, gt = _layered_views(ratios, 2.0, 6.0)
    p = GlobalMultiViewParams()
    if "fine_extra" in overrides:
        p = replace(p, steps=replace(p.steps, fine=replace(p.steps.fine, levels=((3.0, 10), *overrides["fine_extra"]))))
    else:
        p = replace(p, **overrides)
    res = match_multiview_global(ref, views, ratios=ratios, max_disp=8, params=p)
    inner = (slice(4, -4), slice(14, -14))  # the outer columns are seen by one side's views only
    good = np.abs(res.disparity - gt)[inner] <= 1.0
    assert good.mean() > 0.97, good.mean()
    # the square itself, edges included
    assert (np.abs(res.disparity - gt)[12:28, 28:46] <= 1.0).mean() > 0.95
