"""The one-page report of a depth run (``report.png``).

Six panels: the capture, the rectified pair side by side with epipolar lines, the disparity (px), the
depth (mm, with a colour bar), a rendered view of the point cloud, and the run's numbers (timings,
counts, accuracy against ground truth when known).
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from prismstereo.io.atomic import atomic_path

__all__ = ["epipolar_figure", "write_depth_report"]


def epipolar_figure(left: np.ndarray, right: np.ndarray, *, n_lines: int = 12, gap: int = 8) -> np.ndarray:
    """Rectified pair side by side with ``n_lines`` horizontal epipolar lines: (h, 2w + gap, 3) uint8."""
    lt = left if left.ndim == 3 else np.repeat(left[:, :, None], 3, axis=2)
    rt = right if right.ndim == 3 else np.repeat(right[:, :, None], 3, axis=2)
    h, w = lt.shape[:2]
    out = np.full((h, 2 * w + gap, 3), 255, dtype=np.uint8)
    out[:, :w] = lt
    out[:, w + gap:] = rt
    colors = np.array([[255, 40, 40], [40, 200, 40], [40, 120, 255], [240, 200, 0]], dtype=np.uint8)
    for i, y in enumerate(np.linspace(0, h - 1, n_lines + 2)[1:-1].astype(int)):
        out[y, :] = colors[i % len(colors)]
    return out


def _range_line(summary: dict[str, Any], cfg: dict[str, Any]) -> str:
    rng = summary.get("depth_range_mm") or cfg.get("depth_range")
    if not rng:
        return "depth range: ?"
    src = summary.get("depth_range_source", "given")
    return f"depth range: {rng[0]:.0f}–{rng[1]:.0f} mm ({src})"


def _stats_text(summary: dict[str, Any]) -> str:
    cfg = summary.get("config", {})
    lines = [
        f"method: {cfg.get('method')}   triangulation: {cfg.get('triangulation')}",
        f"calibration: {cfg.get('calibration')}   views (L,R): {summary.get('faces', {}).get('left')},"
        f"{summary.get('faces', {}).get('right')}",
        _range_line(summary, cfg),
        f"disparity search: {summary.get('disparity_range')} px",
        f"baseline: {summary.get('baseline_mm', float('nan')):.2f} mm",
    ]
    counts = summary.get("counts", {})
    if counts:
        lines.append(f"points: {counts.get('points')} of {counts.get('region_pixels')} px in view")
    t = summary.get("timings_s", {})
    if t:
        import textwrap

        text = "seconds: " + ", ".join(f"{k} {v:.2f}" for k, v in t.items() if k != "validate")
        lines += textwrap.wrap(text, width=58, subsequent_indent="  ")
    warns = summary.get("warnings") or []
    if warns:
        import textwrap

        lines += ["", "WARNINGS:"]
        for w in warns:
            lines += textwrap.wrap(w, width=58, initial_indent="- ", subsequent_indent="  ")
    acc = summary.get("accuracy")
    if acc:
        lines += [
            "",
            "accuracy vs ground truth:",
            f"  median rel. depth error: {100 * acc['median_rel']:.3f} %",
            f"  95th percentile: {100 * acc['p95_rel']:.3f} %",
            f"  within 1 %: {100 * acc['within_1pct']:.1f} %",
            f"  coverage of common view: {100 * acc['coverage']:.1f} %",
        ]
    return "\n".join(lines)


def write_depth_report(
    path: str | os.PathLike[str],
    *,
    capture: np.ndarray,
    left: np.ndarray,
    right: np.ndarray,
    disparity: np.ndarray,
    depth: np.ndarray,
    points: np.ndarray,
    colors: np.ndarray,
    summary: dict[str, Any],
    title: str = "prismstereo depth",
) -> None:
    """Write the report sheet as PNG (atomically).

    Parameters
    ----------
    path : output PNG path.
    capture : (H, W, 3) uint8 — the real capture.
    left, right : (h, w, 3) uint8 — rectified pair.
    disparity : (h, w) float — px, NaN invalid.
    depth : (h, w) float — mm, NaN invalid.
    points : (N, 3) float — world points, mm; colors : (N, 3) uint8.
    summary : dict — the run summary (``run.json`` content).
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 3, figsize=(16, 9.5), dpi=90)
    ax = axes.ravel()
    ax[0].imshow(capture)
    ax[0].set_title("capture")
    ax[1].imshow(epipolar_figure(left, right))
    ax[1].set_title("rectified pair (left | right) with epipolar lines")
    finite_d = np.isfinite(disparity)
    d_masked = np.ma.masked_invalid(disparity)
    if finite_d.any():
        dlo, dhi = np.percentile(disparity[finite_d], [1, 99])
    else:
        dlo, dhi = 0.0, 1.0
    cmap = plt.get_cmap("turbo").with_extremes(bad="black")
    im = ax[2].imshow(d_masked, cmap=cmap, vmin=dlo, vmax=dhi)
    ax[2].set_title("disparity (px), rectified left view")
    fig.colorbar(im, ax=ax[2], fraction=0.046, pad=0.04, label="px")
    finite_z = np.isfinite(depth)
    if finite_z.any():
        zlo, zhi = np.percentile(depth[finite_z], [1, 99])
    else:
        zlo, zhi = 0.0, 1.0
    cmap_r = plt.get_cmap("turbo_r").with_extremes(bad="black")
    im = ax[3].imshow(np.ma.masked_invalid(depth), cmap=cmap_r, vmin=zlo, vmax=zhi)
    ax[3].set_title("depth Z (mm), rectified left view")
    fig.colorbar(im, ax=ax[3], fraction=0.046, pad=0.04, label="mm")
    ax[4].remove()  # a 3-D panel with labelled world axes instead of a flat render
    ax3 = fig.add_subplot(2, 3, 5, projection="3d")
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if pts.shape[0] > 20_000:  # enough to see the shape; matplotlib's 3-D scatter is slow
        pick = np.random.default_rng(0).choice(pts.shape[0], 20_000, replace=False)
        pts, cols = pts[pick], np.asarray(colors)[pick]
    else:
        cols = np.asarray(colors)
    if pts.shape[0]:
        # plotted as (X, Z, -Y): depth runs into the picture, +Y (down in the camera) points down
        ax3.scatter(pts[:, 0], pts[:, 2], -pts[:, 1], c=cols.reshape(-1, 3) / 255.0, s=0.5, depthshade=False)
    ax3.set_xlabel("X (mm)")
    ax3.set_ylabel("Z (mm)")
    ax3.set_zlabel("−Y (mm)")
    ax3.view_init(elev=20, azim=-65)
    ax3.set_title(f"point cloud ({points.shape[0]} points, world frame)")
    ax[5].text(0.0, 1.0, _stats_text(summary), va="top", ha="left", family="monospace", fontsize=9,
               transform=ax[5].transAxes)
    ax[5].set_title("run")
    for i, a in enumerate(ax):
        if i == 4:
            continue
        a.set_xticks([])
        a.set_yticks([])
    ax[5].axis("off")
    fig.suptitle(title)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
