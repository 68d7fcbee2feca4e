"""The ``coop`` matcher: synthetic piecewise-planar pair, energy monotonicity, registry, Middlebury bound."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from prismstereo.matching.coop.coopcost import aggregated_costs, raw_cost
from prismstereo.matching.coop.cooperative import (
    CoopParams,
    SegmentGraph,
    build_segment_graph,
    cooperative_optimize,
    total_energy,
)
from prismstereo.matching.coop.pipeline import coop_match, initial_disparity
from prismstereo.matching.segments.planes import SegmentIndex, build_segment_index, fit_planes
from prismstereo.matching.segments.segmentation import mean_shift_segment


def _synthetic_pair(seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Textured left image of three planar regions with distinct palettes; right view by z-buffered warp."""
    rng = np.random.default_rng(seed)
    h, w = 90, 120
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    region = np.zeros((h, w), np.int32)
    region[20:70, 40:90] = 1  # a fronto-parallel box in front
    region[75:, :] = 2  # a slanted floor
    disp = np.where(region == 1, 14.0, np.where(region == 2, 6.0 + 0.05 * (yy - 75) * 4, 6.0))
    palettes = np.array([[[60, 90, 160], [90, 120, 190], [40, 70, 130]],
                         [[200, 80, 40], [230, 120, 60], [170, 60, 30]],
                         [[50, 160, 70], [80, 190, 100], [30, 130, 50]]], np.float64)
    blocks = rng.integers(0, 3, size=(h // 3 + 1, w // 3 + 1))
    pick = np.kron(blocks, np.ones((3, 3), np.int64))[:h, :w]
    left = palettes[region, pick] + rng.normal(0, 2.0, (h, w, 3))
    left = np.clip(left, 0, 255).astype(np.uint8)
    right = np.clip(rng.normal(100, 30, (h, w, 3)), 0, 255).astype(np.uint8)  # disoccluded: random texture
    xr = np.rint(xx - disp).astype(int)
    order = np.argsort(disp.ravel(), kind="stable")  # nearer (larger d) written last
    ys, xs = (yy.ravel()[order]).astype(int), (xx.ravel()[order]).astype(int)
    tx = xr.ravel()[order]
    ok = tx >= 0
    right[ys[ok], tx[ok]] = left[ys[ok], xs[ok]]
    return left, right, np.rint(disp)


def _optimisation_inputs(seed: int) -> tuple[SegmentIndex, np.ndarray, np.ndarray, SegmentGraph, np.ndarray]:
    """What the cooperative optimisation works on for a synthetic pair: the segments, the planes fitted to
    the initial map, its reliable pixels, the segment graph and the pixel cost."""
    left, right, _ = _synthetic_pair(seed)
    labels = mean_shift_segment(left)
    cl, cr = aggregated_costs(left, right, max_disp=20)
    init, rel = initial_disparity(cl, cr)
    idx = build_segment_index(labels)
    planes, _ = fit_planes(idx, init, rel)
    pset = planes[np.isfinite(planes[:, 0])]
    return idx, pset, rel, build_segment_graph(labels, left), raw_cost(left, right, max_disp=20)


def test_synthetic_piecewise_planar_pair_is_recovered() -> None:
    left, right, gt = _synthetic_pair()
    res = coop_match(left, right, max_disp=20)
    h, w = gt.shape
    visible = np.ones((h, w), bool)
    visible[:, :20] = False  # left border: no match in the right image
    bad = np.abs(res.disparity - gt) > 1.0
    assert bad[visible].mean() < 0.02
    for arr in (res.labels, res.initial, res.reliable, res.plane_map, res.disparity):
        assert arr.shape == (h, w)
    assert res.info["energy_after"] <= res.info["energy_before"]


def test_energy_never_increases_across_iterations() -> None:
    idx, pset, rel, graph, cost = _optimisation_inputs(1)
    # a poor start: every segment gets a random fitted plane
    a = np.random.default_rng(0).integers(0, len(pset), size=idx.n_segments).astype(np.int32)
    energies = [total_energy(a, pset, idx, graph, cost, rel)]
    for _ in range(6):
        a, pset, info = cooperative_optimize(a, pset, idx, graph, cost, rel, params=CoopParams(max_iter=1))
        energies.append(info["energy_after"])
        assert info["energy_before"] == pytest.approx(energies[-2])
    assert all(e1 <= e0 + 1e-6 for e0, e1 in zip(energies, energies[1:], strict=False))
    assert energies[-1] < energies[0]


def test_remembered_data_terms_match_fresh_ones() -> None:
    """Sweeps within one call reuse data terms across z-buffer changes; one sweep per call computes them all
    afresh. Both must take the same path, and the reported energy must be the recomputed one."""
    idx, pset, rel, graph, cost = _optimisation_inputs(2)
    a0 = np.random.default_rng(3).integers(0, len(pset), size=idx.n_segments).astype(np.int32)
    a_one, _, info = cooperative_optimize(a0, pset, idx, graph, cost, rel, params=CoopParams(max_iter=30))
    assert info["sweeps"] > 2  # the remembered terms were used after z-buffer changes
    assert total_energy(a_one, pset, idx, graph, cost, rel) == info["energy_after"]
    a_step = a0
    for _ in range(int(info["sweeps"])):
        a_step, _, _ = cooperative_optimize(a_step, pset, idx, graph, cost, rel, params=CoopParams(max_iter=1))
    np.testing.assert_array_equal(a_one, a_step)


def test_cached_energy_is_the_fresh_energy_to_the_bit() -> None:
    """The remembered data terms are computed in parallel and summed in segment order: across assignments
    whose z-buffers differ, the cached energy equals the one computed afresh exactly."""
    from prismstereo.matching.coop import cooperative as co

    idx, pset, rel, graph, cost = _optimisation_inputs(4)
    prm = co._prm(CoopParams())
    dt = co._pixel_data(idx, cost, rel, None, 0)
    g = co._graph_arrays(graph)
    # without and with the smoothness terms remembered
    for cache in (co._new_cache(idx, idx.n_segments), co._take_cache(None, idx, graph, cost, rel, prm, 0, pset)):
        rng = np.random.default_rng(5)
        a = rng.integers(0, len(pset), size=idx.n_segments).astype(np.int32)
        for _ in range(6):
            assert co._energy_cached(a, pset, dt, g, prm, cache) == co._energy(a, pset, dt, g, prm)
            moved = rng.choice(idx.n_segments, size=max(1, idx.n_segments // 5), replace=False)
            a[moved] = rng.integers(0, len(pset), size=moved.size)


def test_powell_refinement_lowers_energy_and_keeps_it_monotone() -> None:
    idx, pset, rel, graph, cost = _optimisation_inputs(3)
    a0 = np.zeros(idx.n_segments, np.int32)  # everything on one plane: a poor start
    a_d, p_d, info_d = cooperative_optimize(a0, pset, idx, graph, cost, rel, params=CoopParams(refine_rounds=0))
    a_p, p_p, info_p = cooperative_optimize(a0, pset, idx, graph, cost, rel, params=CoopParams(refine_rounds=2))
    assert info_p["energy_after"] <= info_d["energy_after"] + 1e-6  # Powell reaches equal or lower energy
    assert info_p["energy_after"] <= info_p["energy_before"]
    assert p_p.shape[0] >= pset.shape[0]
    assert total_energy(a_p, p_p, idx, graph, cost, rel) == pytest.approx(info_p["energy_after"])


def test_registered_and_stages_in_extras() -> None:
    from prismstereo.matching.registry import available_matchers, get_matcher

    assert "coop" in available_matchers()
    left, right, _ = _synthetic_pair(2)
    res = get_matcher("coop").compute(left, right, max_disp=20)
    assert res.disparity.dtype == np.float32 and np.isfinite(res.disparity).all()
    for key in ("labels", "initial", "reliable", "plane_map", "planes", "assign"):
        assert key in res.extras
    assert set(res.timings) >= {"segmentation", "initial", "planes", "cooperative"}


# measured nonocc / all / disc: Tsukuba 1.34 / 1.74 / 5.69, Teddy 3.31 / 6.76 / 10.14 (issue 14) (its steep floor and
# repeated textures: the slope-sheared data term and the group moves); the thesis's per-scene rule is nonocc no
# worse than its own by more than 0.5 (Tsukuba 0.89, Teddy 4.02)
@pytest.mark.parametrize(("scene", "bounds"), [("tsukuba", (1.39, 2.1, 7.0)), ("teddy", (4.0, 7.9, 11.0))])
def test_middlebury_bounds(middlebury_dir: Path, scene: str, bounds: tuple[float, float, float]) -> None:
    from prismstereo.evaluation.middlebury import evaluate_disparity, load_scene

    sc = load_scene(scene, middlebury_dir)
    res = coop_match(sc.left, sc.right, max_disp=sc.max_disp)
    bad = evaluate_disparity(res.disparity, sc, thresholds=(1.0,))["bad"]["1.0"]
    for v, b in zip((bad["nonocc"], bad["all"], bad["disc"]), bounds, strict=True):
        assert v < b


def test_sweep_candidates_reach_a_steep_slant() -> None:
    """The global sweep offers a plane near a steep y-slant that a fronto-parallel current plane cannot reach."""
    from prismstereo.matching.coop.pipeline import segment_sweep_candidates
    from prismstereo.matching.coop.steps import SweepParams

    rng = np.random.default_rng(3)
    h, w = 60, 80
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    disp = 4.0 + 0.25 * yy  # 4 .. 18.75
    left = rng.integers(0, 256, size=(h, w, 3)).astype(np.uint8)
    left = np.repeat(np.repeat(left[::2, ::2], 2, 0), 2, 1)[:h, :w]
    right = np.zeros_like(left)
    for y in range(h):
        for c in range(3):
            right[y, :, c] = np.interp(np.arange(w) + disp[y, 0], np.arange(w), left[y, :, c].astype(float))
    labels = np.zeros((h, w), np.int32)
    labels[:, 40:] = 1
    index = build_segment_index(labels)
    planes = np.array([[0.0, 0.0, 11.0]])
    assign = np.zeros(2, np.int32)
    params = SweepParams(frac=1.0, slopes=(-0.25, 0.0, 0.25), keep=2, min_px=10, step=2, dilation=2)
    out, ids = segment_sweep_candidates(left, right, labels, index, assign, planes, min_disp=0, max_disp=24,
                                        params=params)
    assert out.shape[0] > 1
    assert (ids[:, 0] >= 0).all()
    best = out[ids[:, 0]]
    assert np.allclose(best[:, 1], 0.25)
    seg = labels == 1
    d = best[1, 0] * xx[seg] + best[1, 1] * yy[seg] + best[1, 2]
    assert np.mean(np.abs(d - disp[seg]) <= 1.0) > 0.9


def _straddling_scene() -> tuple[np.ndarray, ...]:
    """Red half at d = 10, blue half at d = 4; the coarse segment of the blue half wrongly holds 5 red columns."""
    rng = np.random.default_rng(3)
    h, w, nd = 40, 60, 16
    img = np.zeros((h, w, 3), np.float64)
    img[:, :30] = (200, 40, 40)
    img[:, 30:] = (40, 40, 200)
    img = np.clip(img + rng.normal(0, 1.0, img.shape), 0, 255).astype(np.uint8)
    truth = np.where(np.arange(w)[None, :] < 30, 10.0, 4.0) * np.ones((h, 1))
    labels = np.where(np.arange(w)[None, :] < 25, 0, 1).astype(np.int32) * np.ones((h, 1), np.int32)
    cost = (np.minimum(np.abs(np.arange(nd)[None, None, :] - truth[..., None]), 2.0) * 0.5).astype(np.float32)
    planes = np.array([[0.0, 0.0, 10.0], [0.0, 0.0, 4.0]])
    return img, labels.astype(np.int32), planes, cost, truth.astype(np.float32)


def test_fine_segments_move_the_straddling_columns_to_their_plane() -> None:
    from prismstereo.matching.coop.refine import DataTerm, refine_fine_segments
    from prismstereo.matching.segments.segmentation import SegmentationParams

    img, labels, planes, cost, truth = _straddling_scene()
    ok = np.ones(labels.shape, bool)
    fs = refine_fine_segments(img, labels, np.array([0, 1], np.int32), planes, DataTerm(cost, ok), ok, truth,
                              segmentation=SegmentationParams(hr=3.0, min_region=10), coop=CoopParams())
    disp = fs.planes[fs.assign][fs.labels][..., 2]
    assert np.array_equal(fs.parent[fs.labels], labels)  # fine segments nest in the coarse ones
    np.testing.assert_allclose(disp, truth)
    assert fs.info["fine_moves"] >= 1


def test_fine_segments_given_ahead_are_the_ones_computed_inside() -> None:
    from prismstereo.matching.coop.refine import DataTerm, refine_fine_segments
    from prismstereo.matching.segments.segmentation import SegmentationParams

    img, labels, planes, cost, truth = _straddling_scene()
    ok = np.ones(labels.shape, bool)
    seg = SegmentationParams(hr=3.0, min_region=10)
    args = (img, labels, np.array([0, 1], np.int32), planes, DataTerm(cost, ok), ok, truth)
    inside = refine_fine_segments(*args, segmentation=seg, coop=CoopParams())
    ahead = refine_fine_segments(*args, segmentation=seg, coop=CoopParams(), fine=mean_shift_segment(img, params=seg))
    for name in ("labels", "assign", "planes", "parent"):
        np.testing.assert_array_equal(getattr(ahead, name), getattr(inside, name))


def test_fine_segments_keep_moves_only_with_evidence() -> None:
    from prismstereo.matching.coop.refine import DataTerm, refine_fine_segments
    from prismstereo.matching.segments.segmentation import SegmentationParams

    img, labels, planes, cost, truth = _straddling_scene()
    ok = np.ones(labels.shape, bool)
    wrong_ref = np.where(labels == 1, 4.0, 10.0).astype(np.float32)  # the trusted map sides with the old plane
    fs = refine_fine_segments(img, labels, np.array([0, 1], np.int32), planes, DataTerm(cost, ok), ok, wrong_ref,
                              segmentation=SegmentationParams(hr=3.0, min_region=10), coop=CoopParams())
    disp = fs.planes[fs.assign][fs.labels][..., 2]
    np.testing.assert_allclose(disp, np.where(labels == 1, 4.0, 10.0))
    assert fs.info["fine_moves"] == 0


def test_fine_segments_without_evidence_follow_the_data_term_only_when_check_vetoes() -> None:
    """A sliver no evidence pixel covers: the count rule (``check`` 1) cannot move it, the veto rule (``check``
    0: undone only where the evidence is against the move) leaves the move to the optimisation."""
    from prismstereo.matching.coop.refine import DataTerm, refine_fine_segments
    from prismstereo.matching.segments.segmentation import SegmentationParams

    img, labels, planes, cost, truth = _straddling_scene()
    ok = np.ones(labels.shape, bool)
    blind = ok & (np.abs(np.arange(labels.shape[1]) - 27.5)[None, :] > 3)  # no evidence on the straddling columns
    seg = SegmentationParams(hr=3.0, min_region=10)
    kw = {"segmentation": seg, "coop": CoopParams()}
    count = refine_fine_segments(img, labels, np.array([0, 1], np.int32), planes, DataTerm(cost, ok), blind, truth,
                                 check=1, **kw)
    veto = refine_fine_segments(img, labels, np.array([0, 1], np.int32), planes, DataTerm(cost, ok), blind, truth,
                                check=0, **kw)
    assert count.info["fine_moves"] == 0
    assert veto.info["fine_moves"] >= 1
    np.testing.assert_allclose(veto.planes[veto.assign][veto.labels][..., 2], truth)


def test_cooperative_optimize_leaves_inactive_segments_alone() -> None:
    img, labels, planes, cost, truth = _straddling_scene()
    labels = np.where(np.arange(60)[None, :] < 30, 0, 1).astype(np.int32) * np.ones((40, 1), np.int32)
    idx = build_segment_index(labels)
    graph = build_segment_graph(labels, img)
    wrong = np.array([1, 0], np.int32)
    rel = np.ones(labels.shape, bool)
    a_all, _, _ = cooperative_optimize(wrong, planes, idx, graph, cost, rel, own=np.array([[0, -1], [1, -1]]))
    a_none, _, info = cooperative_optimize(wrong, planes, idx, graph, cost, rel, own=np.array([[0, -1], [1, -1]]),
                                           active=np.zeros(2, bool))
    assert list(a_all) == [0, 1]
    assert list(a_none) == [1, 0] and info["changes"] == 0


def _striped_surface() -> tuple:
    """Five stripe segments that all hold plane A; plane B is cheaper for every one of them, but not by enough
    to pay, alone, the smoothness term against its two neighbours on A."""
    rng = np.random.default_rng(0)
    h, w, nd = 20, 50, 8
    labels = np.repeat((np.arange(w) // 10)[None, :], h, axis=0).astype(np.int32)
    img = np.clip(120 + rng.normal(0, 3.0, (h, w, 3)), 0, 255).astype(np.uint8)
    cost = np.full((h, w, nd), 1.0, np.float32)
    cost[:, :, 1] = 0.5  # plane A: d = 1
    cost[:, :, 2] = 0.45  # plane B: d = 2
    planes = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 2.0]])
    return labels, img, cost, planes


def test_group_moves_take_a_region_that_single_moves_cannot() -> None:
    from prismstereo.matching.coop.cooperative import expand_planes

    labels, img, cost, planes = _striped_surface()
    idx = build_segment_index(labels)
    graph = build_segment_graph(labels, img)
    rel = np.ones(labels.shape, bool)
    params = CoopParams(omega_border=0.0)
    a0 = np.zeros(5, np.int32)
    own = np.full((5, 2), -1, np.int64)
    own[2, 0] = 1  # plane B proposed for the middle stripe only
    single, _, _ = cooperative_optimize(a0, planes, idx, graph, cost, rel, own=own, params=params)
    assert (single == 0).all()  # one stripe alone pays more smoothness than it gains
    cands = np.full((5, 1), -1, np.int64)
    cands[2, 0] = 1
    moved, info = expand_planes(a0, planes, idx, graph, cost, rel, cands, params=params)
    assert (moved == 1).all() and info["group_moves"] == 1.0
    e0 = total_energy(a0, planes, idx, graph, cost, rel, params=params)
    assert total_energy(moved, planes, idx, graph, cost, rel, params=params) < e0
    # a dearer plane is never taken: E does not increase
    dear = cost.copy()
    dear[:, :, 2] = 0.55
    kept, info = expand_planes(a0, planes, idx, graph, dear, rel, cands, params=params)
    assert (kept == 0).all() and info["group_moves"] == 0.0


def test_neighbour_plane_candidates_lists_the_planes_across_boundaries() -> None:
    from prismstereo.matching.coop.cooperative import neighbour_plane_candidates

    labels, img, _, _ = _striped_surface()
    graph = build_segment_graph(labels, img)
    cands = neighbour_plane_candidates(graph, np.array([0, 0, 1, 2, 2]))
    got = [sorted(int(c) for c in row if c >= 0) for row in cands]
    assert got == [[], [1], [0, 2], [1], []]


def test_memo_across_calls_gives_the_results_of_fresh_calls() -> None:
    """A memo carries data terms from call to call: with planes appended, a plane changed in place, a group
    move, a new cost volume and a new mask in between, every call returns what it returns without one."""
    from prismstereo.matching.coop.cooperative import CoopMemo, expand_planes, neighbour_plane_candidates

    idx, pset, rel, graph, cost = _optimisation_inputs(6)
    rng = np.random.default_rng(7)
    k = idx.n_segments
    a0 = rng.integers(0, len(pset), size=k).astype(np.int32)
    own = np.stack([rng.integers(0, len(pset), size=k), np.full(k, -1)], axis=1).astype(np.int64)
    more = np.vstack([pset, pset[rng.integers(0, len(pset), size=8)] + [0.0, 0.0, 1.0]])
    cost2 = cost.copy()
    cost2[:, : cost.shape[1] // 2] *= 1.5  # a new volume (another object) with other costs
    rel2 = rel.copy()
    rel2[::3] = ~rel2[::3]

    def check_remembered(memo: CoopMemo, a: np.ndarray, planes: np.ndarray, c: np.ndarray, r: np.ndarray) -> int:
        # every data term the memo holds is the one computed afresh now (the z-buffer of ``a``)
        from prismstereo.matching.coop import cooperative as co

        cache = memo.take(idx, c, r, co._prm(CoopParams()), 0, planes)
        clab, cval, cn = cache.clab, cache.cval, cache.cn
        z = co._zbuffer(a, planes, idx.order, idx.starts, *idx.shape)
        for j in range(k):
            for t in range(cn[j]):
                fresh = co._data(j, planes[clab[j, t]], co._pixel_data(idx, c, r, None, 0), co._prm(CoopParams()),
                                 *z)
                assert cval[j, t] == fresh
        memo.keep(idx, c, r, co._prm(CoopParams()), 0, planes, cache)
        return int(cn.sum())

    def run(memo: CoopMemo | None) -> list[np.ndarray]:
        out = []
        a = a0
        for planes, c, r in ((pset, cost, rel), (more, cost, rel), (None, cost, rel), (None, cost2, rel),
                             (None, cost2, rel2)):
            if planes is None:
                # the same indices, other planes: candidates (remembered) that no segment holds
                planes = more.copy()
                planes[np.setdiff1d(own[:, 0], a)[:10], 2] += 2.0
            if memo is not None:
                checked.append(check_remembered(memo, a, planes, c, r))
            a, _, info = cooperative_optimize(a, planes, idx, graph, c, r, own=own, memo=memo)
            out += [a, np.array([info["energy_after"], info["sweeps"]])]
            a, ginfo = expand_planes(a, planes, idx, graph, c, r, neighbour_plane_candidates(graph, a), memo=memo)
            out += [a, np.array([ginfo["group_moves"]])]
        return out

    checked: list[int] = []
    fresh, remembered = run(None), run(CoopMemo())
    assert min(checked[1:3]) > 0  # data terms were carried over to the calls with the same volume
    assert len(fresh) == len(remembered)
    for x, y in zip(fresh, remembered, strict=True):
        np.testing.assert_array_equal(x, y)
