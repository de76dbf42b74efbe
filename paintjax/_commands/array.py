"""`paintjax array`: build a platelet array of a sample, print its statistics, draw it."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ._common import add_array_arguments, add_json_argument, add_output_argument, array_overrides, print_json

JSON_KEYS = ("count", "pvc", "overlaps_exact", "overlaps_midplane", "tilt_ks", "seconds")


def register(sub) -> None:
    p = sub.add_parser(
        "array",
        help="generate a platelet array (statistics, overlap removal), print statistics, draw pictures",
        description=(
            "Platelet array of a reference sample: widths, gamma tilts, uniform positions in a periodic "
            "basecoat tile, overlaps removed. Writes a vertical cross-section and the tilt histogram."
        ),
    )
    p.add_argument("--sample", default="silver1", help="reference sample: silver1 or silver2 (default silver1)")
    p.add_argument("--seed", type=int, default=0, help="random seed, integer ≥ 0 (default 0)")
    p.add_argument("--tile", type=float, help="tile side [µm] (default 10 × the largest platelet width)")
    add_array_arguments(p)
    p.add_argument("--overlap-test", default="sat", choices=("sat", "midplane", "none"), help="overlap test used for removal (default sat)")
    p.add_argument("--max-attempts", type=int, default=1000, help="re-placements per platelet (default 1000)")
    p.add_argument("--no-plots", action="store_true", help="do not write the pictures")
    add_output_argument(p, "results/array")
    add_json_argument(p)
    p.set_defaults(func=run)


def compute(sample="silver1", seed=0, tile=None, pvc=None, overlap_test="sat", max_attempts=1000, d50=None,
            platelet_thickness=None) -> tuple:
    """Build the array; returns (array, tilt law, statistics dict incl. the JSON keys, log).

    `pvc`, `d50` and `platelet_thickness` override the sample's (`_common.array_overrides`).
    """
    from .. import GammaTilt, load_sample
    from .._microstructure import array_statistics, platelet_array_for_sample

    s = load_sample(sample)
    overrides = dict(overlap_test=overlap_test, max_attempts=max_attempts,
                     **array_overrides(s, pvc=pvc, d50=d50, platelet_thickness=platelet_thickness))
    if tile is not None:
        overrides["tile"] = tile
    array, log = platelet_array_for_sample(s.name, seed, return_log=True, **overrides)
    tilt = GammaTilt(s.tilt_shape.value, s.tilt_scale.value)
    stats = array_statistics(array, tilt)
    stats.update(sample=s.name, seed=seed, seconds=log.seconds, pvc_target=log.pvc_target, log=log)
    return array, tilt, stats


def plot_cross_section(array, path, y: float | None = None, window: float = 150.0, title: str = "") -> Path:
    """Vertical slice y = const through the basecoat, like a micrograph (true aspect ratio).

    Top: a `window`-µm-wide stretch at true scale; bottom: the whole tile, vertically stretched.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection

    from .._io import atomic_savefig
    from .._microstructure import cross_section

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
    from .._microstructure import _tilt_deg_np, tilt_ks

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


def run(args) -> int:
    array, tilt, stats = compute(args.sample, args.seed, args.tile, args.pvc, args.overlap_test, args.max_attempts,
                                 d50=args.d50, platelet_thickness=args.platelet_thickness)
    paths = []
    if not args.no_plots:
        out = Path(args.out)
        stem = f"{stats['sample']}_seed{args.seed}"
        paths.append(plot_cross_section(array, out / f"{stem}_cross_section.png"))
        paths.append(plot_tilt_histogram(array, tilt, out / f"{stem}_tilt_histogram.png", (stats["tilt_ks"], stats["tilt_ks_pvalue"])))
    if args.json:
        print_json({k: stats[k] for k in JSON_KEYS})
        return 0
    log = stats["log"]
    print(f"Platelet array of {stats['sample']} (seed {args.seed}), tile {stats['tile'][0]:.0f} × {stats['tile'][1]:.0f} µm, basecoat {stats['basecoat_thickness']:.0f} µm")
    print(f"  platelets              {stats['count']} ({array.thickness:g} µm thick)")
    print(f"  PVC                    {100 * stats['pvc']:.3f} % (target {100 * stats['pvc_target']:.1f} %)")
    print(f"  widths D10/D50/D90     {stats['width_d10']:.1f} / {stats['width_d50']:.1f} / {stats['width_d90']:.1f} µm")
    print(f"  mean tilt              {stats['tilt_mean_deg']:.2f}°  (KS D = {stats['tilt_ks']:.4f}, p = {stats['tilt_ks_pvalue']:.3f})")
    print(f"  residual overlaps      exact (SAT) {stats['overlaps_exact']}, mid-plane (Möller) {stats['overlaps_midplane']}")
    print(f"  re-placed platelets    {log.n_replaced} ({log.total_replacements} re-placements, most {log.max_replacements}; {log.n_failed} failed)")
    print(f"  generation time        {stats['seconds']:.2f} s")
    for p in paths:
        print(f"  wrote {p}")
    return 0
