"""Benchmark: where the time of one wavefront step of the ray tracer goes (Silver #1, wave BRDF, five MA98 detectors).

What: per step of all lanes, warm, the stages of `trace`'s wavefront step timed on their own
(`paintjax.tracer.profile_wavefront_step`): traversal + intersection, BRDF sampling and
evaluation, the whole path step, the NEE shadow rays, the new rays, the host's check, and the
tracer's loop per step; what the stages leave of the loop's step is its overhead (tallies,
merges, XLA's loops). The scene is `benchmarks/tracer.py`'s and `simulate`'s default one:
Silver #1's cached array (seed 0), its wave-based platelet BRDF, 45° illumination, the five
standard aspecular angles, the tracer's default options (bidirectional MIS weights included).

How: the lanes are the real chunk's after two calls from fresh rays (mixed depths, shadow rays
pending); each stage is its own jit-compiled function over all lanes, timed warm less the cost of
an empty call; the loop's time per step is that of the chunks of a run of `--rays` rays whose pool
stayed full (the drain is reported on its own). `--repeats` rounds of one call per stage and one
loop run take turns, so that the load of a shared machine touches them alike; medians of the rounds.
Prints a Markdown table; writes benchmarks/output/tracer_profile.json (atomic).

Run: python benchmarks/tracer_profile.py [--lanes 2048] [--repeats 5] [--rays 32768]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from datetime import date
from pathlib import Path

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

from paintjax import atomic_write_json, build_grid, load_sample, ma98_geometry, platelet_brdf, sample_array  # noqa: E402
from paintjax.tracer import TracerOptions, profile_wavefront_step  # noqa: E402


def table(result: dict) -> str:
    """Markdown table of a profile: stage, ms per step, share of the full loop's step (parts indented under their stage)."""
    rows = ["| stage | ms per step | share of the step |", "|---|---:|---:|"]
    for key, label in result["labels"].items():
        depth, parent = 0, result["parents"].get(key)
        while parent is not None:
            depth, parent = depth + 1, result["parents"].get(parent)
        name = "&nbsp;" * 4 * depth + ("↳ " if depth else "") + label
        rows.append(f"| {name} | {1e3 * result['seconds'][key]:.3f} | {100 * result['fractions'][key]:.1f} % |")
    return "\n".join(rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lanes", type=int, default=TracerOptions().lanes, help="rays in flight per device (TracerOptions.lanes)")
    ap.add_argument("--repeats", type=int, default=5, help="timed calls per stage and loop runs (medians)")
    ap.add_argument("--rays", type=int, default=None, help="rays of each loop run (default 16 × lanes)")
    args = ap.parse_args(argv)
    for name in ("lanes", "repeats", "rays"):
        value = getattr(args, name)
        if value is not None and value < (8 if name == "lanes" else 1):
            ap.error(f"--{name} must be {'>= 8' if name == 'lanes' else 'positive'}, got {value}")

    s = load_sample("silver1")
    array = sample_array("silver1", seed=0)
    brdf = platelet_brdf("wave", sigma=s.sigma.value, tau=s.tau.value, n=s.binder_index)
    load_before = os.getloadavg()
    t0 = time.perf_counter()
    result = profile_wavefront_step(array, ma98_geometry(45.0), brdf, grid=build_grid(array), n=s.binder_index,
                                    clearcoat_thickness=s.clearcoat_thickness, lanes=args.lanes, rays=args.rays, repeats=args.repeats)
    seconds = time.perf_counter() - t0
    load_after = os.getloadavg()
    result["machine"] = {
        "platform": platform.platform(), "processor": platform.processor() or platform.machine(), "cpu_count": os.cpu_count(),
        "jax": jax.__version__, "backend": jax.default_backend(), "devices": [str(d) for d in jax.local_devices()],
        "load_average_before": list(load_before), "load_average_after": list(load_after),
    }
    result.update(date=date.today().isoformat(), sample=s.name, brdf="wave", platelets=int(array.widths.shape[0]),
                  profile_seconds=seconds)
    print(f"{jax.default_backend()}: {result['lanes']} lanes × {result['devices']} device(s), {result['rays']} rays, "
          f"{result['loop_steps']} steps ({result['loop_steady_calls']} of {result['loop_calls']} chunk calls with a full pool), "
          f"load {load_before[0]:.1f} → {load_after[0]:.1f}, {seconds:.0f} s", file=sys.stderr)
    print(table(result))
    atomic_write_json(Path(__file__).parent / "output" / "tracer_profile.json", result)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
