"""``prismstereo rectify``: rectify a capture and write the images, rectification.json and the epipolar
figures into a folder (docs/cli.md), atomically."""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from itertools import combinations
from pathlib import Path

import numpy as np

from prismstereo.cameras import calibrate_rig
from prismstereo.config import load_rig
from prismstereo.errors import ConfigError
from prismstereo.io import check_output_dir, output_dir, read_image, write_image, write_json
from prismstereo.rectify.rectification import RectifiedPair, rectify_pair, rectify_views
from prismstereo.rectify.regions import check_image_size, view_regions
from prismstereo.viz.epipolar import epipolar_after, epipolar_after_views, epipolar_before, pick_points, with_title

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RectifyResult:
    """What :func:`rectify_to_folder` wrote."""

    out_dir: Path
    files: tuple[str, ...]
    faces: tuple[int, ...]
    pair: tuple[int, int]
    baseline_mm: float
    size: tuple[int, int]

    def summary(self) -> str:
        return (f"rectified faces {self.faces} ({self.size[0]}x{self.size[1]}); pair left={self.pair[0]} "
                f"right={self.pair[1]}, baseline {self.baseline_mm:.2f} mm; wrote {', '.join(self.files)} "
                f"in {self.out_dir}")


def _most_horizontal(centres: dict[int, np.ndarray], faces: tuple[int, ...]) -> tuple[int, int]:
    best = max(combinations(faces, 2), key=lambda ab: abs(
        (centres[ab[1]] - centres[ab[0]])[0]) / np.linalg.norm(centres[ab[1]] - centres[ab[0]]))
    return best


def rectify_to_folder(
    rig_path: str | os.PathLike[str],
    image_path: str | os.PathLike[str],
    out_dir: str | os.PathLike[str],
    *,
    views: tuple[int, ...] | str | None = None,
    method: str = "fit",
    remap: str = "model",
) -> RectifyResult:
    """Rectify one capture (docs/cli.md ``rectify``).

    Parameters
    ----------
    rig_path, image_path : rig TOML and the capture (must have the rig's sensor size).
    out_dir : output folder.
    views : (i, j) for a pair, (i, j, k, ...) or ``"all"`` for N views; default: the pair for a bi-prism,
        all views otherwise.
    method : virtual camera model, ``fit`` or ``thesis``.
    remap : ``model`` or ``exact`` (see :mod:`prismstereo.rectify.rectification`).

    Writes ``left.png``, ``right.png``, ``rectification.json``, ``epipolar_before.png``,
    ``epipolar_after.png``; with more than two views also ``view_<k>.png`` (shared orientation).
    """

    rig = load_rig(rig_path)
    check_output_dir(out_dir)  # before any work
    image = read_image(image_path, expected_size=(rig.camera.width, rig.camera.height),
                       what="capture (the rig's sensor size)")
    check_image_size(image, rig)
    n = rig.prism.faces
    if views is None or views == "all":
        faces = tuple(range(n))
    else:
        faces = tuple(int(v) for v in views)
    if len(faces) < 2 or len(set(faces)) != len(faces) or not all(0 <= f < n for f in faces):
        raise ConfigError(f"--views: expected at least two distinct faces in [0, {n - 1}], got {faces}")
    if remap not in ("model", "exact"):
        raise ConfigError(f"expected a remap construction in ('model', 'exact'), got {remap!r}")
    cams = calibrate_rig(rig, method=method)
    regions = view_regions(rig)
    sel = [cams[f] for f in faces]
    with output_dir(out_dir) as stage:
        written: list[str] = []
        if len(faces) == 2:
            pair = rectify_pair(rig, sel[0], sel[1], remap=remap, regions=regions)  # type: ignore[arg-type]
            write_json(stage / "rectification.json", pair.to_json())
            written.append("rectification.json")
        else:
            a, b = _most_horizontal({f: cams[f].camera.C for f in faces}, faces)
            pair = rectify_pair(rig, cams[a], cams[b], remap=remap, regions=regions)  # type: ignore[arg-type]
            rv = rectify_views(rig, sel, remap=remap, reference=pair.left_face)  # type: ignore[arg-type]
            for f, img in zip(rv.faces, rv.rectify_images(image), strict=True):
                write_image(stage / f"view_{f}.png", img)
                written.append(f"view_{f}.png")
            data = rv.to_json()
            data["pair"] = pair.to_json()
            write_json(stage / "rectification.json", data)
            written.append("rectification.json")
        left, right = pair.rectify_images(image)
        write_image(stage / "left.png", left)
        write_image(stage / "right.png", right)
        pts = pick_points(rig, pair.left_face, pair.right_face, regions=regions)
        others = [f for f in faces if f != pair.left_face]
        write_image(stage / "epipolar_before.png", with_title(
            epipolar_before(image, rig, pts, others, regions=regions),
            f"before rectification: points of face {pair.left_face} and their exact epipolar curves in faces "
            f"{', '.join(map(str, others))} (capture pixels)"))
        if len(faces) == 2:
            after = epipolar_after(left, right, pair, pts)
        else:
            after = epipolar_after_views(rv.rectify_images(image), rv, pts)
            write_image(stage / "epipolar_after_pair.png", with_title(
                epipolar_after(left, right, pair, pts),
                f"after rectification: left (face {pair.left_face}) | right (face {pair.right_face}); epipolar "
                "curves should lie on the grey horizontal lines"))
            written.append("epipolar_after_pair.png")
        write_image(stage / "epipolar_after.png", with_title(
            after, "after rectification: " + ("left | right" if len(faces) == 2 else
                                              "views " + " | ".join(map(str, rv.faces)))
            + "; epipolar curves should be horizontal lines through the marked points"))
        written += ["left.png", "right.png", "epipolar_before.png", "epipolar_after.png"]
    log.info("rectify: wrote %s", ", ".join(written))
    return RectifyResult(out_dir=Path(out_dir), files=tuple(sorted(written)), faces=faces,
                         pair=(pair.left_face, pair.right_face), baseline_mm=pair.baseline_mm, size=pair.size)


__all__ = ["RectifiedPair", "RectifyResult", "rectify_to_folder"]
