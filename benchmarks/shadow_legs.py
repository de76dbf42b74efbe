"""Benchmark: shadow rays walked in short legs (`TracerOptions.shadow_leg_cells`) against one leg to the top.

The wavefront tracer defers each step's shadow rays and traces them together, compacted into a
buffer. Walked in one leg, every shadow ray pays for all the cells it could cross up to the top of
the basecoat at the flat coat's critical angle (`_shadow_cell_bound`, 10–13 cells in these scenes),
though most end sooner, blocked or out. In legs, a ray not yet decided resumes in the next pass. The
two give the same visibility (tests/test_tracer.py checks both against a brute-force slab test), so
the comparison is the same estimate at two costs.

Scenes, both warm (compilation excluded), the settings taking turns for `--rounds` rounds (medians):
* Silver #1 (the main job's scene): the CLI's 752 µm array, seed 0, wave platelet table, five MA98
  detectors, forward tracer (as the tracer emulator runs it), `--rays` rays;
* a 16-detector hemisphere (the tracer's energy tests): 400 Lambertian platelets (albedo 1) in a
  40 × 40 × 20 µm tile, primer albedo 1, normal illumination, forward tracer, `--hemisphere-rays` rays.

Reports rays/s per setting, the ratio, and whether the tallies are identical.

Usage: python benchmarks/shadow_legs.py [--rounds 3] [--rays 65536] [--hemisphere-rays 15000] [--legs 4] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from paintjax import (  # noqa: E402
    GammaTilt,
    LambertianBRDF,
    boolean_platelet_array,
    build_grid,
    hemisphere_quadrature,
    load_sample,
    ma98_geometry,
    platelet_brdf,
    sample_array,
)
from paintjax.tracer import TracerOptions, trace  # noqa: E402

#: A leg longer than any scene's bound: the single-leg walk.
ONE_LEG = 1000


def scenes(rays: int, hemisphere_rays: int):
    s = load_sample("silver1")
    array = sample_array("silver1", seed=0)
    silver = dict(array=array, geometry=ma98_geometry(45.0), brdf=platelet_brdf("wave", sigma=s.sigma.value, tau=s.tau.value, n=s.binder_index),
                  grid=build_grid(array), n=s.binder_index, clearcoat_thickness=s.clearcoat_thickness, rays=rays, seed=1)
    lamb = boolean_platelet_array(1, 400, tile=(40.0, 40.0), basecoat_thickness=20.0, width=4.0, thickness=0.2,
                                  tilt=GammaTilt(2.29, 2.18), margin=2.2)
    geo, _ = hemisphere_quadrature(1.5)
    hemisphere = dict(array=lamb, geometry=geo, brdf=LambertianBRDF(1.0), grid=build_grid(lamb, 5.0, capacity=24), n=1.5,
                      primer_albedo=1.0, rays=hemisphere_rays, seed=5)
    return {"silver1 (5 detectors, wave BRDF)": silver, "hemisphere (16 detectors, Lambertian)": hemisphere}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--rays", type=int, default=65536, help="rays of the Silver #1 runs")
    ap.add_argument("--hemisphere-rays", type=int, default=15000, help="rays of the hemisphere runs")
    ap.add_argument("--legs", type=int, default=TracerOptions().shadow_leg_cells, help="shadow_leg_cells of the short-leg setting")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    settings = {f"legs of {args.legs}": args.legs, "one leg": ONE_LEG}
    out = {"machine": f"{jax.devices()[0].platform}, {jax.device_count()} device(s)", "rounds": args.rounds, "scenes": {}}
    for name, kw in scenes(args.rays, args.hemisphere_rays).items():
        kw = dict(kw)
        array, geometry, brdf = kw.pop("array"), kw.pop("geometry"), kw.pop("brdf")
        options = {label: TracerOptions(reverse_share=0.0, shadow_leg_cells=leg) for label, leg in settings.items()}
        for label, opt in options.items():  # compile + warm-up
            t0 = time.perf_counter()
            trace(array, geometry, brdf, options=opt, **(kw | {"rays": 4 * opt.lanes, "seed": 99}))
            print(f"{name}, {label}: compile + warm-up {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
        rates = {label: [] for label in options}
        tallies = {}
        for r in range(args.rounds):
            for label, opt in options.items():
                res = trace(array, geometry, brdf, options=opt, **kw)
                rates[label].append(res.rays / res.seconds)
                tallies[label] = np.asarray(res.reflectance_factor)
                print(f"{name}, round {r + 1}, {label}: {rates[label][-1]:.0f} rays/s", file=sys.stderr, flush=True)
        short, one = settings
        med = {label: float(np.median(v)) for label, v in rates.items()}
        out["scenes"][name] = {"rays_per_second_median": med, "rays_per_second": rates, "speedup": med[short] / med[one],
                               "identical_tallies": bool(np.array_equal(tallies[short], tallies[one]))}
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        for name, r in out["scenes"].items():
            print(f"{name}: " + ", ".join(f"{k} {v:.0f} rays/s" for k, v in r["rays_per_second_median"].items())
                  + f"; speed-up {r['speedup']:.2f}x; identical tallies: {r['identical_tallies']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
