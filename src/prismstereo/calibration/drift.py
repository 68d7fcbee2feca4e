"""Has the prism moved? The row misalignment of a capture's rectified views, measured on feature matches.

A rig whose prism pose is right rectifies a capture so that a scene point lands on the same row of both
views. :func:`row_misalignment` rectifies the capture's face pairs with the rig, matches SIFT features
between the rectified views (ratio test, mutual nearest neighbours, fundamental-matrix RANSAC, which does
not assume the rows are aligned) and measures |y_left − y_right| of the consistent matches. Stereo
matching of rectified views searches along rows only; the project's matchers tolerate about half a pixel
of misalignment, so a median above :data:`RECALIBRATE_MEDIAN_PX` or a 95th percentile above
:data:`RECALIBRATE_P95_PX` means the rig needs recalibrating (:func:`prismstereo.calibrate_prism` with
``from_scene=True``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from itertools import combinations

import cv2
import numpy as np

from prismstereo.calibration.from_scene import consistent_matches, match_features, sift_features
from prismstereo.cameras import calibrate_rig
from prismstereo.config import Rig
from prismstereo.errors import GeometryError, ImageError
from prismstereo.io.images import as_image
from prismstereo.rectify import rectify_pair

log = logging.getLogger(__name__)

__all__ = ["RECALIBRATE_MEDIAN_PX", "RECALIBRATE_P95_PX", "RowCheck", "row_misalignment"]

#: a median |dy| above this (px) says the rig needs recalibrating
RECALIBRATE_MEDIAN_PX = 0.3
#: a 95th percentile |dy| above this (px) says the rig needs recalibrating
RECALIBRATE_P95_PX = 1.0
#: how :meth:`RowCheck.summary` says to recalibrate, by default (the library's call)
RECALIBRATE_CALL = "prismstereo.calibrate_prism(rig, [capture], from_scene=True)"
#: fewest consistent matches for a verdict
MIN_CHECK_MATCHES = 30


@dataclass(frozen=True)
class RowCheck:
    """Rectified row misalignment of one capture under one rig.

    Attributes
    ----------
    pairs : list of dict  per rectified face pair: faces, matches, median_px, p95_px, mean_dy_px.
    median_px, p95_px : float  over the matches of all pairs.
    n_matches : int
    needs_recalibration : bool
    """

    pairs: list[dict[str, object]]
    median_px: float
    p95_px: float
    n_matches: int
    needs_recalibration: bool

    def report(self) -> dict[str, object]:
        return {"median_dy_px": self.median_px, "p95_dy_px": self.p95_px, "n_matches": self.n_matches,
                "needs_recalibration": self.needs_recalibration,
                "thresholds_px": {"median": RECALIBRATE_MEDIAN_PX, "p95": RECALIBRATE_P95_PX}, "pairs": self.pairs}

    def summary(self, *, recalibrate: str = RECALIBRATE_CALL) -> str:
        """The per-pair lines and the verdict; ``recalibrate`` says how to recalibrate (the CLI gives its
        command)."""
        lines = [f"faces {p['faces'][0]}-{p['faces'][1]}: {p['matches']} matches, |dy| median "  # type: ignore[index]
                 f"{p['median_px']:.3f} px, p95 {p['p95_px']:.3f} px, mean dy {p['mean_dy_px']:+.3f} px"
                 for p in self.pairs]
        verdict = (f"needs recalibration ({recalibrate})"
                   if self.needs_recalibration else "rows aligned: no recalibration needed")
        lines.append(f"rectified rows |dy| median {self.median_px:.3f} px, p95 {self.p95_px:.3f} px over "
                     f"{self.n_matches} matches (thresholds {RECALIBRATE_MEDIAN_PX:g} / {RECALIBRATE_P95_PX:g} px): "
                     f"{verdict}")
        return "\n".join(lines)


def rectified_row_errors(pair: object, image: np.ndarray, *, erode_px: int = 4) -> np.ndarray:
    """(N,) signed y_left − y_right (px) of the consistent SIFT matches between a pair's rectified views."""
    left, right = pair.rectify_images(as_image(image, channels=1))  # type: ignore[attr-defined]
    kernel = np.ones((2 * erode_px + 1, 2 * erode_px + 1), np.uint8)
    vl, vr = (cv2.erode(np.asarray(v, np.uint8), kernel) > 0 for v in pair.valid_masks())  # type: ignore[attr-defined]
    pl, dl = sift_features(np.asarray(left), vl)
    pr, dr = sift_features(np.asarray(right), vr)
    idx = match_features(dl, dr)
    a, b = pl[idx[:, 0]], pr[idx[:, 1]]
    ok = consistent_matches(a, b)
    return np.asarray(a[ok, 1] - b[ok, 1])


def row_misalignment(rig: Rig, image: np.ndarray, *, calibration: str = "fit",
                     min_matches: int = MIN_CHECK_MATCHES) -> RowCheck:
    """Rectify every overlapping face pair of ``rig`` and measure the row misalignment of ``image``.

    Raises
    ------
    ImageError
        Fewer than ``min_matches`` consistent matches in all pairs together (too little texture).
    """

    views = calibrate_rig(rig, method=calibration)
    pairs: list[dict[str, object]] = []
    all_dy = []
    for a, b in combinations(range(rig.prism.faces), 2):
        try:
            pair = rectify_pair(rig, views[a], views[b])
        except GeometryError as exc:
            log.info("faces %d and %d not checked: %s", a, b, exc)
            continue
        dy = rectified_row_errors(pair, image)
        if dy.size == 0:
            continue
        ady = np.abs(dy)
        pairs.append({"faces": [pair.left_face, pair.right_face], "matches": int(dy.size),
                      "median_px": float(np.median(ady)), "p95_px": float(np.percentile(ady, 95)),
                      "mean_dy_px": float(np.mean(dy))})
        all_dy.append(ady)
    n = int(sum(d.size for d in all_dy))
    if n < min_matches:
        raise ImageError(f"expected at least {min_matches} feature matches between the rectified views, got {n}: the "
                         "capture has too little texture to check the rig; use a capture of a textured scene")
    ady = np.concatenate(all_dy)
    med, p95 = float(np.median(ady)), float(np.percentile(ady, 95))
    return RowCheck(pairs=pairs, median_px=med, p95_px=p95, n_matches=n,
                    needs_recalibration=bool(med > RECALIBRATE_MEDIAN_PX or p95 > RECALIBRATE_P95_PX))
