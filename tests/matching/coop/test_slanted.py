"""Slanted-support-window cost (PatchMatch Stereo's cost, Bleyer et al. 2011) on a synthetic slanted plane."""

from __future__ import annotations

import cv2
import numpy as np

from prismstereo.matching.coop.slanted import plane_cost

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
