"""Benchmark: the wave table's radial lobes looked up in textures against summed over the basis.

A wave table's lobe and sampling density are sums over its 36 basis widths; evaluated at every
BRDF call (sampling, evaluation toward each detector, the MIS pdfs) they were most of a wavefront
step (`benchmarks/tracer_profile.py`). `TabulatedBRDF` now samples each tabulated row once on a fine
grid and looks it up (`radial_texture=True`, default); `with_radial_texture(False)` is the summing
reference. The same random numbers drive both, so the comparison is the same estimate at two costs,
up to the lookup's ≤ 2 × 10⁻⁴ relative error in the BRDF.

Scene: the main job's (`paintjax simulate --sample silver1`): Silver #1's cached 752 µm array
(seed 0), its wave table, five MA98 detectors under 45° illumination, the tracer's default options
(bidirectional), `--rays` rays; warm (compilation excluded), the two settings taking turns for
`--rounds` rounds (medians). Reports rays/s per setting, the ratio, and the largest L* difference
between the two against the runs' standard errors.

Usage: python benchmarks/radial_texture.py [--rounds 3] [--rays 65536] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from datetime import date

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from paintjax import build_grid, load_sample, ma98_geometry, platelet_brdf, sample_array  # noqa: E402
from paintjax.tracer import trace  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--rays", type=int, default=65536)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    s = load_sample("silver1")
    array = sample_array("silver1", seed=0)
    table = platelet_brdf("wave", sigma=s.sigma.value, tau=s.tau.value, n=s.binder_index)
    kw = dict(grid=build_grid(array), n=s.binder_index, clearcoat_thickness=s.clearcoat_thickness, seed=1)
    geometry = ma98_geometry(45.0)
    settings = {"lookup": table.with_radial_texture(True), "sum over the basis": table.with_radial_texture(False)}
    for label, brdf in settings.items():  # compile + warm-up
        t0 = time.perf_counter()
        trace(array, geometry, brdf, **(kw | {"rays": 8192, "seed": 99}))
        print(f"{label}: compile + warm-up {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
    rates = {label: [] for label in settings}
    results = {}
    for r in range(args.rounds):
        for label, brdf in settings.items():
            res = trace(array, geometry, brdf, rays=args.rays, **kw)
            rates[label].append(res.rays / res.seconds)
            results[label] = res
            print(f"round {r + 1}, {label}: {rates[label][-1]:.0f} rays/s", file=sys.stderr, flush=True)
    med = {label: float(np.median(v)) for label, v in rates.items()}
    a, b = (results[label] for label in settings)
    dL = np.abs(np.asarray(a.L_star) - np.asarray(b.L_star))
    se = np.hypot(np.asarray(a.L_star_se), np.asarray(b.L_star_se))
    out = {
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, {jax.devices()[0].platform}, load {os.getloadavg()[0]:.1f}",
        "date": date.today().isoformat(), "rays": args.rays, "rounds": args.rounds, "rays_per_second": rates,
        "rays_per_second_median": med, "speedup": med["lookup"] / med["sum over the basis"],
        "L_star": {label: np.asarray(res.L_star).tolist() for label, res in results.items()},
        "max_abs_dL": float(dL.max()), "max_dL_over_combined_se": float((dL / se).max()),
    }
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        print(", ".join(f"{k} {v:.0f} rays/s" for k, v in med.items()) + f"; speed-up {out['speedup']:.2f}x; "
              f"largest |ΔL*| {out['max_abs_dL']:.3g} ({out['max_dL_over_combined_se']:.2g} combined SE); {out['machine']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
