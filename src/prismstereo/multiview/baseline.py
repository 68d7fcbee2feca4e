"""Multi-baseline building blocks: views with signed baseline ratios, per-pair cost volumes, and their
resampling onto the disparity grid of the unit baseline (thesis §7.1.1, Eqs. 7.3–7.8).

Conventions
-----------
All images are rectified with collinear horizontal baselines (thesis Fig. 7.1). The *reference* image is
matched against every other view ``i``; the view's signed baseline ratio is ``δᵢ = λᵢ / λ_unit`` (Eq. 7.6),
positive for a view to the RIGHT of the reference. For a unit-baseline disparity ``d`` (the disparity of the
reference against a view at ratio +1, ``d = x_ref - x_right >= 0``), reference pixel ``x`` matches view
pixel ``x - δᵢ d`` (Eq. 7.7): a view on the right (``δ > 0``) at ``x - |δ| d``, a view on the LEFT
(``δ < 0``) at ``x + |δ| d``.

Every pair is matched with the project's two-view costs over its own non-negative pair disparity
``s = |δᵢ| d``; a view on the left is handled by mirroring both images (then it *is* a right view of the
mirrored reference), and the volume is mirrored back into the reference frame. The pair volume is then
sampled at ``s = |δᵢ| d`` for every unit disparity ``d`` with linear interpolation along ``s`` (fractional
ratios such as Cones' ±0.25 need it) and the views are summed (Eq. 7.8).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from prismstereo.errors import ConfigError, ImageError, MatchingError
from prismstereo.io.images import as_image
from prismstereo.matching.coop.coopcost import CostParams, aggregated_costs, guided_filter_volume, raw_cost
from prismstereo.matching.coop.pipeline import box_filter_volume, initial_disparity
from prismstereo.matching.local import costs
from prismstereo.matching.local.matchers import BPASWMatcher
from prismstereo.matching.local.selection import cross_check, right_disparity, subpixel_refine, winner_take_all

log = logging.getLogger(__name__)

__all__ = [
    "CostName",
    "PairCost",
    "check_views",
    "fuse_costs",
    "pair_cost",
    "parse_ratio",
    "parse_view_spec",
    "resample_to_unit",
]

F32 = npt.NDArray[np.float32]
CostName = Literal["bpasw", "guided"]


def parse_ratio(text: str) -> float:
    """A signed baseline ratio from text: a decimal (``-2``, ``0.25``) or a fraction (``-1/4``).

    Raises
    ------
    ConfigError
        Not a finite non-zero number.
    """
    t = str(text).strip()
    try:
        if "/" in t:
            num, den = t.split("/", 1)
            value = float(num) / float(den)
        else:
            value = float(t)
    except (ValueError, ZeroDivisionError):
        raise ConfigError(f"expected a baseline ratio like -2, 0.25 or -1/4, got {text!r}") from None
    if not math.isfinite(value) or value == 0.0:
        raise ConfigError(f"expected a finite, non-zero baseline ratio, got {text!r}")
    return value


def parse_view_spec(text: str) -> tuple[str, float]:
    """Split ``IMG:RATIO`` (the CLI's ``--view``) into the path and the signed ratio.

    The ratio follows the LAST colon, so paths with colons (``C:/x.png:2``) work.

    Raises
    ------
    ConfigError
        No colon, an empty path, or a bad ratio.
    """
    if ":" not in text:
        raise ConfigError(f"view: expected IMG:RATIO like col4.png:1 or col1.png:-2, got {text!r}")
    path, ratio = text.rsplit(":", 1)
    if not path:
        raise ConfigError(f"view: expected an image path before ':', got {text!r}")
    return path, parse_ratio(ratio)


def _as_image(img: Any, name: str) -> np.ndarray:
    arr = np.asarray(img)  # the one coercion rule (docs/conventions.md): uint8 kept, else float32 0..255
    return as_image(arr, name=name, dtype=np.uint8 if arr.dtype == np.uint8 else np.float32, channels=3)


def check_views(reference: Any, views: Sequence[Any], ratios: Sequence[float], *,
                max_disp: Any) -> tuple[np.ndarray, list[np.ndarray], list[float], int]:
    """Validate a multi-baseline input set.

    Parameters
    ----------
    reference : (H, W, 3) or (H, W) image
    views : sequence of images of the reference's size
    ratios : sequence of float
        Signed baseline ratios, one per view, non-zero, distinct.
    max_disp : int
        Largest disparity of the UNIT baseline, ``0 <= max_disp < W``.

    Returns
    -------
    reference (H, W, 3), views (list of (H, W, 3)), ratios (list of float), max_disp (int)

    Raises
    ------
    ImageError, ConfigError, MatchingError
    """
    ref = _as_image(reference, "reference image")
    if len(views) == 0:
        raise ConfigError("expected at least one view besides the reference, got none")
    if len(views) != len(ratios):
        raise ConfigError(f"expected one baseline ratio per view, got {len(views)} views and "
                          f"{len(ratios)} ratios")
    vs = []
    for i, v in enumerate(views):
        arr = _as_image(v, f"view {i}")
        if arr.shape[:2] != ref.shape[:2]:
            raise ImageError(f"expected view {i} of the reference's size {ref.shape[1]}×{ref.shape[0]}, "
                             f"got {arr.shape[1]}×{arr.shape[0]}")
        vs.append(arr)
    rs = [float(r) for r in ratios]
    for r in rs:
        if not math.isfinite(r) or r == 0.0:
            raise ConfigError(f"expected finite, non-zero baseline ratios, got {r}")
    if len(set(rs)) != len(rs):
        raise ConfigError(f"expected distinct baseline ratios, got {rs}")
    if isinstance(max_disp, bool) or not isinstance(max_disp, int | np.integer):
        raise MatchingError(f"expected an integer max_disp, got {max_disp!r}")
    md = int(max_disp)
    if md < 0 or md >= ref.shape[1]:
        raise MatchingError(f"expected 0 <= max_disp < image width ({ref.shape[1]}), got {md}")
    return ref, vs, rs, md


@dataclass(frozen=True)
class PairCost:
    """Cost volumes of the reference against one view, in the REFERENCE frame.

    Attributes
    ----------
    ratio : float
        Signed baseline ratio ``δ`` of the view.
    cost : (H, W, S + 1) float32
        Aggregated cost: ``cost[y, x, s]`` compares reference pixel ``(x, y)`` with view pixel
        ``(x - sign(δ) s, y)`` for the integer pair disparity ``s = 0 .. S``. Lower is better.
    disparity : (H, W) float32
        The pair's own WTA + subpixel disparity converted to the UNIT baseline (``s / |δ|``), every pixel.
    reliable : (H, W) bool
        Pixels that passed the pair's left–right check (thesis Eq. 6.7).
    raw : (H, W, S + 1) float32 or None
        The pixel-wise cost before aggregation (lightly box-smoothed), the data term of the global
        method (Eq. 7.16), same indexing as ``cost``.
    step : int
        Slice ``k`` of ``cost``/``raw`` holds the pair disparity ``s = step · k`` (``step = |δ|`` for an
        integer ratio ≥ 2: only the pair disparities that a unit-baseline disparity can reach are
        aggregated).
    raw_row : (H, W, S + 1) float32 or None
        The same pixel-wise cost boxed along the row only (``pair_cost(..., row_radius=r)``), kept beside
        ``raw`` so a row-boxed data term needs no second pass over the pair.
    """

    ratio: float
    cost: F32
    disparity: F32
    reliable: npt.NDArray[np.bool_]
    raw: F32 | None = None
    step: int = 1
    raw_row: F32 | None = None


def _strided_check(agg_l: F32, agg_r: F32, step: int) -> tuple[F32, npt.NDArray[np.bool_]]:
    """WTA + parabola + exact left–right check (Eq. 6.7) on volumes whose slice k is disparity ``step·k``."""
    h, w, nd = agg_l.shape
    dl = agg_l.argmin(axis=2)
    dr = agg_r.argmin(axis=2)
    xr = np.arange(w)[None, :] - step * dl
    inside = xr >= 0
    back = np.take_along_axis(dr, np.clip(xr, 0, w - 1), axis=1)
    ok = inside & (back == dl)
    if nd >= 3:
        k = np.clip(dl, 1, nd - 2)
        c0 = np.take_along_axis(agg_l, (k - 1)[..., None], 2)[..., 0]
        c1 = np.take_along_axis(agg_l, k[..., None], 2)[..., 0]
        c2 = np.take_along_axis(agg_l, (k + 1)[..., None], 2)[..., 0]
        den = c0 - 2.0 * c1 + c2
        off = np.where(den > 1e-6, (c0 - c2) / (2.0 * np.maximum(den, 1e-6)), 0.0)
        sub = np.where((dl > 0) & (dl < nd - 1), dl + np.clip(off, -0.5, 0.5), dl)
    else:
        sub = dl.astype(np.float64)
    return (step * sub).astype(np.float32), ok


def _boxed(pix: F32, keep_raw: bool, data_radius: int, row_box: bool,
           row_radius: int | None) -> tuple[F32 | None, F32 | None]:
    """The pixel-wise cost boxed for the data term (``raw``) and, with ``row_radius``, along the row only."""
    if not keep_raw:
        return None, None
    raw = box_filter_volume(pix, data_radius, vertical=not row_box)
    return raw, (None if row_radius is None else box_filter_volume(pix, row_radius, vertical=False))


def _pair_volumes(left: np.ndarray, right: np.ndarray, max_s: int, cost: CostName, cost_params: dict[str, Any],
                  keep_raw: bool, data_radius: int,
                  step: int = 1, row_box: bool = False, row_radius: int | None = None,
                  ) -> tuple[F32, F32, npt.NDArray[np.bool_], tuple[F32 | None, F32 | None]]:
    """Left aggregated volume, subpixel left disparity (pair px), left–right check and the raw volumes
    (square-boxed or row-boxed with ``row_box``, and row-boxed with ``row_radius``).

    With ``step > 1`` (guided cost only) slice ``k`` holds the pair disparity ``step · k``.
    """
    if cost == "guided":

        cp = CostParams(**cost_params)
        pix = raw_cost(left, right, max_disp=max_s, min_disp=0, params=cp)
        if step == 1:
            agg_l, agg_r = aggregated_costs(left, right, max_disp=max_s, min_disp=0, params=cp, raw=pix)
            disp, ok = initial_disparity(agg_l, agg_r, min_disp=0)
            return agg_l, disp, ok, _boxed(pix, keep_raw, data_radius, row_box, row_radius)
        sel = np.ascontiguousarray(pix[:, :, ::step])
        del pix
        w = sel.shape[1]
        sel_r = np.full_like(sel, np.float32(2.0))
        for k in range(sel.shape[2]):  # right view's volume, slice by slice: C_R(x, s) = C_L(x + s, s)
            sk = step * k
            if sk < w:
                sel_r[:, : w - sk, k] = sel[:, sk:, k]
        lf = np.asarray(left, dtype=np.float32)
        rf = np.asarray(right, dtype=np.float32)
        agg_l = guided_filter_volume(lf, sel, radius=cp.radius, eps=cp.eps)
        agg_r = guided_filter_volume(rf, sel_r, radius=cp.radius, eps=cp.eps)
        disp, ok = _strided_check(agg_l, agg_r, step)
        return agg_l, disp, ok, _boxed(sel, keep_raw, data_radius, row_box, row_radius)
    if cost == "bpasw":

        m = BPASWMatcher(**cost_params)
        vol = m.cost_volume(left, right, max_disp=max_s, min_disp=0)
        d0 = winner_take_all(vol)
        ok = cross_check(d0, right_disparity(vol), tolerance=0.0)
        raws: tuple[F32 | None, F32 | None] = (None, None)
        if keep_raw:
            raws = _boxed(costs.cost_s_ad(left, right, max_disp=max_s, min_disp=0, omega=m.omega,
                                          tau_color=m.tau_color, tau_gradient=m.tau_gradient), True, data_radius,
                          row_box, row_radius)
        return vol, subpixel_refine(vol, d0), ok, raws
    raise ConfigError(f"expected cost 'bpasw' or 'guided', got {cost!r}")


def pair_cost(reference: np.ndarray, view: np.ndarray, ratio: float, *, max_disp: int,
              cost: CostName = "guided", cost_params: dict[str, Any] | None = None, keep_raw: bool = False,
              data_radius: int = 1, stride: bool = True, row_box: bool = False,
              row_radius: int | None = None) -> PairCost:
    """Aggregated cost of the reference against one view (thesis Eq. 7.9), in the reference frame.

    Parameters
    ----------
    reference, view : (H, W, 3) images, 0..255
    ratio : float
        Signed baseline ratio δ of ``view`` (+ = right of the reference).
    max_disp : int
        Largest UNIT-baseline disparity; the pair is searched over ``s = 0 .. ceil(|δ| max_disp) + 1``
        (clipped to ``W - 1``).
    cost : {"guided", "bpasw"}
        ``"bpasw"``: S_AD aggregated with symmetric Weber–Fechner weights (thesis Eqs. 5.6–5.14,
        :class:`~prismstereo.matching.local.matchers.BPASWMatcher`); ``"guided"``: the ``coop`` matcher's cost
        (truncated AD + gradient + census aggregated with a colour guided filter,
        :func:`~prismstereo.matching.coop.coopcost.aggregated_costs`), the same adaptive-support idea at O(1)
        per pixel and disparity.
    cost_params : dict, optional
        Keyword parameters of that cost (``BPASWMatcher`` fields or ``CostParams`` fields).
    keep_raw : bool
        Also return the pixel-wise cost (box radius ``data_radius``) for a data term.
    stride : bool
        For the guided cost and an integer ``|δ| >= 2``, aggregate only the pair disparities
        ``s = |δ| d`` that unit disparities reach (``|δ|`` times fewer slices; identical values there).
    row_box : bool
        Box the pixel-wise cost along the row only (``coop``'s sweep data term on slanted segments).
    row_radius : int, optional
        With ``keep_raw``, also keep the pixel-wise cost boxed along the row only with this radius
        (``raw_row``): the sweep step's data term, from the same pixel cost instead of a second pair pass.

    Returns
    -------
    PairCost
    """
    w = reference.shape[1]
    a = abs(float(ratio))
    step = int(round(a)) if (stride and cost == "guided" and a >= 2 and abs(a - round(a)) < 1e-9) else 1
    max_s = int(min(w - 1, math.ceil(a * max_disp) + step))
    params = dict(cost_params or {})
    if ratio > 0:
        vol, d, ok, (raw, raw_row) = _pair_volumes(reference, view, max_s, cost, params, keep_raw, data_radius,
                                                   step, row_box, row_radius)
    else:
        # mirror both images: the left view becomes a right view of the mirrored reference; mirror back
        vol, d, ok, (raw, raw_row) = _pair_volumes(np.ascontiguousarray(reference[:, ::-1]),
                                                   np.ascontiguousarray(view[:, ::-1]), max_s, cost, params,
                                                   keep_raw, data_radius, step, row_box, row_radius)
        vol, d, ok = (np.ascontiguousarray(vol[:, ::-1]), np.ascontiguousarray(d[:, ::-1]),
                      np.ascontiguousarray(ok[:, ::-1]))
        raw = None if raw is None else np.ascontiguousarray(raw[:, ::-1])
        raw_row = None if raw_row is None else np.ascontiguousarray(raw_row[:, ::-1])
    disp = (np.asarray(d, np.float32) / np.float32(a)).astype(np.float32)
    return PairCost(float(ratio), vol, disp, np.asarray(ok, bool), raw, step, raw_row)


def resample_to_unit(pc: PairCost, *, max_disp: int, raw: bool = False) -> tuple[F32, npt.NDArray[np.bool_]]:
    """Sample a pair volume on the unit-baseline grid ``d = 0 .. max_disp`` (thesis Eq. 7.8).

    ``raw=True`` samples the pixel-wise volume ``pc.raw`` instead of the aggregated ``pc.cost``.

    ``C_i(x, y, d) = (1 - f) cost[y, x, ⌊s⌋] + f cost[y, x, ⌊s⌋ + 1]`` with ``s = |δ| d`` and
    ``f = s - ⌊s⌋`` (linear interpolation along the disparity axis; exact for integer ratios).

    Returns
    -------
    cost : (H, W, max_disp + 1) float32
    seen : (H, W, max_disp + 1) bool
        True where the matching view pixel ``x - δ d`` lies inside the view (the view sees the match).
    """
    src = pc.raw if raw and pc.raw is not None else pc.cost
    if raw and pc.raw is None:
        raise ConfigError("expected a pair cost computed with keep_raw=True, got one without its raw volume")
    h, w, ns = src.shape
    nd = max_disp + 1
    out = np.empty((h, w, nd), np.float32)
    seen = np.empty((h, w, nd), np.bool_)
    xs = np.arange(w, dtype=np.float64)
    a = abs(pc.ratio) / pc.step
    for k in range(nd):  # loop over disparities, not pixels
        s = min(a * k, ns - 1.0)
        s0 = int(math.floor(s))
        f = np.float32(s - s0)
        s1 = min(s0 + 1, ns - 1)
        if f == 0.0:
            out[:, :, k] = src[:, :, s0]
        else:
            out[:, :, k] = (np.float32(1.0) - f) * src[:, :, s0] + f * src[:, :, s1]
        xv = xs - pc.ratio * k
        seen[:, :, k] = ((xv >= -0.5) & (xv <= w - 0.5))[None, :]
    return out, seen


def fuse_costs(pairs: Sequence[PairCost], *, max_disp: int,
               weights: Sequence[float] | None = None) -> tuple[F32, npt.NDArray[np.int32]]:
    """Sum of the views' costs on the unit-baseline grid (thesis Eq. 7.8), normalised by the views that see.

    ``C(x, y, d) = Σᵢ wᵢ sᵢ Cᵢ(x, y, d) / Σᵢ wᵢ sᵢ`` where ``sᵢ`` is 1 when view ``i`` sees the match
    (its pixel ``x - δᵢ d`` is inside the image). Away from the borders every view sees and this is the
    thesis's sum divided by the constant ``Σ wᵢ`` (the same argmin); at the borders a view that cannot see
    the match neither votes for nor against it. Entries no view sees get the largest cost.

    Returns
    -------
    cost : (H, W, max_disp + 1) float32
    count : (H, W, max_disp + 1) int32
        Number of views that see each match.
    """
    if not pairs:
        raise ConfigError("expected at least one pair cost to fuse, got none")
    ws = [1.0] * len(pairs) if weights is None else [float(v) for v in weights]
    acc: F32 | None = None
    den: F32 | None = None
    cnt: npt.NDArray[np.int32] | None = None
    for pc, wgt in zip(pairs, ws, strict=True):
        c, s = resample_to_unit(pc, max_disp=max_disp)
        sw = s.astype(np.float32) * np.float32(wgt)
        if acc is None or den is None or cnt is None:
            acc, den, cnt = c * sw, sw, s.astype(np.int32)
        else:
            acc += c * sw
            den += sw
            cnt += s
    assert acc is not None and den is not None and cnt is not None
    top = float(acc.max()) if acc.size else 0.0
    with np.errstate(invalid="ignore", divide="ignore"):
        fused = np.where(den > 0, acc / np.maximum(den, np.float32(1e-12)), np.float32(top))
    return fused.astype(np.float32), cnt


def resolve_occlusion(mode: str, ratios: Sequence[float], *, weight_by_baseline: bool = True) -> str:
    """The occlusion handling to use: ``"sum"`` or ``"sides"`` (``"auto"`` decides from the ratios).

    ``"sides"`` (the lower of the left views' and the right views' fused cost) only helps when each side is
    a trustworthy estimate on its own; ``"auto"`` picks it when views lie on both sides and the weaker side
    carries at least half the weight of the stronger (weights ``min(|δ|, 1)`` or 1), else ``"sum"``
    (Eq. 7.8 as written). Tsukuba ±1, ±2 → sides; Cones (−0.5, −0.25 | +0.25 … +1.5) → sum.

    Raises
    ------
    ConfigError
        Unknown mode.
    """
    if mode not in ("auto", "sum", "sides"):
        raise ConfigError(f"expected occlusion 'auto', 'sum' or 'sides', got {mode!r}")
    left = [r for r in ratios if r < 0]
    right = [r for r in ratios if r > 0]
    if mode == "sum" or not left or not right:
        return "sum"
    if mode == "sides":
        return "sides"

    def weight(rs: list[float]) -> float:
        return float(sum(min(abs(r), 1.0) if weight_by_baseline else 1.0 for r in rs))

    wl, wr = weight(left), weight(right)
    return "sides" if min(wl, wr) >= 0.5 * max(wl, wr) else "sum"
