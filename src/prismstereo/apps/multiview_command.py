"""What ``prismstereo multiview`` does: read the views, match them, write the disparity (docs/cli.md)."""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from prismstereo.errors import ConfigError
from prismstereo.io import check_output_file, output_files, read_image, write_image, write_pfm
from prismstereo.multiview.api import METHODS, match_multiview
from prismstereo.multiview.baseline import parse_view_spec
from prismstereo.viz.colorize import colorize_disparity

__all__ = ["multiview_command"]


def multiview_command(reference: str | os.PathLike[str], view_specs: Sequence[str], output: str | os.PathLike[str],
                      *, max_disp: int, method: str = "global") -> str:
    """Read the images, match, write ``OUTPUT`` (float32 PFM, disparity of the unit baseline, inf = invalid)
    and ``OUTPUT`` with ``.png`` (colourised); return a one-paragraph summary.

    Parameters
    ----------
    reference : path of the reference image
    view_specs : ``IMG:RATIO`` strings (see :func:`~prismstereo.multiview.baseline.parse_view_spec`)
    output : path of the PFM to write
    max_disp : int, keyword-only, unit-baseline disparity range ``0 .. max_disp``
    method : {"global", "local"}, keyword-only

    Raises
    ------
    ConfigError, ImageError, MatchingError
        Bad specs, unreadable or mismatched images, a bad range (all checked before any matching).
    """
    if str(method).lower() not in METHODS:
        raise ConfigError(f"--method: expected one of {', '.join(METHODS)}, got {method!r}")
    if not view_specs:
        raise ConfigError("--view: expected at least one IMG:RATIO, got none")
    specs = [parse_view_spec(s) for s in view_specs]
    out = Path(output)
    if out.suffix.lower() != ".pfm":
        raise ConfigError(f"-o: expected a .pfm output path, got {str(out)!r}")
    png = out.with_suffix(".png")
    check_output_file(out)  # before any work
    check_output_file(png)
    ref = read_image(reference)
    views = [read_image(p) for p, _ in specs]
    ratios = [r for _, r in specs]
    t = time.perf_counter()
    res = match_multiview(ref, views, ratios=ratios, max_disp=max_disp, method=method)
    dt = time.perf_counter() - t
    disp = res.disparity
    with output_files([out, png]) as (tmp_pfm, tmp_png):  # the two files appear together or not at all
        write_pfm(tmp_pfm, np.where(np.isfinite(disp), disp, np.float32(np.inf)).astype(np.float32))
        write_image(tmp_png, colorize_disparity(disp, vmin=0.0, vmax=float(max(max_disp, 1)),
                                                colorbar="disparity (px, unit baseline)"))
    finite = np.isfinite(disp)
    return (f"{method} multi-view: {len(views)} views (ratios {', '.join(f'{r:+g}' for r in ratios)}), "
            f"d in [0, {max_disp}] for the unit baseline, {100.0 * finite.mean():.1f} % dense, "
            f"{dt:.2f} s\nwrote {out} and {png}")
