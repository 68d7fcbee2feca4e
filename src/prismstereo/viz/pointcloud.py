"""A rendered view of a coloured point cloud (software splatting with a z-buffer, no OpenGL needed)."""

from __future__ import annotations

import numpy as np

from prismstereo.cameras.pinhole import rotation_from_axis

__all__ = ["render_point_cloud"]


def render_point_cloud(
    points: np.ndarray,
    colors: np.ndarray,
    *,
    size: tuple[int, int] = (480, 360),
    yaw_deg: float = -25.0,
    pitch_deg: float = -12.0,
    point_size: int = 2,
    background: tuple[int, int, int] = (255, 255, 255),
    max_points: int = 300_000,
    seed: int = 0,
) -> np.ndarray:
    """Render a point cloud seen from a virtual camera orbiting its centre.

    An orthographic view from the real camera's side, turned by ``yaw_deg`` about the vertical axis and
    ``pitch_deg`` about the horizontal one, framed on the cloud; points are splatted as
    ``point_size``-pixel squares, nearest on top.

    Parameters
    ----------
    points : (N, 3) array
        World points, mm (+X right, +Y down, +Z forward, docs/conventions.md).
    colors : (N, 3) uint8 array
        RGB per point.
    size : (width, height)
        Output size in pixels.
    yaw_deg, pitch_deg : float
        Orbit angles of the viewpoint, degrees.
    point_size : int
    background : RGB
    max_points : int
        Random subsample above this many points (keeps the render fast).

    Returns
    -------
    (height, width, 3) uint8 RGB image.
    """
    w, h = size
    img = np.empty((h, w, 3), dtype=np.uint8)
    img[:] = np.asarray(background, dtype=np.uint8)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    cols = np.asarray(colors).reshape(-1, 3).astype(np.uint8)
    ok = np.all(np.isfinite(pts), axis=1)
    pts, cols = pts[ok], cols[ok]
    if pts.shape[0] == 0:
        return img
    if pts.shape[0] > max_points:
        idx = np.random.default_rng(seed).choice(pts.shape[0], max_points, replace=False)
        pts, cols = pts[idx], cols[idx]
    centre = np.median(pts, axis=0)
    yaw, pitch = np.radians(yaw_deg), np.radians(pitch_deg)
    # viewing direction: +Z turned by yaw about Y, then by pitch about X; orthographic view fitted to the
    # 1–99 % extent of the projected cloud
    view = np.array([np.sin(yaw) * np.cos(pitch), -np.sin(pitch), np.cos(yaw) * np.cos(pitch)])
    R = rotation_from_axis(view)
    xc = (pts - centre) @ R.T
    lo, hi = np.percentile(xc[:, :2], [1, 99], axis=0)
    span = np.maximum(hi - lo, 1e-9)
    scale = 0.9 * min(w / span[0], h / span[1])
    mid = (lo + hi) / 2.0
    u = np.rint((xc[:, 0] - mid[0]) * scale + w / 2.0).astype(np.int64)
    v = np.rint((xc[:, 1] - mid[1]) * scale + h / 2.0).astype(np.int64)
    order = np.argsort(-xc[:, 2])  # far first, near last (near wins)
    u, v, cols = u[order], v[order], cols[order]
    r = max(1, int(point_size))
    for dy in range(r):
        for dx in range(r):
            uu, vv = u + dx - r // 2, v + dy - r // 2
            inside = (uu >= 0) & (uu < w) & (vv >= 0) & (vv < h)
            img[vv[inside], uu[inside]] = cols[inside]
    return img
