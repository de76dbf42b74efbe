"""Experiment: the platelet BRDF for σ = 51 nm, τ = 640 nm (λ0 = 0.5 µm, n = 1.5, ten 20 µm profiles).

Builds (or loads from the cache) the wave-based table and writes into
experiments/output/platelet_brdf/ (atomic writes):

* `platelet_brdf.png`: the BRDF at normal incidence normalised to a peak of 1 (direction-cosine
  map and in-plane cut, wave table against the analytic 3-D Kirchhoff BRDF), and in-plane cuts
  at 0°, 20°, 40°, 60° incidence;
* `platelet_brdf.npz`: the table arrays and the plotted cuts;
* `summary.json`: reflectance, coherent and absorbed fractions, outside-the-disk fraction per
  incidence, lobe widths, build time and the table-vs-Kirchhoff deviation.

Run: python experiments/platelet_brdf.py [--source wave|kirchhoff] [--profiles 10]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import matplotlib  # noqa: E402
import numpy as np  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from paintjax import BeckmannBRDF, TabulatedBRDF, atomic_savefig, atomic_savez, atomic_write_json, platelet_table_arrays  # noqa: E402
from paintjax.brdf import coherent_lobe_width  # noqa: E402

OUT = Path(__file__).parent / "output" / "platelet_brdf"
SIGMA, TAU, WAVELENGTH, N = 0.051, 0.64, 0.5, 1.5
CUTS_DEG = np.array([0.0, 20.0, 40.0, 60.0])
THETA_O = np.linspace(-89.0, 89.0, 357)
LOBE = np.abs(THETA_O) <= 80.0


def fwhm_deg(theta, f):
    """Full width at half maximum of a single-peaked cut [deg] (|θ_o| ≤ 80°: Kirchhoff's 1/cosθ_o
    rise at the horizon is not the lobe)."""
    keep = np.abs(theta) <= 80.0
    theta, f = theta[keep], f[keep]
    above = theta[f >= 0.5 * f.max()]
    return float(above.max() - above.min())


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--source", choices=("wave", "kirchhoff"), default="wave")
    ap.add_argument("--profiles", type=int, default=10)
    ap.add_argument("--cache-dir", default=None)
    args = ap.parse_args(argv)

    t0 = time.perf_counter()
    arrays, info = platelet_table_arrays(SIGMA, TAU, source=args.source, wavelength_um=WAVELENGTH, n_medium=N,
                                         num_profiles=args.profiles, length_um=20.0, seed=0, cache_dir=args.cache_dir)
    build_s = time.perf_counter() - t0
    table = TabulatedBRDF.from_arrays(arrays, coherent_width=coherent_lobe_width(WAVELENGTH, N, 16.0), n_medium=N)
    kirch = BeckmannBRDF(SIGMA, TAU, wavelength_um=WAVELENGTH, n_medium=N)

    def in_plane(brdf, inc):
        ti = np.deg2rad(inc)[:, None]
        to = np.deg2rad(THETA_O)[None, :]
        wi = np.stack(np.broadcast_arrays(np.sin(ti), 0 * to, np.cos(ti)), -1)
        wo = np.stack(np.broadcast_arrays(-np.sin(to), 0 * ti, np.cos(to)), -1)
        return np.asarray(jax.jit(lambda a, b: brdf.incoherent(a, b))(jnp.asarray(wi), jnp.asarray(wo)))

    cuts_table = in_plane(table, CUTS_DEG)
    cuts_kirch = in_plane(kirch, CUTS_DEG)
    # normal-incidence map in direction cosines
    g = np.linspace(-0.7, 0.7, 141)
    bx, by = np.meshgrid(g, g, indexing="ij")
    inside = bx**2 + by**2 < 1
    wo = np.stack([bx, by, np.sqrt(np.clip(1 - bx**2 - by**2, 1e-12, 1))], -1)
    fmap = np.asarray(table.incoherent(jnp.asarray([0.0, 0.0, 1.0]), jnp.asarray(wo))) * inside
    kmap = np.asarray(kirch.incoherent(jnp.asarray([0.0, 0.0, 1.0]), jnp.asarray(wo))) * inside
    core = kmap >= 0.5 * kmap.max()
    dev_core = float(np.max(np.abs(fmap[core] / kmap[core] - 1)))

    fig, ax = plt.subplots(1, 3, figsize=(16, 4.6))
    im = ax[0].imshow(np.where(inside, fmap / fmap.max(), np.nan).T, origin="lower", extent=(g[0], g[-1], g[0], g[-1]), cmap="magma", vmin=0, vmax=1)
    fig.colorbar(im, ax=ax[0], label="f / peak")
    ax[0].set(xlabel="β_x", ylabel="β_y", title="normal incidence (incoherent), peak = 1")
    ax[1].plot(THETA_O, cuts_table[0] / cuts_table[0].max(), label=f"wave table ({args.source})")
    ax[1].plot(THETA_O, cuts_kirch[0] / cuts_kirch[0].max(), "--", label="analytic 3-D Kirchhoff")
    ax[1].set(xlabel="θ_o (°)", ylabel="f / peak", title="normal incidence, in-plane cut", xlim=(-45, 45))
    ax[1].legend()
    for i, th in enumerate(CUTS_DEG):
        line = ax[2].semilogy(THETA_O, np.maximum(cuts_table[i], 1e-6), label=f"θ_i = {th:g}°")[0]
        ax[2].semilogy(THETA_O, np.maximum(cuts_kirch[i], 1e-6), ":", color=line.get_color())
    ax[2].set(xlabel="θ_o (°, > 0 specular side)", ylabel="f [1/sr] (incoherent)", title="in-plane cuts (dotted: Kirchhoff)", ylim=(1e-3, None))
    ax[2].legend(fontsize=8)
    fig.suptitle(f"Platelet BRDF, σ = {SIGMA * 1e3:.0f} nm, τ = {TAU * 1e3:.0f} nm, λ0 = {WAVELENGTH} µm, n = {N}")
    OUT.mkdir(parents=True, exist_ok=True)
    atomic_savefig(fig, OUT / "platelet_brdf.png")
    plt.close(fig)
    atomic_savez(OUT / "platelet_brdf.npz", theta_o_deg=THETA_O, cut_incidence_deg=CUTS_DEG, cuts_table=cuts_table, cuts_kirchhoff=cuts_kirch,
                 normal_map=fmap, beta_grid=g, **{f"table_{k}": v for k, v in arrays.items()})
    summary = {
        "sigma_um": SIGMA, "tau_um": TAU, "wavelength_um": WAVELENGTH, "n_medium": N, "source": args.source,
        "num_profiles": args.profiles, "length_um": 20.0, "cache_hit": info["cache_hit"], "build_seconds": build_s,
        "incidence_deg": arrays["incidence_deg"], "reflectance": arrays["reflectance"], "coherent": arrays["coherent_reflectance"],
        "absorbed": arrays["absorbed"], "outside_fraction": arrays["outside_fraction"], "wave_solved": arrays["wave_solved"],
        "fwhm_in_plane_deg": {f"{th:g}": fwhm_deg(THETA_O, cuts_table[i]) for i, th in enumerate(CUTS_DEG)},
        "fwhm_in_plane_kirchhoff_deg": {f"{th:g}": fwhm_deg(THETA_O, cuts_kirch[i]) for i, th in enumerate(CUTS_DEG)},
        "peak_ratio_table_over_kirchhoff (|θ_o| ≤ 80°)": {f"{th:g}": float(cuts_table[i][LOBE].max() / cuts_kirch[i][LOBE].max()) for i, th in enumerate(CUTS_DEG)},
        "normal_incidence_core_max_deviation_vs_kirchhoff": dev_core,
    }
    atomic_write_json(OUT / "summary.json", summary)
    print(f"table ({args.source}) {'from cache' if info['cache_hit'] else 'built'} in {build_s:.1f} s; "
          f"R(0°) = {arrays['reflectance'][0]:.4f}, coherent {arrays['coherent_reflectance'][0]:.4f}; "
          f"core deviation from Kirchhoff at 0°: {dev_core:.3f}; output in {OUT}")
    return summary


if __name__ == "__main__":
    main()
