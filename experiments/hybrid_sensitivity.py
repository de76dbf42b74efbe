"""Experiment: which modelling choices move the hybrid model's five-angle L*, and by how much?

The hybrid model (`paintjax table1`) is too bright at 25° and 45° aspecular. This experiment
traces one reference sample (default Silver #1, measured microstructure, seed 0, a fixed ray
count so every variant sees the same random numbers) under one change at a time, nothing tuned:

* `baseline`: wave-based platelet BRDF (σ, τ measured), flat clearcoat, primer albedo 0.3,
  aluminium side walls (the `table1` model);
* `single scatter`: only the first scattering event of each path (the share of multiple scattering);
* `edges absorb`: platelet side faces absorb instead of scattering like the faces;
* `waviness 4°`: wavy clearcoat, RMS slope 4°;
* `primer 0.1` / `primer 0.6`: darker / lighter grey primer;
* `kirchhoff BRDF`: the analytic isotropic 3-D Kirchhoff (Beckmann) platelet BRDF instead of the
  wave-based table (same σ, τ);
* `single scatter, kirchhoff`: both at once, the tracer's counterpart of the analytic model below.
* `lobe rotated`: the wave table's 3-D lobe made by rotating the in-plane lobe about the specular
  direction (the original study's axisymmetric assumption) instead of the inverse Abel transform.
* `exponential profiles`: the wave table's platelet profiles synthesised with an exponential
  instead of a Gaussian autocorrelation at the same σ and 1/e length τ (profilometry gives σ
  and τ, not the shape). Such profiles are rough down to the solver's grid (12 points per
  wavelength), so their absorption is not converged in the discretisation (reflectance 0.842 at
  12, 0.830 at 24 points per wavelength, normal incidence; Gaussian 0.8855 at both).
* `platelets D50 10 µm` / `platelets D50 24 µm`: the sample's log-normal width law scaled to
  another median (the brief gives 10–30 µm across and no measured size law; the default D50 is
  16 µm), D10, D90 and the tile in proportion, so the platelet count stays the same.
* `platelets 0.5 µm thick`: half the original study's 1 µm (twice as many platelets at the PVC).
  Width and thickness act through the hot spot (the ratio of platelet width to the mean free
  depth t/PVC) and through the side walls; for these rows the analytic hot-spot model of the
  same layer is reported beside the tracer.

Beside the tracer rows, the analytic single-scatter model (`_microfacet`, no tracing) with the same
Kirchhoff platelet BRDF: entry and exit paths attenuated independently (exact for platelets much
narrower than the mean free path), correlated over the sample's platelet widths (`_hot_spot`, the
`table1` analytic model), and the exit path always clear (`exit_occlusion=False`). The tracer's
single-scatter row against these shows how strongly the 16 µm platelets correlate the entry and
exit paths at the measured PVC, where the mean free depth is t/PVC = 5 µm.

Writes experiments/output/hybrid_sensitivity/{summary.json, sensitivity.png} (atomic; Silver #2 under
hybrid_sensitivity_silver2/, or `--out`). Each row
gives L*, its standard error and the difference to the measurement.

Run: python experiments/hybrid_sensitivity.py [--sample silver1] [--rays 262144] [--out DIR]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from paintjax import (  # noqa: E402
    GammaTilt,
    HotSpot,
    array_overrides,  # noqa: E402
    atomic_savefig,
    atomic_write_json,
    enable_compilation_cache,  # noqa: E402
    load_sample,
    ma98_geometry,
    reflectance_factor_to_lightness,
    simulate,  # noqa: E402
)
from paintjax.brdf import BeckmannBRDF  # noqa: E402
from paintjax.instrument import microfacet_reflectance_factor  # noqa: E402
from paintjax.tracer import TracerOptions  # noqa: E402

OUT = Path(__file__).parent / "output" / "hybrid_sensitivity"

VARIANTS = {
    "baseline": {},
    "single scatter": {"single_scatter": True},
    "edges absorb": {"options": TracerOptions(edges="absorb")},
    "waviness 4°": {"waviness": 4.0},
    "primer 0.1": {"primer_albedo": 0.1},
    "primer 0.6": {"primer_albedo": 0.6},
    "kirchhoff BRDF": {"brdf": "kirchhoff"},
    "single scatter, kirchhoff": {"single_scatter": True, "brdf": "kirchhoff"},
    "lobe rotated": {"brdf_method": "rotate"},
    "exponential profiles": {"correlation": "exponential"},
    "platelets D50 10 µm": {"d50": 10.0},
    "platelets D50 24 µm": {"d50": 24.0},
    "platelets 0.5 µm thick": {"platelet_thickness": 0.5},
}


def plot(result: dict, path: Path) -> Path:
    """Left: L* of the baseline, the measurement and the analytic models; right: ΔL* of every row."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    gamma = np.asarray(result["aspecular_deg"])
    rows = {**result["variants"], **result["analytic"]}
    fig, (ax, hm) = plt.subplots(1, 2, figsize=(13, 5.2), gridspec_kw={"width_ratios": [1, 1.15]})
    ax.errorbar(gamma, result["measured"], yerr=0.3, fmt="ko", label="measured", zorder=5)
    base = result["variants"]["baseline"]
    ax.errorbar(gamma, base["L_star"], yerr=base["L_star_se"], fmt="s-", color="C0", label=f"hybrid baseline (RMS {base['rms']:.1f})")
    for (name, row), style in zip(result["analytic"].items(), ("k:", "r:", "c:")):
        ax.plot(gamma, row["L_star"], style, marker="v", ms=4, label=f"{name} (RMS {row['rms']:.1f})")
    ax.set_xlabel("aspecular angle [deg]")
    ax.set_ylabel("L*")
    ax.set_title(f"{result['sample']}: baseline and analytic models")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    delta = np.array([np.asarray(r["delta"], dtype=float) for r in rows.values()])
    lim = float(np.max(np.abs(delta)))
    im = hm.imshow(delta, cmap="RdBu_r", vmin=-lim, vmax=lim, aspect="auto")
    for (i, j), v in np.ndenumerate(delta):
        hm.text(j, i, f"{v:+.1f}", ha="center", va="center", fontsize=7)
    hm.set_xticks(range(gamma.size), [f"{g:.0f}°" for g in gamma])
    hm.set_yticks(range(len(rows)), [f"{name} (RMS {r['rms']:.1f})" for name, r in rows.items()], fontsize=8)
    hm.set_title(f"model − measured L* (tracer rows: {result['rays']} rays, seed 0)")
    fig.colorbar(im, ax=hm, label="ΔL*")
    fig.tight_layout()
    path = atomic_savefig(fig, path)
    plt.close(fig)
    return path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sample", default="silver1", choices=("silver1", "silver2"))
    ap.add_argument("--rays", type=int, default=262144)
    ap.add_argument("--out", type=Path, help="output folder (default experiments/output/hybrid_sensitivity, with a _silver2 "
                    "suffix for Silver #2)")
    args = ap.parse_args(argv)
    out = args.out or OUT.with_name(OUT.name + ("" if args.sample == "silver1" else f"_{args.sample}"))
    enable_compilation_cache()
    s = load_sample(args.sample)
    measured = np.asarray(s.L_star)
    result = {"sample": args.sample, "rays": args.rays, "measured": measured, "aspecular_deg": list(s.aspecular_deg), "variants": {}}
    geometry, tilt = ma98_geometry(45.0), GammaTilt(s.tilt_shape.value, s.tilt_scale.value)
    platelet = BeckmannBRDF(s.sigma.value, s.tau.value, n_medium=s.binder_index)
    for name, kw in VARIANTS.items():
        t0 = time.perf_counter()
        r = simulate(args.sample, rays=args.rays, seed=0, **kw)
        L = np.asarray(r["L_star"])
        row = {"L_star": L, "L_star_se": np.asarray(r["L_star_se"]), "delta": L - measured,
               "rms": float(np.sqrt(np.mean((L - measured) ** 2))), "energy": r["energy"], "seconds": time.perf_counter() - t0}
        if "d50" in kw or "platelet_thickness" in kw:  # the analytic hot-spot model of the same layer
            layer = array_overrides(s, d50=kw.get("d50"), platelet_thickness=kw.get("platelet_thickness"))
            hot_spot = HotSpot.for_layer(layer.get("sizes", (s.size_d10, s.size_d50, s.size_d90)),
                                         thickness=layer.get("thickness", s.platelet_thickness), pvc=s.pvc.value)
            row["analytic_hot_spot_L_star"] = np.asarray(reflectance_factor_to_lightness(microfacet_reflectance_factor(
                geometry, tilt, n=s.binder_index, platelet=platelet, hot_spot=hot_spot)))
        result["variants"][name] = row
        print(f"{name:>32}: L* " + " ".join(f"{x:6.1f}" for x in L) + "  Δ " + " ".join(f"{x:+6.1f}" for x in row["delta"])
              + f"  RMS {row['rms']:.1f}  ({row['seconds']:.0f} s)"
              + ("; analytic hot spot " + " ".join(f"{x:6.1f}" for x in row["analytic_hot_spot_L_star"]) if "analytic_hot_spot_L_star" in row else ""),
              flush=True)
    result["analytic"] = {}
    occlusion = {"analytic, independent occlusion": {}, "analytic, hot spot": {"hot_spot": HotSpot.for_sample(s)},
                 "analytic, exit path clear": {"exit_occlusion": False}}
    for name, kw in occlusion.items():
        L = np.asarray(reflectance_factor_to_lightness(microfacet_reflectance_factor(
            geometry, tilt, n=s.binder_index, platelet=platelet, **kw)))
        result["analytic"][name] = {"L_star": L, "delta": L - measured, "rms": float(np.sqrt(np.mean((L - measured) ** 2)))}
        print(f"{name:>32}: L* " + " ".join(f"{x:6.1f}" for x in L) + "  Δ " + " ".join(f"{x:+6.1f}" for x in L - measured))
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / "summary.json", result)
    print(f"plot: {plot(result, out / 'sensitivity.png')}; data: {out / 'summary.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
