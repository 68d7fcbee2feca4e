"""Plane-label refinements of the steps: fine segments' labels and the per-pixel boundary choice."""

from __future__ import annotations

import numba
import numpy as np

from prismstereo.matching.coop.refine import _pair_ranks, boundary_pixel_planes


def test_pair_ranks_number_the_distinct_pairs_in_lexicographic_order() -> None:
    rng = np.random.default_rng(0)
    a = rng.integers(0, 30, 5000)
    b = rng.integers(0, 500, 5000)
    _, inv = np.unique(a * 500 + b, return_inverse=True)
    assert np.array_equal(_pair_ranks(a, b), inv.ravel())


def test_boundary_choice_does_not_depend_on_the_number_of_threads() -> None:
    rng = np.random.default_rng(1)
    h, w, nd = 30, 40, 16
    seg = (np.arange(w)[None, :] // 7 + 6 * (np.arange(h)[:, None] // 9)).astype(np.int32)
    k = int(seg.max()) + 1
    planes = np.column_stack([rng.normal(0, 0.05, 2 * k), rng.normal(0, 0.05, 2 * k), rng.uniform(2, 12, 2 * k)])
    assign = np.arange(k, dtype=np.int32)
    assign2 = np.column_stack([np.arange(k, 2 * k), np.full(k, -1)]).astype(np.int32)
    cost = rng.random((h, w, nd)).astype(np.float32) * 20
    active = rng.random((h, w)) > 0.2
    dref = rng.uniform(2, 12, (h, w)).astype(np.float32)
    args = (seg, assign, planes, cost, 0, 3, 1.0, active, dref, 3.0, active | (rng.random((h, w)) > 0.5), assign2)
    prev = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = boundary_pixel_planes(*args)
        numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
        two = boundary_pixel_planes(*args)
    finally:
        numba.set_num_threads(prev)
    own = (planes[assign[seg], 0] * np.arange(w)[None, :] + planes[assign[seg], 1] * np.arange(h)[:, None]
           + planes[assign[seg], 2]).astype(np.float32)
    assert (one != own).mean() > 0.05  # neighbours' planes do win somewhere
    assert np.array_equal(one, two)
