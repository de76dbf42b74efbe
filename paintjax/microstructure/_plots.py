"""Pictures of a platelet array: a micrograph-like cross-section and the realised tilt histogram."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def plot_cross_section(array, path, y: float | None = None, window: float = 150.0, title: str = "") -> Path:
    """Vertical slice y = const through the basecoat, like a micrograph (true aspect ratio).

    Top: a `window`-µm-wide stretch at true scale; bottom: the whole tile, vertically stretched.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection

    from .._io import atomic_savefig
    from ..microstructure._statistics import cross_section

    Lx, Ly = array.tile
    h_b = array.basecoat_thickness
    y = 0.5 * Ly if y is None else y
    polys = cross_section(array, y)
    shifted = [p + np.array([s, 0.0]) for p in polys for s in (-Lx, 0.0, Lx)]
    window = min(window, Lx)
    fig, axes = plt.subplots(2, 1, figsize=(11, 5.2), gridspec_kw=dict(height_ratios=[1.25, 1.0]))
    for ax, width, stretch in ((axes[0], window, 1.0), (axes[1], Lx, None)):
        ax.add_patch(plt.Rectangle((0, -6), width, 6, color="#8a8a8a", lw=0))  # primer
        ax.add_patch(plt.Rectangle((0, 0), width, h_b, color="#d9cbb0", lw=0))  # binder
        ax.add_patch(plt.Rectangle((0, h_b), width, 8, color="#eef3f7", lw=0))  # clearcoat
        ax.add_collection(PolyCollection(shifted, facecolors="#3b3f45", edgecolors="#1c1e21", linewidths=0.3))
        ax.axhline(h_b, color="#9aa7b3", lw=0.6, ls="--")
        ax.set_xlim(0, width)
        ax.set_ylim(-6, h_b + 8)
        if stretch:
            ax.set_aspect("equal")
        ax.set_ylabel("z [µm]")
        ax.text(0.5, -3, "primer", fontsize=7, va="center", color="white")
        ax.text(0.5, h_b + 4, "clearcoat", fontsize=7, va="center", color="#555")
    axes[0].set_title(title or f"vertical cross-section y = {y:.0f} µm (true scale, first {window:.0f} µm)", fontsize=9)
    axes[1].set_title(f"whole tile, {Lx:.0f} µm (vertical scale stretched)", fontsize=9)
    axes[1].set_xlabel("x [µm]")
    fig.tight_layout()
    out = atomic_savefig(fig, path)
    plt.close(fig)
    return out


def plot_tilt_histogram(array, tilt, path, ks: tuple[float, float] | None = None, title: str = "") -> Path:
    """Histogram of the realised tilts against the gamma law's density."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .._io import atomic_savefig
    from ..microstructure._statistics import _tilt_deg_np, tilt_ks

    td = _tilt_deg_np(array)
    ks = tilt_ks(array, tilt) if ks is None else ks
    top = max(float(np.quantile(td, 0.999)) * 1.2, 15.0)
    fig, ax = plt.subplots(figsize=(6, 3.8))
    ax.hist(td, bins=np.linspace(0, top, 41), density=True, color="#9db4cf", edgecolor="white", label=f"array ({td.size} platelets)")
    t = np.linspace(0, top, 400)
    ax.plot(t, np.asarray(tilt.pdf_deg(t)), color="#b5332e", lw=2, label=f"gamma law k={float(tilt.shape):.2f}, θ={float(tilt.scale_deg):.2f}°")
    ax.set_xlabel("tilt [deg]")
    ax.set_ylabel("density [1/deg]")
    ax.set_title(title or f"realised tilts: KS D = {ks[0]:.4f}, p = {ks[1]:.3f}", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    out = atomic_savefig(fig, path)
    plt.close(fig)
    return out
