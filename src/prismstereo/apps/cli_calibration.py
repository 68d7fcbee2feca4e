"""The ``calibrate-camera``, ``calibrate-prism`` (checkerboards or ``--from-scene``) and ``check`` subcommands:
thin wrappers over :mod:`prismstereo.calibration`, registered by :mod:`prismstereo.cli`. The handlers import
the calibration when they run, so that the command line starts without the numerical packages."""

from __future__ import annotations

import argparse
from pathlib import Path

import tomli_w

from prismstereo.errors import ConfigError, ImageError


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
    p = sub.add_parser("calibrate-prism", help="fit the prism's pose to checkerboard captures through it, or "
                                               "(--from-scene) to feature matches in ordinary captures -> rig TOML")
    p.add_argument("rig", help="rig TOML: the calibrated [camera] and the nominal [prism]")
    p.add_argument("captures", nargs="+", help="captures of a checkerboard seen whole through every face, or with "
                                               "--from-scene captures of any textured scene")
    p.add_argument("--from-scene", action="store_true",
                   help="self-calibration: refine the prism's rotation and tilt from SIFT matches between the "
                        "sub-images (no checkerboard; the depth scale, apex distance and index, is kept)")
    p.add_argument("--board", default=None, help="inner corners COLSxROWS, e.g. 8x6 (checkerboard calibration)")
    p.add_argument("--square", default=None, type=float, help="square side, mm (checkerboard calibration)")
    p.add_argument("--free", default=None,
                   help="parameters to fit: rotation, tilt, decenter, apex_distance, refractive_index, "
                        "corner_angle (prism), focal, principal_point, k1 (camera) "
                        "(comma list; default rotation,tilt,decenter,focal; with --from-scene rotation, tilt or "
                        "decenter, default rotation,tilt)")
    p.add_argument("-o", "--output", required=True,
                   help="rig TOML to write; <name>.report.json and <name>.residuals.png are written beside it")
    p.set_defaults(handler=_cmd_calibrate_prism)


def _cmd_calibrate_prism(args: argparse.Namespace) -> int:
    from prismstereo.api import calibrate_prism
    from prismstereo.io.atomic import check_output_file

    if not args.from_scene and (args.board is None or args.square is None):
        raise ConfigError("calibrate-prism: expected --board COLSxROWS and --square MM (checkerboard captures) or "
                          "--from-scene (captures of a textured scene), got neither")
    if args.from_scene:
        check_output_file(args.output)
    result = calibrate_prism(args.rig, args.captures, board=args.board, square=args.square, free=args.free,
                             from_scene=args.from_scene)
    written = result.save(args.output)
    print(result.summary())
    print(f"wrote {', '.join(map(str, written))}")
    return 0


def add_check(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("check", help="measure the rectified row misalignment of a capture: does the rig need "
                                     "recalibrating? (exit 0 no, 3 yes)")
    p.add_argument("rig", help="rig TOML (docs/rig.md)")
    p.add_argument("capture", help="a capture of a textured scene (the rig's sensor size)")
    p.add_argument("-o", "--output", default=None, help="JSON report to write (optional)")
    p.add_argument("--calibration", default="fit", choices=["fit", "thesis"], help="virtual camera model")
    p.set_defaults(handler=_cmd_check)


#: exit status of ``check`` when the rig needs recalibrating (0: aligned, 2: error)
NEEDS_RECALIBRATION_EXIT = 3


def _cmd_check(args: argparse.Namespace) -> int:
    from prismstereo.calibration.drift import row_misalignment
    from prismstereo.config import load_rig
    from prismstereo.io import read_image
    from prismstereo.io.atomic import check_output_file
    from prismstereo.io.jsonio import write_json

    rig = load_rig(args.rig)
    if args.output is not None:
        check_output_file(args.output)
    image = read_image(args.capture, expected_size=(rig.camera.width, rig.camera.height),
                       what="capture (the rig's camera size)")
    result = row_misalignment(rig, image, calibration=args.calibration)
    if args.output is not None:
        write_json(args.output, {"inputs": {"rig": str(args.rig), "capture": str(args.capture)}, **result.report()})
    print(result.summary(recalibrate="prismstereo calibrate-prism RIG CAPTURE --from-scene -o NEW_RIG"))
    if args.output is not None:
        print(f"wrote {args.output}")
    return NEEDS_RECALIBRATION_EXIT if result.needs_recalibration else 0
