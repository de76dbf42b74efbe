"""Benchmark: where the far-angle variance comes from, and reverse rays per detector.

The main job's scene (a sample's 752 µm array, seed 0, its wave platelet table at the measured σ, τ,
five point detectors at 45° illumination) is traced `--seeds` times (ray seeds 10, 11, …) at `--rays`
rays for each variant, the variants taking turns (warm; compilation excluded). Reported per variant:
the mean L*, the RMS of the runs' batch-means SE, the SD of L* over the seeds (the SE's check: the
far angles are heavy-tailed), the median time per run, and the time to SE ≤ 0.3 at all five angles
that these predict (time × max (SE / 0.3)², from the SE and from the SD).

* default: reverse rays per forward ray, `TracerOptions.reverse_share`: 0.5 for every detector, the
  forward tracer alone, the default "aspecular" (0, 0, 0, 0.5, 1 at 15–110°) and other per-detector shares;
* `--split`: the default tracer with one ingredient changed at a time (forward tracing alone, primer
  albedo 0, the platelets' coherent reflectance zeroed, the coherent lobe 8× wider, single scattering):
  which light carries the variance.

Usage: python benchmarks/reverse_shares.py [--sample silver1] [--seeds 16] [--rays 131072] [--split] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from paintjax import build_grid, load_sample, ma98_geometry, platelet_brdf, sample_array  # noqa: E402
from paintjax.tracer import TracerOptions, trace  # noqa: E402

SHARES = {"0.5 every detector": 0.5, "forward alone": 0.0, "aspecular (default)": "aspecular", "(0, 0, 0, 0.5, 0.5)": (0, 0, 0, 0.5, 0.5),
          "(0, 0, 0.25, 0.5, 0.5)": (0, 0, 0.25, 0.5, 0.5), "(0, 0, 0, 1, 2)": (0, 0, 0, 1.0, 2.0)}


def split_variants(sample, brdf):
    """The default tracer with one ingredient changed at a time (keyword arguments of `trace`)."""
    from paintjax.brdf import TabulatedBRDF, coherent_lobe_width, platelet_brdf_table

    no_coherent = TabulatedBRDF(brdf.incidence_deg, brdf.widths, brdf.coef, brdf.proposal_coef, brdf.scale, 0.0 * brdf.coherent_reflectance_table,
                                brdf.incoherent_reflectance_table, brdf.absorbed, brdf.outside_fraction, coherent=brdf.coherent,
                                coherent_width=brdf.coherent_width, n_medium=brdf.n_medium)
    wide = platelet_brdf_table(sample.sigma.value, sample.tau.value, n_medium=sample.binder_index,
                               coherent_width=8 * coherent_lobe_width(0.5, sample.binder_index, 16.0))
    default = TracerOptions()
    return {"default": dict(brdf=brdf, options=default), "forward alone": dict(brdf=brdf, options=TracerOptions(reverse_share=0.0)),
            "primer albedo 0": dict(brdf=brdf, options=default, primer_albedo=0.0),
            "coherent reflectance 0": dict(brdf=no_coherent, options=default),
            "coherent lobe 8x wider": dict(brdf=wide, options=default), "single scattering": dict(brdf=brdf, options=default, single_scatter=True)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sample", default="silver1", choices=("silver1", "silver2"))
    ap.add_argument("--seeds", type=int, default=16)
    ap.add_argument("--rays", type=int, default=131072)
    ap.add_argument("--split", action="store_true", help="the variance split instead of the reverse shares")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()

    s = load_sample(args.sample)
    array = sample_array(args.sample, seed=0)
    kw = dict(grid=build_grid(array), n=s.binder_index, clearcoat_thickness=s.clearcoat_thickness)
    brdf = platelet_brdf("wave", sigma=s.sigma.value, tau=s.tau.value, n=s.binder_index)
    geo = ma98_geometry(45.0, detector_aperture_deg=0.0)
    if args.split:
        variants = split_variants(s, brdf)
    else:
        variants = {name: dict(brdf=brdf, options=TracerOptions(reverse_share=v)) for name, v in SHARES.items()}
    for v in variants.values():  # compile + warm-up
        trace(array, geo, rays=8 * v["options"].lanes, seed=99, **kw, **v)
    runs = {name: [] for name in variants}
    for seed in range(10, 10 + args.seeds):
        for name, v in variants.items():  # taking turns
            r = trace(array, geo, rays=args.rays, seed=seed, **kw, **v)
            runs[name].append((np.asarray(r.L_star), np.asarray(r.L_star_se), r.seconds))
        print(f"seed {seed} done", file=sys.stderr, flush=True)
    out = {"machine": f"{platform.machine()} {os.cpu_count()} cores, {jax.devices()[0].platform}, load {os.getloadavg()[0]:.1f}",
           "sample": args.sample, "rays": args.rays, "seeds": args.seeds, "variants": {}}
    for name, rs in runs.items():
        L, se, t = np.array([r[0] for r in rs]), np.array([r[1] for r in rs]), float(np.median([r[2] for r in rs]))
        se_rms, sd = np.sqrt(np.mean(se**2, axis=0)), L.std(axis=0, ddof=1)
        row = {"L_star": L.mean(0).tolist(), "se_rms": se_rms.tolist(), "sd_over_seeds": sd.tolist(), "seconds_median": t,
               "ttse_from_se": t * float(np.max((se_rms / 0.3) ** 2)), "ttse_from_sd": t * float(np.max((sd / 0.3) ** 2))}
        out["variants"][name] = row
        print(f"{name:24s} L* {np.round(row['L_star'], 1)}  SE {np.round(se_rms, 2)}  SD {np.round(sd, 2)}  {t:.2f} s/run  "
              f"-> SE <= 0.3 in {row['ttse_from_se']:.1f} s (from SE), {row['ttse_from_sd']:.1f} s (from SD)")
    if args.json:
        print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
