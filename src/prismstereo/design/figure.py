"""``design.png``: the prediction against depth, the sub-image layout on the sensor and the glass to scale."""

from __future__ import annotations

import io
import math

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Polygon  # noqa: E402

from prismstereo.design.predict import Prediction  # noqa: E402
from prismstereo.optics import face_map  # noqa: E402

__all__ = ["design_figure"]


def _layout(ax: plt.Axes, pred: Prediction) -> None:
    rig = pred.rig
    fm = face_map(rig)
    n = rig.prism.faces
    shown = np.where(fm < 0, np.nan, fm.astype(float))
    ax.imshow(shown, cmap="tab10", vmin=0, vmax=9, interpolation="nearest")
    for s in pred.sub_images:
        ys, xs = np.nonzero(fm == s.face)
        if xs.size:
            ax.text(xs.mean(), ys.mean(), f"face {s.face}\n{s.width_px:.0f}×{s.height_px:.0f} px",
                    ha="center", va="center", fontsize=8, color="white",
                    bbox={"facecolor": "black", "alpha": 0.5, "pad": 2})
    ax.set_title(f"sub-images on the {rig.camera.width}×{rig.camera.height} sensor (N = {n}, widths within "
                 f"{100 * pred.width_spread:.0f} %)", fontsize=9)
    ax.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")


def _glass(ax_side: plt.Axes, ax_front: plt.Axes, pred: Prediction) -> None:
    p = pred.rig.prism
    g = pred.glass
    r, h, a, b = p.inradius, p.face_height, p.apex_distance, p.back_distance
    dx = p.decenter[0]
    # side section through the apex along face 0's direction: z right, lateral up
    xs = [a, a + h, b, b, a + h]
    ys = [0.0, r, r, -r, -r]
    if p.faces % 2:  # the opposite side is an edge between faces, at the circumradius
        rc = r / math.cos(math.pi / p.faces)
        ys = [0.0, r, r, -rc, -rc]
        xs = [a, a + h, b, b, a + h]
    ax_side.add_patch(Polygon(np.stack([xs, np.array(ys) + dx], 1), closed=True, facecolor="#9ecae1",
                              edgecolor="k"))
    fov = pred.rig.camera.width / 2 / pred.rig.camera.focal_xy[0]
    ax_side.plot([0, b], [0, b * fov], "r--", lw=0.8)
    ax_side.plot([0, b], [0, -b * fov], "r--", lw=0.8)
    ax_side.plot([0], [0], "ko")
    ax_side.annotate("camera", (0, 0), textcoords="offset points", xytext=(4, 4), fontsize=8)
    ax_side.set_title(f"side section: apex {a:.1f} mm, back {b:.1f} mm, thickness {g.thickness:.2f} mm, "
                      f"α {p.corner_angle:.2f}°", fontsize=9)
    ax_side.set_xlabel("z (mm)")
    ax_side.set_ylabel("lateral (mm)")
    ax_side.set_aspect("equal")
    ax_side.set_xlim(-10, b + 15)
    ax_side.set_ylim(-max(r, b * fov) * 1.2 + dx, max(r, b * fov) * 1.2 + dx)
    # front view: the outline seen from the camera
    if p.faces == 2:
        L = g.length / 2
        outline = np.array([[-r, -L], [r, -L], [r, L], [-r, L]])
        ax_front.plot([0, 0], [-L, L], "k:", lw=0.8)
        title = f"front: {g.across_flats:.1f} × {g.length:.1f} mm (ridge dotted)"
    else:
        rc = r / math.cos(math.pi / p.faces)
        # corners between faces k and k+1 at θ_k + 180°/N
        th = np.radians(p.rotation + 360.0 * (np.arange(p.faces) + 0.5) / p.faces)
        outline = np.stack([rc * np.cos(th), rc * np.sin(th)], 1)
        for c in outline:
            ax_front.plot([p.decenter[0], c[0] + p.decenter[0]], [p.decenter[1], c[1] + p.decenter[1]], "k:", lw=0.8)
        title = f"front: {g.across_flats:.1f} mm across flats, {g.across_corners:.1f} mm across corners"
    outline = outline + np.array(p.decenter)
    ax_front.add_patch(Polygon(outline, closed=True, facecolor="#9ecae1", edgecolor="k", alpha=0.8))
    cam = pred.rig.camera
    fx, fy = cam.focal_xy
    wz, hz = b * (cam.width / 2) / fx, b * (cam.height / 2) / fy
    ax_front.add_patch(Polygon(np.array([[-wz, -hz], [wz, -hz], [wz, hz], [-wz, hz]]), closed=True, fill=False,
                               edgecolor="r", ls="--"))
    ax_front.plot([0], [0], "k+")
    ax_front.set_aspect("equal")
    lim = max(np.abs(outline).max(), wz, hz) * 1.15
    ax_front.set_xlim(-lim, lim)
    ax_front.set_ylim(lim, -lim)
    ax_front.set_title(title + "; field at the back plane dashed", fontsize=9)
    ax_front.set_xlabel("x (mm)")
    ax_front.set_ylabel("y (mm)")


def design_figure(pred: Prediction, *, title: str = "", reference: Prediction | None = None,
                  measured: list[tuple[float, float]] | None = None) -> bytes:
    """PNG bytes of the figure for one prediction (``reference``: another prism's, drawn dashed;
    ``measured``: (depth mm, median relative error) points of :func:`~prismstereo.design.verify`)."""
    fig = plt.figure(figsize=(13, 9), dpi=90)
    ax_err = fig.add_subplot(2, 2, 1)
    ax_lay = fig.add_subplot(2, 2, 2)
    ax_side = fig.add_subplot(2, 2, 3)
    ax_front = fig.add_subplot(2, 2, 4)
    z = [p.depth_mm for p in pred.depths]
    ax_err.plot(z, [100 * p.relative_error for p in pred.depths], "b-o", ms=3, label="expected error (this prism)")
    if reference is not None:
        ax_err.plot([p.depth_mm for p in reference.depths], [100 * p.relative_error for p in reference.depths], "b--",
                    label="expected error (given prism)")
    if measured:
        ax_err.plot([m[0] for m in measured], [100 * m[1] for m in measured], "kx", ms=8,
                    label="measured (rendered captures)")
    ax_err.set_xlabel("depth Z (mm)")
    ax_err.set_ylabel("median |δZ|/Z (%)", color="b")
    ax_f = ax_err.twinx()
    ax_f.plot(z, [p.field_width_mm for p in pred.depths], "g-", label="common field width")
    ax_f.plot(z, [p.field_height_mm for p in pred.depths], "g:", label="common field height")
    ax_f.set_ylabel("common field (mm)", color="g")
    lines = ax_err.get_legend_handles_labels()
    more = ax_f.get_legend_handles_labels()
    ax_err.legend(lines[0] + more[0], lines[1] + more[1], fontsize=7, loc="upper left")
    ax_err.set_title(f"prediction (|δd| = {pred.disparity_precision:.4f} px, baseline "
                     f"{pred.depths[0].baseline_mm:.1f} mm)", fontsize=9)
    _layout(ax_lay, pred)
    _glass(ax_side, ax_front, pred)
    if title:
        fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    return buf.getvalue()
