"""Middlebury scenes: loading (two folder layouts), evaluation and a whole-method harness.

A data folder holds one sub-folder per scene (or is itself one scene), in either layout:

* **shared layout** (``../shared/data/middlebury`` with the v2 scenes Tsukuba, Venus, Teddy, Cones, and
  ``../shared/data/middlebury-extra`` with validation scenes; see their READMEs): ``left.png``, ``right.png``,
  ``disp_left.png`` (ground truth × scale factor, 0 = unknown), the masks ``nonocc.png``, ``all.png``,
  ``disc.png`` (255 = evaluated) and ``manifest.json``, whose ``ground_truth.scale_factor`` and
  ``disparity_search_range.max`` give the decoding and the search range of each scene;
* **Middlebury 2014 layout** (as distributed): ``im0.png``, ``im1.png``, ``disp0GT.pfm`` (pixels, inf =
  unknown), ``mask0nocc.png`` (255 = non-occluded, 128 = occluded, 0 = unknown) and ``calib.txt``, whose
  ``ndisp`` gives the search range ``0 .. ndisp - 1``. The 2014 set has no discontinuity mask: ``disc`` is
  derived as in the validation manifests (non-occluded pixels within 4 px of a ground-truth jump > 2 px).
"""

from __future__ import annotations

import json
import logging
import os
import re
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from prismstereo.errors import ConfigError, ImageError
from prismstereo.evaluation.metrics import bad_pixel_rate, mean_abs_error
from prismstereo.io import check_output_dir, output_dir, read_image, read_pfm, write_image, write_json, write_pfm
from prismstereo.matching import get_matcher, match
from prismstereo.matching.registry import resolved_params
from prismstereo.progress import progress_bar
from prismstereo.viz.colorize import colorize_disparity

log = logging.getLogger(__name__)

__all__ = [
    "MASKS",
    "SCENES",
    "MiddleburyScene",
    "default_data_dir",
    "evaluate_disparity",
    "evaluate_method",
    "format_results_table",
    "list_scenes",
    "load_scene",
    "load_scene_folder",
]

#: the four v2 scenes of ``../shared/data/middlebury`` (the thesis's Table 6.2)
SCENES: tuple[str, ...] = ("tsukuba", "venus", "teddy", "cones")
MASKS: tuple[str, ...] = ("nonocc", "all", "disc")
_SHARED_FILES = ("left.png", "right.png", "disp_left.png", "manifest.json")
_M2014_FILES = ("im0.png", "im1.png", "disp0GT.pfm", "calib.txt")


@dataclass(frozen=True)
class MiddleburyScene:
    """One scene.

    Attributes
    ----------
    name : str
    left, right : ndarray, uint8, (H, W, 3)  RGB pair.
    gt : ndarray, float32, (H, W)  ground-truth disparity of the left image in pixels, NaN unknown.
    masks : dict[str, ndarray]  bool (H, W) for ``nonocc``, ``all``, ``disc``.
    max_disp : int  largest disparity searched (from the manifest or ``calib.txt``; v2: 15, 19, 59, 59).
    scale : float  ground-truth file scale factor (1 for PFM ground truth).
    """

    name: str
    left: np.ndarray
    right: np.ndarray
    gt: np.ndarray
    masks: dict[str, np.ndarray]
    max_disp: int
    scale: float


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


def resolve_data_dir(data_dir: str | os.PathLike[str] | None) -> Path:
    """The Middlebury folder to read: ``data_dir``, else :func:`default_data_dir`.

    Raises
    ------
    ConfigError
        No folder given and none found, or ``data_dir`` is not a folder.
    """
    if data_dir is None:
        found = default_data_dir()
        if found is None:
            raise ConfigError("data_dir: expected the Middlebury folder (or $PRISMSTEREO_MIDDLEBURY), "
                              "got none at ../shared/data/middlebury")
        return found
    p = Path(data_dir)
    if not p.is_dir():
        raise ConfigError(f"expected a Middlebury data folder, got {str(p)!r} (not a directory)")
    return p


def _layout(folder: Path) -> str | None:
    if all((folder / f).is_file() for f in _SHARED_FILES):
        return "shared"
    if all((folder / f).is_file() for f in _M2014_FILES):
        return "2014"
    return None


def list_scenes(data_dir: str | os.PathLike[str] | None = None) -> tuple[str, ...]:
    """Names of the scene folders (either layout) in ``data_dir``, sorted; the folder's own name when it
    is itself a scene."""
    root = resolve_data_dir(data_dir)
    if _layout(root) is not None:
        return (root.name,)
    return tuple(sorted(p.name for p in root.iterdir() if p.is_dir() and _layout(p) is not None))


def _derived_disc(gt: np.ndarray, nonocc: np.ndarray, *, jump: float = 2.0, radius: int = 4) -> np.ndarray:
    # pixels next to a ground-truth jump: the neighbour differences above ``jump`` (unknown counts as none)
    g = np.asarray(gt, np.float32)
    edge = np.zeros(gt.shape, bool)
    dx = np.abs(np.diff(g, axis=1)) > jump
    dy = np.abs(np.diff(g, axis=0)) > jump
    edge[:, 1:] |= dx
    edge[:, :-1] |= dx
    edge[1:, :] |= dy
    edge[:-1, :] |= dy
    k = np.ones((2 * radius + 1, 2 * radius + 1), np.uint8)
    return (cv2.dilate(edge.astype(np.uint8), k) > 0) & nonocc


def _read_json(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ConfigError(f"expected a readable JSON manifest, got {str(path)!r} ({exc})") from None
    if not isinstance(data, dict):
        raise ConfigError(f"expected a JSON object in {str(path)!r}, got {type(data).__name__}")
    return data


def _load_shared(folder: Path, name: str) -> MiddleburyScene:

    man = _read_json(folder / "manifest.json")
    try:
        scale = float(man["ground_truth"]["scale_factor"])
        max_disp = int(man["disparity_search_range"]["max"])
    except (KeyError, TypeError, ValueError):
        raise ConfigError(f"expected ground_truth.scale_factor and disparity_search_range.max in "
                          f"{str(folder / 'manifest.json')!r}, got {sorted(man)}") from None
    if scale <= 0 or max_disp < 1:
        raise ConfigError(f"expected a positive scale factor and search range in {str(folder)!r}, "
                          f"got scale {scale} and max {max_disp}")
    left = read_image(folder / "left.png")
    right = read_image(folder / "right.png")
    raw = read_image(folder / "disp_left.png", gray=True).astype(np.float32)
    gt = np.where(raw > 0, raw / np.float32(scale), np.float32(np.nan)).astype(np.float32)
    masks = {m: read_image(folder / f"{m}.png", gray=True) == 255 for m in MASKS}
    return MiddleburyScene(name, left, right, gt, masks, max_disp, scale)


def _read_calib(path: Path) -> dict[str, str]:
    out = {}
    for line in path.read_text().splitlines():
        m = re.match(r"\s*(\w+)\s*=\s*(.*?)\s*$", line)
        if m:
            out[m.group(1)] = m.group(2)
    return out


def _load_2014(folder: Path, name: str) -> MiddleburyScene:

    calib = _read_calib(folder / "calib.txt")
    try:
        ndisp = int(calib["ndisp"])
    except (KeyError, ValueError):
        raise ConfigError(f"expected 'ndisp=<int>' in {str(folder / 'calib.txt')!r}, got keys "
                          f"{sorted(calib)}") from None
    if ndisp < 2:
        raise ConfigError(f"expected ndisp >= 2 in {str(folder / 'calib.txt')!r}, got {ndisp}")
    left = read_image(folder / "im0.png")
    right = read_image(folder / "im1.png")
    gt = read_pfm(folder / "disp0GT.pfm")
    if gt.ndim != 2:
        raise ImageError(f"expected a one-channel disp0GT.pfm in {str(folder)!r}, got shape {gt.shape}")
    gt = np.where(np.isfinite(gt) & (gt > 0), gt, np.nan).astype(np.float32)
    known = np.isfinite(gt)
    if (folder / "mask0nocc.png").is_file():
        mk = read_image(folder / "mask0nocc.png", gray=True)
        if mk.shape != gt.shape:
            raise ImageError(f"expected mask0nocc.png of shape {gt.shape} in {str(folder)!r}, got {mk.shape}")
        nonocc = (mk == 255) & known
        allm = (mk > 0) & known
    else:
        nonocc = allm = known
    masks = {"nonocc": nonocc, "all": allm, "disc": _derived_disc(gt, nonocc)}
    return MiddleburyScene(name, left, right, gt, masks, ndisp - 1, 1.0)


def load_scene_folder(folder: str | os.PathLike[str]) -> MiddleburyScene:
    """Load one scene folder in either layout (see the module docstring).

    Raises
    ------
    ConfigError
        If the folder holds neither layout or its manifest / calib lacks the search range.
    ImageError
        If the images, ground truth and masks differ in size.
    """
    f = Path(folder)
    if not f.is_dir():
        raise ConfigError(f"expected a scene folder, got {str(f)!r} (not a directory)")
    kind = _layout(f)
    if kind is None:
        raise ConfigError(f"expected {', '.join(_SHARED_FILES)} (or the 2014 files {', '.join(_M2014_FILES)}) "
                          f"in {str(f)!r}, got {sorted(p.name for p in f.iterdir())[:12]}")
    sc = _load_shared(f, f.name) if kind == "shared" else _load_2014(f, f.name)
    shapes = {sc.left.shape[:2], sc.right.shape[:2], sc.gt.shape, *(m.shape for m in sc.masks.values())}
    if len(shapes) != 1:
        raise ImageError(f"expected the pair, ground truth and masks of one size in {str(f)!r}, got {sorted(shapes)}")
    return sc


def load_scene(name: str, data_dir: str | os.PathLike[str] | None = None) -> MiddleburyScene:
    """Load the scene folder ``name`` of ``data_dir`` (default :func:`default_data_dir`), either layout."""
    root = resolve_data_dir(data_dir)
    if _layout(root) is not None and root.name.lower() == name.lower():
        return load_scene_folder(root)
    folder = root / name
    if not folder.is_dir():
        folder = root / name.lower()
    if not folder.is_dir():
        raise ConfigError(f"expected a scene among {', '.join(list_scenes(root)) or '(none)'} in {str(root)!r}, "
                          f"got {name!r}")
    return load_scene_folder(folder)


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


def _is_2014(results: dict[str, Any]) -> bool:
    return results.get("layout") == "2014"


def format_results_table(results: dict[str, Any], *, title: str = "") -> str:
    """Markdown table of bad 1.0 (nonocc/all/disc), bad 0.5 and 2.0 (nonocc), MAE and seconds.

    For the Middlebury 2014 layout (``results["layout"] == "2014"``) bad 2.0 nonocc is the first column (the
    number MiddEval3 reports at quarter resolution). With a baseline in ``results["baseline"]``
    (:func:`evaluate_method`'s ``baseline``) its bad 2.0 and 1.0 nonocc and seconds follow, side by side.
    """
    lines = [title] if title else []
    first = _is_2014(results)
    base = results.get("baseline")
    bname = base["method"] if base else ""
    head = ["scene"] + (["bad2 nonocc"] if first else []) + ["bad1 nonocc", "bad1 all", "bad1 disc",
                                                              "bad0.5 nonocc"]
    head += ([] if first else ["bad2 nonocc"]) + ["MAE nonocc", "s"]
    if base:
        head += [f"{bname} bad2 nonocc", f"{bname} bad1 nonocc", f"{bname} s"]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]

    def row(label: str, b2: float, b1: float, b1a: float, b1d: float, b05: float, mae: float, sec: float,
            extra: list[float]) -> str:
        cells = [label] + ([f"{b2:.2f}"] if first else []) + [f"{b1:.2f}", f"{b1a:.2f}", f"{b1d:.2f}",
                                                              f"{b05:.2f}"]
        cells += ([] if first else [f"{b2:.2f}"]) + [f"{mae:.3f}", f"{sec:.2f}"]
        cells += [f"{extra[0]:.2f}", f"{extra[1]:.2f}", f"{extra[2]:.2f}"] if extra else []
        return "| " + " | ".join(cells) + " |"

    for name, r in results["scenes"].items():
        b = r["bad"]
        extra: list[float] = []
        if base:
            rb = base["scenes"][name]
            extra = [rb["bad"]["2.0"]["nonocc"], rb["bad"]["1.0"]["nonocc"], rb["seconds"]]
        lines.append(row(name, b["2.0"]["nonocc"], b["1.0"]["nonocc"], b["1.0"]["all"], b["1.0"]["disc"],
                         b["0.5"]["nonocc"], r["mae"]["nonocc"], r["seconds"], extra))
    a = results["average"]
    extra = []
    if base:
        ab = base["average"]
        extra = [ab["bad2.0_nonocc"], ab["nonocc"], ab["seconds"]]
    lines.append(row("**average**", a["bad2.0_nonocc"], a["nonocc"], a["all"], a["disc"], a["bad0.5_nonocc"],
                     a["mae_nonocc"], a["seconds"], extra))
    if base:
        lines.append(f"bad2 nonocc average: {results['method']} {a['bad2.0_nonocc']:.2f}, {bname} "
                     f"{ab['bad2.0_nonocc']:.2f} (ratio {a['bad2.0_nonocc'] / max(ab['bad2.0_nonocc'], 1e-9):.3f}); "
                     f"seconds ratio {a['seconds'] / max(ab['seconds'], 1e-9):.2f}")
    return "\n".join(lines)


def _average(per: dict[str, Any]) -> dict[str, float]:
    avg: dict[str, float] = {m: float(np.mean([per[s]["bad"]["1.0"][m] for s in per])) for m in MASKS}
    avg["bad0.5_nonocc"] = float(np.mean([per[s]["bad"]["0.5"]["nonocc"] for s in per]))
    avg["bad2.0_nonocc"] = float(np.mean([per[s]["bad"]["2.0"]["nonocc"] for s in per]))
    avg["mae_nonocc"] = float(np.mean([per[s]["mae"]["nonocc"] for s in per]))
    avg["seconds"] = float(np.mean([per[s]["seconds"] for s in per]))
    return avg


def evaluate_method(method: str, *, data_dir: str | os.PathLike[str] | None = None,
                    out_dir: str | os.PathLike[str] | None = None, scenes: tuple[str, ...] | None = None,
                    baseline: str | None = None, **params: Any) -> dict[str, Any]:
    """Run a registered matcher on the scenes; write ``<scene>.pfm``, ``<scene>.png``, ``results.json``.

    Parameters
    ----------
    method : str
        Registered matcher name (validated before any image is read).
    data_dir : path, optional
        Folder of scenes in either layout, or one scene folder (default :func:`default_data_dir`).
    scenes : tuple of str, optional
        Scene folder names (default: every scene of ``data_dir``, :func:`list_scenes`).
    out_dir : path, optional
        Output folder; nothing is written when None.
    baseline : str, optional
        A second registered matcher (e.g. ``"sgbm"``, OpenCV StereoSGBM), run with its defaults on the same
        scenes in the same process and scored the same way: ``results["baseline"]`` holds its ``method``,
        ``scenes`` and ``average`` (its maps are not written).
    **params
        The matcher's tuning parameters.

    Returns
    -------
    dict
        ``{"method", "params", "layout", "scenes": {name: {bad, mae, seconds, ...}}, "average": {...}}``;
        ``params`` holds every parameter of the matcher, the defaults included; ``layout`` is ``"2014"`` when
        every scene is in the Middlebury 2014 layout, else ``"shared"``.
    """

    get_matcher(method, **params)  # validates name and parameters first
    if baseline is not None:
        get_matcher(baseline)
    root = resolve_data_dir(data_dir)
    found = list_scenes(root)
    if scenes is None:
        scenes = found
    if not scenes:
        raise ConfigError(f"expected scene folders (left.png/right.png/disp_left.png/manifest.json or "
                          f"im0.png/im1.png/disp0GT.pfm/calib.txt) in {str(root)!r}, got none")
    lower = {f.lower(): f for f in found}
    missing = [s for s in scenes if s.lower() not in lower]
    if missing:
        raise ConfigError(f"expected scenes among {', '.join(found)}, got {', '.join(map(repr, missing))}")
    scenes = tuple(lower[s.lower()] for s in scenes)
    out = Path(out_dir) if out_dir is not None else None
    if out is not None:
        check_output_dir(out)  # before any work; nothing is created until every scene is done
    per: dict[str, Any] = {}
    base: dict[str, Any] = {}
    maps: dict[str, tuple[np.ndarray, int]] = {}
    folders = [root] if _layout(root) is not None else [root / s for s in scenes]
    layout = "2014" if all(_layout(f) == "2014" for f in folders) else "shared"
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
        if baseline is not None:
            t = time.perf_counter()
            bres = match(scene.left, scene.right, max_disp=scene.max_disp, method=baseline)
            bev = evaluate_disparity(bres.disparity, scene)
            bev["seconds"] = time.perf_counter() - t
            base[scene.name] = bev
        if out is not None:
            maps[scene.name] = (res.disparity, scene.max_disp)
    avg = _average(per)
    # every tuning parameter with its default, so that the numbers can be reproduced after a default changes
    results = {"method": method, "params": resolved_params(method, **params),
               "protocol": "Middlebury v2, bad if |d-gt|>t over the mask, NaN estimates bad", "data": str(root),
               "layout": layout, "scenes": per, "average": avg}
    if baseline is not None:
        results["baseline"] = {"method": baseline, "params": resolved_params(baseline), "scenes": base,
                               "average": _average(base)}
    if out is not None:  # all scenes' files appear together, or none (a broken scene, Ctrl-C)
        with output_dir(out) as stage:
            for name, (disp, max_disp) in maps.items():
                write_pfm(stage / f"{name}.pfm", disp)
                write_image(stage / f"{name}.png", colorize_disparity(disp, vmin=0.0, vmax=float(max_disp),
                                                                     colorbar="disparity (px)"))
            write_json(stage / "results.json", results)
    return results
