"""Experiment: how far do the measured inputs' own uncertainties move the hybrid model's L*?

`paintjax table1` runs the hybrid model at the measured microstructure. Every input it takes from
the measurement has a standard uncertainty (brief §2): tilt gamma shape and scale, roughness σ and
τ, PVC. This experiment propagates them through the model, nothing fitted:

* for each input k, two tracer runs at value ± h_k·u_k (everything else at the measured values,
  the same seed and ray count as the central run), a central difference
  c_k = [L*(+h_k u_k) − L*(−h_k u_k)] / (2 h_k), the L* change per standard uncertainty;
* the input uncertainty of the prediction u_in = √(Σ c_k²) per angle (inputs independent: the
  sources give no correlations; σ and τ come from the same profiles, so this is a choice);
* the measured − model difference in units of the combined uncertainty
  z = ΔL* / √(u_in² + SE² + 0.3²) (tracer SE, instrument repeatability).

Steps: h = 1 for σ, τ and PVC; h = 4 for shape and scale, whose uncertainties (±0.05, ±0.03°)
are so small that a new array's noise would swamp a ±1 difference (the tilt changes regenerate
the array). The noise of each c_k from the tracer SEs is reported beside it.

Writes experiments/output/input_uncertainty/{summary.json, input_uncertainty.png} (atomic).

Run: python experiments/input_uncertainty.py [--samples silver1 silver2] [--rays 262144] [--seed 0]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from paintjax import (  # noqa: E402
    atomic_savefig,
    atomic_write_json,
    enable_compilation_cache,  # noqa: E402
    load_sample,  # noqa: E402
    simulate,  # noqa: E402
)

OUT = Path(__file__).parent / "output" / "input_uncertainty"
INSTRUMENT_SD = 0.3
#: input → (Sample attribute, `simulate` keyword, step in standard uncertainties)
INPUTS = {
    "shape": ("tilt_shape", "shape", 4.0),
    "scale": ("tilt_scale", "scale", 4.0),
    "sigma": ("sigma", "sigma", 1.0),
    "tau": ("tau", "tau", 1.0),
    "pvc": ("pvc", "pvc", 1.0),
}


def propagate(sample: str, rays: int, seed: int) -> dict:
    """Central run and ± runs per input for one sample; the propagated input uncertainty."""
    s = load_sample(sample)
    measured = np.asarray(s.L_star)

    def run(label, **kw):
        t0 = time.perf_counter()
        r = simulate(sample, rays=rays, seed=seed, **kw)
        L, se = np.asarray(r["L_star"]), np.asarray(r["L_star_se"])
        print(f"  {sample} {label:>16}: L* " + " ".join(f"{x:6.1f}" for x in L) + "  SE " + " ".join(f"{x:4.2f}" for x in se)
              + f"  ({time.perf_counter() - t0:.0f} s)", flush=True)
        return L, se

    L0, se0 = run("measured")
    contributions, noise, runs = {}, {}, {}
    for name, (attr, keyword, h) in INPUTS.items():
        m = getattr(s, attr)
        lo, hi = m.value - h * m.uncertainty, m.value + h * m.uncertainty
        Lm, sem = run(f"{name}={lo:.4g}", **{keyword: lo})
        Lp, sep = run(f"{name}={hi:.4g}", **{keyword: hi})
        contributions[name] = (Lp - Lm) / (2 * h)
        noise[name] = np.hypot(sep, sem) / (2 * h)
        runs[name] = {"values": [lo, hi], "step_sd": h, "L_star": [Lm, Lp], "L_star_se": [sem, sep]}
    u_in = np.sqrt(sum(c**2 for c in contributions.values()))
    delta = L0 - measured
    z = -delta / np.sqrt(u_in**2 + se0**2 + INSTRUMENT_SD**2)
    return {
        "measured": measured, "L_star": L0, "L_star_se": se0, "delta": delta, "rms": float(np.sqrt(np.mean(delta**2))),
        "per_sd": contributions, "per_sd_noise": noise, "input_sd": u_in, "z": z, "runs": runs,
        "inputs": {name: [getattr(s, a).value, getattr(s, a).uncertainty] for name, (a, _, _) in INPUTS.items()},
    }


def plot(result: dict, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    gamma = np.asarray(result["aspecular_deg"], float)
    samples = result["samples"]
    fig, axes = plt.subplots(2, len(samples), figsize=(6 * len(samples), 8), squeeze=False)
    for j, (name, r) in enumerate(samples.items()):
        ax = axes[0, j]
        L, u = np.asarray(r["L_star"]), np.asarray(r["input_sd"])
        ax.fill_between(gamma, L - 2 * u, L + 2 * u, color="C0", alpha=0.15, label="hybrid ± 2 u_in (inputs)")
        ax.fill_between(gamma, L - u, L + u, color="C0", alpha=0.3, label="hybrid ± 1 u_in")
        ax.errorbar(gamma, L, yerr=r["L_star_se"], fmt="-s", color="C0", ms=3, label="hybrid (tracer SE)")
        ax.errorbar(gamma, r["measured"], yerr=INSTRUMENT_SD, fmt="ko", label="measured", zorder=5)
        for g, y, zz in zip(gamma, r["measured"], r["z"]):
            ax.annotate(f"z={zz:+.1f}", (g, y), textcoords="offset points", xytext=(4, -12), fontsize=7)
        ax.set_title(f"{name}: hybrid model with its inputs' uncertainty ({result['rays']} rays, seed {result['seed']})", fontsize=9)
        ax.set_xlabel("aspecular angle [deg]")
        ax.set_ylabel("L*")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
        ax = axes[1, j]
        width = 0.8 / len(r["per_sd"])
        x = np.arange(len(gamma))
        for k, (inp, c) in enumerate(r["per_sd"].items()):
            ax.bar(x + (k - (len(r["per_sd"]) - 1) / 2) * width, np.abs(c), width, yerr=r["per_sd_noise"][inp], label=inp, capsize=2)
        ax.set_xticks(x, [f"{g:.0f}°" for g in gamma])
        ax.set_ylabel("|ΔL*| per standard uncertainty")
        ax.set_title("contribution of each input", fontsize=9)
        ax.grid(alpha=0.3, axis="y")
        ax.legend(fontsize=7)
    fig.tight_layout()
    path = atomic_savefig(fig, path)
    plt.close(fig)
    return path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", nargs="+", default=["silver1", "silver2"], choices=("silver1", "silver2"))
    ap.add_argument("--rays", type=int, default=262144, help="rays per run (default 262144)")
    ap.add_argument("--seed", type=int, default=0, help="seed of every run's array and rays (default 0)")
    args = ap.parse_args(argv)
    if args.rays < 1:
        ap.error(f"--rays must be a positive integer, got {args.rays}")
    enable_compilation_cache()
    t0 = time.perf_counter()
    result = {"rays": args.rays, "seed": args.seed, "aspecular_deg": list(load_sample(args.samples[0]).aspecular_deg),
              "instrument_sd": INSTRUMENT_SD, "samples": {}}
    for sample in args.samples:
        r = propagate(sample, args.rays, args.seed)
        result["samples"][sample] = r
        print(f"{sample}: ΔL* " + " ".join(f"{x:+6.1f}" for x in r["delta"]) + "  u_in " + " ".join(f"{x:5.2f}" for x in r["input_sd"])
              + "  z " + " ".join(f"{x:+5.1f}" for x in r["z"]) + f"  (RMS ΔL* {r['rms']:.1f})", flush=True)
    result["seconds"] = time.perf_counter() - t0
    OUT.mkdir(parents=True, exist_ok=True)
    atomic_write_json(OUT / "summary.json", result)
    print(f"plot: {plot(result, OUT / 'input_uncertainty.png')}; data: {OUT / 'summary.json'} ({result['seconds']:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
