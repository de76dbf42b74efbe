"""Experiment: does next-event estimation account for all the light that leaves a lossless paint?

Lossless Lambertian platelets (a Boolean layer: 400 platelets, w = 4 µm, t = 0.2 µm, Silver #1
tilts, 40 × 40 × 20 µm tile) over a white primer under a flat coat of n = 1.5, normal illumination.
The paint is statistically isotropic, so one detector azimuth stands for all, and
(1/π) ∫ R cos θ dω over the exit hemisphere (`hemisphere_quadrature`: 16 detectors), must equal the ledger's exited fraction. `tests/test_tracer.py`
checks this at 15 000 rays (SE 0.6 %); this script runs it at high precision, with side walls that
scatter (the default) and that absorb.

Writes experiments/output/nee_energy_closure/summary.json (atomic).

Run: python experiments/nee_energy_closure.py [--rays 400000] [--seed 11]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from paintjax import (  # noqa: E402
    LambertianBRDF,
    atomic_write_json,  # noqa: E402
    boolean_platelet_array,
    build_grid,
    enable_compilation_cache,  # noqa: E402
    hemisphere_quadrature,
    trace,
)
from paintjax.tracer import TracerOptions  # noqa: E402

OUT = Path(__file__).parent / "output" / "nee_energy_closure"
N = 1.5


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rays", type=int, default=400_000)
    ap.add_argument("--seed", type=int, default=11)
    args = ap.parse_args(argv)
    if args.rays < 1:
        ap.error(f"--rays must be a positive integer, got {args.rays}")
    enable_compilation_cache()
    geometry, weights = hemisphere_quadrature(N)
    array = boolean_platelet_array(1, 400, tile=(40.0, 40.0), basecoat_thickness=20.0, width=4.0, thickness=0.2, tilt=(2.29, 2.18), margin=2.2)
    grid = build_grid(array, 5.0)
    result = {"rays": args.rays, "seed": args.seed, "rows": {}}
    for edges in ("scatter", "absorb"):
        t0 = time.perf_counter()
        opt = TracerOptions(lanes=1024, batches=32, reverse_share=0.0, edges=edges)
        res = trace(array, geometry, LambertianBRDF(1.0), grid=grid, n=N, primer_albedo=1.0, rays=args.rays, seed=args.seed, options=opt)
        exited = res.energy["exited"]
        hemisphere = float(res.reflectance_factor @ weights)
        batches = res.batch_reflectance_factor @ weights
        se = float(batches.std(ddof=1) / np.sqrt(batches.size))
        row = {"hemisphere_nee": hemisphere, "exited": exited, "relative_excess": hemisphere / exited - 1.0,
               "z": (hemisphere - exited) / se, "relative_se": se / exited, "energy": res.energy, "seconds": time.perf_counter() - t0}
        result["rows"][edges] = row
        print(f"side walls {edges:7s}: NEE over the hemisphere / exited − 1 = {row['relative_excess']:+.4f} "
              f"({row['z']:+.1f} SE, SE {row['relative_se']:.4f}), {row['seconds']:.0f} s", flush=True)
    OUT.mkdir(parents=True, exist_ok=True)
    atomic_write_json(OUT / "summary.json", result)
    print(f"data: {OUT / 'summary.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
