"""Thesis Table 3.4 reproduced: correspondence transfer, geometric virtual cameras vs Zhang's calibration
(bi-prism α = 6.4°).

Thesis metric (Table 3.3): for a pixel of the left view, the corresponding pixel in the right view
predicted by a camera model at the known depth, against the true correspondence. The thesis measured
the truth on lab images (its numbers include its hardware's misalignment); here the truth is exact ray
tracing and the calibration images are rendered (see :mod:`prismstereo.rectify.baseline`).
The thesis's 8 test pixels (its column 2) are used at a depth of 1.5 m (the thesis does not state it),
plus a summary over random common-view points at 0.8–2.5 m.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from prismstereo.apps.reproduce import TableResult
from prismstereo.config import thesis_biprism
from prismstereo.rectify.baseline import TransferExperiment, biprism_experiment

__all__ = ["THESIS_TABLE_3_4", "format_experiment", "reproduce"]

#: thesis Table 3.4: (left pixel, geometric prediction, actual, calibration prediction, d geo, d cal)
THESIS_TABLE_3_4: list[tuple[tuple[int, int], tuple[int, int], tuple[int, int], tuple[int, int], float, float]] = [
    ((58, 90), (576, 89), (573, 86), (581, 92), 4.2426, 10.0),
    ((100, 120), (612, 126), (617, 125), (621, 134), 5.099, 9.8489),
    ((157, 83), (665, 88), (670, 86), (660, 84), 5.3851, 10.1980),
    ((180, 200), (694, 195), (698, 187), (702, 198), 8.9442, 11.7047),
    ((216, 265), (726, 261), (732, 263), (735, 256), 6.3246, 7.6158),
    ((300, 350), (806, 351), (810, 354), (815, 359), 5.000, 7.0710),
    ((443, 526), (950, 528), (955, 521), (961, 508), 8.6023, 14.3178),
    ((480, 550), (998, 537), (991, 545), (1004, 553), 10.6301, 15.2643),
]
THESIS_AVG_3_4 = {"geometric": 6.7784, "calibration": 10.7526}

_MAIN = ("geometric (thesis construction)", "geometric (fitted model)", "Zhang (k1,k2,p1,p2,k3)")


def _pt(p: np.ndarray) -> str:
    return "–" if not np.all(np.isfinite(p)) else f"({p[0]:.1f}, {p[1]:.1f})"


def format_experiment(exp: TransferExperiment, *, title: str, thesis_geo: float, thesis_cal: float,
                      roles: tuple[str, ...]) -> str:
    """Markdown: the listed points (ours) and the summary beside the thesis's averages."""
    tp: dict[str, Any] = exp.table_points  # type: ignore[assignment]
    names = list(exp.summary)
    src = ("rendered images (findChessboardCorners + cornerSubPix)" if exp.zhang["source"] == "render"
           else "exact projection + Gaussian noise (0.2 px)")
    lines = [f"## {title}", "",
             f"Rig {exp.rig_name}; faces {exp.faces}; listed points at Z = {exp.depth_mm:g} mm; Zhang calibration "
             f"from {exp.zhang['poses']} checkerboard poses, corners from {src}"
             f" (detected per view: {exp.zhang['detected']}, detection RMS px: "
             + ", ".join(f"{k}: {v:.3f}" for k, v in exp.zhang["detection_rms_px"].items()) + ").", ""]  # type: ignore[attr-defined]
    head = "| # | " + " | ".join(f"{r} pixel" for r in roles) + " | exact | " + " | ".join(
        f"{n} pred / err px" for n in _MAIN) + " |"
    lines += [head, "|" + "---|" * (2 + len(roles) + len(_MAIN))]
    n = tp["exact"].shape[0]
    for i in range(n):
        cells = [_pt(tp["pixels"][r][i]) for r in roles] + [_pt(tp["exact"][i])]
        cells += [f"{_pt(tp[m]['pred'][i])} / {tp[m]['err'][i]:.2f}" for m in _MAIN]
        lines.append(f"| {i + 1} | " + " | ".join(cells) + " |")
    lines.append("| AVG | " + " | ".join("" for _ in roles) + " | | " + " | ".join(
        f"{np.nanmean(tp[m]['err']):.2f}" for m in _MAIN) + " |")
    lines += ["", f"Summary over {int(exp.summary[names[0]]['n'])} common-view points at "
              f"{exp.depth_range[0]:g}–{exp.depth_range[1]:g} mm (transfer error, px):", "",
              "| model | mean | median | p95 | max | thesis average |", "|---|---|---|---|---|---|"]
    for m in names:
        s = exp.summary[m]
        th = f"{thesis_geo:.2f} (geometric)" if m.startswith("geometric") else (
            f"{thesis_cal:.2f} (calibration)" if m.startswith("Zhang") else "")
        lines.append(f"| {m} | {s['mean']:.2f} | {s['median']:.2f} | {s['p95']:.2f} | {s['max']:.1f} | {th} |")
    lines += ["", "Zhang reprojection RMS px per view (OpenCV): " + "; ".join(
        f"{k}: " + ", ".join(f"{f}={v:.3f}" for f, v in d["rms_px"].items())  # type: ignore[index]
        for k, d in exp.zhang["models"].items()), ""]  # type: ignore[attr-defined]
    return "\n".join(lines)


def reproduce(*, data_dir: Path | None = None, quick: bool = False) -> TableResult:
    """Re-measure Table 3.4 (``quick``: exact corners + 0.2 px noise instead of rendered checkerboards)."""
    rig = thesis_biprism(6.4)
    pixels = np.array([p[0] for p in THESIS_TABLE_3_4], dtype=np.float64)
    exp = biprism_experiment(rig, pixels, source="exact" if quick else "render", n_summary=500 if quick else 2000)
    md = format_experiment(exp, title="Table 3.4 — bi-prism correspondence transfer, ours vs thesis",
                           thesis_geo=THESIS_AVG_3_4["geometric"], thesis_cal=THESIS_AVG_3_4["calibration"],
                           roles=("left",))
    md += ("\nThesis (lab images): geometric 6.78 px vs Zhang calibration 10.75 px on its 8 points. Ours are "
           "simulated without hardware misalignment, so the geometric errors are the model's alone.\n")
    data = {"experiment": exp, "thesis": {"rows": THESIS_TABLE_3_4, "average": THESIS_AVG_3_4}}
    return TableResult(name="table3.4", markdown=md, data=data)
