"""The ``calibrate-camera`` and ``calibrate-prism`` subcommands: thin wrappers over
:mod:`prismstereo.calibration`, registered by :mod:`prismstereo.cli`. The handlers import the calibration
when they run, so that the command line starts without the numerical packages."""

from __future__ import annotations

import argparse
from pathlib import Path

import tomli_w

from prismstereo.errors import ImageError


def _read_images(paths: list[str]) -> list:
    from prismstereo.io import read_image

    if not paths:
        raise ImageError("expected at least one image, got none")
    return [read_image(p) for p in paths]


def add_calibrate_camera(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("calibrate-camera",
                       help="camera intrinsics + lens distortion from checkerboard photos (no prism) -> camera.toml")
    p.add_argument("images", nargs="+", help="photos of a checkerboard taken without the prism")
    p.add_argument("--board", required=True, help="inner corners COLSxROWS, e.g. 8x6")
    p.add_argument("--square", required=True, type=float, help="square side, mm")
    p.add_argument("--min-views", type=int, default=5, help="fewest good photos (default 5)")
    p.add_argument("-o", "--output", required=True, help="camera TOML to write (the [camera] table)")
    p.set_defaults(handler=_cmd_calibrate_camera)


def _cmd_calibrate_camera(args: argparse.Namespace) -> int:
    from prismstereo.calibration import calibrate_camera, camera_toml, parse_board
    from prismstereo.io.atomic import atomic_write_text

    board = parse_board(args.board, args.square)
    images = _read_images(args.images)
    result = calibrate_camera(images, board, names=[Path(p).name for p in args.images], min_views=args.min_views)
    atomic_write_text(args.output, tomli_w.dumps(camera_toml(result.camera)))
    print(result.summary())
    print(f"wrote {args.output}")
    return 0


def add_calibrate_prism(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("calibrate-prism", help="fit the prism's pose to checkerboard captures through it -> rig TOML")
    p.add_argument("rig", help="rig TOML: the calibrated [camera] and the nominal [prism]")
    p.add_argument("captures", nargs="+", help="captures of a checkerboard seen whole through every face")
    p.add_argument("--board", required=True, help="inner corners COLSxROWS, e.g. 8x6")
    p.add_argument("--square", required=True, type=float, help="square side, mm")
    p.add_argument("--free", default="rotation,tilt,decenter,focal",
                   help="parameters to fit: rotation, tilt, decenter, apex_distance, refractive_index, "
                        "corner_angle (prism), focal, principal_point, k1 (camera) "
                        "(comma list; default rotation,tilt,decenter,focal)")
    p.add_argument("-o", "--output", required=True,
                   help="rig TOML to write; <name>.report.json and <name>.residuals.png are written beside it")
    p.set_defaults(handler=_cmd_calibrate_prism)


def _cmd_calibrate_prism(args: argparse.Namespace) -> int:
    from prismstereo.calibration import calibrate_prism, parse_board, parse_free
    from prismstereo.calibration.report import residual_figure
    from prismstereo.config import load_rig
    from prismstereo.io.atomic import atomic_write_bytes
    from prismstereo.io.jsonio import write_json

    rig = load_rig(args.rig)
    board = parse_board(args.board, args.square)
    free = parse_free(args.free)
    images = _read_images(args.captures)
    result = calibrate_prism(rig, images, board, names=[Path(p).name for p in args.captures], free=free)
    out = Path(args.output)
    png = residual_figure(result, rig.camera.width, rig.camera.height)
    stem = out.with_suffix("") if out.suffix == ".toml" else out
    report_path = Path(f"{stem}.report.json")
    plot_path = Path(f"{stem}.residuals.png")
    write_json(report_path, result.report())
    atomic_write_bytes(plot_path, png)
    result.rig.save(out)  # last: a rig file on disk means the whole calibration succeeded
    print(result.summary())
    print(f"wrote {out}, {report_path}, {plot_path}")
    return 0
