"""The apex band in the pipeline (issue 26): depth with and without the camera's lens keys on lens renders.

Run: PYTHONPATH=src NUMBA_CACHE_DIR=.numba_cache python benchmarks/bench_apex_band.py [--data ../shared/data]
     [--scenes cloth3,Motorcycle] [--f-numbers 8] [--presets balanced]

Each scene is ``bench_real_scenes.make_scene`` with the ``real`` realism (thin lens f/N focused at the centre
depth 1400 mm, Bayer RGGB, JPEG 85) through the thesis bi-prism; ``prismstereo depth`` then runs on the rig
without lens keys (the apex band is matched like any pixel) and on the rig with ``[camera] f_number`` and
``focus_distance`` (the band, ``optics.lens.apex_band_mask``, left out of matching). Per row: the band's
modelled width, median error, share within 1 %, coverage of the common view (``evaluate_depth``).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_real_scenes import default_data, make_scene, true_rig  # noqa: E402

from prismstereo.depth import DepthConfig, run_depth  # noqa: E402
from prismstereo.evaluation.depth_metrics import evaluate_depth  # noqa: E402
from prismstereo.matching.registry import PRESETS  # noqa: E402
from prismstereo.optics.lens import apex_band_width_px  # noqa: E402
from prismstereo.simulate import render_capture  # noqa: E402
from prismstereo.simulate.scene import ThinLens  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=None)
    ap.add_argument("--scenes", default="cloth3,Motorcycle")
    ap.add_argument("--f-numbers", default="8")
    ap.add_argument("--presets", default="balanced")
    args = ap.parse_args()
    data = args.data or default_data()
    rig = true_rig("biprism")
    print("| scene | f-number | band px | preset | lens keys | median % | within 1 % | coverage % | depth s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name in args.scenes.split(","):
        for n in (float(v) for v in args.f_numbers.split(",")):
            scene = make_scene(data, name, rig, realism="real", center_depth=1400.0, fill=1.3, seed=1)
            scene = dataclasses.replace(scene, lens=ThinLens(f_number=n, focus_distance=1400.0, samples=16))
            image = render_capture(rig, scene).image
            lens_rig = dataclasses.replace(rig, camera=dataclasses.replace(rig.camera, f_number=n,
                                                                           focus_distance=1400.0))
            width = apex_band_width_px(rig, f_number=n, focus_distance=1400.0)
            for preset in args.presets.split(","):
                for label, used in (("no", rig), ("yes", lens_rig)):
                    t0 = time.perf_counter()
                    res = run_depth(used, image, config=DepthConfig(method=PRESETS[preset]), progress=False)
                    secs = time.perf_counter() - t0
                    acc = evaluate_depth(res, scene=scene)
                    print(f"| {name} | {n:g} | {width:.0f} | {preset} | {label} | {100 * acc['median_rel']:.3f} | "
                          f"{100 * acc['within_1pct']:.1f} | {100 * acc['coverage']:.1f} | {secs:.0f} |", flush=True)


if __name__ == "__main__":
    main()
