"""Thin command line over the library (docs/cli.md). No algorithm code lives here.

Each subcommand has an ``_add_<name>`` function that declares its arguments and a ``_cmd_<name>``
function that calls the library. The handlers import what they run when they run: the numerical packages
(numba, scipy, OpenCV, Dask) take a second to import, seconds on a loaded machine, and ``prismstereo --help``
or a mistyped option should not wait for them. Every import here is downward (apps is the top layer).
Errors the user can fix (``PrismStereoError``) become one line on stderr and exit code 2; anything else is exit code 1.
"""

from __future__ import annotations

import argparse
import logging
import os
import re
import sys
from collections.abc import Callable, Sequence

from prismstereo import __version__
from prismstereo.apps.cli_args import parse_pair
from prismstereo.errors import ConfigError, PrismStereoError

log = logging.getLogger("prismstereo")

Handler = Callable[[argparse.Namespace], int]


def _parse_views(text: str | None) -> tuple[int, ...] | str | None:
    if text is None:
        return None
    if text.strip().lower() == "all":
        return "all"
    try:
        return tuple(int(v) for v in text.split(","))
    except ValueError:
        raise ConfigError(f"--views: expected face indices like 1,0 or 'all', got {text!r}") from None


# --------------------------------------------------------------------------- simulate
def _add_simulate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help="render a prism capture of a scene with exact ground truth")
    p.add_argument("scene", help="scene TOML (a [camera], [prism] and the scene objects)")
    p.add_argument("-o", "--output", required=True, help="output folder")
    p.add_argument("--supersample", type=int, default=None, help="samples per pixel side (overrides the scene)")
    p.set_defaults(handler=_cmd_simulate)


def _cmd_simulate(args: argparse.Namespace) -> int:
    from prismstereo.apps.simulate_folder import simulate_to_folder

    result = simulate_to_folder(args.scene, args.output, supersample=args.supersample)
    if result.capture.coverage < 0.01:
        log.warning("the render is %s: no object is seen through the prism (objects behind the camera or the "
                    "prism, or outside the field of view; see docs/rig.md for the frame)",
                    "blank" if result.capture.coverage == 0 else f"{100 * result.capture.coverage:.2f} % covered")
    print(result.summary())
    return 0


# --------------------------------------------------------------------------- calibrate
def _add_calibrate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("calibrate", help="virtual cameras of a rig from its optics -> cameras.json")
    p.add_argument("rig", help="rig TOML (docs/rig.md)")
    p.add_argument("-o", "--output", required=True, help="cameras.json to write")
    p.add_argument("--method", choices=["thesis", "fit"], default="fit", help="virtual camera model")
    p.set_defaults(handler=_cmd_calibrate)


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from prismstereo.cameras import calibrate_rig, cameras_table, write_cameras_json
    from prismstereo.config import load_rig
    from prismstereo.io import check_output_file

    rig = load_rig(args.rig)
    check_output_file(args.output)
    cams = calibrate_rig(rig, method=args.method)
    write_cameras_json(args.output, rig, cams, method=args.method)
    print(cameras_table(rig, cams))
    print(f"wrote {args.output}")
    return 0


_MIDDLEBURY_HELP = ("Middlebury folder of scenes, or one scene folder (default $PRISMSTEREO_MIDDLEBURY, else "
                     "../shared/data/middlebury); the Middlebury 2014 layout (im0.png, im1.png, disp0GT.pfm, "
                     "mask0nocc.png, calib.txt) is read too. "
                     "The v2 scenes come from https://vision.middlebury.edu/stereo/data/ (2003: teddy, cones; "
                     "2001: tsukuba, venus); layout: DIR/<scene>/left.png, right.png, disp_left.png "
                     "(ground truth x scale, 0 = unknown), nonocc.png, all.png, disc.png (see docs/formats.md)")


# --------------------------------------------------------------------------- reproduce
def _add_reproduce(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("reproduce", help="re-measure a thesis table beside the thesis's numbers")
    p.add_argument("table", help="table3.4, table4.3, table5.1, table6.1, table6.2, table7.1 or table7.2")
    p.add_argument("-o", "--output", required=True, help="output folder (markdown + JSON)")
    p.add_argument("--data", default=None, help=_MIDDLEBURY_HELP)
    p.add_argument("--quick", action="store_true", help="smaller, faster run (for smoke tests)")
    p.set_defaults(handler=_cmd_reproduce)


def _cmd_reproduce(args: argparse.Namespace) -> int:
    from pathlib import Path

    from prismstereo.apps.reproduce import reproduce_table

    result = reproduce_table(args.table, args.output, data_dir=Path(args.data) if args.data else None,
                             quick=args.quick)
    print(result.markdown)
    return 0


# --------------------------------------------------------------------------- match
def _parse_params(items: Sequence[str] | None) -> dict[str, object]:
    """``-p key=value`` tuning parameters; values parsed as JSON when possible (numbers, true, null)."""
    import json

    params: dict[str, object] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"--param: expected key=value, got {item!r}")
        try:
            params[key.strip()] = json.loads(value)
        except ValueError:
            params[key.strip()] = value
    return params


def _add_match(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("match", help="disparity of a rectified pair -> PFM (+ colourised PNG)")
    p.add_argument("left", help="rectified left image")
    p.add_argument("right", help="rectified right image")
    p.add_argument("-o", "--output", required=True, help="output disparity .pfm (a .png beside it)")
    p.add_argument("--max-disp", type=int, required=True, help="largest disparity searched (px)")
    p.add_argument("--min-disp", type=int, default=0, help="smallest disparity searched (px)")
    p.add_argument("--method", default="bpasw", help="matcher name (sad, ssd, ncc, shd, bpasw, sgbm, ...)")
    p.add_argument("-p", "--param", action="append", metavar="KEY=VALUE", help="matcher tuning parameter")
    _add_scale_flags(p, default="auto")
    p.set_defaults(handler=_cmd_match)


def _add_scale_flags(p: argparse.ArgumentParser, *, default: str | None) -> None:
    p.add_argument("--coarse-to-fine", default=default, choices=["auto", "on", "off"],
                   help="match a half-size pair over the whole range, then the full size in a band around it "
                        "(auto: from 4 megapixels, or where the full search would exceed --max-memory; docs/cli.md)")
    p.add_argument("--max-memory", default=None, metavar="SIZE",
                   help="peak-memory budget of the run, e.g. 6G (default: 80%% of the available memory); "
                        "the match is tiled to fit what the rest leaves, refused only when no tile fits")


def _cmd_match(args: argparse.Namespace) -> int:
    from pathlib import Path

    import numpy as np

    from prismstereo.io import check_output_file, output_files, read_image, write_image, write_pfm
    from prismstereo.io.images import image_size
    from prismstereo.io.memory import check_fits_in_memory
    from prismstereo.matching import get_matcher, match
    from prismstereo.matching.diagnostics import limit_warnings
    from prismstereo.matching.scale import (
        ScaleParams,
        default_memory_budget,
        estimate_memory,
        parse_memory,
        planned_memory,
    )
    from prismstereo.viz.colorize import colorize_disparity

    params = _parse_params(args.param)
    get_matcher(args.method, **params)  # method and parameters checked before reading images
    out = Path(args.output)
    if out.suffix.lower() != ".pfm":
        raise ConfigError(f"-o: expected a .pfm file name, got {args.output!r}")
    if args.max_disp < 0 or args.min_disp < 0 or args.min_disp > args.max_disp:
        raise ConfigError(f"expected 0 <= --min-disp <= --max-disp, got {args.min_disp} and {args.max_disp}")
    png = out.with_suffix(".png")
    check_output_file(out)  # before any work
    check_output_file(png)
    scale = ScaleParams(coarse_to_fine=args.coarse_to_fine, max_memory=parse_memory(args.max_memory))
    size = image_size(args.left)  # header only: refuse a match that cannot fit even tiled, before decoding
    if size is not None:
        # the images themselves first: a pair that cannot be held is not a matter of the tiling budget
        check_fits_in_memory(size[0] * size[1] * 64, what=f"a {size[0]}×{size[1]} pair and its maps",
                             hint="use smaller images", error=ConfigError)
        nd = args.max_disp - args.min_disp + 1
        budget = scale.max_memory if scale.max_memory is not None else default_memory_budget()
        # the run as it will be tiled (coarse levels, stitched maps, largest tile); refused here if no tile fits
        planned = planned_memory(args.method, size[1], size[0], max_disp=args.max_disp, min_disp=args.min_disp,
                                 scale=scale)
        log.info("match %s %d×%d, %d disparities: peak memory estimate %.2f GiB (budget %.2f GiB; untiled full "
                 "search %.2f GiB)", args.method, size[0], size[1], nd, planned / 2**30, budget / 2**30,
                 estimate_memory(args.method, size[1], size[0], nd) / 2**30)
    left, right = read_image(args.left), read_image(args.right)
    res = match(left, right, max_disp=args.max_disp, min_disp=args.min_disp, method=args.method, scale=scale,
                **params)
    d = res.disparity
    region = np.asarray((left.reshape(left.shape[0], left.shape[1], -1) > 0).any(axis=2))  # not a black border
    for line in limit_warnings(d, res.valid, min_disp=args.min_disp, max_disp=args.max_disp, region=region,
                               hint="--min-disp/--max-disp"):
        log.warning("%s", line)
    with output_files([out, png]) as (tmp_pfm, tmp_png):
        write_pfm(tmp_pfm, d)
        write_image(tmp_png, colorize_disparity(d, vmin=float(args.min_disp), vmax=float(args.max_disp),
                                                colorbar="disparity (px)"))
    fin = np.isfinite(d)
    print(f"{args.method}: {d.shape[1]}x{d.shape[0]}, valid (cross-check) {100.0 * res.valid.mean():.1f} %, "
          f"d in [{np.nanmin(d) if fin.any() else float('nan'):.2f}, "
          f"{np.nanmax(d) if fin.any() else float('nan'):.2f}], "
          f"{sum(res.timings.values()):.2f} s")
    print(f"wrote {out} and {png}")
    return 0


# --------------------------------------------------------------------------- evaluate
def _add_evaluate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("evaluate", help="evaluate a matcher on a benchmark (middlebury)")
    p.add_argument("benchmark", choices=["middlebury"], help="benchmark name")
    p.add_argument("--data", default=None, help=_MIDDLEBURY_HELP)
    p.add_argument("--method", default="bpasw", help="matcher name")
    p.add_argument("-o", "--output", required=True, help="output folder")
    p.add_argument("--scenes", default=None, help="comma-separated scene folder names (default: every scene in --data)")
    p.add_argument("-p", "--param", action="append", metavar="KEY=VALUE", help="matcher tuning parameter")
    p.add_argument("--baseline", default=None, metavar="METHOD",
                   help="also run this matcher (e.g. sgbm: OpenCV StereoSGBM) with its defaults and print it "
                        "side by side")
    p.set_defaults(handler=_cmd_evaluate)


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from prismstereo.evaluation.middlebury import evaluate_method, format_results_table
    from prismstereo.matching import get_matcher

    params = _parse_params(args.param)
    get_matcher(args.method, **params)
    scenes = tuple(s.strip() for s in args.scenes.split(",") if s.strip()) if args.scenes else None
    res = evaluate_method(args.method, data_dir=args.data, out_dir=args.output, scenes=scenes,
                          baseline=args.baseline, **params)
    print(format_results_table(res, title=f"{args.method} on {res['data']} (bad % at the column's threshold)"))
    print(f"wrote {args.output}/results.json")
    return 0


_ADDERS: list[Callable[[argparse._SubParsersAction], None]] = [_add_simulate, _add_calibrate, _add_reproduce,
                                                               _add_match, _add_evaluate]



# --------------------------------------------------------------------------- rectify
def _add_rectify(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("rectify", help="rectify a capture's views -> left/right (or view_<k>) images + JSON")
    p.add_argument("rig", help="rig TOML (docs/rig.md)")
    p.add_argument("image", help="the capture (the rig's sensor size)")
    p.add_argument("-o", "--output", required=True, help="output folder")
    p.add_argument("--views", default=None, help="faces to rectify: I,J for a pair, I,J,K or 'all' for more")
    p.add_argument("--method", choices=["fit", "thesis"], default="fit", help="virtual camera model")
    p.add_argument("--remap", choices=["model", "exact"], default="model",
                   help="remap through the camera model or through exact refraction at a reference depth")
    p.set_defaults(handler=_cmd_rectify)


def _cmd_rectify(args: argparse.Namespace) -> int:
    from prismstereo.apps.rectify_folder import rectify_to_folder

    res = rectify_to_folder(args.rig, args.image, args.output, views=_parse_views(args.views), method=args.method,
                            remap=args.remap)
    print(res.summary())
    return 0


_ADDERS.append(_add_rectify)


# --------------------------------------------------------------------------- depth
def _parse_roi(text: str | None) -> tuple[int, int, int, int] | None:
    if text is None:
        return None
    try:
        x, y, w, h = (int(v) for v in text.split(","))
    except ValueError:
        raise ConfigError(f"--roi: expected x,y,w,h (integers, rectified left pixels), got {text!r}") from None
    return x, y, w, h


def _add_depth(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("depth", help="depth from one prism capture -> disparity, depth, points.ply, report")
    p.add_argument("rig", nargs="?", default=None, help="rig TOML (docs/rig.md); with --config: the run's")
    p.add_argument("image", nargs="?", default=None,
                   help="the capture (the rig's sensor size); with --config: the run's")
    p.add_argument("-o", "--output", required=True, help="output folder")
    p.add_argument("--config", default=None, metavar="RUN.json",
                   help="replay an earlier run: its rig, capture, ground truth and resolved configuration (every "
                        "step's parameters, the matcher's included) from its run.json; options given here "
                        "override them")
    p.add_argument("--method", default=None, help="matcher name (any registered: bpasw (default), sgm, coop, ...)")
    p.add_argument("--preset", default=None, metavar="fast|balanced|accurate",
                   help="fast = sgm and a video frame's refinement, balanced = bpasw, accurate = coop (instead of "
                        "--method; options given explicitly win over the preset's settings; docs/cli.md)")
    p.add_argument("-p", "--param", action="append", metavar="KEY=VALUE", help="matcher tuning parameter")
    p.add_argument("--depth-range", default=None, metavar="MIN,MAX",
                   help="world depths to search, mm (MIN > the prism's back_distance); default: derived from the "
                        "rig (depths where the views share a field) and a coarse match of the images, printed and "
                        "written to run.json (docs/cli.md)")
    p.add_argument("--roi", default=None, metavar="X,Y,W,H", help="region of the rectified left view")
    p.add_argument("--views", default=None, metavar="I,J|all",
                   help="faces to pair (default: 1,0 for a bi-prism, else 0,1); 'all' uses every face (N >= 3)")
    p.add_argument("--triangulation", default=None, choices=["exact", "midpoint", "dlt", "q"],
                   help="exact refractive rays (default), virtual-pinhole midpoint or DLT, or Q (Eq. 7.23)")
    p.add_argument("--calibration", default=None, choices=["fit", "thesis"],
                   help="virtual camera model for rectification and pinhole triangulation (default fit)")
    p.add_argument("--gt", default=None, metavar="DEPTH_GT.pfm",
                   help="ground-truth depth per real pixel (simulate's depth_gt.pfm): adds accuracy to run.json")
    p.add_argument("--no-refine", action="store_true", help="skip the sub-pixel disparity refinement")
    p.add_argument("--refine-fill", action=argparse.BooleanOptionalAction, default=None,
                   help="where no cross-checked match was kept, refine from the matcher's dense map and keep what "
                        "the sub-pixel left-right check and --min-confidence confirm: more points on weak texture, "
                        "less precise ones (default off: DepthConfig.refine_fill; by default a dense-map value is "
                        "kept only where two window sizes agree, DepthConfig.refine_fill_agree)")
    p.add_argument("--self-calibrate", action="store_true",
                   help="first refine the prism's rotation and tilt from feature matches in this capture "
                        "(calibrate-prism --from-scene); the refined rig is written as rig_refined.toml")
    p.add_argument("--min-confidence", type=float, default=None, metavar="C",
                   help="keep points whose confidence (0..1, in confidence.pfm and points.ply) is at least C; "
                        "0 keeps every match (default: DepthConfig's, docs/formats.md)")
    _add_scale_flags(p, default=None)
    p.set_defaults(handler=_cmd_depth)


def _parse_memory(text: str | None) -> int | None:
    from prismstereo.matching.scale import parse_memory

    return parse_memory(text)


def _cmd_depth(args: argparse.Namespace) -> int:
    from prismstereo.apps.depth_command import depth_command
    from prismstereo.matching.registry import resolve_preset

    views = _parse_views(args.views)
    depth_range = None if args.depth_range is None else parse_pair(args.depth_range, "--depth-range")
    method, preset = (args.method, None) if args.preset is None and args.config is not None \
        else resolve_preset(args.preset, args.method)
    _first_run(args.command, method or "bpasw")
    print(depth_command(args.rig, args.image, args.output, method=args.method, preset=preset,
                        params=_parse_params(args.param),
                        depth_range=depth_range, roi=_parse_roi(args.roi), views=views,
                        triangulation=args.triangulation, calibration=args.calibration, gt=args.gt,
                        refine=False if args.no_refine else None, refine_fill=args.refine_fill,
                        config_path=args.config, self_calibrate=args.self_calibrate,
                        min_confidence=args.min_confidence,
                        coarse_to_fine=args.coarse_to_fine, max_memory=_parse_memory(args.max_memory)))
    return 0


def _first_run(command: str, method: str) -> None:
    """A first run in this environment (the depth pipeline's kernels are not in numba's cache): compile what
    the command needs in two processes at once (the matcher's kernels, the pipeline's), saying so once."""
    from prismstereo.depth.refine import REFINE_KERNELS
    from prismstereo.numba_cache import has_cached_code

    if (os.cpu_count() or 1) < 2 or all(has_cached_code(k) for k in REFINE_KERNELS):
        return  # one core: compiling in the run itself costs the same
    from prismstereo.apps.warmup import warmup
    from prismstereo.matching import available_matchers

    _compiling(command)
    warmup([method] if method.lower() in available_matchers() else [], parts=("pipeline",))


def _add_demo(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="simulate the built-in bi-prism scene, recover its depth, print accuracy")
    p.add_argument("-o", "--output", default="demo_out", help="output folder (default demo_out)")
    p.add_argument("--method", default="bpasw", help="matcher name")
    p.set_defaults(handler=_cmd_demo)


def _cmd_demo(args: argparse.Namespace) -> int:
    from prismstereo.apps.depth_command import demo_command

    print(demo_command(args.output, method=args.method))
    return 0


_ADDERS.extend([_add_depth, _add_demo])


# --------------------------------------------------------------------------- multiview
def _add_multiview(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("multiview", help="disparity of a reference image from several collinear views")
    p.add_argument("--reference", required=True, help="reference image (rectified with the views)")
    p.add_argument("--view", action="append", required=True, metavar="IMG:RATIO",
                   help="a view and its signed baseline ratio (+ = right of the reference, 1 = unit baseline); "
                        "repeat for every view")
    p.add_argument("--max-disp", type=int, required=True, help="largest disparity of the unit baseline")
    p.add_argument("--method", default="global", help="local (Eq. 7.8) or global (§7.1.2; default)")
    p.add_argument("-o", "--output", required=True, help="disparity PFM to write (a colourised .png beside it)")
    p.set_defaults(handler=_cmd_multiview)


def _cmd_multiview(args: argparse.Namespace) -> int:
    from prismstereo.apps.multiview_command import multiview_command

    print(multiview_command(args.reference, args.view, args.output, max_disp=args.max_disp, method=args.method))
    return 0


_ADDERS.append(_add_multiview)


#: options whose value may start with "-" (a negative number): argparse would take it for an option
_SIGNED_VALUE_OPTIONS = ("--depth-range", "--roi")


def _join_signed_values(argv: Sequence[str]) -> list[str]:
    """``--depth-range -100,5000`` -> ``--depth-range=-100,5000`` so that the value reaches its parser."""
    out: list[str] = []
    items = list(argv)
    i = 0
    while i < len(items):
        a = items[i]
        if a in _SIGNED_VALUE_OPTIONS and i + 1 < len(items) and items[i + 1].startswith("-") \
                and len(items[i + 1]) > 1 and (items[i + 1][1].isdigit() or items[i + 1][1] == "."):
            out.append(f"{a}={items[i + 1]}")
            i += 2
            continue
        out.append(a)
        i += 1
    return out


def _add_common(p: argparse.ArgumentParser) -> None:
    # SUPPRESS: a subcommand's -v adds to (does not reset) a -v given before the subcommand. A subcommand
    # that declares either option itself keeps its own.
    taken = set(p._option_string_actions)
    if not taken & {"-v", "--verbose"}:
        p.add_argument("-v", "--verbose", action="count", default=argparse.SUPPRESS,
                       help="more log output (-vv for debug); also before the subcommand")
    if not taken & {"-q", "--quiet"}:
        p.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS,
                       help="no progress bars (they show only on a terminal anyway)")

# --------------------------------------------------------------------------- real rigs
from prismstereo.apps.cli_calibration import add_calibrate_camera, add_calibrate_prism, add_check  # noqa: E402

_ADDERS += [add_calibrate_camera, add_calibrate_prism, add_check]

# --------------------------------------------------------------------------- warmup
def _add_warmup(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("warmup", help="compile the numba kernels once into numba's disk cache (first-run cost)")
    p.add_argument("--methods", default=None, help="comma-separated matchers to warm (default: all)")
    p.add_argument("--parts", default=None, metavar="depth,multiview",
                   help="also warm the depth pipeline with the renderer (depth), without it (pipeline) and/or "
                        "multi-view matching (default depth,multiview; 'none' for neither)")
    p.add_argument("--jobs", type=int, default=None,
                   help="processes compiling at the same time (default: one per core)")
    p.set_defaults(handler=_cmd_warmup)


def _cmd_warmup(args: argparse.Namespace) -> int:
    from prismstereo.apps.warmup import PARTS, warmup

    methods = [m.strip() for m in args.methods.split(",") if m.strip()] if args.methods else None
    parts = PARTS if args.parts is None else tuple(p.strip() for p in args.parts.split(",")
                                                    if p.strip() and p.strip() != "none")
    print(warmup(methods, parts=parts, jobs=args.jobs).summary())
    return 0


_ADDERS.append(_add_warmup)

# --------------------------------------------------------------------------- batch
def _add_batch(sub: argparse._SubParsersAction) -> None:
    from prismstereo.apps.batch_command import BATCH_EPILOG

    p = sub.add_parser("batch", help="depth of many frames (images, folders, globs, videos) on Dask",
                       epilog=BATCH_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("rig", help="rig TOML (docs/rig.md)")
    p.add_argument("inputs", nargs="+", metavar="INPUT", help="image files, folders, globs or video files")
    p.add_argument("-o", "--output", required=True, help="output folder")
    p.add_argument("--method", default=None,
                   help="matcher name (any registered: bpasw (default), sad, sgbm, coop, ...)")
    p.add_argument("--preset", default=None, metavar="fast|balanced|accurate",
                   help="fast = sgm and a video frame's refinement, balanced = bpasw, accurate = coop (instead of "
                        "--method; options given explicitly win over the preset's settings; docs/cli.md)")
    p.add_argument("--min-confidence", type=float, default=None, metavar="C",
                   help="keep points whose confidence (0..1) is at least C; 0 keeps every match (default: depth's)")
    p.add_argument("-p", "--param", action="append", metavar="KEY=VALUE", help="matcher tuning parameter")
    p.add_argument("--depth-range", default=None, metavar="MIN,MAX",
                   help="scene depths to search, mm (default: every depth at which the views share a field, "
                        "from the rig); sets the disparity range")
    p.add_argument("--roi", default=None, metavar="X,Y,W,H", help="region of the rectified left view")
    p.add_argument("--views", default=None, metavar="I,J", help="faces to pair (default: 1,0 for a bi-prism)")
    p.add_argument("--triangulation", default="exact", choices=["exact", "midpoint", "dlt", "q"],
                   help="exact refractive rays (default), virtual-pinhole midpoint or DLT, or Q (Eq. 7.23)")
    p.add_argument("--calibration", default="fit", choices=["fit", "thesis"], help="virtual camera model")
    p.add_argument("--no-refine", action="store_true", help="skip the sub-pixel disparity refinement")
    p.add_argument("--outputs", default=None, metavar="FILES",
                   help="files per frame, comma-separated, among disparity.pfm, disparity.png, depth.pfm, "
                        "confidence.pfm, depth.png (16-bit, mm), points.ply, report.png, run.json (default: "
                        "depth's files)")
    p.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT", help="use a running Dask scheduler")
    p.add_argument("--workers", type=int, default=None, help="local cluster: worker processes (default: one per core)")
    p.add_argument("--threads-per-worker", type=int, default=1, help="local cluster: threads per worker (default 1)")
    p.add_argument("--in-process", action="store_true",
                   help="local cluster: workers as threads of this process (small runs, debugging)")
    p.add_argument("--numba-threads", type=int, default=None,
                   help="numba/OpenCV threads per task (default: cores // worker threads on the host)")
    p.add_argument("--retries", type=int, default=2, help="reruns of a frame whose worker died (default 2)")
    p.set_defaults(handler=_cmd_batch)


def _cmd_batch(args: argparse.Namespace) -> int:
    from prismstereo.apps.batch_command import batch_command
    from prismstereo.matching.registry import resolve_preset

    depth_range = None if args.depth_range is None else parse_pair(args.depth_range, "--depth-range")
    method, preset = resolve_preset(args.preset, args.method)
    return batch_command(args.rig, args.inputs, args.output, method=method, preset=preset,
                         params=_parse_params(args.param),
                         min_confidence=args.min_confidence,
                         depth_range=depth_range, roi=_parse_roi(args.roi), views=_parse_views(args.views),
                         triangulation=args.triangulation, calibration=args.calibration, refine=not args.no_refine,
                         outputs=args.outputs, scheduler=args.scheduler, workers=args.workers,
                         threads_per_worker=args.threads_per_worker, processes=not args.in_process,
                         retries=args.retries, numba_threads=args.numba_threads)


_ADDERS.append(_add_batch)

from prismstereo.apps.design_cli import add_design  # noqa: E402

_ADDERS.append(add_design)


# --------------------------------------------------------------------------- stream
def _add_stream(sub: argparse._SubParsersAction) -> None:
    from prismstereo.apps.stream_command import STREAM_EPILOG

    p = sub.add_parser("stream", help="depth of frames as they arrive (camera, video, folder that fills up)",
                       epilog=STREAM_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("rig", help="rig TOML (docs/rig.md)")
    p.add_argument("source", help="camera index, video file or folder")
    p.add_argument("-o", "--output", required=True, help="output folder")
    p.add_argument("--method", default=None, help="matcher name (default: the fast preset's, sgm)")
    p.add_argument("--preset", default=None, metavar="fast|balanced|accurate",
                   help="fast (default: sgm and a video frame's refinement), balanced = bpasw, accurate = coop "
                        "(instead of --method; docs/cli.md)")
    p.add_argument("-p", "--param", action="append", metavar="KEY=VALUE", help="matcher tuning parameter")
    p.add_argument("--depth-range", default=None, metavar="MIN,MAX", help="scene depths to search, mm")
    p.add_argument("--roi", default=None, metavar="X,Y,W,H", help="region of the rectified left view")
    p.add_argument("--views", default=None, metavar="I,J", help="faces to pair (default: 1,0 for a bi-prism)")
    p.add_argument("--triangulation", default="exact", choices=["exact", "midpoint", "dlt", "q"])
    p.add_argument("--no-refine", action="store_true", help="skip the sub-pixel disparity refinement")
    p.add_argument("--min-confidence", type=float, default=None, metavar="C",
                   help="keep points whose confidence (0..1) is at least C; 0 keeps every match")
    p.add_argument("--outputs", default=None, metavar="FILES",
                   help="files per frame, comma-separated (as batch's), or 'none' (default: disparity.pfm,depth.png)")
    p.add_argument("--video", default=None, metavar="PATH", help="also write a colourised depth video (mp4, avi)")
    p.add_argument("--video-fps", type=float, default=10.0, help="frame rate of --video (default 10)")
    p.add_argument("--idle-timeout", type=float, default=10.0, metavar="S",
                   help="folder source: stop after S seconds without a new image (default 10)")
    p.add_argument("--max-frames", type=int, default=None, help="stop after this many frames")
    p.add_argument("--no-temporal-prior", action="store_true",
                   help="search every frame's whole range (default: sgm searches a band around the previous frame's "
                        "matches, with a full frame every 10 and where the band fails its check)")
    p.set_defaults(handler=_cmd_stream)


def _cmd_stream(args: argparse.Namespace) -> int:
    from prismstereo.apps.stream_command import stream_command
    from prismstereo.matching.registry import resolve_preset

    depth_range = None if args.depth_range is None else parse_pair(args.depth_range, "--depth-range")
    # no matcher named: the fast preset (its matcher and its refinement), what a video frame affords
    method, preset = resolve_preset("fast" if args.preset is None and args.method is None else args.preset,
                                    args.method)
    return stream_command(args.rig, args.source, args.output, method=method, preset=preset,
                          params=_parse_params(args.param),
                          depth_range=depth_range, roi=_parse_roi(args.roi), views=_parse_views(args.views),
                          triangulation=args.triangulation, refine=not args.no_refine,
                          min_confidence=args.min_confidence, outputs=args.outputs, video=args.video,
                          video_fps=args.video_fps, idle_timeout=args.idle_timeout, max_frames=args.max_frames,
                          temporal_prior=not args.no_temporal_prior)


_ADDERS.append(_add_stream)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="prismstereo",
        description="Depth from a single camera and a prism: simulate, calibrate, rectify, match, depth.",
        epilog="Documentation in the repository: docs/cli.md (commands), docs/rig.md (rig TOML keys), "
               "docs/formats.md (files), docs/conventions.md (frames, units, disparity sign).",
    )
    parser.add_argument("--version", action="version", version=f"prismstereo {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    parser.add_argument("-q", "--quiet", action="store_true", default=False,
                        help="no progress bars (they show only on a terminal anyway)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for add in _ADDERS:
        add(sub)
    for p in sub.choices.values():
        _add_common(p)
    return parser


class _CliFormatter(logging.Formatter):
    """Warnings as one ``prismstereo CMD: warning: ...`` line; -v/-vv records with their logger name."""

    def __init__(self, command: str) -> None:
        super().__init__("%(levelname)s %(name)s: %(message)s")
        self.command = command

    def format(self, record: logging.LogRecord) -> str:
        if record.levelno >= logging.WARNING and record.name != "py.warnings":
            return f"prismstereo {self.command}: warning: {cli_warning(self.command, record.getMessage())}"
        return super().format(record)


def _setup_logging(command: str, verbose: int) -> None:
    import warnings

    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_CliFormatter(command))
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(logging.WARNING - 10 * min(verbose, 2))
    # numpy's RuntimeWarnings and other library warnings: only with -v (one line per error otherwise)
    logging.captureWarnings(True)
    logging.getLogger("py.warnings").setLevel(logging.DEBUG if verbose else logging.CRITICAL)
    if not verbose:
        warnings.simplefilter("ignore")


def _os_error_line(exc: OSError) -> str:
    from prismstereo.io.atomic import os_error_reason

    where = exc.filename if exc.filename is not None else ""
    return f"{os_error_reason(exc)}: {where}" if where else os_error_reason(exc)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(_join_signed_values(sys.argv[1:] if argv is None else argv))
    _setup_logging(args.command, args.verbose)
    handler: Handler = args.handler
    if not args.quiet:
        return _run_handler(handler, args)
    # tqdm reads its defaults from TQDM_* variables (bars show only on a terminal anyway); put the variable
    # back afterwards, so that --quiet does not silence later calls of main() in the same process
    previous = os.environ.get("TQDM_DISABLE")
    os.environ["TQDM_DISABLE"] = "1"
    try:
        return _run_handler(handler, args)
    finally:
        if previous is None:
            del os.environ["TQDM_DISABLE"]
        else:
            os.environ["TQDM_DISABLE"] = previous


#: library parameter names whose command-line flag is not the name with dashes
_FLAG_OF = {"ground_truth": "--gt", "data_dir": "--data", "matcher_params": "--param"}


def cli_message(parser: argparse.ArgumentParser, command: str, message: str) -> str:
    """A library error with the parameter it names first (``views: ...``, ``DepthConfig.min_confidence: ...``)
    as the command's flag (``--views: ...``) when the command has one; otherwise the message as it is."""
    m = re.match(r"(?:[A-Z]\w*\.)?([a-z_]\w*): ", message)
    flag = None if m is None else _flag(parser, command, m.group(1))
    return message if m is None or flag is None else flag + message[m.end(1):]


def _flag(parser: argparse.ArgumentParser, command: str, name: str) -> str | None:
    """The flag of ``command`` that sets the library parameter ``name``, or None when it has none."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs or command not in subs[0].choices:
        return None
    flag = _FLAG_OF.get(name, "--" + name.replace("_", "-"))
    return flag if flag in subs[0].choices[command]._option_string_actions else None


def cli_warning(command: str, message: str) -> str:
    """A library warning with each ``<Class>.<parameter>`` it names (``widen DepthConfig.depth_range``) as the
    command's flag (``widen --depth-range``) where the command has one; the rest as it is."""
    if not re.search(r"\b[A-Z]\w*\.[a-z_]", message):
        return message
    parser = build_parser()
    return re.sub(r"\b[A-Z]\w*\.([a-z_]\w*)\b", lambda m: _flag(parser, command, m.group(1)) or m.group(0),
                  message)


def _compiling(command: str) -> None:
    """The first kernel of a run that is not in numba's cache: say why the run is slow, once."""
    line = ("compiling the numba kernels this run needs (first run in this environment; later runs load them "
            "from the cache; `prismstereo warmup` compiles them ahead)")
    if sys.stderr.isatty():
        print(f"prismstereo {command}: {line}", file=sys.stderr, flush=True)
    else:
        log.info("%s", line)


def _run_handler(handler: Handler, args: argparse.Namespace) -> int:
    """Run a subcommand's handler; errors become one line on stderr and the exit code."""
    from prismstereo.numba_cache import compilation_notice, tolerate_cache_write_errors

    tolerate_cache_write_errors()  # a numba cache that cannot be written costs a compile, not the command
    try:
        with compilation_notice(lambda: _compiling(args.command)):
            return handler(args)
    except PrismStereoError as exc:
        print(f"prismstereo {args.command}: error: {cli_message(build_parser(), args.command, str(exc))}",
              file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"prismstereo {args.command}: interrupted", file=sys.stderr)
        return 130
    except MemoryError:
        print(f"prismstereo {args.command}: error: expected inputs that fit in memory, got out of memory "
              "(use a smaller image, --roi or a narrower --depth-range)", file=sys.stderr)
        return 2
    except OSError as exc:  # the system refused a read or write (disk full, permissions, ...)
        if args.verbose:
            raise
        print(f"prismstereo {args.command}: error: {_os_error_line(exc)}", file=sys.stderr)
        return 2
    except Exception as exc:  # noqa: BLE001 - last resort: one line, exit 1, traceback with -v
        if args.verbose:
            raise
        print(f"prismstereo {args.command}: unexpected failure: {type(exc).__name__}: {exc} "
              "(run with -v for the traceback)", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
