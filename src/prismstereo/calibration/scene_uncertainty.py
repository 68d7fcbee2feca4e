"""What the parameters a self-calibration could not observe can do to depth.

A scene observes a prism parameter only if it moves the matches off their epipolar curves; tilt about the
camera's Y axis (``tilt_y``) mostly changes the horizontal disparity, which any depth explains, so one scene
leaves it where its prior holds it (:func:`~prismstereo.calibration.from_scene.calibrate_from_scene`'s
notes). Whatever it is off by goes into the depth scale. :func:`unobserved_depth_error` turns each such
parameter's remaining standard deviation into a relative depth error at the depths of the scene's own
matches: every match is triangulated (exact refracted rays, the midpoint of their closest points) with the
fitted prism and with that parameter moved by its std, both ways, and the median relative change of the
depth is reported, in %, for the worse way. The change is not odd in the parameter: a tilt moves the depth
of the whole view one way (second order) and tilts it (first order), so the median |change| of one way can
be half the other's (the misaligned bi-prism of issue 26: tilt y −2° moves the depth of bowling1's matches
by 1.06 %, +2° by 0.40 %).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from prismstereo.calibration.from_scene import SceneCalibration
from prismstereo.calibration.prism import prism_values, with_prism_values
from prismstereo.config import Rig
from prismstereo.optics import trace_pixels

__all__ = ["DEPTH_ERROR_WARN_PCT", "unobserved_depth_error", "uncertainty_warnings"]

#: a median depth error (%) from unobserved parameters above this is worth a warning: the pipeline's own
#: accuracy on a well-calibrated rig is 0.05–0.15 % (docs/EXPERIMENTS.md)
DEPTH_ERROR_WARN_PCT = 0.2


def _depths(rig: Rig, cal: SceneCalibration) -> np.ndarray:
    """(N,) depth (Z, mm) of every match of ``cal``, triangulated through ``rig``'s prism; NaN where a ray
    is invalid or the rays do not converge in front of the prism."""
    out = []
    for m in cal.matches:
        a = trace_pixels(rig, m.pixels_a, face=m.face_a)
        b = trace_pixels(rig, m.pixels_b, face=m.face_b)
        o1, d1, o2, d2 = a.origins, a.directions, b.origins, b.directions
        w = o1 - o2
        aa, bb, cc = (d1 * d1).sum(-1), (d1 * d2).sum(-1), (d2 * d2).sum(-1)
        dd, ee = (d1 * w).sum(-1), (d2 * w).sum(-1)
        den = aa * cc - bb * bb
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (bb * ee - cc * dd) / den
            t = (aa * ee - bb * dd) / den
        p = 0.5 * (o1 + s[:, None] * d1 + o2 + t[:, None] * d2)
        z = np.where(a.valid & b.valid & (s > 0) & (t > 0), p[:, 2], np.nan)
        out.append(z)
    return np.concatenate(out) if out else np.zeros(0)


def unobserved_depth_error(cal: SceneCalibration) -> dict[str, Any]:
    """The depth error each parameter the scene did not observe can cause, at the scene's own depths.

    Parameters
    ----------
    cal : SceneCalibration
        A finished self-calibration (its matches and the std of each fitted parameter).

    Returns
    -------
    dict
        ``depth_mm``: the matches' depths (5th, 50th, 95th percentile); ``parameters``: for each unobserved
        parameter its std, the median / 95th percentile relative depth change (%) when it moves by that
        std the worse way (``direction``: ``"+"`` or ``"-"``; ``by_direction``: both ways' median and
        p95), and that median per unit of the parameter (% per degree or mm); ``max_median_pct``: the
        largest of those medians (0 when every parameter was observed).
    """
    z0 = _depths(cal.rig, cal)
    ok0 = np.isfinite(z0)
    out: dict[str, Any] = {
        "depth_mm": [round(float(v), 1) for v in np.percentile(z0[ok0], [5, 50, 95])] if ok0.any() else None,
        "parameters": {}, "max_median_pct": 0.0}
    base = prism_values(cal.rig)
    for k, seen in cal.observed.items():
        if seen:
            continue
        ways: dict[str, tuple[float, float]] = {}
        for sign in ("+", "-"):
            values = dict(base)
            values[k] = base[k] + (cal.std[k] if sign == "+" else -cal.std[k])
            z1 = _depths(with_prism_values(cal.rig, values), cal)
            ok = ok0 & np.isfinite(z1)
            if ok.any():
                rel = 100.0 * np.abs(z1[ok] - z0[ok]) / z0[ok]
                ways[sign] = (float(np.median(rel)), float(np.percentile(rel, 95)))
        if not ways:
            continue
        # the input value may be off either way: the worse one is what the depth can be off by
        worse = max(ways, key=lambda w: ways[w][0])
        med, p95 = ways[worse]
        out["parameters"][k] = {
            "std": float(cal.std[k]), "median_pct": round(med, 4), "p95_pct": round(p95, 4),
            "per_unit_pct": round(med / max(abs(float(cal.std[k])), 1e-12), 4), "direction": worse,
            "by_direction": {w: {"median_pct": round(m, 4), "p95_pct": round(q, 4)} for w, (m, q) in ways.items()}}
        out["max_median_pct"] = max(out["max_median_pct"], round(med, 4))
    return out


def uncertainty_warnings(report: dict[str, Any], *, limit_pct: float = DEPTH_ERROR_WARN_PCT) -> list[str]:
    """One line per unobserved parameter whose depth error (:func:`unobserved_depth_error`) exceeds
    ``limit_pct``."""
    lines = []
    for k, v in report["parameters"].items():
        if v["median_pct"] > limit_pct:
            lines.append(f"self-calibration: {k} was not observed by this scene (± {v['std']:.3g}); it can change "
                         f"the depth by {v['median_pct']:.2f} % (median, p95 {v['p95_pct']:.2f} %) at "
                         f"the scene's depths: calibrate from a checkerboard (calibrate-prism) or from several "
                         "scenes for better than that")
    return lines
