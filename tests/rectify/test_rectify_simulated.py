"""Rectification of a rendered capture: the rectified images agree row by row at the true disparity."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import map_coordinates

from prismstereo.cameras import calibrate_rig
from prismstereo.config import thesis_biprism
from prismstereo.rectify import rectify_pair


def _ncc(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a - a.mean(), b - b.mean()
    return float((a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum()))


def test_rendered_capture_rows_align() -> None:
    sim = pytest.importorskip("prismstereo.simulate")
    rig = thesis_biprism(6.4)
    z_plane = 1500.0
    scene = sim.Scene(objects=(sim.Plane(center=(0.0, 0.0, z_plane), texture=sim.NoiseTexture(scale=8.0)),),
                      supersample=1)
    cap = sim.render_capture(rig, scene)
    views = calibrate_rig(rig)
    pair = rectify_pair(rig, views[0], views[1])
    left, right = (im.astype(np.float64).mean(axis=2) for im in pair.rectify_images(cap.image))
    vl, vr = pair.valid_masks()
    # left rectified pixels on a grid, their point on the plane, its right rectified pixel (same row)
    ys, xs = np.mgrid[40:pair.size[1] - 40:3, 40:pair.size[0] - 40:3]
    px = np.stack([xs.ravel(), ys.ravel()], axis=1).astype(np.float64)
    dirs = np.concatenate([px, np.ones((px.shape[0], 1))], axis=1) @ np.linalg.inv(pair.K).T @ pair.R
    s = (z_plane - pair.C_left[2]) / dirs[:, 2]
    X = pair.C_left + s[:, None] * dirs
    pr = pair.project(X, "right")
    assert np.allclose(pr[:, 1], px[:, 1], atol=1e-6)
    keep = vl[px[:, 1].astype(int), px[:, 0].astype(int)] & (pr[:, 0] > 2) & (pr[:, 0] < pair.size[0] - 3)
    keep[keep] &= vr[np.rint(pr[keep, 1]).astype(int), np.rint(pr[keep, 0]).astype(int)]
    assert keep.sum() > 5000
    px, pr = px[keep], pr[keep]
    lv = left[px[:, 1].astype(int), px[:, 0].astype(int)]
    scores = []
    for dy in (-1.0, 0.0, 1.0):
        rv = map_coordinates(right, [pr[:, 1] + dy, pr[:, 0]], order=1)
        scores.append(_ncc(lv, rv))
    assert scores[1] > 0.9
    # sub-pixel peak of the row offset (parabola through −1, 0, +1): the rows agree within 0.2 px
    a, b, c = scores
    peak = 0.5 * (a - c) / (a - 2 * b + c)
    print(f"row NCC at dy = -1, 0, +1: {scores}; peak offset {peak:+.3f} px")
    assert abs(peak) < 0.2
