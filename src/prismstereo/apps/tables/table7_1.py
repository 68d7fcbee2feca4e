"""Thesis Table 7.1: multi-view matching on Tsukuba's five views, beside the thesis and our two-view methods.

Tsukuba (``views/col1..col5``): ``col3`` is the reference (= the v2 left image), ``col1, col2, col4, col5``
are at signed baseline ratios −2, −1, +1, +2 (``col4`` = the v2 right image, the unit baseline). The thesis
reports bad-pixel percentages (> 1 px) of 1.345 (local) and 1.021 (global) without naming the mask; its
two-view method scores 0.89 / 1.21 / 5.84 (nonocc / all / disc, Table 6.2) and its text says the global
multi-view result is better than the two-view one, which holds for ``all`` (1.021 < 1.21) but not for
``nonocc`` (0.89) — so the thesis's number is most likely over ``all``. We report all three v2 masks and
compare on both readings.

Rows: ``two-view coop`` is the registry matcher as it stands; ``global, one view`` is our global method
with the unit view only, i.e. the two-view ``coop`` pipeline rebuilt from the same building blocks
(segmentation, planes, cooperative optimisation), so that the effect of adding views is measured with
everything else fixed; the local rows use side-aware fusion where both sides are balanced
(``occlusion="auto"``), baseline weights, and the two-view BPASW matcher's hole filling and final median.
The global rows include ``coop``'s post-optimisation steps with multi-view evidence
(:mod:`prismstereo.multiview.poststeps`: candidate planes fitted to the fused BPASW map, boundary step on the
fused BPASW cost, occlusion step per side, subpixel-preserving median), so the one-view global row is ``coop``'s
whole pipeline rebuilt from the same blocks.

Extra rows: Cones with all nine views (``im2`` reference, ``imK`` at ratio (K − 2)/4) beside our two-view
``coop`` on im2/im6, and the time of five views against two.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

import numpy as np

from prismstereo.apps.reproduce import TableResult
from prismstereo.evaluation.middlebury import evaluate_disparity, load_scene, resolve_data_dir
from prismstereo.io import read_image
from prismstereo.matching.api import match
from prismstereo.multiview.api import match_multiview

log = logging.getLogger(__name__)

__all__ = ["THESIS", "TSUKUBA_VIEWS", "cones_views", "reproduce"]

#: thesis Table 7.1 (mask not stated) and the two-view anchors of Table 6.2
THESIS = {"local": 1.345, "global": 1.021, "two_view_coop": (0.89, 1.21, 5.84)}
#: Tsukuba: file -> signed baseline ratio (reference col3)
TSUKUBA_VIEWS = {"col1": -2.0, "col2": -1.0, "col4": 1.0, "col5": 2.0}


def cones_views() -> dict[str, float]:
    """Cones: ``imK`` -> ratio ``(K - 2) / 4`` for the eight views besides the reference im2."""
    return {f"im{k}": (k - 2) / 4.0 for k in range(9) if k != 2}


def _bad(disp: np.ndarray, scene: Any) -> dict[str, float]:

    b = evaluate_disparity(disp, scene, thresholds=(1.0,))["bad"]["1.0"]
    return {m: round(float(v), 3) for m, v in b.items()}


def _run(name: str, fn: Any, repeat: int = 1) -> tuple[np.ndarray, float]:
    """Disparity and the minimum time of ``repeat`` runs (the shared machine is noisy)."""
    dt = float("inf")
    for _ in range(max(repeat, 1)):
        t = time.perf_counter()
        res = fn()
        dt = min(dt, time.perf_counter() - t)
    log.info("%s: %.2f s", name, dt)
    return res.disparity, dt


def _scene_rows(scene_name: str, views: dict[str, float], ref_name: str, *, data_dir: Path | None,
                local: bool, subsets: list[list[str]], timing_repeat: int = 1) -> list[dict[str, Any]]:

    scene = load_scene(scene_name, data_dir)
    folder = resolve_data_dir(data_dir) / scene_name / "views"
    ref = read_image(folder / f"{ref_name}.png")
    imgs = {k: read_image(folder / f"{k}.png") for k in views}
    unit = next(k for k, r in views.items() if r == 1.0)
    md = scene.max_disp
    rows: list[dict[str, Any]] = []
    # warm-up on a crop so that just-in-time compilation is not timed
    crop = (slice(0, 64), slice(0, 96))
    match(ref[crop], imgs[unit][crop], max_disp=min(md, 40), method="coop")
    match_multiview(ref[crop], [imgs[k][crop] for k in subsets[-1]], ratios=[views[k] for k in subsets[-1]],
                    max_disp=min(md, 20), method="global")
    if local:
        match(ref[crop], imgs[unit][crop], max_disp=min(md, 40), method="bpasw")

    def add(method: str, used: list[str], disp: np.ndarray, dt: float) -> None:
        rows.append({"scene": scene_name, "method": method, "views": [ref_name, *used],
                     "ratios": [views[k] for k in used], "bad": _bad(disp, scene), "seconds": round(dt, 2)})

    d, dt = _run("coop", lambda: match(ref, imgs[unit], max_disp=md, method="coop"), repeat=timing_repeat)
    add("two-view coop", [unit], d, dt)
    d, dt = _run("global 1", lambda: match_multiview(ref, [imgs[unit]], ratios=[1.0], max_disp=md, method="global"))
    add("global, one view (= coop's pipeline, our blocks)", [unit], d, dt)
    if local:
        d, dt = _run("bpasw", lambda: match(ref, imgs[unit], max_disp=md, method="bpasw"))
        add("two-view BPASW (checked + filled)", [unit], d, dt)
    for used in subsets:
        ratios = [views[k] for k in used]
        ims = [imgs[k] for k in used]
        if local:
            d, dt = _run("local", lambda ims=ims, ratios=ratios: match_multiview(
                ref, ims, ratios=ratios, max_disp=md, method="local"))
            add("local multi-baseline (BPASW, Eq. 7.8)", used, d, dt)
        d, dt = _run("global", lambda ims=ims, ratios=ratios: match_multiview(
            ref, ims, ratios=ratios, max_disp=md, method="global"),
            repeat=timing_repeat if len(used) == len(views) else 1)
        add("global multi-view (§7.1.2)", used, d, dt)
    return rows


def _fmt(rows: list[dict[str, Any]]) -> list[str]:
    out = ["| scene | method | views (ratios) | nonocc | all | disc | s | thesis |",
           "|---|---|---|---:|---:|---:|---:|---|"]
    for r in rows:
        thesis = ""
        n = len(r["views"])
        if r["scene"] == "tsukuba":
            if r["method"].startswith("local") and n == 5:
                thesis = f"{THESIS['local']} (mask not stated)"
            elif r["method"].startswith("global") and n == 5:
                thesis = f"{THESIS['global']} (mask not stated)"
            elif r["method"] == "two-view coop":
                thesis = "0.89 / 1.21 / 5.84 (Table 6.2)"
        ratios = ", ".join(f"{v:+g}" for v in r["ratios"])
        b = r["bad"]
        out.append(f"| {r['scene']} | {r['method']} | {n} ({ratios}) | {b['nonocc']:.2f} | {b['all']:.2f} | "
                   f"{b['disc']:.2f} | {r['seconds']:.2f} | {thesis} |")
    return out


def reproduce(*, data_dir: Path | None = None, quick: bool = False) -> TableResult:
    """Re-measure thesis Table 7.1 (and the Cones nine-view extension).

    ``quick``: Tsukuba only, global method only (five views), beside two-view ``coop``.
    """
    all_t = list(TSUKUBA_VIEWS)
    rows = _scene_rows("tsukuba", TSUKUBA_VIEWS, "col3", data_dir=data_dir, local=not quick,
                       subsets=[all_t] if quick else [["col2", "col4"], all_t], timing_repeat=3)
    if not quick:
        rows += _scene_rows("cones", cones_views(), "im2", data_dir=data_dir, local=True,
                            subsets=[list(cones_views())])
    t_rows = [r for r in rows if r["scene"] == "tsukuba"]
    coop_s = next(r["seconds"] for r in t_rows if r["method"] == "two-view coop")
    g5 = next(r for r in t_rows if r["method"].startswith("global") and len(r["views"]) == 5)
    lines = ["# Table 7.1 — multi-view stereo matching (bad pixels > 1 px, %)", "",
             "Tsukuba: reference col3; col1, col2, col4, col5 at baseline ratios −2, −1, +1, +2 (col4 = unit "
             "baseline). Cones: reference im2; imK at ratio (K − 2)/4. All three v2 masks are reported; the "
             "thesis does not name its mask (its text ranks global multi-view above its two-view 1.21, which "
             "fits the 'all' mask).", "", *_fmt(rows), "",
             f"Five-view global vs two-view coop time on Tsukuba: {g5['seconds']:.2f} s vs {coop_s:.2f} s "
             f"(×{g5['seconds'] / max(coop_s, 1e-9):.2f}; each the minimum of three runs; 2 shared CPU cores, noisy)."]
    return TableResult("table7.1", "\n".join(lines) + "\n", {"rows": rows, "thesis": THESIS})
