"""Depth at the camera's resolution: every preset at 0.8, 3 and 12 megapixels (issue 30, item 6).

For each built-in scene (``robot``: the simulator's bi-prism robot scene; ``demo``: the demo's box, ball and
panel; ``plane``: a tilted textured plane at 1.4 m) a capture is rendered at each size through the thesis
bi-prism rig (:func:`prismstereo.simulate.robot_scene`'s camera scaled: width W, height 3W/4, pixel size
4.65 µm × 1024 / W, so the optics and the field of view stay the thesis rig's); ``mb:NAME`` is a photographed
validation scene of ``bench_real_scenes.py`` (``mb:Adirondack``, ``mb:wood2``: its RGB-D copy at 1.4 m, ideal
realism, its seed) through the same scaled rig. Then, per preset, ONE
subprocess (so that its peak memory is its own: ``resource.getrusage(RUSAGE_SELF).ru_maxrss``; tracemalloc
misses numpy's and numba's allocations):

1. ``run_depth(rig, capture, apply_preset(DepthConfig(), p))`` (the preset's profile) once (numba's cache
   loaded, the rig's set-up computed and cached on disk), then again: the second run is the one measured, as
   ``prismstereo depth RIG capture.png --preset P`` on a rig whose set-up is cached (its ``run.json`` ``timings_s``);
2. OpenCV StereoSGBM (``MODE_SGBM_3WAY``, block 5, P1 = 8·3·25, P2 = 32·3·25) on the same rectified pair
   and disparity range, best of 3, in the same process;
3. accuracy against the render's ground truth (:func:`~prismstereo.evaluation.depth_metrics.evaluate_depth`):
   median relative depth error, share of points within 1 %, coverage of the common view.

Printed: seconds per frame (the pipeline's own total), its stages, the per-frame work outside matching as
a share of the frame (wall, and in CPU seconds of the process, which a loaded machine distorts less),
× SGBM (the whole frame, and the match step alone, against SGBM's time in the same process), seconds per
megapixel, peak RSS, accuracy, the load average when the child ended. ``--c2f on,off`` runs each preset with
coarse-to-fine forced on and off (one child each) and prints, per preset and size, the on − off differences
of median depth error and coverage (the issue's "accuracy does not pay": within 0.02 points and 2 points).
``--stream`` adds a streaming run (:func:`prismstereo.batch.stream.run_stream`, ``fast``) over a lossless
video of ``--stream-frames`` renders at the first size, once with the depth range :data:`STREAM_RANGE_MM`
given and once without (the stream narrows the rig's range with the first frame): frames/s; each with the stream's
temporal prior on and off (``--stream-prior``: the previous frame's matches as each pixel's band,
:mod:`prismstereo.matching.temporal`). ``--stream-motion N`` streams N renders of a moving scene instead of
copies (the robot's objects walking 1.5 mm right and 15 mm nearer per frame; from frame ``N - N // 4`` a cut to the
``plane`` scene), with the range given, prior on and off in one child, and prints each frame's accuracy against
its ground truth in both (off = the per-frame path).

    NUMBA_CACHE_DIR=.numba_cache PYTHONPATH=src .venv/bin/python benchmarks/bench_scale.py \\
        --sizes 1024,2048 --presets fast,balanced --scenes robot [--stream] [--json out.json]
    ... --sizes 4096 --presets fast          # 12 MP: several GB per run; run one at a time
    ... --sizes 1024 --presets fast --c2f on,off   # coarse-to-fine against the full search

Each run is a fresh process: numba's compiled kernels come from its disk cache (``prismstereo warmup``
first, or the first run pays the compile, which the warm-up run absorbs).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("NUMBA_CACHE_DIR", os.path.join(os.path.dirname(__file__), "..", ".numba_cache"))

SCENES = ("robot", "demo", "plane")
#: prefix of a photographed validation scene (``mb:Adirondack``, ``mb:wood2``: bench_real_scenes' list)
PHOTOGRAPHED = "mb:"
PRESETS = ("fast", "balanced", "accurate")
#: the stream's depth range (a stream has no image to narrow the rig's range with): the built-in scenes' objects
#: and walls lie at 1.2-2.2 m
STREAM_RANGE_MM = (1000.0, 2500.0)


def _scene(name: str, width: int) -> tuple[Any, Any]:
    from dataclasses import replace

    from prismstereo.apps.demo import demo_scene, plane_scene
    from prismstereo.simulate import robot_scene

    rig, robot = robot_scene(width=width)
    if name == "robot":
        return rig, robot
    if name == "demo":
        return rig, replace(demo_scene(), supersample=2)
    if name == "plane":
        return rig, plane_scene(1400.0, tilt_deg=25.0)
    if name.startswith(PHOTOGRAPHED):
        # the validation scenes as bench_real_scenes renders them (ideal realism, its centre depth, fill and
        # seed), through the same rig scaled to this width
        import bench_real_scenes as brs

        mb = name.removeprefix(PHOTOGRAPHED)
        if mb not in brs.EXTRA + brs.MB2014:
            raise SystemExit(f"--scenes: expected mb:NAME among {', '.join(brs.EXTRA + brs.MB2014)}, got {name!r}")
        return rig, brs.make_scene(brs.default_data(), mb, rig, realism="ideal", center_depth=1400.0, fill=1.3,
                                   seed=(brs.EXTRA + brs.MB2014).index(mb))
    raise SystemExit(f"--scenes: expected names among {', '.join(SCENES)} or mb:NAME, got {name!r}")


def _render(scene: str, width: int, folder: Path) -> None:
    """capture.png, depth_gt.pfm and rig.toml of a scene at a width (in a child: a 12 MP render is large)."""
    from prismstereo.io import write_image, write_pfm
    from prismstereo.simulate import render_capture

    rig, sc = _scene(scene, width)
    cap = render_capture(rig, sc)
    folder.mkdir(parents=True, exist_ok=True)
    write_image(folder / "capture.png", cap.image)
    write_pfm(folder / "depth_gt.pfm", cap.depth)
    rig.save(folder / "rig.toml")


def _sgbm_seconds(left: Any, right: Any, lo: int, hi: int, repeat: int = 3) -> float:
    import cv2

    n = int(math.ceil((hi - lo + 1) / 16.0)) * 16
    b = 5
    sgbm = cv2.StereoSGBM_create(minDisparity=int(lo), numDisparities=n, blockSize=b, P1=8 * 3 * b * b,  # type: ignore[attr-defined]
                                 P2=32 * 3 * b * b, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    best = float("inf")
    for _ in range(repeat):
        t = time.perf_counter()
        sgbm.compute(left, right)
        best = min(best, time.perf_counter() - t)
    return best


def _depth_child(folder: Path, what: str) -> dict[str, Any]:
    """One preset (``preset`` or ``preset:c2f-mode``) on one capture (a child process): the measured second
    run, SGBM, accuracy, peak RSS."""
    import numpy as np

    from prismstereo.config import load_rig
    from prismstereo.depth import DepthConfig, run_depth
    from prismstereo.depth.presets import apply_preset
    from prismstereo.evaluation.depth_metrics import evaluate_depth, read_depth_gt
    from prismstereo.io import read_image

    rig = load_rig(folder / "rig.toml")
    img = read_image(folder / "capture.png")
    gt = read_depth_gt(folder / "depth_gt.pfm", rig)
    preset, _, mode = what.partition(":")
    cfg = apply_preset(DepthConfig(coarse_to_fine=mode or "auto"), preset, given=["coarse_to_fine"])
    t = time.perf_counter()
    run_depth(rig, img, config=cfg, progress=False)
    first = time.perf_counter() - t
    res = run_depth(rig, img, config=cfg, progress=False)
    acc = evaluate_depth(res, depth_gt=gt)
    lo, hi = res.disparity_range
    sgbm = _sgbm_seconds(np.ascontiguousarray(res.left), np.ascontiguousarray(res.right), lo, hi)
    return {"timings": {k: round(v, 4) for k, v in res.timings.items()},
            "cpu": {k: round(v, 4) for k, v in res.cpu_timings.items()},
            "match_timings": {k: round(v, 4) for k, v in res.match_timings.items()},
            "first_run_s": round(first, 3), "sgbm_s": round(sgbm, 4), "disparity_range": [lo, hi],
            "rectified": list(res.left.shape[:2]),
            "median_rel": acc["median_rel"], "within_1pct": acc["within_1pct"], "coverage": acc["coverage"],
            "c2f": bool(res.match_info.get("coarse_to_fine", False)),
            "peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20,
            "load": open("/proc/loadavg").read().split()[0]}


#: the moving scene of ``--stream-motion``: the robot's objects move this far per frame (mm, camera frame)
MOTION_MM = (1.5, 0.0, -15.0)


def _render_motion(width: int, folder: Path, frames: int) -> None:
    """``--stream-motion``: frame_<k>.png and depth_gt_<k>.pfm of the moving robot scene, a cut to the ``plane``
    scene from frame ``frames - frames // 4`` (in a child)."""
    from dataclasses import replace

    from prismstereo.apps.demo import plane_scene
    from prismstereo.io import write_image, write_pfm
    from prismstereo.simulate import render_capture, robot_scene

    rig, robot = robot_scene(width=width)
    folder.mkdir(parents=True, exist_ok=True)
    rig.save(folder / "rig.toml")
    cut = frames - frames // 4
    for k in range(frames):
        if k < cut:
            objs = list(robot.objects)
            moved = [o if o.name in ("wall", "floor") else
                     replace(o, center=tuple(c + k * m for c, m in zip(o.center, MOTION_MM, strict=True)))
                     for o in objs]
            scene = replace(robot, objects=tuple(moved))
        else:
            scene = plane_scene(1400.0, tilt_deg=25.0)
        cap = render_capture(rig, scene)
        write_image(folder / f"frame_{k:03d}.png", cap.image)
        write_pfm(folder / f"depth_gt_{k:03d}.pfm", cap.depth)


def _video_of(images: list[Any], path: Path) -> Path:
    import cv2

    vw = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"FFV1"), 10.0, (images[0].shape[1], images[0].shape[0]))
    for img in images:
        vw.write(cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    vw.release()
    return path


def _stream_child(folder: Path, frames: int, given: bool = True, prior: bool = True) -> dict[str, Any]:
    """A fast stream over a lossless video of ``frames`` copies of the capture (a child process); ``given``:
    with :data:`STREAM_RANGE_MM`, else the stream narrows the rig's range with the first frame; ``prior``: the
    stream's temporal prior on (its default) or off."""
    from prismstereo.batch.stream import run_stream
    from prismstereo.config import load_rig
    from prismstereo.depth import DepthConfig
    from prismstereo.depth.presets import apply_preset
    from prismstereo.io import read_image

    rig = load_rig(folder / "rig.toml")
    img = read_image(folder / "capture.png")
    temporal = {} if prior else {"temporal": None}
    with tempfile.TemporaryDirectory() as tmp:
        video = _video_of([img] * frames, Path(tmp) / "caps.avi")
        # warm: numba's kernels loaded and the set-up cached, on the first frames (a banded one among them)
        cfg = apply_preset(DepthConfig(depth_range=STREAM_RANGE_MM if given else None), "fast", given=["depth_range"])
        run_stream(rig, str(video), Path(tmp) / "warm", config=cfg, max_frames=2, preset="fast", **temporal)
        c = time.process_time()
        s = run_stream(rig, str(video), Path(tmp) / "out", config=cfg, preset="fast", **temporal)
        cpu = time.process_time() - c
        info = json.loads((Path(tmp) / "out" / "stream.json").read_text())
    return {"frames": s.frames, "frames_per_s": round(s.frames_per_s, 3), "stage_s": s.stage_s,
            "cpu_per_frame": round(cpu / max(s.frames, 1), 4), "prior": prior,
            "temporal": (info.get("temporal_prior") or {}).get("frames"),
            "range": "given" if given else "narrowed by the first frame",
            "disparity_range": info["disparity_range"], "range_searches": info.get("range_searches", 0),
            "setup_s": round(s.setup_s, 3), "peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20}


def _motion_child(folder: Path, frames: int) -> dict[str, Any]:
    """``--stream-motion``: the moving scene's frames streamed with the prior off and on (range given), each
    frame's accuracy against its ground truth, frames/s and CPU seconds per frame of both."""
    from prismstereo.batch.stream import run_stream
    from prismstereo.config import load_rig
    from prismstereo.depth import DepthConfig
    from prismstereo.depth.presets import apply_preset
    from prismstereo.evaluation.depth_metrics import evaluate_depth, read_depth_gt
    from prismstereo.io import read_image

    rig = load_rig(folder / "rig.toml")
    images = [read_image(folder / f"frame_{k:03d}.png") for k in range(frames)]
    gts = [read_depth_gt(folder / f"depth_gt_{k:03d}.pfm", rig) for k in range(frames)]
    cfg = apply_preset(DepthConfig(depth_range=STREAM_RANGE_MM), "fast", given=["depth_range"])
    out: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp:
        video = _video_of(images, Path(tmp) / "moving.avi")
        run_stream(rig, str(video), Path(tmp) / "warm", config=cfg, max_frames=2, preset="fast")
        for name, temporal in (("off", {"temporal": None}), ("on", {})):
            runs: list[Any] = []
            c = time.process_time()
            s = run_stream(rig, str(video), Path(tmp) / name, config=cfg, preset="fast",
                           on_frame=lambda _, res, runs=runs: runs.append(res), **temporal)
            cpu = time.process_time() - c
            accs = []
            for res, gt in zip(runs, gts, strict=True):
                a = evaluate_depth(res, depth_gt=gt)
                accs.append({"median_rel": a["median_rel"], "within_1pct": a["within_1pct"],
                             "coverage": a["coverage"], "match": res.match_info.get("band_mean")})
            info = json.loads((Path(tmp) / name / "stream.json").read_text())
            kinds = [json.loads((Path(tmp) / name / "frames" / f"moving_{k:06d}" / "frame.json").read_text())["match"]
                     for k in range(frames)]
            out[name] = {"frames_per_s": round(s.frames_per_s, 3), "cpu_per_frame": round(cpu / max(s.frames, 1), 4),
                         "stage_s": s.stage_s, "accuracy": accs, "kinds": kinds,
                         "temporal": (info.get("temporal_prior") or {}).get("frames")}
    return out


def _child(args: list[str]) -> dict[str, Any]:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(__file__).resolve().parents[1] / "src"),
                                                        os.environ.get("PYTHONPATH", "")])}
    p = subprocess.run([sys.executable, __file__, *args], capture_output=True, text=True, env=env)
    if p.returncode != 0:
        return {"error": (p.stderr.strip().splitlines() or [f"exit {p.returncode}"])[-1],
                "exit": p.returncode}
    return dict(json.loads(p.stdout.strip().splitlines()[-1]))


def _row(scene: str, width: int, preset: str, r: dict[str, Any]) -> str:
    mp = width * width * 3 / 4 / 1e6
    if "error" in r:
        return f"| {scene} | {width}×{width * 3 // 4} | {preset} | failed: {r['error']} (exit {r['exit']}) |"
    t = r["timings"]
    total = t["total"]
    outside = total - t.get("match", 0.0)
    stages = ", ".join(f"{k} {v:.2f}" for k, v in t.items() if k not in ("total", "validate") and v >= 0.005)
    cpu = r.get("cpu", {})
    cpu_total = sum(cpu.values())
    cpu_out = cpu_total - cpu.get("match", 0.0)
    return (f"| {scene} | {width}×{width * 3 // 4} | {preset} | {total:.2f} | {100 * outside / total:.0f} % | "
            f"{cpu_total:.2f} | {100 * cpu_out / max(cpu_total, 1e-9):.0f} % | "
            f"{total / r['sgbm_s']:.0f}× ({r['sgbm_s']:.3f} s) | {t.get('match', 0.0) / r['sgbm_s']:.0f}× | "
            f"{total / mp:.2f} | {r['peak_rss_gb']:.2f} | "
            f"{100 * r['median_rel']:.3f} % | {100 * r['within_1pct']:.1f} % | {100 * r['coverage']:.1f} % | "
            f"{'on' if r.get('c2f') else 'off'} | {r.get('load', '')} | {stages} |")


def _c2f_rows(results: list[dict[str, Any]]) -> list[str]:
    """Coarse-to-fine on − off, per scene, size and preset, where both ran."""
    out = []
    by = {(r["scene"], r["width"], r["preset"], r.get("mode")): r for r in results if "error" not in r
          and not r.get("stream")}
    for (scene, width, preset, mode), on in by.items():
        off = by.get((scene, width, preset, "off"))
        if mode != "on" or off is None:
            continue
        out.append(f"| {scene} | {width}×{width * 3 // 4} | {preset} | "
                   f"{100 * (on['median_rel'] - off['median_rel']):+.4f} | "
                   f"{100 * (on['coverage'] - off['coverage']):+.2f} | "
                   f"{on['timings']['match'] / off['timings']['match']:.2f} |")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="1024,2048,4096", help="sensor widths (4:3): 1024 = 0.8 MP, 2048 = 3 MP, "
                                                              "4096 = 12 MP")
    ap.add_argument("--presets", default=",".join(PRESETS))
    ap.add_argument("--scenes", default="robot", help=f"among {','.join(SCENES)}, or mb:NAME for a photographed "
                                                      "validation scene of bench_real_scenes.py (mb:Adirondack)")
    ap.add_argument("--stream", action="store_true", help="also a fast stream at the first size: frames/s")
    ap.add_argument("--stream-frames", type=int, default=12)
    ap.add_argument("--stream-prior", default="on,off", help="the stream's temporal prior: on, off or on,off")
    ap.add_argument("--stream-motion", type=int, default=0, metavar="N",
                    help="also stream N renders of a moving scene (a cut at the last quarter), prior on and off")
    ap.add_argument("--c2f", default=None, metavar="MODES",
                    help="coarse-to-fine modes to run each preset with (auto,on,off; default: auto only)")
    ap.add_argument("--json", default=None, help="write the measurements here")
    ap.add_argument("--work", default=None, help="folder for the renders (default: a temporary one)")
    ap.add_argument("--child", nargs=3, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--table", default=None, metavar="JSON", help="print the table of an earlier --json and exit")
    args = ap.parse_args()
    if args.child is not None:
        kind, folder, what = args.child
        if kind == "render":
            scene, width = what.rsplit(":", 1)
            _render(scene, int(width), Path(folder))
            print(json.dumps({"ok": True}))
        elif kind == "depth":
            print(json.dumps(_depth_child(Path(folder), what)))
        elif kind == "motion-render":
            width, _, frames = what.partition(":")
            _render_motion(int(width), Path(folder), int(frames))
            print(json.dumps({"ok": True}))
        elif kind == "motion":
            print(json.dumps(_motion_child(Path(folder), int(what))))
        else:
            frames, rng, prior = (what.split(":") + ["on"])[:3]
            print(json.dumps(_stream_child(Path(folder), int(frames), given=rng != "auto", prior=prior == "on")))
        return
    if args.table is not None:
        rows = json.loads(Path(args.table).read_text())
        for r in rows:
            if not r.get("stream"):
                print(_row(r["scene"], r["width"], r["preset"], r))
        for line in _c2f_rows(rows):
            print(line)
        return
    sizes = [int(s) for s in args.sizes.split(",")]
    presets = [p.strip() for p in args.presets.split(",")]
    scenes = [s.strip() for s in args.scenes.split(",")]
    modes = [m.strip() for m in args.c2f.split(",")] if args.c2f else [""]
    bad = ([p for p in presets if p not in PRESETS]
           + [s for s in scenes if s not in SCENES and not s.startswith(PHOTOGRAPHED)]
           + [m for m in modes if m not in ("", "auto", "on", "off")])
    if bad:
        raise SystemExit(f"expected presets among {PRESETS} and scenes among {SCENES} or mb:NAME, got {bad}")
    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="bench_scale-"))
    results: list[dict[str, Any]] = []
    print(f"load average {open('/proc/loadavg').read().split()[:3]}; renders in {work}")
    print("| scene | capture | preset | s per frame | outside match | CPU s | CPU outside match | × SGBM-3WAY | "
          "match × SGBM | s per MP | peak RSS GB | median depth err | within 1 % | coverage | c2f | load | "
          "stages (s) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for scene in scenes:
        for width in sizes:
            folder = work / f"{scene.replace(':', '-')}-{width}"
            if not (folder / "capture.png").is_file():
                r = _child(["--child", "render", str(folder), f"{scene}:{width}"])
                if "error" in r:
                    print(f"| {scene} | {width} | render failed: {r['error']} |")
                    continue
            for preset in presets:
                for mode in modes:
                    r = _child(["--child", "depth", str(folder), f"{preset}:{mode}" if mode else preset])
                    results.append({"scene": scene, "width": width, "preset": preset, "mode": mode, **r})
                    print(_row(scene, width, preset, r), flush=True)
    priors = [p.strip() for p in args.stream_prior.split(",")]
    for rng, prior in ((r_, p_) for r_ in ("given", "auto") for p_ in priors) if args.stream else ():
        folder = work / f"{scenes[0].replace(':', '-')}-{sizes[0]}"
        r = _child(["--child", "stream", str(folder), f"{args.stream_frames}:{rng}:{prior}"])
        results.append({"scene": scenes[0], "width": sizes[0], "stream": True, **r})
        if "error" in r:
            print(f"stream: failed: {r['error']}")
        else:
            s = r["stage_s"]
            print(f"stream ({scenes[0]}, {sizes[0]}×{sizes[0] * 3 // 4}, fast, {r['frames']} frames, depth range "
                  f"{r['range']}: {r['disparity_range']} px, {r['range_searches']} searches, prior {prior} "
                  f"{r.get('temporal') or ''}): {r['frames_per_s']:.2f} frames/s, CPU {r['cpu_per_frame']:.3f} s a "
                  f"frame (per frame: read {s['read']:.3f} s, depth {s['depth']:.3f} s, write {s['write']:.3f} s, "
                  f"overlapped), peak RSS {r['peak_rss_gb']:.2f} GB, load {open('/proc/loadavg').read().split()[0]}",
                  flush=True)
    if args.stream_motion:
        folder = work / f"motion-{sizes[0]}-{args.stream_motion}"
        if not (folder / f"frame_{args.stream_motion - 1:03d}.png").is_file():
            _child(["--child", "motion-render", str(folder), f"{sizes[0]}:{args.stream_motion}"])
        r = _child(["--child", "motion", str(folder), str(args.stream_motion)])
        results.append({"scene": "motion", "width": sizes[0], "stream": True, **r})
        if "error" in r:
            print(f"moving stream: failed: {r['error']}")
        else:
            for name in ("off", "on"):
                m = r[name]
                print(f"moving stream, prior {name}: {m['frames_per_s']:.2f} frames/s, CPU {m['cpu_per_frame']:.3f} s "
                      f"a frame, depth {m['stage_s']['depth']:.3f} s a frame, {m['temporal']}")
            print("| frame | match (on) | median err off / on | within 1 % off / on | coverage off / on |")
            print("|---|---|---|---|---|")
            for k, (a, b) in enumerate(zip(r["off"]["accuracy"], r["on"]["accuracy"], strict=True)):
                print(f"| {k} | {r['on']['kinds'][k]} (band {b['match'] or '-'}) | {100 * a['median_rel']:.4f} / "
                      f"{100 * b['median_rel']:.4f} % | {100 * a['within_1pct']:.2f} / "
                      f"{100 * b['within_1pct']:.2f} % | {100 * a['coverage']:.2f} / {100 * b['coverage']:.2f} % |")
            print(f"load {open('/proc/loadavg').read().split()[0]}", flush=True)
    lines = _c2f_rows(results)
    if lines:
        print("\n| scene | capture | preset | median depth err on − off (points) | coverage on − off (points) | "
              "match s on / off |")
        print("|---|---|---|---|---|---|")
        for line in lines:
            print(line)
    print(f"load average {open('/proc/loadavg').read().split()[:3]}")
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
