"""Experiment: rough aluminium (σ = 280 nm, τ = 1770 nm) at 10° incidence, λ = 0.5 µm, in air:
wave-based BRDF against He–Torrance (1991) and the analytic Kirchhoff BRDF.

The published validation case of the wave part (full-wave results agreed with He–Torrance across
the lobe). Writes into experiments/output/he_torrance_comparison/ (atomic writes):

* `he_torrance_comparison.png`: in-plane incoherent BRDF at 10° incidence (wave table, He–Torrance
  directional diffuse, Kirchhoff), and the raw 1-D wave lobe against the 1-D Kirchhoff closed form;
* `he_torrance_comparison.npz`: the plotted curves;
* `summary.json`: the differences (lobe-core rms and max relative difference, peak ratio and
  position, reflectances and coherent fractions of the three models).

The near-specular bump (wave table ≈ 1.7–1.8× He–Torrance within ±3° of specular, table version 6:
1.72×) is not the coherent part (kσ ≈ 3.5, R_coh ≈ 0.1 %: putting it into the lobe raises the bump by
only ≈ 5 %) but a narrow-lobe artefact of the 2-D → 3-D step: the raw 1-D wave lobes carry a
near-specular excess of 10–20 % over 1-D Kirchhoff within |u| ≲ 0.05 at every incidence (the memory
effect repeats it about each specular point, so pooling over incidences does not average it out),
and the inverse Abel transform turns a narrow 1-D excess into a 2-D peak amplified by ~ lobe
width / excess width. It scales with the narrowest basis width admitted: min_width = 2/(kτ) gives
1.72×, 2·2/(kτ) 1.23×, 4·2/(kτ) 1.12× (core rms 0.23 → 0.10 → 0.08); admitting one basis width just
below 2/(kτ) gives 1.99×. Its origin in the wave lobes (speckle of 40 profiles or a finite-beam
effect) is not settled here.

Run: python experiments/he_torrance_comparison.py [--profiles 40] [--length 40]
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

from paintjax import (  # noqa: E402
    BeckmannBRDF,
    HeTorranceBRDF,
    TabulatedBRDF,
    atomic_savefig,
    atomic_savez,
    atomic_write_json,
    kirchhoff_lobes,
    platelet_table_arrays,
)

OUT = Path(__file__).parent / "output" / "he_torrance_comparison"
SIGMA, TAU, WAVELENGTH, N, INCIDENCE = 0.28, 1.77, 0.5, 1.0, 10.0
THETA_O = np.linspace(-89.0, 89.0, 357)


def in_plane(brdf, inc_deg):
    ti, to = np.deg2rad(inc_deg), np.deg2rad(THETA_O)
    wi = jnp.asarray([np.sin(ti), 0.0, np.cos(ti)])
    wo = jnp.asarray(np.stack([-np.sin(to), 0 * to, np.cos(to)], -1))
    return np.asarray(jax.jit(lambda a, b: brdf.incoherent(a, b))(wi, wo))


def differences(f, ref, core):
    rel = f[core] / ref[core] - 1.0
    return {
        "core_rms_relative": float(np.sqrt(np.mean(rel**2))),
        "core_max_relative": float(np.max(np.abs(rel))),
        "peak_ratio": float(f.max() / ref.max()),
        "peak_theta_o_deg": float(THETA_O[np.argmax(f)]),
    }


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--source", choices=("wave", "kirchhoff"), default="wave")
    ap.add_argument("--profiles", type=int, default=40)
    ap.add_argument("--length", type=float, default=40.0, help="profile length [µm] (≥ 20 correlation lengths)")
    ap.add_argument("--cache-dir", default=None)
    args = ap.parse_args(argv)

    t0 = time.perf_counter()
    arrays, info = platelet_table_arrays(SIGMA, TAU, source=args.source, wavelength_um=WAVELENGTH, n_medium=N,
                                         num_profiles=args.profiles, length_um=args.length, seed=0, cache_dir=args.cache_dir)
    build_s = time.perf_counter() - t0
    table = TabulatedBRDF.from_arrays(arrays, coherent="delta")
    ht = HeTorranceBRDF(SIGMA, TAU, wavelength_um=WAVELENGTH, n_medium=N, coherent="delta")
    kirch = BeckmannBRDF(SIGMA, TAU, wavelength_um=WAVELENGTH, n_medium=N, coherent="delta")
    f_wave, f_ht, f_k = in_plane(table, INCIDENCE), in_plane(ht, INCIDENCE), in_plane(kirch, INCIDENCE)
    core = f_ht >= 0.5 * f_ht.max()
    mu = jnp.cos(jnp.deg2rad(INCIDENCE))
    refl = {
        "wave": {"total": float(table.albedo(mu)), "coherent": float(table.coherent_reflectance(mu))},
        "he_torrance": {"total": float(ht.albedo(mu)), "coherent": float(ht.coherent_reflectance(mu))},
        "kirchhoff": {"total": float(kirch.albedo(mu)), "coherent": float(kirch.coherent_reflectance(mu))},
    }
    # the raw in-plane lobe (1-D) of the source against the 1-D Kirchhoff closed form
    j = int(np.argmin(np.abs(arrays["incidence_deg"] - INCIDENCE)))
    ts = arrays["lobe_theta_s_deg"]
    sig1 = arrays["lobe_sigma"][j] - arrays["lobe_sigma_coherent"][j]
    k1 = kirchhoff_lobes(SIGMA, TAU, incidence_deg=[arrays["incidence_deg"][j]], theta_s_deg=ts, wavelength_um=WAVELENGTH, n_medium=N)
    sig1_k = k1.sigma[0] - k1.sigma_coherent[0]
    core1 = sig1_k >= 0.5 * sig1_k.max()

    fig, ax = plt.subplots(1, 2, figsize=(13, 4.6))
    ax[0].plot(THETA_O, f_wave, label=f"wave table ({args.source}, {args.profiles} × {args.length:g} µm)")
    ax[0].plot(THETA_O, f_ht, "--", label="He–Torrance (directional diffuse)")
    ax[0].plot(THETA_O, f_k, ":", label="Kirchhoff (Beckmann series)")
    ax[0].set(xlabel="θ_o (°, > 0 specular side)", ylabel="f [1/sr] (incoherent)", title=f"3-D BRDF in the plane of incidence, θ_i = {INCIDENCE:g}°")
    ax[0].legend(fontsize=8)
    ax[1].plot(ts, sig1, label="wave, profile average (1-D)")
    ax[1].plot(ts, sig1_k, ":", label="1-D Kirchhoff closed form")
    ax[1].set(xlabel="θ_s (°)", ylabel="σ(θ_s) [1/rad] (incoherent)", title=f"in-plane lobe of the 1-D profiles, θ_i = {arrays['incidence_deg'][j]:g}°")
    ax[1].legend(fontsize=8)
    fig.suptitle(f"Rough aluminium in air, σ = {SIGMA * 1e3:.0f} nm, τ = {TAU * 1e3:.0f} nm, λ = {WAVELENGTH} µm")
    OUT.mkdir(parents=True, exist_ok=True)
    atomic_savefig(fig, OUT / "he_torrance_comparison.png")
    plt.close(fig)
    atomic_savez(OUT / "he_torrance_comparison.npz", theta_o_deg=THETA_O, wave=f_wave, he_torrance=f_ht, kirchhoff=f_k,
                 theta_s_deg=ts, wave_1d=sig1, kirchhoff_1d=sig1_k)
    summary = {
        "sigma_um": SIGMA, "tau_um": TAU, "wavelength_um": WAVELENGTH, "n_medium": N, "incidence_deg": INCIDENCE,
        "source": args.source, "num_profiles": args.profiles, "length_um": args.length, "cache_hit": info["cache_hit"],
        "build_seconds": build_s, "lobe_core": "where He–Torrance ≥ half its peak",
        "wave_vs_he_torrance": differences(f_wave, f_ht, core),
        "wave_vs_he_torrance_outside_specular_8deg": differences(f_wave, f_ht, core & (np.abs(THETA_O - INCIDENCE) > 8.0)),
        "wave_vs_kirchhoff": differences(f_wave, f_k, core),
        "he_torrance_vs_kirchhoff": differences(f_ht, f_k, core),
        "wave_1d_vs_kirchhoff_1d": differences(np.interp(THETA_O, ts, sig1), np.interp(THETA_O, ts, sig1_k), np.interp(THETA_O, ts, core1.astype(float)) > 0.5),
        "reflectance": refl,
    }
    atomic_write_json(OUT / "summary.json", summary)
    d = summary["wave_vs_he_torrance"]
    print(f"wave vs He–Torrance at {INCIDENCE:g}°: core rms {d['core_rms_relative']:.3f}, max {d['core_max_relative']:.3f}, "
          f"peak ratio {d['peak_ratio']:.3f}; reflectance wave {refl['wave']['total']:.3f} HT {refl['he_torrance']['total']:.3f} "
          f"Kirchhoff {refl['kirchhoff']['total']:.3f}; output in {OUT}")
    return summary


if __name__ == "__main__":
    main()
