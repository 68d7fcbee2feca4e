"""Sub-pixel refinement along the epipolar curve: the right window on the rows where the match lies."""

from __future__ import annotations

import numpy as np
import pytest

from prismstereo.depth.confidence import confident_matches
from prismstereo.depth.refine import refine_disparity


def _diagonal_pair(d: float, dy: float, *, h: int = 60, w: int = 140) -> tuple[np.ndarray, np.ndarray]:
    """Two diagonal gratings, and the same texture whose match of left (x, y) is (x − d, y + dy) (both
    evaluated exactly)."""

    def texture(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return (128 + 60 * np.sin(0.45 * (x + y)) + 20 * np.sin(0.23 * (x - 2.0 * y))).astype(np.float32)

    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    return texture(xx, yy), texture(xx + d, yy - dy)


def test_row_offset_removes_the_bias_a_vertical_offset_gives_a_diagonal_texture() -> None:
    d, dy = 9.3, 0.3
    left, right = _diagonal_pair(d, dy)
    init = np.full(left.shape, 9.0, dtype=np.float32)
    inner = (slice(10, -10), slice(25, -25))
    same_row, _ = refine_disparity(left, right, init, radius=5)
    rows = np.full(left.shape, dy)
    along, conf = refine_disparity(left, right, init, radius=5, row_offset=rows)
    # on stripes at 45° a row offset of dy reads as a disparity offset of about dy
    assert abs(float(np.median(same_row[inner])) - d) > 0.15
    assert abs(float(np.median(along[inner])) - d) < 0.02
    assert np.nanmedian(conf[inner]) > 0.98
    # a zero offset is the same as none
    zero, _ = refine_disparity(left, right, init, radius=5, row_offset=np.zeros(left.shape))
    assert np.array_equal(zero, same_row)


def test_the_left_right_check_reads_the_right_view_on_its_own_curve() -> None:
    """With the epipolar offsets the right view's refinement (mirrored) agrees with the left's, so the
    sub-pixel check keeps the matches; on the left rows alone it does not see the same disparity."""

    class _Constant:
        def __init__(self, dy: float) -> None:
            self.dy = dy

        def row_offset(self, ys, xs, d):  # type: ignore[no-untyped-def]
            return np.where(np.isfinite(d), self.dy, np.nan)

        def row_offset_map(self, disparity):  # type: ignore[no-untyped-def]
            return np.where(np.isfinite(disparity), np.float32(self.dy), np.float32(np.nan))

    d, dy = 9.3, 0.3
    left, right = _diagonal_pair(d, dy)
    init = np.full(left.shape, 9.0, dtype=np.float32)
    inner = (slice(10, -10), slice(25, -25))
    disp, conf = confident_matches(left, right, init, radius=5, min_confidence=0.5, max_lr_gap=0.1,
                                   epipolar=_Constant(dy))  # type: ignore[arg-type]
    assert np.mean(np.isfinite(disp[inner])) > 0.95
    assert abs(float(np.nanmedian(disp[inner])) - d) < 0.02


@pytest.mark.slow
def test_rendered_triprism_refines_closer_to_exact_correspondences() -> None:
    """A tri-prism capture of a plane with a grating (rendered by exact refraction): refined from the
    rounded true disparities, the disparities along the epipolar curves are closer to the exact
    correspondences than those on the left pixels' rows."""
    sim = pytest.importorskip("prismstereo.simulate")
    from prismstereo.apps.demo import scaled_rig
    from prismstereo.config import thesis_triprism
    from prismstereo.depth import DepthConfig
    from prismstereo.depth import pipeline as pl
    from prismstereo.optics import project_exact, trace_pixels

    rig = scaled_rig(thesis_triprism(), 2)
    cfg = pl.validate_config(rig, DepthConfig(method="sad"))
    views = pl.virtual_cameras(rig, cfg)
    pair = pl.rectify_geometry(rig, views, cfg)
    z = 1500.0
    n = 256
    yy, xx = np.mgrid[0:n, 0:n] / n
    img = 0.5 + 0.2 * np.sin(2 * np.pi * (9.0 * xx + 7.0 * yy)) + 0.12 * np.sin(2 * np.pi * (5.0 * xx - 11.0 * yy))
    tex = sim.ImageTexture(image=np.repeat((np.clip(img, 0, 1) * 255).astype(np.uint8)[..., None], 3, 2),
                           size=(90.0, 90.0))
    cap = sim.render_capture(rig, sim.Scene(objects=(sim.Plane(center=(0.0, 0.0, z), texture=tex),), supersample=1))
    left, right = pl.rectify_capture(pair, cap.image)
    vl, vr = pair.valid_masks()
    ys, xs = np.nonzero(vl)
    px = np.stack([xs, ys], axis=1).astype(np.float64)
    rays = trace_pixels(rig, pair.rectified_to_real(px, "left"), face=int(pair.left_face), bounded=False)
    pr, ok = project_exact(rays.point_at_depth(z), rig, int(pair.right_face))
    r = pair.real_to_rectified(pr, "right")
    h, w = vl.shape
    ri, ci = np.rint(r[:, 1]).astype(np.int64), np.rint(r[:, 0]).astype(np.int64)
    ok &= (ri >= 0) & (ri < h) & (ci >= 0) & (ci < w)
    ok[ok] &= vr[ri[ok], ci[ok]]
    ys, xs, d_true = ys[ok], xs[ok], (xs - r[:, 0])[ok]
    assert ys.size > 5000
    init = np.full((h, w), np.nan, dtype=np.float32)
    init[ys, xs] = np.rint(d_true)
    errs = {}
    for name, epi in (("rows", None), ("curves", pl.epipolar_curves(pair))):
        disp, _ = confident_matches(left, right, init, min_confidence=0.5, valid_left=vl, valid_right=vr,
                                    epipolar=epi)
        e = np.abs(disp[ys, xs] - d_true)
        errs[name] = float(np.median(e[np.isfinite(e)]))
    assert errs["curves"] < 0.75 * errs["rows"], errs


def test_cut_windows_follow_the_curve_near_a_horizontal_edge_of_the_right_view() -> None:
    """Next to the right view's top edge the windows are cut to the rows both views have; with the row
    offset they are refined there as accurately as inside, and as many as without it."""
    d, dy = 9.3, -0.3
    left, right = _diagonal_pair(d, dy)
    valid_r = np.ones(left.shape, dtype=bool)
    valid_r[:15] = False
    init = np.full(left.shape, 9.0, dtype=np.float32)
    band = (slice(12, 22), slice(25, -25))  # windows reach above row 15
    kw = dict(radius=5, min_pixels=49, valid_left=np.ones(left.shape, dtype=bool), valid_right=valid_r)
    along, conf = refine_disparity(left, right, init, row_offset=np.full(left.shape, dy), **kw)
    _, conf_rows = refine_disparity(left, right, init, **kw)
    assert np.isfinite(conf[band]).sum() >= np.isfinite(conf_rows[band]).sum() > 0
    refined = np.isfinite(conf[band])
    assert np.all(np.abs(along[band][refined] - d) < 0.05)
