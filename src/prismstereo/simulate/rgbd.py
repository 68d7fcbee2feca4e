"""Photographed scenes for the simulator: colour + depth maps (RGB-D), their files and their mesh.

* :func:`depth_from_disparity` — Z = baseline · f / (d + doffs) (Middlebury's calibration).
* :func:`read_depth_map`, :func:`read_disparity_map` — depth or disparity files (PFM, 8/16-bit PNG).
* :func:`middlebury_rgbd` — the left view of a Middlebury folder (2005/2006 ``manifest.json`` with a
  ``depth`` block, or 2014 ``calib.txt``) as an :class:`~prismstereo.simulate.scene.RGBDSurface`.
* :func:`surface_mesh` — the filled depth map and the per-triangle "ground truth unknown" flags that the
  ray-intersection kernel (:mod:`.kernels`) reads.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np
from scipy import ndimage

from prismstereo.errors import ConfigError, ImageError, PrismStereoError
from prismstereo.io import read_image, read_pfm
from prismstereo.simulate.scene import RGBDSurface

__all__ = ["depth_from_disparity", "fill_unknown_depth", "middlebury_rgbd", "read_depth_map",
           "read_disparity_map", "surface_mesh"]


def depth_from_disparity(disparity: np.ndarray, *, focal_px: float, baseline_mm: float,
                         doffs_px: float = 0.0) -> np.ndarray:
    """Depth of a rectified stereo pair's disparity map: Z = baseline · f / (d + doffs).

    Parameters
    ----------
    disparity : (H, W) float array
        Disparity in px; NaN/inf = unknown.
    focal_px : float
        Focal length, px (> 0).
    baseline_mm : float
        Baseline, mm (> 0).
    doffs_px : float
        x-difference of the two principal points, px (Middlebury's ``doffs``).

    Returns
    -------
    (H, W) float64 depth, mm; NaN where unknown or where d + doffs ≤ 0.
    """
    for key, v, pos in (("focal_px", focal_px, True), ("baseline_mm", baseline_mm, True),
                        ("doffs_px", doffs_px, False)):
        if isinstance(v, bool) or not isinstance(v, int | float | np.floating) or not math.isfinite(v) \
                or (pos and v <= 0):
            what = "a positive number" if pos else "a finite number"
            raise ConfigError(f"{key}: expected {what}, got {v!r}")
    d = np.asarray(disparity, dtype=np.float64) + float(doffs_px)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = float(baseline_mm) * float(focal_px) / d
    return np.where(np.isfinite(d) & (d > 0), z, np.nan)


def _read_map(path: str | os.PathLike[str], what: str) -> np.ndarray:
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"{what}: expected an existing PFM or PNG file, got {str(p)!r} (no such file)")
    try:
        if p.suffix.lower() == ".pfm":
            return np.asarray(read_pfm(p), dtype=np.float64)
        img = read_image(p, gray=True)
    except (ImageError, PrismStereoError, ValueError, OSError) as exc:
        raise ConfigError(f"{what}: cannot read {str(p)!r}: {exc}") from None
    return np.asarray(img, dtype=np.float64)


def read_depth_map(path: str | os.PathLike[str], *, scale: float = 1.0) -> np.ndarray:
    """Depth map file → (H, W) float64 mm (value × ``scale``); 0, NaN, inf = unknown.

    PFM holds floats; an 8- or 16-bit grey PNG holds integers (e.g. mm with scale 1, or 0.1 mm with 0.1).
    """
    z = _read_map(path, "depth") * float(scale)
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(z) & (z > 0), z, np.nan)


def read_disparity_map(path: str | os.PathLike[str], *, scale: float = 1.0) -> np.ndarray:
    """Disparity map file → (H, W) float64 px (value / ``scale``); NaN, inf and, in a PNG, 0 = unknown.

    ``scale`` is the file's scale factor (Middlebury 2005/2006 PNGs at third size store 3 × d).
    """
    p = Path(path)
    d = _read_map(p, "disparity")
    if p.suffix.lower() != ".pfm":
        d = np.where(d > 0, d, np.nan)
    d = d / float(scale)
    return np.where(np.isfinite(d), d, np.nan)


def _parse_calib(text: str, where: str) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for line in text.splitlines():
        if "=" not in line:
            continue
        key, val = (s.strip() for s in line.split("=", 1))
        if val.startswith("["):
            rows = [r.split() for r in val.strip("[]").split(";")]
            try:
                out[key] = np.array([[float(x) for x in r] for r in rows])
            except ValueError:
                raise ConfigError(f"{where} {key}: expected a 3×3 matrix of numbers, got {val!r}") from None
        else:
            try:
                out[key] = float(val)
            except ValueError:
                out[key] = val
    return out


def middlebury_rgbd(folder: str | os.PathLike[str], *, center_depth: float, scale: float | None = None,
                    width: float | None = None, jump: float = 0.02) -> RGBDSurface:
    """The left view of a Middlebury scene folder with its true depth, placed in the world.

    Two layouts: 2005/2006 (this project's ``middlebury-extra``: ``left.png``, ``disp_left.png`` and
    ``manifest.json`` with ``ground_truth.scale_factor`` and a ``depth`` block ``focal_px``,
    ``baseline_mm``, ``doffs_px``, principal point at the image centre) and MiddEval3 2014 (``im0.png``,
    ``disp0GT.pfm``, ``calib.txt`` with ``cam0``, ``baseline``, ``doffs``).

    Parameters
    ----------
    folder : path
    center_depth, scale, width, jump
        As :meth:`RGBDSurface.placed`.

    Raises
    ------
    ConfigError
        If the folder has neither layout, a file is missing or unreadable, or the calibration is invalid.
    """
    f = Path(folder)
    if (f / "calib.txt").is_file():
        calib = _parse_calib((f / "calib.txt").read_text(), f"{f / 'calib.txt'}")
        cam0 = calib.get("cam0")
        if not isinstance(cam0, np.ndarray) or cam0.shape != (3, 3):
            raise ConfigError(f"{f / 'calib.txt'} cam0: expected a 3×3 intrinsic matrix, got {cam0!r}")
        for key in ("baseline", "doffs"):
            if not isinstance(calib.get(key), float):
                raise ConfigError(f"{f / 'calib.txt'} {key}: expected a number, got {calib.get(key)!r}")
        color_file, disp_file = f / "im0.png", f / "disp0GT.pfm"
        focal, cxy = (float(cam0[0, 0]), float(cam0[1, 1])), (float(cam0[0, 2]), float(cam0[1, 2]))
        baseline, doffs, factor = float(calib["baseline"]), float(calib["doffs"]), 1.0
    elif (f / "manifest.json").is_file():
        try:
            man = json.loads((f / "manifest.json").read_text())
            dep = man["depth"]
            baseline, doffs = float(dep["baseline_mm"]), float(dep["doffs_px"])
            focal = (float(dep["focal_px"]), float(dep["focal_px"]))
            factor = float(man.get("ground_truth", {}).get("scale_factor", 1.0))
            color_file = f / man.get("left", "left.png")
            disp_file = f / man.get("ground_truth", {}).get("file", "disp_left.png")
        except (KeyError, TypeError, ValueError) as exc:
            raise ConfigError(f"{f / 'manifest.json'}: expected a 'depth' block with focal_px, baseline_mm and "
                              f"doffs_px, got an error at {exc}") from None
        cxy = None
    else:
        raise ConfigError(f"middlebury folder: expected calib.txt (2014) or manifest.json (2005/2006) in "
                          f"{str(f)!r}, got neither")
    try:
        image = read_image(color_file)
    except ImageError as exc:
        raise ConfigError(f"color: {exc}") from None
    disp = read_disparity_map(disp_file, scale=factor)
    depth = depth_from_disparity(disp, focal_px=focal[0], baseline_mm=baseline, doffs_px=doffs)
    source: dict[str, Any] = {"color": str(color_file.resolve()), "disparity": str(disp_file.resolve()),
                              "disparity_scale": factor, "baseline": baseline, "doffs": doffs}
    return RGBDSurface.placed(image, depth, focal=focal, principal_point=cxy, center_depth=center_depth,
                              scale=scale, width=width, jump=jump, name=f.name, source=source)


def fill_unknown_depth(depth: np.ndarray) -> np.ndarray:
    """Fill NaN depths for rendering: the farther of the nearest known depths left and right in the row
    (occluded pixels of a stereo depth map belong to the background), else the nearest known pixel.

    Parameters
    ----------
    depth : (H, W) float, NaN = unknown (at least one known).

    Returns
    -------
    (H, W) float64 without NaN.
    """
    z = np.asarray(depth, dtype=np.float64)
    known = np.isfinite(z)
    if known.all():
        return z.copy()
    h, w = z.shape
    cols = np.arange(w)[None, :]
    rows = np.arange(h)[:, None]
    left = np.maximum.accumulate(np.where(known, cols, -1), axis=1)
    right = np.minimum.accumulate(np.where(known, cols, w)[:, ::-1], axis=1)[:, ::-1]
    zl = np.where(left >= 0, z[rows, np.clip(left, 0, w - 1)], np.nan)
    zr = np.where(right < w, z[rows, np.clip(right, 0, w - 1)], np.nan)
    out = np.where(known, z, np.fmax(zl, zr))
    rest = ~np.isfinite(out)
    if rest.any():  # rows without any known depth: the nearest known pixel
        _, (iy, ix) = ndimage.distance_transform_edt(~known, return_indices=True)
        out[rest] = z[iy[rest], ix[rest]]
    return out


def surface_mesh(surface: RGBDSurface) -> tuple[np.ndarray, np.ndarray]:
    """The kernel's view of an RGB-D surface: filled depths and the unknown-triangle flags.

    Returns
    -------
    depth : (H, W) float64
        Source depths with the unknown ones filled (:func:`fill_unknown_depth`), mm.
    flags : (H − 1, W − 1) uint8
        Per cell: bit 0 set = triangle (u, v)–(u+1, v)–(u+1, v+1) has no ground truth, bit 1 = triangle
        (u, v)–(u+1, v+1)–(u, v+1); a triangle has none when a vertex's depth is unknown or its three depths
        spread by more than ``surface.jump`` times their smallest (skin across a depth jump).
    """
    raw = surface.depth
    z = fill_unknown_depth(raw)
    unk = ~np.isfinite(raw)
    z00, z10, z01, z11 = z[:-1, :-1], z[:-1, 1:], z[1:, :-1], z[1:, 1:]
    u00, u10, u01, u11 = unk[:-1, :-1], unk[:-1, 1:], unk[1:, :-1], unk[1:, 1:]

    def bad(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
        lo = np.minimum(np.minimum(a, b), c)
        hi = np.maximum(np.maximum(a, b), c)
        return np.asarray((hi - lo) > surface.jump * lo)

    t0 = bad(z00, z10, z11) | u00 | u10 | u11
    t1 = bad(z00, z11, z01) | u00 | u11 | u01
    flags = (t0.astype(np.uint8) | (t1.astype(np.uint8) << 1)).astype(np.uint8)
    return np.ascontiguousarray(z), np.ascontiguousarray(flags)
