"""Slanted-support-window cost (PatchMatch Stereo's cost, Bleyer et al. 2011) on a synthetic slanted plane."""

from __future__ import annotations

import cv2
import numpy as np

from prismstereo.matching.slanted import plane_cost, refine_plane_labels, refine_segment_planes

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


def test_segment_plane_refinement_recovers_the_slant() -> None:
    left, right = _pair()
    h, w = left.shape[:2]
    order = np.arange(h * w, dtype=np.int64)
    starts = np.array([0, h * w], np.int64)
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    dc = A * cx + B * cy + C
    init = np.array([[0.0, 0.0, dc + 0.6]])  # fronto-parallel, 0.6 px off at the centre
    ref, c0, c1 = refine_segment_planes(left, right, order, starts, init, min_disp=0, max_disp=60, max_px=64)
    assert c1[0] < c0[0]
    # a local (pattern) search: closer to the true slant than the fronto-parallel start
    assert abs(ref[0, 0] - A) < 0.05 and abs(ref[0, 1] - B) < B
    assert abs(ref[0, 0] * cx + ref[0, 1] * cy + ref[0, 2] - dc) < 0.6
    # the per-pixel refinement picks the true plane over a fronto-parallel one where both are offered
    planes = np.array([[0.0, 0.0, dc], [A, B, C]])
    segs = (np.arange(w)[None, :] >= w // 2).astype(np.int32).repeat(h, axis=0)
    lab = refine_plane_labels(left, right, segs, np.array([0, 1], np.int32), planes, min_disp=0, max_disp=60,
                              seg_radius=w, iterations=0)
    assert (lab[16:-16, 40:-16] == 1).mean() > 0.95
