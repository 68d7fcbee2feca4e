"""Middlebury v2 scenes (Tsukuba, Venus, Teddy, Cones): loading, evaluation and a whole-method harness.

The data live outside the repository (``../shared/data/middlebury``; see its README): ``left.png``,
``right.png``, ``disp_left.png`` (ground truth × scale, 0 = unknown) and the v2 masks ``nonocc``, ``all``,
``disc`` (255 = evaluated).
"""

from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from prismstereo.errors import ConfigError, ImageError
from prismstereo.evaluation.metrics import bad_pixel_rate, mean_abs_error

log = logging.getLogger(__name__)

__all__ = [
    "MASKS",
    "SCENES",
    "MiddleburyScene",
    "default_data_dir",
    "evaluate_disparity",
    "evaluate_method",
    "format_results_table",
    "load_scene",
]

SCENES: tuple[str, ...] = ("tsukuba", "venus", "teddy", "cones")
MASKS: tuple[str, ...] = ("nonocc", "all", "disc")
#: ground-truth scale factor and number of disparity levels (README of the data folder)
_SCALE = {"tsukuba": 16, "venus": 8, "teddy": 4, "cones": 4}
_LEVELS = {"tsukuba": 16, "venus": 20, "teddy": 60, "cones": 60}


@dataclass(frozen=True)
class MiddleburyScene:
    """One v2 scene.

    Attributes
    ----------
    name : str
    left, right : ndarray, uint8, (H, W, 3)  RGB pair.
    gt : ndarray, float32, (H, W)  ground-truth disparity of the left image in pixels, NaN unknown.
    masks : dict[str, ndarray]  bool (H, W) for ``nonocc``, ``all``, ``disc`` (value 255 in the files).
    max_disp : int  largest disparity searched (levels − 1: 15, 19, 59, 59).
    scale : int  ground-truth file scale factor.
    """

    name: str
    left: np.ndarray
    right: np.ndarray
    gt: np.ndarray
    masks: dict[str, np.ndarray]
    max_disp: int
    scale: int


def _repo_root() -> Path:
    return Path(__file__).resolve().parents[3]


def default_data_dir() -> Path | None:
    """``$PRISMSTEREO_MIDDLEBURY``, else ``../shared/data/middlebury`` beside the repo root or the cwd.

    Returns None when no such folder exists.
    """
    env = os.environ.get("PRISMSTEREO_MIDDLEBURY")
    candidates = [Path(env)] if env else []
    candidates += [_repo_root().parent / "shared" / "data" / "middlebury",
                   Path.cwd().parent / "shared" / "data" / "middlebury"]
    for c in candidates:
        if c.is_dir():
            return c
    return None


def _resolve(data_dir: str | os.PathLike[str] | None) -> Path:
    if data_dir is None:
        found = default_data_dir()
        if found is None:
            raise ConfigError("expected the Middlebury folder (--data DIR or $PRISMSTEREO_MIDDLEBURY), "
                              "got none at ../shared/data/middlebury")
        return found
    p = Path(data_dir)
    if not p.is_dir():
        raise ConfigError(f"expected a Middlebury data folder, got {str(p)!r} (not a directory)")
    return p


def load_scene(name: str, data_dir: str | os.PathLike[str] | None = None) -> MiddleburyScene:
    """Load a scene by name (one of :data:`SCENES`)."""
    from prismstereo.io import read_image

    key = name.lower()
    if key not in SCENES:
        raise ConfigError(f"expected a scene among {', '.join(SCENES)}, got {name!r}")
    folder = _resolve(data_dir) / key
    if not folder.is_dir():
        raise ConfigError(f"expected scene folder {str(folder)!r}, got nothing there")
    left = read_image(folder / "left.png")
    right = read_image(folder / "right.png")
    if left.shape != right.shape:
        raise ImageError(f"expected a pair of one size in {folder}, got {left.shape} and {right.shape}")
    raw = read_image(folder / "disp_left.png", gray=True).astype(np.float32)
    gt = np.where(raw > 0, raw / np.float32(_SCALE[key]), np.float32(np.nan)).astype(np.float32)
    masks = {m: read_image(folder / f"{m}.png", gray=True) == 255 for m in MASKS}
    return MiddleburyScene(key, left, right, gt, masks, _LEVELS[key] - 1, _SCALE[key])


def evaluate_disparity(disp: np.ndarray, scene: MiddleburyScene, *,
                       thresholds: tuple[float, ...] = (0.5, 1.0, 2.0)) -> dict[str, Any]:
    """Bad-pixel percentages (v2: ``|d - gt| > t`` over mask == 255; NaN estimates are bad) and MAE.

    Returns
    -------
    dict
        ``{"bad": {"1.0": {"nonocc": %, "all": %, "disc": %}, ...}, "mae": {"nonocc": px, ...},
        "invalid_percent": % of NaN estimates over the ``all`` mask}``.
    """
    d = np.asarray(disp, dtype=np.float32)
    if d.shape != scene.gt.shape:
        raise ImageError(f"expected a disparity map of shape {scene.gt.shape}, got {d.shape}")
    out: dict[str, Any] = {"bad": {}, "mae": {}}
    for t in thresholds:
        out["bad"][f"{t:.1f}"] = {m: bad_pixel_rate(d, scene.gt, scene.masks[m], threshold=t) for m in MASKS}
    out["mae"] = {m: mean_abs_error(d, scene.gt, scene.masks[m]) for m in MASKS}
    out["invalid_percent"] = float(100.0 * (~np.isfinite(d[scene.masks["all"]])).mean())
    return out


def format_results_table(results: dict[str, Any], *, title: str = "") -> str:
    """Markdown table of bad 1.0 (nonocc/all/disc), bad 0.5 and 2.0 (nonocc), MAE and seconds."""
    lines = [title] if title else []
    lines += ["| scene | bad1 nonocc | bad1 all | bad1 disc | bad0.5 nonocc | bad2 nonocc | MAE nonocc | s |",
              "|---|---|---|---|---|---|---|---|"]
    scenes = results["scenes"]
    for name, r in scenes.items():
        b = r["bad"]
        lines.append(f"| {name} | {b['1.0']['nonocc']:.2f} | {b['1.0']['all']:.2f} | {b['1.0']['disc']:.2f} | "
                     f"{b['0.5']['nonocc']:.2f} | {b['2.0']['nonocc']:.2f} | {r['mae']['nonocc']:.3f} | "
                     f"{r['seconds']:.2f} |")
    a = results["average"]
    lines.append(f"| **average** | {a['nonocc']:.2f} | {a['all']:.2f} | {a['disc']:.2f} | "
                 f"{a['bad0.5_nonocc']:.2f} | {a['bad2.0_nonocc']:.2f} | {a['mae_nonocc']:.3f} | "
                 f"{a['seconds']:.2f} |")
    return "\n".join(lines)


def evaluate_method(method: str, *, data_dir: str | os.PathLike[str] | None = None,
                    out_dir: str | os.PathLike[str] | None = None, scenes: tuple[str, ...] = SCENES,
                    **params: Any) -> dict[str, Any]:
    """Run a registered matcher on the scenes; write ``<scene>.pfm``, ``<scene>.png``, ``results.json``.

    Parameters
    ----------
    method : str
        Registered matcher name (validated before any image is read).
    data_dir : path, optional
        Middlebury folder (default :func:`default_data_dir`).
    out_dir : path, optional
        Output folder; nothing is written when None.
    **params
        The matcher's tuning parameters.

    Returns
    -------
    dict
        ``{"method", "params", "scenes": {name: {bad, mae, seconds, ...}}, "average": {...}}``.
    """
    from prismstereo.io import check_output_dir, output_dir, write_image, write_json, write_pfm
    from prismstereo.matching import get_matcher, match
    from prismstereo.progress import progress_bar
    from prismstereo.viz.colorize import colorize_disparity

    get_matcher(method, **params)  # validates name and parameters first
    root = _resolve(data_dir)
    for s in scenes:
        if s.lower() not in SCENES:
            raise ConfigError(f"expected scenes among {', '.join(SCENES)}, got {s!r}")
    out = Path(out_dir) if out_dir is not None else None
    if out is not None:
        check_output_dir(out)  # before any work; nothing is created until every scene is done
    per: dict[str, Any] = {}
    maps: dict[str, tuple[np.ndarray, int]] = {}
    bar = progress_bar(scenes, desc=f"evaluate {method}", unit="scene", leave=False)
    for s in bar:
        bar.set_postfix_str(s)
        scene = load_scene(s, root)
        t = time.perf_counter()
        res = match(scene.left, scene.right, max_disp=scene.max_disp, method=method, **params)
        seconds = time.perf_counter() - t
        ev = evaluate_disparity(res.disparity, scene)
        ev["seconds"] = seconds
        ev["timings"] = res.timings
        if res.disparity_raw is not None:
            ev["raw"] = evaluate_disparity(res.disparity_raw, scene, thresholds=(1.0,))
        per[scene.name] = ev
        log.info("%s %s: bad1 nonocc %.2f %% (%.2f s)", method, s, ev["bad"]["1.0"]["nonocc"], seconds)
        if out is not None:
            maps[scene.name] = (res.disparity, scene.max_disp)
    avg: dict[str, float] = {m: float(np.mean([per[s]["bad"]["1.0"][m] for s in per])) for m in MASKS}
    avg["bad0.5_nonocc"] = float(np.mean([per[s]["bad"]["0.5"]["nonocc"] for s in per]))
    avg["bad2.0_nonocc"] = float(np.mean([per[s]["bad"]["2.0"]["nonocc"] for s in per]))
    avg["mae_nonocc"] = float(np.mean([per[s]["mae"]["nonocc"] for s in per]))
    avg["seconds"] = float(np.mean([per[s]["seconds"] for s in per]))
    results = {"method": method, "params": params, "protocol": "Middlebury v2, bad if |d-gt|>t over "
               "mask==255, NaN estimates bad", "scenes": per, "average": avg}
    if out is not None:  # all scenes' files appear together, or none (a broken scene, Ctrl-C)
        with output_dir(out) as stage:
            for name, (disp, max_disp) in maps.items():
                write_pfm(stage / f"{name}.pfm", disp)
                write_image(stage / f"{name}.png", colorize_disparity(disp, vmin=0.0, vmax=float(max_disp),
                                                                     colorbar="disparity (px)"))
            write_json(stage / "results.json", results)
    return results
