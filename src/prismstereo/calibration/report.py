"""Figures and files of a prism calibration: the residual plot and the JSON report."""

from __future__ import annotations

import io

import numpy as np

from prismstereo.calibration.prism import PrismCalibration


def residual_figure(result: PrismCalibration, width: int, height: int, *, scale: float = 200.0) -> bytes:
    """PNG bytes: the corner residuals as arrows over the image (×``scale``), and the RMS of every view."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(13, 4.8), gridspec_kw={"width_ratios": [1.4, 1]})
    o, r = result.observed, result.residuals
    norm = np.linalg.norm(r, axis=1)
    q = ax.quiver(o[:, 0], o[:, 1], r[:, 0] * scale, r[:, 1] * scale, norm, angles="xy", scale_units="xy",
                  scale=1.0, cmap="viridis", width=0.002)
    fig.colorbar(q, ax=ax, label="residual, px")
    ax.set_xlim(0, width)
    ax.set_ylim(height, 0)
    ax.set_aspect("equal")
    ax.set_title(f"corner residuals ×{scale:g} (RMS {result.rms_px:.3f} px)")
    names = list(result.per_view_rms)
    bx.barh(np.arange(len(names)), [result.per_view_rms[n] for n in names], color="tab:blue")
    bx.set_yticks(np.arange(len(names)), names, fontsize=6)
    bx.invert_yaxis()
    bx.set_xlabel("RMS, px")
    bx.set_title("per view (capture:face)")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return buf.getvalue()
