"""The arguments of ``prismstereo design`` (registered by cli.py) and their parsing; the work is in
:mod:`prismstereo.apps.design_command`."""

from __future__ import annotations

import argparse

from prismstereo.apps.cli_args import parse_pair
from prismstereo.errors import ConfigError

__all__ = ["add_design", "parse_accuracy", "parse_faces"]


def parse_accuracy(text: str | None) -> float | None:
    """``0.002`` or ``0.2%`` -> 0.002."""
    if text is None:
        return None
    raw = text.strip()
    try:
        return float(raw[:-1]) / 100.0 if raw.endswith("%") else float(raw)
    except ValueError:
        raise ConfigError(f"--accuracy: expected a relative depth error like 0.002 or 0.2%, got {text!r}") from None


def parse_faces(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(v) for v in text.split(","))
    except ValueError:
        raise ConfigError(f"--faces: expected face counts like 2 or 2,3,4, got {text!r}") from None


def _pair(text: str | None, name: str) -> tuple[float, float] | None:
    return None if text is None else parse_pair(text, name, example="1200,1800")


def add_design(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("design", help="choose the prism for a camera and a depth range (predicted, --verify: measured)")
    p.add_argument("rig", nargs="?", default=None,
                   help="TOML with the camera's [camera] table (a rig file: its [prism] is ranked beside the "
                        "proposals)")
    p.add_argument("--width", type=int, default=None, help="sensor width, px (instead of RIG.toml)")
    p.add_argument("--height", type=int, default=None, help="sensor height, px")
    p.add_argument("--pixel-size", type=float, default=None, help="pixel pitch, mm")
    p.add_argument("--focal-length", type=float, default=None, help="focal length, mm")
    p.add_argument("--range", required=True, metavar="NEAR,FAR", help="world depths of the job, mm")
    p.add_argument("--field", default=None, metavar="W,H", help="field both views must share at FAR, mm")
    p.add_argument("--accuracy", default=None, metavar="P",
                   help="expected relative depth error wanted at FAR (0.002 or 0.2%%)")
    p.add_argument("--faces", default="2", metavar="N[,N...]", help="face counts to search (default 2)")
    p.add_argument("--glass", default="N-BK7", metavar="NAME|n=...",
                   help="N-BK7 (default), fused-silica, PMMA, polycarbonate, n=<index>; several comma-separated")
    p.add_argument("--max-size", type=float, default=100.0, metavar="MM", help="largest glass dimension (default 100)")
    p.add_argument("--min-apex-distance", type=float, default=50.0, metavar="MM",
                   help="nearest apex to the camera's centre, clearing the lens (default 50)")
    p.add_argument("--max-apex-distance", type=float, default=400.0, metavar="MM",
                   help="farthest apex searched (default 400)")
    p.add_argument("--preset", default="balanced", choices=["fast", "balanced", "accurate"],
                   help="matcher whose measured disparity precision the prediction uses (and --verify runs)")
    p.add_argument("--verify", action="store_true",
                   help="render textured planes across the range through the proposal (and the given prism), run "
                        "depth and print predicted against measured error")
    p.add_argument("--dispersion", action="store_true",
                   help="with --verify: render with the glass's dispersion (its Abbe number), as a colour camera "
                        "sees it")
    p.add_argument("-o", "--output", required=True, help="output folder: rig.toml, design.json, design.png")
    p.set_defaults(handler=_cmd_design)


def _cmd_design(args: argparse.Namespace) -> int:
    from prismstereo.apps.design_command import design_command

    rng = _pair(args.range, "--range")
    assert rng is not None
    print(design_command(args.rig, args.output, near=rng[0], far=rng[1], field=_pair(args.field, "--field"),
                         accuracy=parse_accuracy(args.accuracy), faces=parse_faces(args.faces), glass=args.glass,
                         max_size=args.max_size, min_apex_distance=args.min_apex_distance,
                         max_apex_distance=args.max_apex_distance, preset=args.preset, verify_design=args.verify,
                         verify_given=args.verify and args.rig is not None and _has_prism(args.rig),
                         dispersion=args.dispersion,
                         width=args.width, height=args.height, pixel_size=args.pixel_size,
                         focal_length=args.focal_length))
    return 0


def _has_prism(path: str) -> bool:
    from prismstereo.config import read_toml

    return "prism" in read_toml(path)
