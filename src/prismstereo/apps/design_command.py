"""What ``prismstereo design`` does, kept out of cli.py: read the camera, search, optionally verify, write.

Outputs (docs/design.md), written together or not at all into the output folder: ``rig.toml`` (the best
candidate's rig: it loads in every command), ``design.json`` (the request, every candidate with its
prediction per depth or its rejection, the verification when asked) and ``design.png``.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from prismstereo.config import CameraSpec, PrismSpec, Rig, read_toml, rig_from_dict
from prismstereo.design import Design, VerifyRow, predict, search, verify
from prismstereo.design.figure import design_figure
from prismstereo.design.geometry import colour_spread_px
from prismstereo.design.precision import MEASURED_WITH
from prismstereo.design.verify import AGREEMENT
from prismstereo.errors import ConfigError
from prismstereo.io.atomic import atomic_write_bytes, check_output_dir, output_dir
from prismstereo.io.jsonio import library_versions, write_json

log = logging.getLogger(__name__)

__all__ = ["camera_from_options", "design_command"]

#: depths of the range verified by ``--verify``
VERIFY_DEPTHS = 4


def camera_from_options(rig_path: str | None, *, width: int | None, height: int | None, pixel_size: float | None,
                        focal_length: float | None) -> tuple[CameraSpec, PrismSpec | None]:
    """The camera from a TOML file's ``[camera]`` table (and its ``[prism]`` if any) or from the four options."""
    given = {"--width": width, "--height": height, "--pixel-size": pixel_size, "--focal-length": focal_length}
    if rig_path is not None:
        if any(v is not None for v in given.values()):
            raise ConfigError("expected the camera from RIG.toml or from --width/--height/--pixel-size/"
                              "--focal-length, got both")
        data = read_toml(rig_path)
        if "camera" not in data:
            raise ConfigError(f"{rig_path}: expected a [camera] table (docs/rig.md), got none")
        prism = data.get("prism")
        dummy = {"faces": 2, "corner_angle": 1.0, "refractive_index": 1.5, "apex_distance": 1.0,
                 "back_distance": 2.0}
        rig = rig_from_dict({"camera": data["camera"], "prism": prism if prism is not None else dummy})
        return rig.camera, (rig.prism if prism is not None else None)
    missing = [k for k, v in given.items() if v is None]
    if missing:
        raise ConfigError(f"expected a rig TOML with a [camera] table or all of --width --height --pixel-size "
                          f"--focal-length, got no {', '.join(missing)}")
    return CameraSpec(width=width, height=height, focal_length=focal_length, pixel_size=pixel_size), None  # type: ignore[arg-type]


def _verify_rows(rows: tuple[VerifyRow, ...]) -> list[str]:
    lines = [f"{'depth mm':>9} {'predicted %':>12} {'measured %':>11} {'ratio':>6} {'|δd| px':>8} "
             f"{'coverage':>9}  agree"]
    for r in rows:
        m = r.measured
        lines.append(f"{r.depth_mm:>9.0f} {100 * r.predicted_rel:>12.4f} {100 * m.median_rel:>11.4f} {r.ratio:>6.2f} "
                     f"{m.median_abs_disparity_px:>8.4f} {m.coverage:>9.3f}  {'yes' if r.agrees else 'NO'}")
    return lines


def design_command(rig_path: str | None, out_dir: str, *, near: float, far: float,
                   field: tuple[float, float] | None = None, accuracy: float | None = None,
                   faces: tuple[int, ...] = (2,), glass: str = "N-BK7", max_size: float = 100.0,
                   min_apex_distance: float = 50.0, max_apex_distance: float = 400.0, preset: str = "balanced",
                   verify_design: bool = False, verify_given: bool = False, dispersion: bool = False,
                   width: int | None = None,
                   height: int | None = None, pixel_size: float | None = None,
                   focal_length: float | None = None) -> str:
    """Run ``prismstereo design`` and return the lines to print."""
    camera, given = camera_from_options(rig_path, width=width, height=height, pixel_size=pixel_size,
                                        focal_length=focal_length)
    if verify_given and given is None:
        raise ConfigError("--verify-given: expected a RIG.toml with a [prism] table, got none")
    check_output_dir(out_dir)
    design: Design = search(camera, near=near, far=far, field=field, accuracy=accuracy, faces=faces, glass=glass,
                            max_size=max_size, min_apex_distance=min_apex_distance,
                            max_apex_distance=max_apex_distance, disparity_precision=preset,
                            include=(given,) if given is not None else ())
    best = design.best
    assert best.rig is not None and best.prediction is not None
    rig = Rig(camera=camera, prism=best.rig.prism, name="design")
    ref = next((c for c in design.candidates if c.source == "given"), None)
    lines = [f"prismstereo design: {len(design.candidates)} candidates, {len(design.feasible)} meet the request "
             f"({', '.join(f'{k} {v}' for k, v in design.rejections().items() if v)} rejected) in "
             f"{design.seconds:.1f} s",
             _describe("best", best)]
    if ref is not None:
        lines.append(_describe("given", ref))
    spread = colour_spread_px(rig, best.glass.abbe)
    if spread > 0.5:
        lines.append(f"note: the glass's dispersion spreads red and blue by up to {spread:.1f} px on the sensor; the "
                     "prediction holds for a monochrome or narrow-band capture (docs/design.md, limits)")
    extra: dict[str, Any] = {}
    measured = None
    if verify_design or verify_given:
        depths = np.linspace(near, far, VERIFY_DEPTHS)
        targets = ([("best", rig, best)] if verify_design else []) + \
            ([("given", Rig(camera=camera, prism=given), ref)] if verify_given and given is not None else [])
        extra["verify"] = {}
        for name, r, cand in targets:
            rows = verify(r, depths=depths, preset=preset, depth_range=(0.9 * near, 1.1 * far),
                          abbe=cand.glass.abbe if cand is not None and dispersion else None)
            lines.append(f"verify ({name} prism, preset {preset}, fronto-parallel textured planes"
                         f"{', with the glass dispersion' if dispersion else ''}, predicted within "
                         f"±{100 * AGREEMENT:.0f} %):")
            lines.extend(_verify_rows(rows))
            extra["verify"][name] = [row.to_dict() for row in rows]
            if name == "best":
                measured = [(row.depth_mm, row.measured.median_rel) for row in rows]
            bad = [row for row in rows if not row.agrees]
            if bad:
                log.warning("measured and predicted errors disagree by more than %.0f %% at %s mm (%s prism): "
                            "the prediction is not reliable for this rig", 100 * AGREEMENT,
                            ", ".join(f"{r.depth_mm:.0f}" for r in bad), name)
    fine = predict(rig, depths=np.linspace(near, far, 13), disparity_precision=preset)
    ref_pred = None
    if given is not None and ref is not None and ref.prediction is not None:
        ref_pred = predict(Rig(camera=camera, prism=given), depths=np.linspace(near, far, 13),
                           disparity_precision=preset)
    p = rig.prism
    png = design_figure(fine, reference=ref_pred, measured=measured,
                        title=f"{p.faces}-face prism, α {p.corner_angle:.2f}°, glass {best.glass.name} "
                              f"(n_d {p.refractive_index:g}), apex {p.apex_distance:.1f} mm, range {near:g}-{far:g} mm")
    payload = {**design.to_dict(), "prediction": fine.to_dict(), "colour_spread_px": spread,
               "precision_measured_with": MEASURED_WITH,
               "versions": library_versions(), **extra}
    with output_dir(out_dir) as stage:
        rig.save(stage / "rig.toml")
        write_json(stage / "design.json", payload)
        atomic_write_bytes(stage / "design.png", png)
    lines.append(f"outputs in {out_dir}/: design.json, design.png, rig.toml")
    return "\n".join(lines)


def _describe(label: str, c: Any) -> str:
    p = c.rig.prism
    pred = c.prediction
    if pred is None:
        return (f"{label}: {p.faces} faces, corner angle {p.corner_angle:.2f}°, apex {p.apex_distance:.1f} mm: "
                f"rejected ({c.rejected}: {c.reason})")
    far = pred.depths[-1]
    g = pred.glass
    state = "meets the request" if c.feasible else f"rejected ({c.rejected}: {c.reason})"
    dec = f", decenter {p.decenter[0]:.2f},{p.decenter[1]:.2f} mm" if any(p.decenter) else ""
    glass = c.glass.name if c.glass.name.startswith("n=") else f"{c.glass.name} (n {p.refractive_index:g})"
    return (f"{label}: {p.faces} faces, corner angle {p.corner_angle:.2f}°, {glass}, "
            f"apex {p.apex_distance:.1f} mm, back {p.back_distance:.2f} mm{dec}; glass {g.largest:.1f} mm; "
            f"baseline {far.baseline_mm:.1f} mm; expected error {100 * far.relative_error:.4f} % at "
            f"{far.depth_mm:.0f} mm, "
            f"common field {far.field_width_mm:.0f} × {far.field_height_mm:.0f} mm there; sub-images "
            + " / ".join(f"{s.width_px:.0f}" for s in pred.sub_images) + f" px wide; {state}")
