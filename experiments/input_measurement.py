"""Experiment: measurement models for the inputs. What do the published σ, τ and tilt laws say about the true ones?

* *Roughness.* The published procedure (10 platelets, one white-light-interferometer line scan over
  each whole platelet of 10–30 µm, Gaussian filter with a cutoff of 50 % of the scan length,
  end-point levelling; σ the RMS over the platelets, τ the 1/e autocorrelation length) runs on
  synthesised Gaussian surfaces of known true (σ, τ) (`paintjax.inverse.Profilometer`, PSF FWHM
  0.55 µm, pixel 0.1 µm). σ only scales the reading, so its law is simulated at 16 true τ in
  0.2–2.5 µm (`build_reading_model`); for each of three readings of the σ definition the published
  reading (51 nm, 640 nm) becomes a likelihood over the true (σ, τ): where do the true surfaces lie
  that read as published?
* *Instrument and procedure.* At the published point: what an ideal instrument, the PSF and the filter
  each do to the reading; the predicted spread across the 10 platelets against the published ±.
* *Tilt law.* The sampling SD of a gamma fit to n measured tilts (closed form and simulation), the
  count n the published ± would need, and what a fit to apparent (cross-section) tilts reads.

Writes experiments/output/input_measurement/{summary.json, input_measurement.png}.
Run from the repository root: python experiments/input_measurement.py  (about 5 min on 2 cores)
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from paintjax import atomic_savefig, atomic_write_json, load_sample  # noqa: E402
from paintjax.inverse import (  # noqa: E402
    SIGMA_DEFINITIONS,
    Profilometer,
    build_reading_model,
    gamma_fit_sd,
    platelets_for_sd,
    smoothed_gaussian_statistics,
    tilt_fit_distribution,
)

OUT = Path("experiments/output/input_measurement")
PUBLISHED = {"sigma_um": 0.051, "sigma_pm_um": 0.010, "tau_um": 0.64, "tau_pm_um": 0.11}
#: True (σ, τ) the L* data prefer (input-consistency optima and the corner point; docs/input_consistency.md).
L_STAR_PREFERRED = {"Silver #1 ±2 u": (0.0423, 0.536), "Silver #1 corner": (0.0248, 0.359), "Silver #2 ±2 u": (0.0408, 0.420),
                    "Silver #2 ±3 u": (0.0325, 0.340)}


def roughness_likelihood(campaigns: int, seed: int) -> dict:
    """The published reading's likelihood over the true (σ, τ), for every σ reading (`build_reading_model`:
    σ only scales the heights, so the reading's law is simulated over τ alone and is exact in σ)."""
    model = build_reading_model(campaigns=campaigns, seed=seed, progress=True)
    taus = np.exp(np.asarray(model.log_tau_nodes))
    sig = np.geomspace(0.01, 0.2, 161)
    tau = np.geomspace(taus[0], taus[-1], 161)
    S, T = np.meshgrid(sig, tau, indexing="ij")
    out = {"sigma_true_um": sig, "tau_true_um": tau, "tau_nodes_um": taus,
           "tau_hat_median_um": np.exp(np.asarray(model.log_tau_hat_mean)), "tau_hat_log_sd": np.asarray(model.log_tau_hat_sd),
           "by_definition": {}}
    for name in SIGMA_DEFINITIONS:
        ll = np.asarray(model.log_likelihood(S, T, PUBLISHED["sigma_um"], PUBLISHED["tau_um"], name))
        i, j = np.unravel_index(np.argmax(ll), ll.shape)
        at = lambda s, t: float(ll.max() - model.log_likelihood(s, t, PUBLISHED["sigma_um"], PUBLISHED["tau_um"], name))  # noqa: E731
        inside = ll >= ll.max() - 1.15  # 68 % region of a 2-D normal (Δ log L = χ²₂(0.68)/2)
        out["by_definition"][name] = {
            "log_likelihood": ll, "ratio_median": np.exp(np.asarray(model.log_ratio_mean[name])), "ratio_log_sd": np.asarray(model.log_ratio_sd[name]),
            "max_likelihood_true": {"sigma_um": float(sig[i]), "tau_um": float(tau[j])},
            "region_68": {"sigma_um": [float(S[inside].min()), float(S[inside].max())], "tau_um": [float(T[inside].min()), float(T[inside].max())]},
            "delta_log_likelihood": {"published reading taken as true": at(PUBLISHED["sigma_um"], PUBLISHED["tau_um"]),
                                     **{k: at(*v) for k, v in L_STAR_PREFERRED.items()}},
        }
    return out


def procedure_steps(campaigns: int, seed: int) -> list[dict]:
    """At the published (σ, τ) taken as true: the reading of each instrument/procedure variant."""
    key = jax.random.PRNGKey(seed + 1)
    rows = []
    for label, prof in (("ideal instrument, no filter (200 µm scans)", Profilometer(resolution_um=0.0, pixel_um=0.02, cutoff_fraction=None,
                                                                                  scan_range_um=(200.0, 200.0))),
                        ("PSF 0.55 µm, no filter (200 µm scans)", Profilometer(cutoff_fraction=None, scan_range_um=(200.0, 200.0))),
                        ("ideal instrument, published procedure", Profilometer(resolution_um=0.0, pixel_um=0.05)),
                        ("PSF 0.55 µm, published procedure (default)", Profilometer()),
                        ("PSF 1.0 µm, published procedure", Profilometer(resolution_um=1.0))):
        d = prof.campaign_distribution(key, PUBLISHED["sigma_um"], PUBLISHED["tau_um"], campaigns)
        rows.append({"variant": label, "resolution_um": prof.resolution_um, "tau_mean_um": d["tau_mean_um"], "tau_sd_um": d["tau_sd_um"],
                     "platelet_tau_sd_um": d["platelet_tau_sd_um"],
                     "closed_form_no_filter": list(smoothed_gaussian_statistics(PUBLISHED["sigma_um"], PUBLISHED["tau_um"], prof.resolution_um)),
                     "sigma": {n: {"mean_um": v["sigma_mean_um"], "sd_um": v["sigma_sd_um"]} for n, v in d["by_definition"].items()},
                     "platelet_sigma_sd_um": d["platelet_sigma_sd_um"]})
        print(f"  {label}: σ̂ {[round(1000 * v['sigma_mean_um'], 1) for v in d['by_definition'].values()]} nm "
              f"(rq, local_pv, scan_pv), τ̂ {d['tau_mean_um']:.3f} µm", flush=True)
    return rows


def tilt_study(seed: int, replicates: int) -> dict:
    out = {}
    for name in ("silver1", "silver2"):
        s = load_sample(name)
        k, th = s.tilt_shape.value, s.tilt_scale.value
        rows = []
        for n in (50, 200, 1000, 5000):
            true = tilt_fit_distribution(seed, k, th, n, replicates=replicates)
            sec = tilt_fit_distribution(seed, k, th, n, section=True, replicates=replicates)
            sd_k, sd_th, rho = gamma_fit_sd(k, th, n)
            rows.append({"n": n, "closed_form_shape_sd": sd_k, "closed_form_scale_sd": sd_th, "closed_form_correlation": rho,
                         "true_tilts": {kk: true[kk] for kk in ("shape_mean", "shape_sd", "scale_mean", "scale_sd", "correlation")},
                         "apparent_tilts": {kk: sec[kk] for kk in ("shape_mean", "shape_sd", "scale_mean", "scale_sd", "correlation")}})
        out[name] = {"published": {"shape": k, "shape_pm": s.tilt_shape.uncertainty, "scale": th, "scale_pm": s.tilt_scale.uncertainty},
                     "platelets_for_published_shape_pm": platelets_for_sd(k, th, s.tilt_shape.uncertainty),
                     "platelets_for_published_scale_pm": platelets_for_sd(k, th, s.tilt_scale.uncertainty, "scale"),
                     "by_count": rows}
        print(f"  {name}: the published ± need {out[name]['platelets_for_published_shape_pm']} (shape) and "
              f"{out[name]['platelets_for_published_scale_pm']} (scale) platelets if sampling alone", flush=True)
    return out


def plot(result: dict, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    g = result["roughness_grid"]
    S, T = np.meshgrid(1000 * np.asarray(g["sigma_true_um"]), np.asarray(g["tau_true_um"]), indexing="ij")
    fig, axes = plt.subplots(1, 5, figsize=(23, 4.4))
    for ax, name in zip(axes[:3], SIGMA_DEFINITIONS):
        ll = np.asarray(g["by_definition"][name]["log_likelihood"])
        rel = ll - ll.max()
        cs = ax.contourf(S, T, np.maximum(rel, -12), levels=np.arange(-12, 0.5, 1.0), cmap="viridis")
        ax.contour(S, T, rel, levels=[-3.0, -1.15], colors="w", linewidths=(0.8, 1.4))  # 95 %, 68 % (2-D normal)
        ax.plot(1000 * PUBLISHED["sigma_um"], PUBLISHED["tau_um"], "r*", ms=12, label="published reading taken as true")
        for (lab, (s, t)), m in zip(L_STAR_PREFERRED.items(), "osd^"):
            ax.plot(1000 * s, t, m, mfc="none", mec="w", ms=8, label=f"L*-preferred: {lab}")
        ax.set_xscale("log"), ax.set_yscale("log")
        ax.set_xlabel("true σ [nm]"), ax.set_ylabel("true τ [µm]")
        ax.set_title(f"log p(reading 51 nm, 640 nm | true σ, τ), σ read as {name}\n(white: 68 % and 95 % regions)", fontsize=9)
        fig.colorbar(cs, ax=ax, fraction=0.046)
    axes[0].legend(fontsize=6, loc="lower right")
    ax = axes[3]
    tn = np.asarray(g["tau_nodes_um"])
    med, sd = np.asarray(g["tau_hat_median_um"]), np.asarray(g["tau_hat_log_sd"])
    ax.fill_between(tn, med * np.exp(-sd), med * np.exp(sd), alpha=0.3, label="τ̂ (campaign of 10), ±1 SD")
    ax.plot(tn, med, "C0-")
    for name, c in zip(SIGMA_DEFINITIONS, ("C1", "C2", "C3")):
        ax.plot(tn, np.asarray(g["by_definition"][name]["ratio_median"]), "--", color=c, label=f"σ̂/σ, {name}")
    ax.plot(tn, tn, "k:", lw=0.8, label="reads the truth")
    ax.axhline(PUBLISHED["tau_um"], color="r", lw=0.8)
    ax.set_xscale("log"), ax.set_yscale("log")
    ax.set_xlabel("true τ [µm]"), ax.set_ylabel("τ̂ [µm]  /  σ̂ / σ")
    ax.set_title("what the procedure reads (PSF 0.55 µm, filter 50 %)", fontsize=9)
    ax.legend(fontsize=6)
    ax = axes[4]
    for name, m in (("silver1", "o"), ("silver2", "s")):
        rows = result["tilt"][name]["by_count"]
        n = [r["n"] for r in rows]
        ax.loglog(n, [r["closed_form_shape_sd"] for r in rows], "-", color="C0" if name == "silver1" else "C1", label=f"{name}: shape SD, closed form")
        ax.loglog(n, [r["true_tilts"]["shape_sd"] for r in rows], m, color="C0" if name == "silver1" else "C1", label=f"{name}: simulated fits")
        ax.axhline(result["tilt"][name]["published"]["shape_pm"], color="C0" if name == "silver1" else "C1", ls=":", lw=1)
    ax.set_xlabel("platelets measured"), ax.set_ylabel("SD of the fitted gamma shape")
    ax.set_title("tilt law: sampling SD of the gamma fit\n(dotted: published ±)", fontsize=9)
    ax.legend(fontsize=6)
    fig.suptitle("Measurement models for the inputs (python experiments/input_measurement.py)", fontsize=10)
    fig.tight_layout()
    out = atomic_savefig(fig, path, dpi=130)
    plt.close(fig)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--campaigns", type=int, default=64, help="simulated measurement campaigns per true τ node (default 64)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--tilt-replicates", type=int, default=200)
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    print("instrument and procedure at the published point", flush=True)
    steps = procedure_steps(args.campaigns, args.seed)
    print("tilt law", flush=True)
    tilt = tilt_study(args.seed, args.tilt_replicates)
    print("roughness: true → measured over the grid", flush=True)
    grid = roughness_likelihood(args.campaigns, args.seed)
    result = {"published": PUBLISHED, "instrument": {"resolution_um": Profilometer().resolution_um, "pixel_um": Profilometer().pixel_um,
                                                     "platelets": 10, "scan_range_um": [10.0, 30.0], "cutoff_fraction": 0.5},
              "campaigns": args.campaigns, "seed": args.seed, "procedure_steps": steps, "tilt": tilt, "roughness_grid": grid,
              "seconds": time.perf_counter() - t0}
    for name, d in grid["by_definition"].items():
        ml, reg = d["max_likelihood_true"], d["region_68"]
        print(f"σ read as {name}: most likely true σ {1000 * ml['sigma_um']:.0f} nm (68 %: {1000 * reg['sigma_um'][0]:.0f}–"
              f"{1000 * reg['sigma_um'][1]:.0f}), τ {ml['tau_um']:.2f} µm ({reg['tau_um'][0]:.2f}–{reg['tau_um'][1]:.2f}); "
              f"Δ log-likelihood from the most likely: { {k: round(v, 1) for k, v in d['delta_log_likelihood'].items()} }", flush=True)
    OUT.mkdir(parents=True, exist_ok=True)
    atomic_write_json(OUT / "summary.json", result)
    print(f"figure: {plot(result, OUT / 'input_measurement.png')}; {time.perf_counter() - t0:.0f} s", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
