"""Every matcher on the three Middlebury sets: bad 2.0 / bad 1.0 (non-occluded) and seconds, side by side.

Usage::

    PYTHONPATH=src NUMBA_CACHE_DIR=.numba_cache .venv/bin/python benchmarks/bench_middlebury2014.py
        [--sets 2014,v2,validation] [--methods sgbm,sgm,bpasw,coop] [--scenes a,b] [--json out.json]

The sets are ``../shared/data/middlebury-2014`` (MiddEval3 training, quarter resolution, ``ndisp`` from each
``calib.txt``), ``../shared/data/middlebury`` (v2) and ``../shared/data/middlebury-extra`` (2005/2006 validation);
``--root`` changes the folder holding them. Each matcher runs with its defaults through the evaluation harness
(:func:`prismstereo.evaluation.middlebury.evaluate_method`), all in this one process, so seconds are comparable
as ratios (OpenCV SGBM, ``sgbm``, is the reference; state the load average beside them). Per set: one row per
scene with ``bad2 / bad1 / s`` per matcher, the average, the ratio of each average to SGBM's, and for ``coop``
the scenes where it is above ``sgm`` or ``bpasw`` by more than 0.2 points (bad 2.0). For v2 the 12-number
average (bad 1.0 nonocc / all / disc) is printed too.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from prismstereo.evaluation.middlebury import evaluate_method, list_scenes

ROOT = Path(__file__).resolve().parents[1].parent / "shared" / "data"
SETS = {"2014": "middlebury-2014", "v2": "middlebury", "validation": "middlebury-extra"}


def _table(name: str, res: dict[str, dict[str, Any]]) -> list[str]:
    methods = list(res)
    scenes = list(next(iter(res.values()))["scenes"])
    lines = [f"### {name}", "", "| scene | " + " | ".join(f"{m} bad2 / bad1 / s" for m in methods) + " |",
             "|---|" + "---|" * len(methods)]
    for s in scenes:
        rows = {m: res[m]["scenes"][s] for m in methods}
        cells = [f"{r['bad']['2.0']['nonocc']:.2f} / {r['bad']['1.0']['nonocc']:.2f} / {r['seconds']:.2f}"
                 for r in rows.values()]
        lines.append(f"| {s} | " + " | ".join(cells) + " |")
    avg = [f"**{res[m]['average']['bad2.0_nonocc']:.2f} / {res[m]['average']['nonocc']:.2f} / "
           f"{res[m]['average']['seconds']:.2f}**" for m in methods]
    lines.append("| **average** | " + " | ".join(avg) + " |")
    if "sgbm" in res:
        ref = res["sgbm"]["average"]
        ratio = [f"{res[m]['average']['bad2.0_nonocc'] / max(ref['bad2.0_nonocc'], 1e-9):.3f} / "
                 f"{res[m]['average']['nonocc'] / max(ref['nonocc'], 1e-9):.3f} / "
                 f"{res[m]['average']['seconds'] / max(ref['seconds'], 1e-9):.1f}x" for m in methods]
        lines.append("| ratio to sgbm | " + " | ".join(ratio) + " |")
    if name == "v2":
        twelve = {m: float(np.mean([res[m]["scenes"][s]["bad"]["1.0"][k] for s in scenes
                                    for k in ("nonocc", "all", "disc")])) for m in methods}
        lines += ["", "v2 avg12 (bad 1.0 nonocc/all/disc): " + ", ".join(f"{m} {v:.3f}" for m, v in twelve.items())]
    if "coop" in res:
        def b2(m: str, s: str) -> float:
            return float(res[m]["scenes"][s]["bad"]["2.0"]["nonocc"])

        worse = [f"{s} ({o} {b2(o, s):.2f} < coop {b2('coop', s):.2f})"
                 for s in scenes for o in ("sgm", "bpasw") if o in res and b2("coop", s) > b2(o, s) + 0.2]
        lines += ["", "coop above sgm / bpasw by > 0.2 (bad 2.0): " + (", ".join(worse) or "none")]
    return lines + [""]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", default="2014,v2,validation")
    ap.add_argument("--methods", default="sgbm,sgm,bpasw,coop")
    ap.add_argument("--scenes", default="", help="comma-separated scene names (of any set; others skipped)")
    ap.add_argument("--root", default=str(ROOT), help="folder holding the three data sets")
    ap.add_argument("--json", default="")
    args = ap.parse_args()
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    want = {s.strip().lower() for s in args.scenes.split(",") if s.strip()}
    out: dict[str, Any] = {"load_average_start": os.getloadavg()[0], "sets": {}}
    for key in [s.strip() for s in args.sets.split(",") if s.strip()]:
        if key not in SETS:
            raise SystemExit(f"expected sets among {', '.join(SETS)}, got {key!r}")
        data = Path(args.root) / SETS[key]
        scenes = tuple(s for s in list_scenes(data) if not want or s.lower() in want)
        if not scenes:
            continue
        res = {m: evaluate_method(m, data_dir=data, scenes=scenes) for m in methods}
        out["sets"][key] = res
        print("\n".join(_table(key, res)), flush=True)
    out["load_average_end"] = os.getloadavg()[0]
    print(f"load average (1 min) at start {out['load_average_start']:.2f}, at end {out['load_average_end']:.2f}")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1, default=float))


if __name__ == "__main__":
    main()
