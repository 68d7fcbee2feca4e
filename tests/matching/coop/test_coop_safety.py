"""Safety rules of ``coop`` on synthetic scenes where the unsafe move is tempting."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from prismstereo.matching.coop.coopcost import raw_cost
from prismstereo.matching.segments.planes import (
    PlaneParams,
    build_segment_index,
    fit_planes,
    fit_planes_splitting,
    render_planes,
)


def _repetitive_pair(d_true: int = 10, period: int = 8, h: int = 60, w: int = 140) -> tuple[np.ndarray, np.ndarray]:
    """A large fronto-parallel plane at ``d_true`` textured by a pattern repeating every ``period`` columns
    (a printed dot pattern) with a weak non-repeating part, and independent sensor noise in each view."""
    rng = np.random.default_rng(7)
    tile = rng.integers(40, 215, size=(h, period, 3)).astype(np.float64)
    pattern = np.tile(tile, (1, w // period + 2, 1))[:, : w + d_true]
    pattern += rng.normal(0.0, 2.0, pattern.shape)  # the weak non-repeating part: the only tie-breaker
    left = np.clip(pattern[:, :w] + rng.normal(0.0, 3.0, (h, w, 3)), 0, 255).astype(np.uint8)
    right = np.clip(pattern[:, d_true:d_true + w] + rng.normal(0.0, 3.0, (h, w, 3)), 0, 255).astype(np.uint8)
    return left, right  # x_right = x_left - d_true


def test_large_repetitive_plane_keeps_its_plane_when_part_of_the_initial_map_takes_the_alias() -> None:
    """A large plane of repetitive texture whose initial map fell for the alias (one period off) on 7 % of it:
    the alias is tempting (the pixel cost barely tells them apart), but the plane is supported by the rest of
    the evidence, so the segment is neither split nor moved: coop keeps the true plane."""
    period, d_true, max_disp = 8, 10, 24
    left, right = _repetitive_pair(d_true, period)
    raw = raw_cost(left, right, max_disp=max_disp)
    inner = (slice(5, -5), slice(max_disp + 5, -5))
    c_true, c_alias = raw[inner][..., d_true].mean(), raw[inner][..., d_true + period].mean()
    assert abs(c_alias - c_true) < 0.25 * (raw[inner].mean() - c_true)
    h, w = left.shape[:2]
    labels = np.zeros((h, w), np.int32)
    labels[:, :max_disp] = 1  # the left border (no match in the right view) apart
    initial = np.full((h, w), float(d_true), np.float32)
    initial[: h // 12, w // 3:] = d_true + period  # the initial map fell for the alias on 7 % of the plane
    ok = np.ones((h, w), bool)
    prm = PlaneParams(split_min_pixels=1000)
    lab, _, planes, ancestor = fit_planes_splitting(labels, left, initial, ok, params=prm)
    assert lab.max() == 1 and np.isnan(ancestor).all()
    np.testing.assert_allclose(planes[0], [0.0, 0.0, float(d_true)], atol=1e-6)
    from prismstereo.matching.coop.pipeline import coop_match

    res = coop_match(left, right, max_disp=max_disp, planes=PlaneParams(split_min_pixels=1000))
    assert np.mean(np.abs(res.disparity[inner] - d_true) <= 1.0) > 0.9


def _curved_scene(h: int = 80, w: int = 120) -> tuple[np.ndarray, np.ndarray]:
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    # a ball-like surface: 20 px at the centre falling to ~8 px at the corners
    d = 20.0 - 0.0035 * ((xx - w / 2) ** 2 + (yy - h / 2) ** 2)
    return d.astype(np.float32), np.full((h, w, 3), 128, np.uint8)


def test_large_segment_on_a_curved_surface_is_split_until_planes_fit() -> None:
    disp, image = _curved_scene()
    labels = np.zeros(disp.shape, np.int32)  # mean shift's one segment over a uniformly coloured ball
    ok = np.ones(disp.shape, bool)
    index = build_segment_index(labels)
    one, _ = fit_planes(index, disp, ok)
    single = render_planes(index, one, np.zeros(1, np.int32))
    assert np.mean(np.abs(single - disp) <= 1.0) < 0.6  # one plane cannot follow the ball
    lab, idx, planes, ancestor = fit_planes_splitting(labels, image, disp, ok, params=PlaneParams())
    assert lab.max() > 0 and np.isfinite(ancestor[:, 0]).all()  # split, every piece remembers its parent
    pieces = render_planes(idx, planes, np.arange(planes.shape[0], dtype=np.int32))
    assert np.mean(np.abs(pieces - disp) <= 1.0) > 0.9


def test_planar_segment_with_some_wrong_evidence_is_not_split() -> None:
    """A plane supported by most of its evidence stays one segment even when 7.5 % of the pixels are wrong."""
    h, w = 80, 120
    disp = np.full((h, w), 12.0, np.float32)
    disp[:6, :] = 20.0  # a wrong patch of the initial map (7.5 %)
    labels = np.zeros((h, w), np.int32)
    ok = np.ones((h, w), bool)
    lab, _, planes, ancestor = fit_planes_splitting(labels, np.full((h, w, 3), 90, np.uint8), disp, ok)
    assert lab.max() == 0 and planes.shape[0] == 1 and np.isnan(ancestor).all()
    np.testing.assert_allclose(planes[0], [0.0, 0.0, 12.0], atol=1e-6)
    # a small segment is never split, whatever its support
    small = np.zeros((30, 40), np.int32)
    d2 = np.where(np.arange(40)[None, :] < 20, 5.0, 15.0).astype(np.float32) * np.ones((30, 1), np.float32)
    lab2, *_ = fit_planes_splitting(small, np.full((30, 40, 3), 90, np.uint8), d2, np.ones((30, 40), bool))
    assert lab2.max() == 0


def test_bpasw_dense_map_is_the_bpasw_matcher_output() -> None:
    """The fallback map of non-planar segments is exactly issue 3's ``bpasw`` matcher (defaults)."""
    from prismstereo.matching import match
    from prismstereo.matching.coop.pipeline import bpasw_dense_map, bpasw_volume

    left, right = _repetitive_pair(6, 8, h=32, w=64)
    vol = bpasw_volume(left, right, max_disp=16)
    ours = bpasw_dense_map(vol, left)
    ref = match(left, right, max_disp=16, method="bpasw").disparity
    np.testing.assert_array_equal(ours, ref)


def test_bpasw_dense_map_where_is_the_full_map_there() -> None:
    from prismstereo.matching.coop.pipeline import bpasw_dense_map, bpasw_volume
    from prismstereo.matching.local.selection import right_winner

    left, right = _repetitive_pair(6, 8, h=32, w=64)
    vol = bpasw_volume(left, right, max_disp=16)
    full = bpasw_dense_map(vol, left)
    where = np.zeros(full.shape, bool)
    where[5:20, 10:40] = True
    part = bpasw_dense_map(vol, left, where=where, right_winner=right_winner(vol))
    np.testing.assert_array_equal(part[where], full[where])
    # a small patch of a larger image: only the holes within the median's window of it are smoothed first
    left, right = _repetitive_pair(5, 9, h=64, w=128)  # smoothing only the holes within 4 px would fail
    vol = bpasw_volume(left, right, max_disp=16)
    full = bpasw_dense_map(vol, left)
    where = np.zeros(full.shape, bool)
    where[40:46, 90:100] = True
    part = bpasw_dense_map(vol, left, where=where)
    np.testing.assert_array_equal(part[where], full[where])


def _fallback_pair(seed: int, h: int, w: int, d_true: int = 6, max_disp: int = 16
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A random-texture pair at one disparity ``d_true`` (x_r = x_l − d), its BPASW volume and dense local map."""
    from prismstereo.matching.coop.pipeline import bpasw_dense_map, bpasw_volume

    tex = np.random.default_rng(seed).integers(0, 255, size=(h, w + d_true, 3)).astype(np.uint8)
    left, right = np.ascontiguousarray(tex[:, :w]), np.ascontiguousarray(tex[:, d_true:])
    vol = bpasw_volume(left, right, max_disp=max_disp)
    return left, right, vol, bpasw_dense_map(vol, left)


def _plane_state(labels: np.ndarray, plane_d: float) -> Any:
    """Plane labels where every segment of ``labels`` holds the fronto-parallel plane d = ``plane_d``."""
    from prismstereo.matching.coop.steps import PlaneLabels
    from prismstereo.matching.segments.planes import build_segment_index

    n = int(labels.max()) + 1
    return PlaneLabels(labels=labels, index=build_segment_index(labels), graph=None,  # type: ignore[arg-type]
                       assign=np.zeros(n, np.int32), planes=np.array([[0.0, 0.0, plane_d]]),
                       own=np.full((n, 2), -1, np.int64), parent=np.zeros(n, np.int64),
                       pairs=np.zeros((0, 2), np.int32))


def _fallback_evidence(left: np.ndarray, right: np.ndarray, vol: np.ndarray, initial: np.ndarray,
                       evidence: np.ndarray, max_disp: int = 16) -> Any:
    """The pair's evidence for the fallback step alone: ``evidence`` as every cross-checked mask, ``initial``
    as the initial and local maps."""
    from prismstereo.matching.coop.pipeline import PairMaps, PairSetup, _PairEvidence

    maps = PairMaps(data=np.zeros((1, 1, 1), np.float32), reliable=evidence, initial=initial, bvol=vol,
                    bdisp=initial, brel=evidence, nonplanar=np.zeros(evidence.shape, bool), evidence=evidence)
    params = PairSetup(coop=None, segmentation=None, planes=None, cost=None, slopes=None)  # type: ignore[arg-type]
    return _PairEvidence(left, right, min_disp=0, max_disp=max_disp, maps=maps, params=params)


def test_large_segment_whose_plane_the_evidence_barely_covers_takes_the_local_map() -> None:
    """The fallback step's coverage rule: a large segment whose final plane is wrong (3 px off) but which the
    evidence covers on only 30 % of its pixels keeps nothing of that plane (the local map there); covered on
    60 %, the plane stands (the other steps decided on evidence; the contradiction rule, which would take it,
    is off here)."""
    from prismstereo.matching.coop.steps import FallbackParams

    d_true, max_disp = 6, 16
    h, w = 70, 100
    left, right, vol, local = _fallback_pair(3, h, w)
    state = _plane_state(np.zeros((h, w), np.int32), d_true + 3.0)
    wrong = np.full((h, w), d_true + 3.0, np.float32)
    for cover, taken in ((0.3, True), (0.6, False)):
        evidence = np.zeros((h, w), bool)
        evidence[: int(cover * h)] = True
        ev = _fallback_evidence(left, right, vol, local, evidence)
        out = ev.fallback(state, wrong, FallbackParams(max_agreement=0.0))
        if taken:
            np.testing.assert_array_equal(out, local)
            assert np.mean(np.abs(out[:, max_disp:] - d_true) <= 1.0) > 0.95
        else:
            np.testing.assert_array_equal(out, wrong)


def test_large_segment_whose_plane_scattered_evidence_agrees_with_keeps_it() -> None:
    """The coverage rule's reach: a large segment (a dark, weakly textured wall in a noisy capture) whose evidence
    is scattered over 30 % of its pixels, every piece of it agreeing with the plane, keeps the plane (between the
    evidence pixels it is interpolated, not extrapolated). The same 30 % in one block at the top, or the reach
    off, still takes the local map."""
    from prismstereo.errors import ConfigError
    from prismstereo.matching.coop.steps import FallbackParams

    d_true = 6
    h, w = 70, 100
    left, right, vol, local = _fallback_pair(3, h, w)
    state = _plane_state(np.zeros((h, w), np.int32), d_true + 0.4)
    plane = np.full((h, w), d_true + 0.4, np.float32)  # within tol of the evidence, not the local map's values
    initial = np.full((h, w), float(d_true), np.float32)
    scattered = np.random.default_rng(1).random((h, w)) < 0.3
    block = np.zeros((h, w), bool)
    block[: int(0.3 * h)] = True
    one = ("bpasw",)  # the sgm candidate's rules play no part here
    for evidence, params, kept in ((scattered, FallbackParams(candidates=one), True),
                                   (scattered, FallbackParams(candidates=one, coverage_reach=0), False),
                                   (block, FallbackParams(candidates=one), False)):
        ev = _fallback_evidence(left, right, vol, initial, evidence)
        out = ev.fallback(state, plane, params)
        np.testing.assert_array_equal(out, plane if kept else local)
    with pytest.raises(ConfigError, match="coverage_reach"):
        FallbackParams(coverage_reach=-1)


def test_segment_whose_map_contradicts_its_evidence_takes_the_local_map() -> None:
    """The fallback step's contradiction rule: a segment whose final plane is wrong (3 px off, where the
    optimisation put it: the data term preferred it, as under an exposure change between the views) although
    the evidence covers 60 % of it at the true disparity keeps nothing of that plane (the local map there). With
    the plane on the evidence, or the evidence covering only 30 % of the segment, the plane stands."""
    from prismstereo.matching.coop.steps import FallbackParams

    d_true, max_disp = 6, 16
    h, w = 70, 100
    left, right, vol, local = _fallback_pair(3, h, w)
    state = _plane_state(np.zeros((h, w), np.int32), d_true + 3.0)
    wrong = np.full((h, w), d_true + 3.0, np.float32)
    right_plane = np.full((h, w), float(d_true), np.float32)
    initial = np.full((h, w), float(d_true), np.float32)  # both cross-checked maps agree on the true disparity
    for cover, final, params, taken in ((0.6, wrong, FallbackParams(), True),
                                        (0.6, right_plane, FallbackParams(), False),
                                        (0.3, wrong, FallbackParams(min_coverage=0.0), False),
                                        (0.6, wrong, FallbackParams(max_agreement=0.0), False),
                                        (0.6, wrong, FallbackParams(against_pixels=h * w + 1), False)):
        evidence = np.zeros((h, w), bool)
        evidence[: int(cover * h)] = True
        ev = _fallback_evidence(left, right, vol, initial, evidence)
        out = ev.fallback(state, final, params)
        if taken:
            np.testing.assert_array_equal(out, local)
            assert np.mean(np.abs(out[:, max_disp:] - d_true) <= 1.0) > 0.95
        else:
            np.testing.assert_array_equal(out, final)


def test_segment_without_evidence_takes_the_local_map_at_any_scale() -> None:
    """The fallback step's bare rule: a small segment (1 % of the image) that no evidence pixel covers holds a plane
    3 px off, the one its neighbour pulled it to; nothing of its own supports it, so it takes the local map. With
    10 % of it covered, or below ``bare_share`` of the image, the plane stands."""
    from prismstereo.matching.coop.steps import FallbackParams

    d_true = 6
    h, w = 60, 100
    left, right, vol, local = _fallback_pair(5, h, w)
    labels = np.zeros((h, w), np.int32)
    patch = (slice(20, 32), slice(50, 55))  # 60 px, 1 % of the image
    labels[patch] = 1
    state = _plane_state(labels, d_true + 3.0)
    final = np.full((h, w), float(d_true), np.float32)
    final[patch] = d_true + 3.0
    for cover, params, taken in ((0.0, FallbackParams(), True), (0.1, FallbackParams(), False),
                                 (0.0, FallbackParams(bare_share=0.02), False),
                                 (0.0, FallbackParams(bare_coverage=0.0), False)):
        evidence = labels == 0
        evidence[20:20 + int(round(cover * 12)), 50:55] = True
        ev = _fallback_evidence(left, right, vol, local, evidence)
        out = ev.fallback(state, final, params)
        np.testing.assert_array_equal(out[labels == 0], final[labels == 0])  # the covered segment stands
        if taken:
            np.testing.assert_array_equal(out[patch], local[patch])
            assert np.mean(np.abs(out[patch] - d_true) <= 1.0) > 0.9
        else:
            np.testing.assert_array_equal(out[patch], final[patch])


def _framed_print(seed: int, *, h: int = 60, w: int = 80, period: int = 8, d_face: int = 10, band: int = 16
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A box face printed with a pattern repeating every ``period`` columns (2112 px at ``d_face``), framed on
    three sides by a nearer band of the same print one period closer (``d_face + period``, the face's alias):
    the frame pulls the face onto its alias through the smoothness term, and the print barely tells the two
    apart (a weak non-repeating part, sensor noise in each view). Returns left, right, labels (0 = the face,
    1-3 = the frame's left, right and top)."""
    rng = np.random.default_rng(seed)
    d_frame = d_face + period
    tile = rng.integers(40, 215, size=(h, period, 3)).astype(np.float64)
    pattern = np.tile(tile, (1, (w + d_frame) // period + 2, 1))[:, : w + d_frame]
    pattern += rng.normal(0.0, 1.0, pattern.shape)
    yy, xx = np.mgrid[0:h, 0:w]
    labels = np.zeros((h, w), np.int32)
    labels[:, :band] = 1
    labels[:, w - band:] = 2
    labels[:band, band:w - band] = 3
    left = pattern[:, :w]
    right = pattern[:, d_face:d_face + w].copy()  # the face everywhere, then the nearer frame over it
    frame = (labels > 0) & (xx >= d_frame)
    right[yy[frame], xx[frame] - d_frame] = left[frame]

    def noisy(a: np.ndarray) -> np.ndarray:
        return np.clip(a + rng.normal(0.0, 3.0, a.shape), 0, 255).astype(np.uint8)

    return noisy(left), noisy(right), labels


def _face_plane_after(step: str, seed: int, check: bool) -> float:
    """The face's plane after the ``sweep`` or ``group_moves`` step from the right labelling (face on d = 10,
    frame on 18), with the step's data check on or off."""
    import dataclasses

    from prismstereo.matching.coop.coopcost import CostParams, sheared_costs
    from prismstereo.matching.coop.cooperative import CoopParams, build_segment_graph
    from prismstereo.matching.coop.pipeline import PairMaps, PairSetup, _bpasw_reliable, _PairEvidence, bpasw_volume
    from prismstereo.matching.coop.steps import PlaneLabels, StepParams, step_group_moves, step_sweep
    from prismstereo.matching.local.selection import right_winner
    from prismstereo.matching.segments.segmentation import SegmentationParams

    left, right, labels = _framed_print(seed)
    max_disp, slopes = 26, (-1.0, -0.5, 0.0, 0.5, 1.0)
    bvol = bpasw_volume(left, right, max_disp=max_disp)
    bright = right_winner(bvol, min_disp=0)
    brel, bdisp = _bpasw_reliable(bvol, bright, 0)
    maps = PairMaps(data=sheared_costs(left, right, max_disp=max_disp, slopes=slopes, radius=1),
                    reliable=np.ones(labels.shape, bool), initial=bdisp, bvol=bvol, bdisp=bdisp, brel=brel,
                    nonplanar=np.zeros(labels.shape, bool), evidence=brel, bright=bright)
    ev = _PairEvidence(left, right, min_disp=0, max_disp=max_disp, maps=maps,
                       params=PairSetup(coop=CoopParams(), segmentation=SegmentationParams(), planes=PlaneParams(),
                                         cost=CostParams(), slopes=slopes))
    state = PlaneLabels(labels=labels, index=build_segment_index(labels), graph=build_segment_graph(labels, left),
                        assign=np.array([0, 1, 1, 1], np.int32), planes=np.array([[0.0, 0.0, 10.0], [0.0, 0.0, 18.0]]),
                        own=np.full((4, 2), -1, np.int64), parent=np.arange(4, dtype=np.int64),
                        pairs=np.zeros((0, 2), np.int32))
    p = StepParams()
    if step == "sweep":  # every segment offered its sweep planes: the face's two cheapest are 10 and 18
        out = step_sweep(state, ev, dataclasses.replace(p, sweep=dataclasses.replace(p.sweep, frac=1.0, min_px=10,
                                                                                     data_check=check)))
    else:
        out = step_group_moves(state, ev, dataclasses.replace(
            p, group_moves=dataclasses.replace(p.group_moves, data_check=check)))
    return float(out.planes[out.assign[0], 2])


@pytest.mark.parametrize(("step", "seeds"), [("sweep", (0, 1)), ("group_moves", (0, 4))])
def test_a_large_repetitive_face_is_not_moved_onto_its_alias_by_its_frame(step: str, seeds: tuple[int, ...]) -> None:
    """The data check of the sweep and group-move steps: without it, the step moves the 2112-px printed face
    onto the alias plane of its nearer frame (the smoothness gain, and for the group move the frame hiding
    part of the face in the right view, outweigh a data term the print barely tells apart); with it (the
    default) the face keeps its plane, because its own data term does not support the move."""
    from prismstereo.matching.coop.steps import StepParams

    assert getattr(StepParams(), step).data_check  # the rule is on by default
    for seed in seeds:
        assert _face_plane_after(step, seed, check=False) == 18.0  # the unsafe move is taken without the rule
        assert _face_plane_after(step, seed, check=True) == 10.0


def test_unsupported_moves_need_a_lower_data_term_over_most_of_the_segment() -> None:
    """A move is supported when the segment's mean truncated pixel cost over the pixels both planes match
    inside the range and the view is lower under the new plane, and those pixels cover ``min_cover`` of it."""
    from prismstereo.matching.coop.steps import unsupported_moves

    h, w, nd = 10, 40, 30
    labels = np.zeros((h, w), np.int32)
    labels[:, 20:] = 1
    index = build_segment_index(labels)
    cost = np.ones((h, w, nd), np.float32)
    cost[:, :, 5] = 0.2  # both segments match best at d = 5
    cost[:, :, 15] = 0.1  # cheaper at d = 15, where only x >= 15 of segment 0 stays in the right view
    before = np.array([[0.0, 0.0, 5.0], [0.0, 0.0, 5.0]])
    to15 = np.array([[0.0, 0.0, 15.0]] * 2)
    kw = {"min_disp": 0, "slopes": None, "trunc": 1.5, "min_cover": 0.5}
    # segment 1 (x >= 20) keeps every pixel in the view: supported; segment 0 keeps 5 of its 20 columns
    assert list(unsupported_moves(index, before, to15, cost, **kw)) == [0]
    assert unsupported_moves(index, before, to15, cost, **{**kw, "min_cover": 0.2}).size == 0
    # to a dearer plane: neither; no move: nothing to check
    assert list(unsupported_moves(index, before, np.array([[0.0, 0.0, 9.0]] * 2), cost, **kw)) == [0, 1]
    assert unsupported_moves(index, before, before, cost, **kw).size == 0


def test_fallback_candidates_are_chosen_per_segment_by_their_evidence() -> None:
    """With several candidate maps a fallback segment keeps the first unless another's checked pixels cover a
    larger share of it by more than the margin; each segment on its own."""
    from prismstereo.errors import ConfigError
    from prismstereo.matching.coop.pipeline import segment_support_choice
    from prismstereo.matching.coop.steps import FallbackParams

    labels = np.zeros((10, 20), np.int32)
    labels[:, 10:] = 1
    labels[:, 15:] = 2
    first = np.zeros((10, 20), bool)
    first[:5] = True  # half of every segment
    other = np.zeros((10, 20), bool)
    other[:, 10:15] = True  # all of segment 1
    other[:6, 15:] = True  # 60 % of segment 2: within the margin of the first's 50 %
    where = np.ones((10, 20), bool)
    where[:, :2] = False
    pick = segment_support_choice(labels, where, [first, other], margin=0.2)
    assert (pick[labels == 0] == 0).all() and (pick[labels == 1] == 1).all() and (pick[labels == 2] == 0).all()
    pick = segment_support_choice(labels, where, [first, other], margin=0.05)
    assert (pick[labels == 2] == 1).all()
    for bad in ({"candidates": ()}, {"candidates": ("plane", "plane")}, {"candidates": ("median",)},
                {"margin": 1.5}):
        with pytest.raises(ConfigError, match="fallback"):
            FallbackParams(**bad)  # type: ignore[arg-type]


def test_fallback_can_take_the_sgm_map() -> None:
    """The ``sgm`` candidate: a segment whose BPASW map has no checked pixel takes the ``sgm`` matcher's map."""
    from prismstereo.matching.coop.steps import FallbackParams
    from prismstereo.matching.local.sgm import SGMMatcher

    d_true = 6
    h, w = 70, 100
    left, right, vol, local = _fallback_pair(3, h, w)
    state = _plane_state(np.zeros((h, w), np.int32), d_true + 3.0)
    wrong = np.full((h, w), d_true + 3.0, np.float32)
    evidence = np.zeros((h, w), bool)
    evidence[:20] = True
    ev = _fallback_evidence(left, right, vol, local, evidence)
    ev.bright = np.full((h, w), 15, np.int64)  # the BPASW check fails everywhere
    out = ev.fallback(state, wrong, FallbackParams(max_agreement=0.0, candidates=("bpasw", "sgm")))
    sgm = SGMMatcher().compute(left, right, max_disp=16).disparity
    np.testing.assert_array_equal(out, sgm)


def test_fallback_takes_sgm_where_the_bpasw_cost_is_flat() -> None:
    """A segment whose BPASW cost is flat (a guessed winner 3 px off, which BPASW's own check still keeps
    everywhere) takes the ``sgm`` map, which the share rule alone would not give it; ``flat_ratio`` 0: BPASW's."""
    from prismstereo.matching.coop.steps import FallbackParams
    from prismstereo.matching.local.sgm import SGMMatcher

    d_true = 6
    h, w = 70, 100
    left, right, _vol, _local = _fallback_pair(3, h, w)
    flat = np.ones((h, w, 17), np.float32)
    flat[:, :, d_true + 3] = 0.99  # peak ratio 0.01
    state = _plane_state(np.zeros((h, w), np.int32), d_true + 3.0)
    wrong = np.full((h, w), d_true + 3.0, np.float32)
    evidence = np.zeros((h, w), bool)
    evidence[:20] = True
    kw = {"max_agreement": 0.0, "candidates": ("bpasw", "sgm")}
    ev = _fallback_evidence(left, right, flat, wrong, evidence)
    out = ev.fallback(state, wrong, FallbackParams(**kw))  # type: ignore[arg-type]
    np.testing.assert_array_equal(out, SGMMatcher().compute(left, right, max_disp=16).disparity)
    ev = _fallback_evidence(left, right, flat, wrong, evidence)
    out = ev.fallback(state, wrong, FallbackParams(**kw, flat_ratio=0.0, contradicted_share=0.0))  # type: ignore[arg-type]
    assert np.mean(np.abs(out - (d_true + 3)) <= 1.0) > 0.9


def test_fallback_takes_sgm_where_the_two_checks_contradict() -> None:
    """A segment whose BPASW volume has a distinct minimum 3 px off (a radiometric bias moves it; BPASW's own
    check keeps it everywhere, its cost is not flat) while ``sgm``'s check keeps the true disparity: both checks
    hold on two disparities, so the segment takes ``sgm``'s map; ``contradicted_share`` 0: BPASW's."""
    from prismstereo.matching.coop.steps import FallbackParams
    from prismstereo.matching.local.sgm import SGMMatcher

    d_true = 6
    h, w = 70, 100
    left, right, _vol, _local = _fallback_pair(3, h, w)
    biased = np.ones((h, w, 17), np.float32)
    biased[:, :, d_true + 3] = 0.5  # peak ratio 1: a distinct minimum
    state = _plane_state(np.zeros((h, w), np.int32), d_true + 3.0)
    wrong = np.full((h, w), d_true + 3.0, np.float32)
    evidence = np.zeros((h, w), bool)
    evidence[:20] = True
    kw = {"max_agreement": 0.0, "candidates": ("bpasw", "sgm")}
    sgm = SGMMatcher().compute(left, right, max_disp=16)
    assert np.mean(np.asarray(sgm.valid) & (np.abs(sgm.disparity - d_true) <= 1.0)) > 0.5
    ev = _fallback_evidence(left, right, biased, wrong, evidence)
    out = ev.fallback(state, wrong, FallbackParams(**kw))  # type: ignore[arg-type]
    np.testing.assert_array_equal(out, sgm.disparity)
    ev = _fallback_evidence(left, right, biased, wrong, evidence)
    out = ev.fallback(state, wrong, FallbackParams(**kw, contradicted_share=0.0))  # type: ignore[arg-type]
    assert np.mean(np.abs(out - (d_true + 3)) <= 1.0) > 0.9
