"""Pictures of a car-paint fit: the tracer's gonio table against the fitted model, and ΔL* per MA98 geometry."""

from __future__ import annotations

import os

import numpy as np

from ..instrument._geometry import direction
from ..instrument._lightness import lightness_np


def plot_car_paint_fit(fit, path: str | os.PathLike):
    """In-plane L* cuts per incidence (tracer ± SE, fitted model) and ΔL* at the 19 MA98 geometries; written atomically."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .._io import atomic_savefig

    t = fit.table
    L, se = t.lightness()
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(12, 4.6), gridspec_kw={"width_ratios": [1.4, 1]})
    signed = np.where(np.isclose(t.azimuth_deg, 180.0), -t.polar_deg, t.polar_deg)
    in_plane = (np.isclose(t.azimuth_deg, 0.0) | np.isclose(t.azimuth_deg, 180.0)) & ~t.is_ma98
    theta = np.linspace(-85.0, 85.0, 341)
    for c, theta_i in enumerate(np.unique(t.illumination_deg)):
        sel = in_plane & (t.illumination_deg == theta_i)
        ax.errorbar(signed[sel], L[sel], yerr=se[sel], fmt="o", ms=3, color=f"C{c}", label=f"tracer, θi {theta_i:g}°")
        wi = np.asarray(direction(theta_i, 180.0))
        wo = np.asarray(direction(np.abs(theta), np.where(theta < 0, 180.0, 0.0)))
        R = np.asarray(fit.model.reflectance_factor(np.broadcast_to(wi, wo.shape), wo))
        ax.plot(theta, lightness_np(100.0 * R), "-", color=f"C{c}", lw=1)
    ax.set_xlabel("outgoing polar angle in the plane of incidence [deg] (+: specular side)")
    ax.set_ylabel("L*")
    ax.set_title(f"{t.paint.get('sample', '')}: tracer (points) and the fitted car-paint model (lines)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    rows = fit.ma98_report()
    y = np.arange(len(rows))
    bx.barh(y, [r["delta_L"] for r in rows], xerr=[r["L_star_se"] for r in rows], color="C0")
    bx.axvline(0.0, color="k", lw=0.8)
    for s in (-1.0, 1.0):
        bx.axvline(s, color="0.5", ls="--", lw=0.8)
    bx.set_yticks(y, [r["name"] for r in rows], fontsize=7)
    bx.invert_yaxis()
    bx.set_xlabel("ΔL* (model − tracer), bars: tracer SE")
    bx.set_title(f"MA98 geometries: RMS {fit.rms_ma98:.2f}, max {fit.max_ma98:.2f}")
    bx.grid(alpha=0.3, axis="x")
    fig.tight_layout()
    out = atomic_savefig(fig, path)
    plt.close(fig)
    return out
