"""The platelet lobe: σ = 51 nm, τ = 640 nm, λ0 = 0.5 µm in n = 1.5, ten 20 µm profiles, normal incidence.

Aluminium (Leontovich impedance), TE, TM and unpolarised, each normalised to a peak of 1, with the
Kirchhoff prediction (Gaussian surface, Fresnel factor of Al at the facet angle) overlaid.
Regenerate: `python experiments/platelet_lobe.py` → experiments/output/platelet_lobe/.
"""

from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from paintjax import atomic_savefig, atomic_savez, atomic_write_json  # noqa: E402
from paintjax.wave import (  # noqa: E402  # noqa: E402
    default_spacing,
    kirchhoff_coherent_fraction,
    kirchhoff_sigma,
    profile_statistics,
    solve_profiles,
    synthesize_profiles,
)

OUT = Path(__file__).parent / "output" / "platelet_lobe"
SIGMA, TAU, LAM, N_MED, LENGTH, COUNT, SEED = 0.051, 0.64, 0.5, 1.5, 20.0, 10, 0


def smooth(s, width=24):
    """Running mean over `width` samples (6° here, two speckle widths λ/(√2 g)): a lobe estimate that averages the 10-profile speckle."""
    return np.convolve(s, np.ones(width) / width, mode="same")


def fwhm(theta, s):
    above = theta[s >= 0.5 * s.max()]
    return float(above.max() - above.min())


def main():
    theta = np.arange(-90.0, 90.001, 0.25)
    prof = synthesize_profiles(jax.random.PRNGKey(SEED), SIGMA, TAU, length_um=LENGTH, spacing_um=default_spacing(LAM, N_MED), num_profiles=COUNT)
    stats = profile_statistics(np.asarray(prof.h), prof.spacing)
    res, data, summary = {}, {"theta_s_deg": theta}, {}
    for pol in ("te", "tm"):
        res[pol] = solve_profiles(prof, [0.0], theta, wavelength_um=LAM, n_medium=N_MED, boundary="impedance", polarization=pol)
    rad = np.radians(theta)
    for pol in ("te", "tm", "unpolarized"):
        if pol == "unpolarized":
            sig = 0.5 * (np.asarray(res["te"].sigma[0]) + np.asarray(res["tm"].sigma[0]))
            coh = 0.5 * (np.asarray(res["te"].sigma_coherent[0]) + np.asarray(res["tm"].sigma_coherent[0]))
            refl = 0.5 * float(res["te"].reflected[0] + res["tm"].reflected[0])
            absb = 0.5 * float(res["te"].absorbed[0] + res["tm"].absorbed[0])
        else:
            sig, coh = np.asarray(res[pol].sigma[0]), np.asarray(res[pol].sigma_coherent[0])
            refl, absb = float(res[pol].reflected[0]), float(res[pol].absorbed[0])
        inc = (sig - coh) * COUNT / (COUNT - 1)  # unbiased incoherent part
        coh_unbiased = (COUNT * coh - sig) / (COUNT - 1)
        ka = np.asarray(kirchhoff_sigma([0.0], theta, SIGMA, TAU, boundary="impedance", polarization=pol))[0]
        data[f"sigma_{pol}"], data[f"sigma_coherent_{pol}"], data[f"kirchhoff_{pol}"] = sig, coh, ka
        data[f"sigma_incoherent_{pol}"], data[f"sigma_incoherent_smoothed_{pol}"] = inc, smooth(inc)
        core = np.abs(theta) <= 15
        summary[pol] = {
            "reflected": refl, "absorbed": absb, "energy_sum": refl + absb,
            "coherent_fraction": float(np.trapezoid(coh_unbiased, rad)),
            "kirchhoff_coherent_fraction": float(kirchhoff_coherent_fraction([0.0], SIGMA, boundary="impedance", polarization=pol)[0]),
            "incoherent_fwhm_deg": fwhm(theta, smooth(inc)),
            "kirchhoff_fwhm_deg": fwhm(theta, ka),
            "core_incoherent_over_kirchhoff": float(np.trapezoid(inc[core], rad[core]) / np.trapezoid(ka[core], rad[core])),
        }
    summary["profiles"] = {"count": COUNT, "length_um": LENGTH, "points": int(prof.x.shape[0]), "spacing_um": prof.spacing,
                           "realised_sigma_um": float(stats["sigma_um"].mean()), "realised_tau_um": float(stats["tau_um"].mean())}
    atomic_savez(OUT / "platelet_lobe.npz", **data)
    atomic_write_json(OUT / "platelet_lobe.json", summary)

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8), sharey=True)
    for ax, pol in zip(axes, ("te", "tm", "unpolarized")):
        s, sm, ka = data[f"sigma_incoherent_{pol}"], data[f"sigma_incoherent_smoothed_{pol}"], data[f"kirchhoff_{pol}"]
        ax.plot(theta, s / sm.max(), color="C0", lw=0.5, alpha=0.5, label="full wave, 10 profiles (speckle)")
        ax.plot(theta, sm / sm.max(), color="C0", lw=1.8, label="full wave, 6° running mean")
        ax.plot(theta, ka / ka.max(), "k--", lw=1.2, label="Kirchhoff")
        ax.set_title(f"{pol}: R = {summary[pol]['reflected']:.3f}, A = {summary[pol]['absorbed']:.3f}", fontsize=9)
        ax.set_xlim(-45, 45)
        ax.set_xlabel("θ_s [deg]")
    axes[0].set_ylabel("incoherent σ / peak")
    axes[0].legend(fontsize=8)
    fig.suptitle("Al platelet lobe, σ = 51 nm, τ = 640 nm, λ0 = 500 nm in n = 1.5, normal incidence", fontsize=10)
    atomic_savefig(fig, OUT / "platelet_lobe.png")
    print(summary)


if __name__ == "__main__":
    main()
