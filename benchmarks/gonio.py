"""Benchmark: a paint's gonio table and car-paint fit (`paintjax gonio`), goal ≤ 5 min per paint on 2 CPU cores.

Times, in one process with an empty cache for the table (`use_cache=False`; the platelet array and the
wave BRDF table come from the cache, as they do for `paintjax gonio` after any earlier command):

* the gonio table at the defaults (6 incidences, 41–51 directions each, 100 000 rays per incidence);
* the 3-lobe fit;
* the floor: the same rays at the same six incidences with only the five standard detectors (what
  `paintjax simulate` traces), i.e. the cost of the paths themselves without the extra shadow rays;
* the straightforward alternative: one tracer run per detector direction instead of one per incidence,
  estimated from one incidence's directions at the same rays each (extrapolated to the table, not run).

Prints one JSON line and writes benchmarks/output/gonio.json (atomic).
Usage: python benchmarks/gonio.py [--sample silver1] [--rays 100000]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from datetime import date
from pathlib import Path

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

from paintjax import atomic_write_json, custom_geometry, fit_car_paint, gonio_table, load_sample, simulate, to_jsonable  # noqa: E402
from paintjax.tracer import TracerOptions  # noqa: E402

GOAL_S = 300.0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sample", default="silver1")
    ap.add_argument("--rays", type=int, default=100_000)
    ap.add_argument("--lanes", type=int, default=TracerOptions().lanes, help="rays in flight per device (TracerOptions.lanes)")
    args = ap.parse_args()
    s = load_sample(args.sample)
    options = TracerOptions(lanes=args.lanes, reverse_share=0.0)
    simulate(s.name, rays=8192, options=options)  # array, BRDF table and the tracer's compilation, outside the timings

    t0 = time.perf_counter()
    table = gonio_table(s.name, rays=args.rays, use_cache=False, options=options)
    t_table = time.perf_counter() - t0
    t0 = time.perf_counter()
    fit = fit_car_paint(table, coat_index=s.binder_index)
    t_fit = time.perf_counter() - t0

    incidences = sorted(set(table.illumination_deg.tolist()))
    t0 = time.perf_counter()
    for j, theta_i in enumerate(incidences):
        five = custom_geometry(max(theta_i, 1.0), [30.0, 20.0, 0.0, 30.0, 65.0], [0.0, 0.0, 0.0, 180.0, 180.0])
        simulate(s.name, geometry=five, rays=args.rays, seed=7919 * j, options=options)
    t_floor = time.perf_counter() - t0

    per_direction = []
    for p, a in ((30.0, 0.0), (45.0, 90.0), (60.0, 180.0)):  # three of one incidence's directions, one run each
        t0 = time.perf_counter()
        simulate(s.name, geometry=custom_geometry(45.0, [p], [a]), rays=args.rays, options=options)
        per_direction.append(time.perf_counter() - t0)
    t_alternative = sum(per_direction) / len(per_direction) * table.reflectance_factor.size

    L, se = table.lightness()
    out = {
        "machine": f"{platform.machine()}, {os.cpu_count()} cores", "date": date.today().isoformat(), "sample": s.name,
        "rays_per_incidence": args.rays, "entries": int(table.reflectance_factor.size), "incidences": incidences,
        "table_s": t_table, "fit_s": t_fit, "total_s": t_table + t_fit, "goal_s": GOAL_S, "meets_goal": t_table + t_fit <= GOAL_S,
        "L_star_se_range": [float(se.min()), float(se.max())], "ma98_L_star_se_max": float(se[table.is_ma98].max()),
        "fit_rms_ma98": fit.rms_ma98, "fit_converged": fit.converged,
        "floor_five_detectors_s": t_floor, "ratio_to_floor": t_table / t_floor,
        "alternative_one_run_per_direction_s": t_alternative, "ratio_alternative_to_table": t_alternative / t_table,
    }
    atomic_write_json(Path(__file__).parent / "output" / "gonio.json", out)
    print(json.dumps(to_jsonable(out)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
