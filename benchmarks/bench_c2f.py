"""Coarse-to-fine against the full search on the Middlebury scenes (issue 30), same process.

For every scene of v2 (``../shared/data/middlebury``), the validation scenes (``middlebury-extra``) and
Middlebury 2014 Q (``middlebury-2014``), each method runs twice on the scene's own range: the full search
(``scale=None``, the matcher called once) and :func:`~prismstereo.matching.scale.match_scaled` with
``coarse_to_fine="on"`` (the images are below the automatic size, so it is forced) and 96 px tiles (``--tile``;
the default 256 would give these small images only 2-4 tiles) and ``--band`` (``segment``: a band per row segment
for the matchers that take one, ``tile``: one per tile). Printed per data set:
bad > 1 px nonocc (%), the median absolute disparity error over nonocc (px), coverage (cross-checked pixels
over nonocc, %) and the seconds of each, and the averages; with ``--json`` the table as JSON.

    PYTHONPATH=src NUMBA_CACHE_DIR=.numba_cache .venv/bin/python benchmarks/bench_c2f.py --methods sgm,bpasw
    ... --methods bpasw --band tile        # the band per tile (before stop 38)
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("NUMBA_CACHE_DIR", os.path.join(os.path.dirname(__file__), "..", ".numba_cache"))

import numpy as np  # noqa: E402

from prismstereo.evaluation.middlebury import evaluate_disparity, list_scenes, load_scene  # noqa: E402
from prismstereo.matching import match  # noqa: E402
from prismstereo.matching.scale import ScaleParams  # noqa: E402

_SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
SETS = {"v2": "middlebury", "validation": "middlebury-extra", "2014": "middlebury-2014"}


def _stats(disp: np.ndarray, valid: np.ndarray, scene: object) -> dict[str, float]:
    ev = evaluate_disparity(disp, scene)  # type: ignore[arg-type]
    m = scene.masks["nonocc"]  # type: ignore[attr-defined]
    gt = scene.gt  # type: ignore[attr-defined]
    err = np.abs(disp - gt)[m & np.isfinite(disp)]
    return {"bad1": ev["bad"]["1.0"]["nonocc"], "median_err": float(np.median(err)) if err.size else float("nan"),
            "coverage": float(100.0 * valid[m].mean())}


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--methods", default="sgm,bpasw")
    ap.add_argument("--sets", default="v2,validation,2014")
    ap.add_argument("--data", default=str(_SHARED))
    ap.add_argument("--json", default=None)
    ap.add_argument("--factor", type=int, default=2)
    ap.add_argument("--tile", type=int, default=96, help="core tile side (default 96: several tiles per scene)")
    ap.add_argument("--band", default="segment", choices=("segment", "tile"),
                    help="ScaleParams.band: a band per row segment (default) or per tile")
    args = ap.parse_args()
    out: dict[str, object] = {"loadavg": open("/proc/loadavg").read().split()[:3], "band": args.band}
    scale = ScaleParams(coarse_to_fine="on", factor=args.factor, tile=args.tile, band=args.band)
    for method in args.methods.split(","):
        for group in args.sets.split(","):
            root = Path(args.data) / SETS[group]
            if not root.is_dir():
                print(f"{group}: {root} missing, skipped")
                continue
            rows = []
            print(f"\n{method} on {group} (load {open('/proc/loadavg').read().split()[0]})")
            print("| scene | bad1 full | bad1 c2f | med err full | med err c2f | cover full | cover c2f | s full | "
                  "s c2f | band | full-range tiles |")
            print("|---|---|---|---|---|---|---|---|---|---|---|")
            for name in list_scenes(root):
                sc = load_scene(name, root)
                lo = int(getattr(sc, "min_disp", 0) or 0)
                t = time.perf_counter()
                a = match(sc.left, sc.right, max_disp=sc.max_disp, min_disp=lo, method=method)
                ta = time.perf_counter() - t
                t = time.perf_counter()
                b = match(sc.left, sc.right, max_disp=sc.max_disp, min_disp=lo, method=method, scale=scale)
                tb = time.perf_counter() - t
                sa, sb = _stats(a.disparity, a.valid, sc), _stats(b.disparity, b.valid, sc)
                info = b.extras["scale"]
                rows.append({"scene": name, "full": sa, "c2f": sb, "s_full": ta, "s_c2f": tb,
                             "band": info["band_mean"], "full_range_tiles": info["full_range_tiles"],
                             "tiles": info["tiles"]})
                print(f"| {name} | {sa['bad1']:.2f} | {sb['bad1']:.2f} | {sa['median_err']:.3f} | "
                      f"{sb['median_err']:.3f} | {sa['coverage']:.1f} | {sb['coverage']:.1f} | {ta:.2f} | {tb:.2f} | "
                      f"{info['band_mean']:.0f}/{sc.max_disp - lo + 1} | {info['full_range_tiles']}/{info['tiles']} |")
                sys.stdout.flush()
            if rows:
                def avg(k: str, f: str, rows: list = rows) -> float:
                    return float(np.mean([r[k][f] for r in rows]))
                print(f"| **average** | {avg('full', 'bad1'):.2f} | {avg('c2f', 'bad1'):.2f} | "
                      f"{avg('full', 'median_err'):.3f} | {avg('c2f', 'median_err'):.3f} | "
                      f"{avg('full', 'coverage'):.1f} | {avg('c2f', 'coverage'):.1f} | "
                      f"{np.mean([r['s_full'] for r in rows]):.2f} | {np.mean([r['s_c2f'] for r in rows]):.2f} | | |")
            out[f"{method}/{group}"] = rows
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
