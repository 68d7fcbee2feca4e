"""OpenCV StereoSGBM behind the registry: the semi-global baseline users know (Hirschmüller 2008)."""

from __future__ import annotations

import time
from dataclasses import dataclass

import cv2
import numpy as np

from prismstereo.checks import check_fields, fail
from prismstereo.io.images import as_image
from prismstereo.matching.local import selection
from prismstereo.matching.registry import MatchResult, register_matcher

__all__ = ["SGBMMatcher"]


def _as_uint8(image: np.ndarray) -> np.ndarray:
    img = as_image(image, unit=False)  # validated by match(): uint8 or float32 on the 0..255 scale
    if img.ndim == 3:
        img = cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_RGB2BGR)
    return np.ascontiguousarray(img)


_MODES = {"hh": cv2.STEREO_SGBM_MODE_HH, "sgbm": cv2.STEREO_SGBM_MODE_SGBM,
          "3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY, "hh4": cv2.STEREO_SGBM_MODE_HH4}


@register_matcher("sgbm")
@dataclass(frozen=True, kw_only=True)
class SGBMMatcher:
    """``cv2.StereoSGBM`` in full 8-path mode (``MODE_HH``), then hole filling.

    ``P1 = 8·C·b²`` and ``P2 = 32·C·b²`` (C channels, b block size), uniqueness ratio, speckle filter
    and ``disp12MaxDiff`` left–right check as OpenCV recommends. OpenCV's fixed-point disparities (×16)
    are converted to float pixels; its invalid pixels and disparities outside ``[min_disp, max_disp]``
    become NaN. ``fill=True`` fills them like the local matchers for a dense map.
    """

    block_size: int = 5
    p1_factor: int = 8
    p2_factor: int = 32
    uniqueness: int = 10
    speckle_window: int = 100
    speckle_range: int = 2
    disp12_max_diff: int = 1
    pre_filter_cap: int = 63
    mode: str = "hh"
    fill: bool = True

    def __post_init__(self) -> None:
        # OpenCV's own limits: an odd block, P1 < P2, uniqueness a percentage, disp12MaxDiff < 0 = off
        check_fields(self, {"block_size": (1, 255), "p1_factor": (0, None), "p2_factor": (0, None),
                            "uniqueness": (0, 100), "speckle_window": (0, None), "speckle_range": (0, None),
                            "disp12_max_diff": (-1, None), "pre_filter_cap": (1, 255)})
        if self.block_size % 2 == 0:
            fail(self, "block_size", "an odd integer", self.block_size)
        if self.p2_factor <= self.p1_factor:
            fail(self, "p2_factor", f"an integer > p1_factor = {self.p1_factor}", self.p2_factor)
        if self.mode not in _MODES:
            fail(self, "mode", f"one of {', '.join(_MODES)}", self.mode)

    def compute(self, left: np.ndarray, right: np.ndarray, *, max_disp: int,
                min_disp: int = 0) -> MatchResult:
        timings: dict[str, float] = {}
        t = time.perf_counter()
        lt, rt = _as_uint8(left), _as_uint8(right)
        h, w = lt.shape[:2]
        ndisp = int(np.ceil((max_disp - min_disp + 1) / 16.0)) * 16
        # OpenCV leaves the first min_disp + ndisp columns unmatched: pad on the left so every pixel of
        # the image gets a search, and on the right so tiny images are wide enough.
        pad_l = ndisp + min_disp
        pad_r = max(0, self.block_size + 16 - w)
        if pad_l or pad_r:
            lt = cv2.copyMakeBorder(lt, 0, 0, pad_l, pad_r, cv2.BORDER_REPLICATE)
            rt = cv2.copyMakeBorder(rt, 0, 0, pad_l, pad_r, cv2.BORDER_REPLICATE)
        cn = 1 if lt.ndim == 2 else lt.shape[2]
        b = self.block_size
        sgbm = cv2.StereoSGBM_create(  # type: ignore[attr-defined]
            minDisparity=int(min_disp), numDisparities=ndisp, blockSize=b,
            P1=self.p1_factor * cn * b * b, P2=self.p2_factor * cn * b * b,
            disp12MaxDiff=self.disp12_max_diff, preFilterCap=self.pre_filter_cap,
            uniquenessRatio=self.uniqueness, speckleWindowSize=self.speckle_window,
            speckleRange=self.speckle_range, mode=_MODES[self.mode])
        raw16 = sgbm.compute(lt, rt)
        raw16 = raw16[:, pad_l:pad_l + w]
        disp = raw16.astype(np.float32) / np.float32(16.0)
        valid = (raw16 >= min_disp * 16) & (disp <= max_disp) & (raw16 != (min_disp - 1) * 16)
        disp[~valid] = np.nan
        # columns where x - d < 0 can only have been matched against the padding
        xs = np.arange(w, dtype=np.float32)[None, :]
        bad_border = np.isfinite(disp) & (xs - disp < -0.5)
        valid &= ~bad_border
        disp[bad_border] = np.nan
        timings["sgbm"] = time.perf_counter() - t
        if self.fill and not valid.all() and valid.any():
            t = time.perf_counter()
            dense = selection.fill_holes(disp, valid, image=left)
            timings["fill"] = time.perf_counter() - t
            return MatchResult(dense, valid, disp, timings, {})
        return MatchResult(disp, valid, None, timings, {})
