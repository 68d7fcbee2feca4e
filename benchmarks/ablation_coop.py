"""Ablation of ``coop``'s steps: each step off in turn, on Middlebury v2 and on the validation scenes.

Usage::

    NUMBA_CACHE_DIR=.numba_cache .venv/bin/python benchmarks/ablation_coop.py [--steps full,split,sweep,...]
        [--v2 DIR] [--validation DIR] [--quick] [--json out.json]

``--v2`` defaults to ``../shared/data/middlebury`` (Tsukuba, Venus, Teddy, Cones: 12 numbers, bad > 1 px
nonocc / all / disc) and ``--validation`` to ``../shared/data/middlebury-extra`` (every scene found there,
nonocc / all); ``--quick`` runs Tsukuba and the first validation scene only (CI's time budget). Each row is one
configuration: ``full`` (the defaults), ``split`` (the plane support test off) or a step of
:data:`~prismstereo.matching.coop.steps.STEP_NAMES` (that step off, ``StepParams().without(step)``). A step earns
its place when switching it off raises the validation average and does not lower the v2 average by more than
0.1. The last full run: docs/EXPERIMENTS.md (issue 14, item 3) and ``benchmarks/results/ablation_coop.json``.

Per-step maps (where a scene is lost)::

    ... benchmarks/ablation_coop.py --stages OUTDIR --data ../shared/data/middlebury-2014 [--scenes a,b]

runs ``coop`` once per scene with ``keep_stages`` and prints, per scene, the bad-pixel rate (non-occluded; 2.0 px
for the Middlebury 2014 layout, else 1.0) of the map after each step, beside the BPASW and ``sgm`` maps and the
radiometry decision; ``OUTDIR/<scene>.npz`` keeps every map (``labels``, ``reliable``, the stage maps, ``sgm``)
for offline analysis.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from prismstereo.evaluation.middlebury import evaluate_disparity, list_scenes, load_scene
from prismstereo.matching import match
from prismstereo.matching.coop.pipeline import coop_match
from prismstereo.matching.coop.steps import STEP_NAMES, StepParams
from prismstereo.matching.segments.planes import PlaneParams

ROOT = Path(__file__).resolve().parents[1]
#: each step of ``coop`` after the initial map, and the keyword arguments that switch it off
STEPS: dict[str, dict[str, Any]] = {
    "full": {},
    "split": {"planes": PlaneParams(split_rounds=0)},
    **{name: {"steps": StepParams().without(name)} for name in STEP_NAMES if name != "optimise"},
}


def _run(scenes: list[tuple[str, Path]], kw: dict[str, Any]) -> dict[str, dict[str, float]]:
    out = {}
    for name, root in scenes:
        sc = load_scene(name, root)
        t = time.perf_counter()
        res = coop_match(sc.left, sc.right, max_disp=sc.max_disp, **kw)
        b = evaluate_disparity(res.disparity, sc, thresholds=(1.0,))["bad"]["1.0"]
        out[name] = {**b, "seconds": time.perf_counter() - t}
    return out


def _stages(out: Path, data: Path, names: list[str]) -> None:
    out.mkdir(parents=True, exist_ok=True)
    for name in names:
        sc = load_scene(name, data)
        t = 2.0 if (data / name / "calib.txt").is_file() or (data / "calib.txt").is_file() else 1.0
        t0 = time.perf_counter()
        res = coop_match(sc.left, sc.right, max_disp=sc.max_disp, keep_stages=True)
        sec = time.perf_counter() - t0
        maps = {**res.stages, "final": res.disparity,
                "sgm": match(sc.left, sc.right, max_disp=sc.max_disp, method="sgm").disparity}
        np.savez_compressed(out / f"{name}.npz", labels=res.labels, reliable=res.reliable, **maps)
        bad = {k: evaluate_disparity(v, sc, thresholds=(t,))["bad"][f"{t:.1f}"]["nonocc"]
               for k, v in maps.items() if k not in ("evidence", "split")}
        radio = {k: round(v, 2) for k, v in res.info.items() if k.startswith("radiometry")}
        print(f"{name} (bad {t:.1f} nonocc, coop {sec:.1f} s): " + ", ".join(f"{k} {v:.2f}" for k, v in bad.items())
              + f"; fallback px {res.info.get('fallback_pixels', 0):.0f}; {radio}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stages", default="", help="save and score each step's map per scene into this folder")
    ap.add_argument("--data", default="", help="with --stages: the data folder")
    ap.add_argument("--scenes", default="", help="with --stages: comma-separated scenes (default: all)")
    ap.add_argument("--steps", default=",".join(STEPS), help="configurations: full and/or step names")
    ap.add_argument("--v2", default=str(ROOT.parent / "shared" / "data" / "middlebury"))
    ap.add_argument("--validation", default=str(ROOT.parent / "shared" / "data" / "middlebury-extra"))
    ap.add_argument("--quick", action="store_true", help="Tsukuba and the first validation scene only")
    ap.add_argument("--json", default="")
    args = ap.parse_args()
    if args.stages:
        if not args.data:
            raise SystemExit("expected --data DIR with --stages")
        names = [s.strip() for s in args.scenes.split(",") if s.strip()] or list(list_scenes(args.data))
        _stages(Path(args.stages), Path(args.data), names)
        return
    v2 = [(s, Path(args.v2)) for s in ("tsukuba", "venus", "teddy", "cones")]
    val = [(s, Path(args.validation)) for s in list_scenes(args.validation)]
    if args.quick:
        v2, val = v2[:1], val[:1]
    names = [s.strip() for s in args.steps.split(",") if s.strip()]
    for n in names:
        if n not in STEPS:
            raise SystemExit(f"expected steps among {', '.join(STEPS)}, got {n!r}")
    head = (["config"] + [f"{s} {m}" for s, _ in v2 for m in ("nonocc", "all", "disc")] + ["v2 avg"]
            + [f"{s} {m}" for s, _ in val for m in ("nonocc", "all")] + ["val avg nonocc", "val avg all", "s/pair"])
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    rows = {}
    for n in names:
        r2 = _run(v2, STEPS[n])
        rv = _run(val, STEPS[n])
        twelve = [r2[s][m] for s, _ in v2 for m in ("nonocc", "all", "disc")]
        vn = [rv[s]["nonocc"] for s, _ in val]
        va = [rv[s]["all"] for s, _ in val]
        secs = np.mean([r["seconds"] for r in list(r2.values()) + list(rv.values())])
        cells = ([("full" if n == "full" else f"-{n}")] + [f"{v:.2f}" for v in twelve] + [f"{np.mean(twelve):.3f}"]
                 + [f"{v:.2f}" for s, _ in val for v in (rv[s]["nonocc"], rv[s]["all"])]
                 + [f"{np.mean(vn):.3f}", f"{np.mean(va):.3f}", f"{secs:.1f}"])
        print("| " + " | ".join(cells) + " |", flush=True)
        rows[n] = {"v2": r2, "validation": rv, "v2_avg12": float(np.mean(twelve)),
                   "val_avg_nonocc": float(np.mean(vn)), "val_avg_all": float(np.mean(va))}
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
