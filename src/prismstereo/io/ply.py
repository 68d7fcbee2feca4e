"""PLY point clouds (plyfile): float x y z in mm, uchar red green blue, optional float per-vertex properties."""

from __future__ import annotations

import os
from collections.abc import Mapping

import numpy as np
from plyfile import PlyData, PlyElement

from prismstereo.errors import ImageError
from prismstereo.io.atomic import atomic_path


def write_ply(
    path: str | os.PathLike[str],
    points: np.ndarray,
    colors: np.ndarray | None = None,
    *,
    binary: bool = True,
    properties: Mapping[str, np.ndarray] | None = None,
) -> None:
    """Write N×3 points (mm), optional N×3 uint8 RGB colours and float properties as a PLY file, atomically.

    ``properties`` maps a vertex property name (e.g. ``confidence``) to N values, written as float32 after
    the colours.
    """
    pts = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    fields = [("x", "f4"), ("y", "f4"), ("z", "f4")]
    if colors is not None:
        cols = np.asarray(colors).reshape(-1, 3)
        if cols.shape[0] != pts.shape[0]:
            raise ImageError(f"expected one colour per point ({pts.shape[0]}), got {cols.shape[0]}")
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    extra = {name: np.asarray(v, dtype=np.float32).reshape(-1) for name, v in (properties or {}).items()}
    for name, v in extra.items():
        if v.shape[0] != pts.shape[0] or name in ("x", "y", "z", "red", "green", "blue"):
            raise ImageError(f"expected a new vertex property {name!r} with one value per point ({pts.shape[0]}), "
                             f"got {v.shape[0]} values")
        fields.append((name, "f4"))
    vertex = np.empty(pts.shape[0], dtype=fields)
    vertex["x"], vertex["y"], vertex["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
    if colors is not None:
        cols = np.clip(cols, 0, 255).astype(np.uint8)
        vertex["red"], vertex["green"], vertex["blue"] = cols[:, 0], cols[:, 1], cols[:, 2]
    for name, v in extra.items():
        vertex[name] = v
    ply = PlyData([PlyElement.describe(vertex, "vertex")], text=not binary, byte_order="<")
    with atomic_path(path) as tmp:
        ply.write(str(tmp))


def read_ply(path: str | os.PathLike[str]) -> tuple[np.ndarray, np.ndarray | None]:
    """Read a PLY file: (N×3 float32 points, N×3 uint8 colours or None)."""
    ply = PlyData.read(str(path))
    v = ply["vertex"].data
    pts = np.stack([v["x"], v["y"], v["z"]], axis=1).astype(np.float32)
    names = v.dtype.names or ()
    cols = np.stack([v["red"], v["green"], v["blue"]], axis=1).astype(np.uint8) if "red" in names else None
    return pts, cols
