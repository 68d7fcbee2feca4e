"""Photographed scenes through the prism (issue 26): depth accuracy on the 13 Middlebury validation scenes.

Run (from the repository root):

    PYTHONPATH=src NUMBA_CACHE_DIR=.numba_cache python benchmarks/bench_real_scenes.py -o OUT \
        [--data ../shared/data] [--scenes books,Piano,...] [--rigs biprism,triprism,misaligned] \
        [--presets fast,balanced,accurate] [--realism ideal,real] [--calib none,board,self] [--render-cache DIR]

Every scene is the left view of a Middlebury pair with its true depth (``simulate.middlebury_rgbd``: the five
2005/2006 scenes of ``middlebury-extra``, the eight 2014 scenes of ``middlebury-2014``), a similar copy whose
median depth is at ``--center-depth`` (1400 mm) and whose field there is ``--fill`` (1.3) times one half-sensor
view wide, rendered as an RGB-D height field through the rig (s = 2 supersampling, sensor noise σ 1.5, its seed
the scene's place in the full list whatever ``--scenes`` holds):

* rigs: ``biprism`` (the thesis bi-prism: 1024×768, f 25 mm, 4.65 µm, α 6.4°, n 1.5, apex 210, back 215.6),
  ``triprism`` (examples/rigs/triprism.toml, default views), ``misaligned`` (the bi-prism tilted (−0.9, 1.1)°,
  decentred (−0.8, 0.7) mm, rotated −1.5°, on a lens with k1 −0.10, k2 0.12; judged against the true rig);
* realism: ``ideal`` (pinhole, lossless) or ``real`` (thin lens f/8 focused at the centre depth, Bayer RGGB
  with edge-aware demosaicing, JPEG 85);
* calib (misaligned rig only): ``none`` (the nominal prism on the true camera), ``board`` (``calibrate_prism``
  from 10 board captures through the true rig, once per run), ``self`` (``calibrate_from_scene`` on the capture
  itself, what ``depth --self-calibrate`` does);
* presets: fast = sgm, balanced = bpasw, accurate = coop.

Per row: median relative depth error, share of reconstructed points within 1 %, coverage of the common view
(``evaluation.depth_metrics``: ground truth by exact scene rays; the skin across depth jumps and pixels of unknown
depth are not judged), the pipeline's warnings (calib self: with the self-calibration's, as ``depth
--self-calibrate`` gives them) and seconds. Rows are printed as a markdown table and appended to
``OUT/results.json`` as they finish (a partial run keeps its rows; rerunning skips rows already there).
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from prismstereo.calibration import Board, calibrate_prism
from prismstereo.calibration.from_scene import calibrate_from_scene
from prismstereo.calibration.scene_uncertainty import uncertainty_warnings, unobserved_depth_error
from prismstereo.config import Rig, load_rig, thesis_biprism
from prismstereo.depth import DepthConfig, run_depth
from prismstereo.depth.presets import apply_preset
from prismstereo.errors import PrismStereoError
from prismstereo.evaluation.depth_metrics import evaluate_depth
from prismstereo.matching.registry import PRESETS
from prismstereo.simulate import Scene, render_capture
from prismstereo.simulate.checkerboard import checkerboard_poses
from prismstereo.simulate.rgbd import middlebury_rgbd
from prismstereo.simulate.scene import ThinLens

REPO = Path(__file__).resolve().parents[1]
EXTRA = ("books", "bowling1", "cloth3", "reindeer", "wood2")
MB2014 = ("Adirondack", "ArtL", "Jadeplant", "Motorcycle", "MotorcycleE", "Piano", "PianoL", "Pipes")
RIGS = ("biprism", "triprism", "misaligned")
REALISM = ("ideal", "real")
CALIB = ("none", "board", "self")


def default_data() -> Path:
    env = os.environ.get("PRISMSTEREO_MIDDLEBURY")
    return Path(env).parent if env else REPO.parent / "shared" / "data"


def scene_folder(data: Path, name: str) -> Path:
    return data / ("middlebury-extra" if name in EXTRA else "middlebury-2014") / name


def true_rig(name: str) -> Rig:
    if name == "biprism":
        return thesis_biprism()
    if name == "triprism":
        return load_rig(REPO / "examples" / "rigs" / "triprism.toml")
    rig = thesis_biprism()
    cam = dataclasses.replace(rig.camera, distortion=(-0.10, 0.12, 0.0, 0.0, 0.0))
    return dataclasses.replace(rig, camera=cam, name="misaligned").with_prism(
        rotation=-1.5, tilt=(-0.9, 1.1), decenter=(-0.8, 0.7))


def nominal_rig(true: Rig) -> Rig:
    """The true camera (from a camera calibration) with the nominal, centred prism."""
    return dataclasses.replace(true, name="nominal").with_prism(rotation=0.0, tilt=(0.0, 0.0), decenter=(0.0, 0.0))


def make_scene(data: Path, name: str, rig: Rig, *, realism: str, center_depth: float, fill: float,
               seed: int) -> Scene:
    half_view = rig.camera.width / 2.0 / rig.camera.focal_px * center_depth  # mm at the centre depth
    surf = middlebury_rgbd(scene_folder(data, name), center_depth=center_depth, width=fill * half_view)
    scene = Scene(objects=(surf,), supersample=2, noise=1.5, seed=seed, name=name)
    if realism == "real":
        scene = dataclasses.replace(scene, lens=ThinLens(f_number=8.0, focus_distance=center_depth, samples=16),
                                    bayer="RGGB", demosaic="edge-aware", jpeg_quality=85)
    return scene


def cached_render(true: Rig, scene: Scene, cache: Path | None, key: str) -> np.ndarray:
    """The capture of ``scene`` through ``true``, read from ``cache/key.npy`` when an earlier run rendered it."""
    file = None if cache is None else cache / f"{key}.npy"
    if file is not None and file.is_file():
        return np.load(file)
    image = render_capture(true, scene).image
    if file is not None:
        file.parent.mkdir(parents=True, exist_ok=True)
        np.save(file, image)
    return image


def board_calibrated(true: Rig, out: Path) -> tuple[Rig, dict[str, Any]]:
    """calibrate_prism from 10 board captures through the true rig, starting from the nominal prism (cached)."""
    cached = out / "board_calibrated_rig.toml"
    info_file = out / "board_calibration.json"
    if cached.is_file() and info_file.is_file():
        return load_rig(cached), json.loads(info_file.read_text())
    t0 = time.perf_counter()
    board = Board(8, 6, 3.0)
    poses = checkerboard_poses(true, n_poses=10, squares=(9, 7), square_mm=3.0, distance_range=(600.0, 1200.0),
                               seed=1)
    caps = [render_capture(true, dataclasses.replace(p.scene, noise=1.0, seed=100 + i), supersample=2).image
            for i, p in enumerate(poses)]
    pc = calibrate_prism(nominal_rig(true), caps, board)
    info = {"seconds": time.perf_counter() - t0, "estimates": dict(pc.estimates), "std": dict(pc.std)}
    pc.rig.save(cached)
    info_file.write_text(json.dumps(info, indent=1))
    return pc.rig, info


def run_row(rig_used: Rig, true: Rig, image: np.ndarray, scene: Scene, preset: str,
            max_memory: int | None = None) -> dict[str, Any]:
    t0 = time.perf_counter()
    c0 = time.process_time()
    res = run_depth(rig_used, image, config=apply_preset(DepthConfig(max_memory=max_memory), preset))
    secs = time.perf_counter() - t0
    cpu = time.process_time() - c0
    judged = copy.copy(res)
    object.__setattr__(judged, "rig", true)  # the truth: the real pixels' rays through the true prism
    acc = evaluate_depth(judged, scene=scene)
    return {"median_pct": 100 * acc["median_rel"], "within_1pct": 100 * acc["within_1pct"],
            "coverage_pct": 100 * acc["coverage"], "p95_pct": 100 * acc["p95_rel"], "n_points": acc["n_points"],
            "n_common": acc["n_common"], "depth_s": secs, "cpu_s": cpu, "warnings": list(res.warnings),
            "disparity_range": list(res.disparity_range), "depth_range": [round(v, 1) for v in res.depth_range],
            "range_source": res.depth_range_source, "tiles": res.match_info.get("tiles")}


def _key(r: dict[str, Any]) -> tuple[str, ...]:
    return (r["scene"], r["rig"], r["realism"], r["calib"], r["preset"])


def _fmt(r: dict[str, Any]) -> str:
    if "error" in r:
        return f"| {r['scene']} | {r['rig']} | {r['realism']} | {r['calib']} | {r['preset']} | failed: {r['error']} |"
    return (f"| {r['scene']} | {r['rig']} | {r['realism']} | {r['calib']} | {r['preset']} | {r['median_pct']:.3f} | "
            f"{r['within_1pct']:.1f} | {r['coverage_pct']:.1f} | {r['depth_s']:.0f} | {len(r['warnings'])} | "
            f"{'–'.join(str(v) for v in r.get('disparity_range', ()))} |")


HEADER = ("| scene | rig | realism | calib | preset | median % | within 1 % | coverage % | depth s | warnings | "
          "searched px |\n|---|---|---|---|---|---|---|---|---|---|---|")


def _csv(v: str, allowed: tuple[str, ...], what: str) -> list[str]:
    items = [x.strip() for x in v.split(",") if x.strip()]
    bad = [x for x in items if x not in allowed]
    if bad:
        sys.exit(f"--{what}: unknown {', '.join(bad)}; expected some of {', '.join(allowed)}")
    return items


def summary(rows: list[dict[str, Any]]) -> str:
    """Per (rig, realism, calib, preset): worst median, worst within-1 %, worst coverage, over the scenes."""
    groups: dict[tuple[str, ...], list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault(_key(r)[1:], []).append(r)
    out = ["| rig | realism | calib | preset | scenes | failed | median % (median / worst) | within 1 % (worst) | "
           "coverage % (median / worst) |", "|---|---|---|---|---|---|---|---|---|"]
    for k, rs in sorted(groups.items()):
        ok = [r for r in rs if "error" not in r]
        if not ok:
            out.append(f"| {' | '.join(k)} | {len(rs)} | {len(rs)} | | | |")
            continue
        med = [r["median_pct"] for r in ok]
        w1 = [r["within_1pct"] for r in ok]
        cov = [r["coverage_pct"] for r in ok]
        out.append(f"| {' | '.join(k)} | {len(rs)} | {len(rs) - len(ok)} | {np.median(med):.3f} / {max(med):.3f} | "
                   f"{min(w1):.1f} | {np.median(cov):.1f} / {min(cov):.1f} |")
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--out", required=True, help="output folder (results.json, board calibration)")
    ap.add_argument("--data", default=None, help="folder holding middlebury-extra and middlebury-2014")
    ap.add_argument("--scenes", default=",".join(EXTRA + MB2014))
    ap.add_argument("--rigs", default="biprism")
    ap.add_argument("--presets", default="balanced")
    ap.add_argument("--realism", default="ideal")
    ap.add_argument("--calib", default="none,board,self", help="for the misaligned rig")
    ap.add_argument("--render-cache", default=None,
                    help="folder of rendered captures (SCENE_RIG_REALISM_DEPTH_FILL.npy): read when there, else "
                         "rendered and saved (the render is deterministic: the scene's seed is fixed)")
    ap.add_argument("--center-depth", type=float, default=1400.0)
    ap.add_argument("--fill", type=float, default=1.3, help="scene width / one half-sensor view at the centre depth")
    ap.add_argument("--max-memory", type=float, default=None,
                    help="DepthConfig.max_memory, bytes (default: 80 %% of the free memory, which varies on a shared "
                         "machine, and coop's map depends on the tiling it sets)")
    args = ap.parse_args()
    data = Path(args.data) if args.data else default_data()
    scenes = _csv(args.scenes, EXTRA + MB2014, "scenes")
    rigs = _csv(args.rigs, RIGS, "rigs")
    presets = _csv(args.presets, tuple(PRESETS), "presets")
    realisms = _csv(args.realism, REALISM, "realism")
    calibs = _csv(args.calib, CALIB, "calib")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    res_file = out / "results.json"
    rows: list[dict[str, Any]] = json.loads(res_file.read_text())["rows"] if res_file.is_file() else []
    done = {_key(r) for r in rows}
    load0 = os.getloadavg()
    print(HEADER, flush=True)
    for rig_name in rigs:
        true = true_rig(rig_name)
        used: list[tuple[str, Rig | None]] = [("none", true)]
        if rig_name == "misaligned":
            used = []
            for c in calibs:
                if c == "board":
                    used.append(("board", board_calibrated(true, out)[0]))
                else:
                    used.append((c, nominal_rig(true) if c == "none" else None))
        for realism in realisms:
            for name in scenes:
                todo = [(c, r, p) for c, r in used for p in presets
                        if (name, rig_name, realism, c, p) not in done]
                if not todo:
                    continue
                scene = make_scene(data, name, true, realism=realism, center_depth=args.center_depth,
                                   fill=args.fill, seed=(EXTRA + MB2014).index(name))
                t0 = time.perf_counter()
                image = cached_render(true, scene, None if args.render_cache is None else Path(args.render_cache),
                                      f"{name}_{rig_name}_{realism}_{args.center_depth:g}_{args.fill:g}")
                render_s = time.perf_counter() - t0
                self_rig: Rig | None = None
                self_err = ""
                self_info: dict[str, Any] = {}
                for calib, rig_used, preset in todo:
                    base = {"scene": name, "rig": rig_name, "realism": realism, "calib": calib, "preset": preset,
                            "render_s": render_s}
                    try:
                        if calib == "self":
                            if self_rig is None and not self_err:
                                try:
                                    cal = calibrate_from_scene(nominal_rig(true), [image])
                                    self_rig = cal.rig
                                    self_info = {k: v for k, v in cal.report().items() if k != "rig"}
                                    self_info["depth_error_unobserved"] = unobserved_depth_error(cal)
                                except PrismStereoError as exc:
                                    self_err = f"self-calibration: {exc}"
                            if self_err:
                                raise PrismStereoError(self_err)
                            rig_used = self_rig
                        assert rig_used is not None
                        row = {**base, **run_row(rig_used, true, image, scene, preset,
                                                  None if args.max_memory is None else int(args.max_memory))}
                        if calib == "self":
                            row["self_calibration"] = self_info
                            # what depth --self-calibrate adds to the run's warnings (api.depth)
                            row["warnings"] = (uncertainty_warnings(self_info["depth_error_unobserved"])
                                               + row["warnings"])
                    except PrismStereoError as exc:
                        row = {**base, "error": str(exc).splitlines()[0][:200]}
                    rows.append(row)
                    done.add(_key(row))
                    print(_fmt(row), flush=True)
                    tmp = res_file.with_suffix(".json.tmp")
                    tmp.write_text(json.dumps({"rows": rows, "load_start": load0}, indent=1, default=str))
                    tmp.replace(res_file)
    print("\n" + summary(rows))
    print(f"\nload average at start {load0[0]:.1f}, at end {os.getloadavg()[0]:.1f} ({os.cpu_count()} CPUs)")


if __name__ == "__main__":
    main()
