"""Benchmark of the inverse layer: least-squares fit time and posterior wall time to ≥ 1000 effective samples.

Silver #1 measured L*, the analytic single-scatter forward model (`AnalyticForward`, rough
platelets) with the CLI's default free parameters (shape, scale, σ, τ, diffuse; + discrepancy δ
in the posterior). Reports the first fit in a fresh process (includes JIT compilation), a second
fit (compiled), and an emcee run (32 walkers) until ≥ 50 τ_int and ≥ 1000 effective samples.
Goals (issue 7): fit ≤ 60 s, posterior ≤ 10 min on the 2-core CPU.

Writes benchmarks/output/inverse.json (atomic) and prints a Markdown table.

Run: python benchmarks/inverse.py [--walkers 32] [--max-steps 20000]
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from paintjax import (  # noqa: E402
    AnalyticForward,
    atomic_write_json,  # noqa: E402
    fit_least_squares,
    load_sample,
    sample_posterior,
)

FREE = ("shape", "scale", "sigma", "tau", "diffuse")


def cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--walkers", type=int, default=32)
    ap.add_argument("--max-steps", type=int, default=20000)
    ap.add_argument("--starts", type=int, default=8)
    a = ap.parse_args(argv)
    y = np.asarray(load_sample("silver1").L_star)
    forward = AnalyticForward()
    res = {"machine": f"{platform.machine()} {os.cpu_count()} cores, {platform.python_implementation()} {platform.python_version()}, "
                      f"JAX {jax.__version__} CPU", "load_average_start": os.getloadavg()}
    for label in ("fit_first", "fit_second"):
        t, c = time.perf_counter(), cpu()
        fr = fit_least_squares(forward, y, free=FREE, n_starts=a.starts, seed=0)
        res[label] = {"wall_s": time.perf_counter() - t, "cpu_s": cpu() - c, "chi2": fr.chi2, "status": fr.status,
                      "n_converged": fr.n_converged, "n_starts": fr.n_starts}
        print(label, res[label], flush=True)
    t, c = time.perf_counter(), cpu()
    post = sample_posterior(forward, y, free=FREE + ("discrepancy",), walkers=a.walkers, max_steps=a.max_steps, min_steps=500,
                            check_every=500, n_tau=50, min_ess=1000, init=fr, seed=0, progress=False)
    res["posterior"] = {"wall_s": time.perf_counter() - t, "cpu_s": cpu() - c, "walkers": post.walkers, "steps": post.steps,
                        "n_eff": post.n_eff, "tau_int_max": max(post.tau_int.values()), "converged": post.converged,
                        "acceptance": post.acceptance, "evaluations": post.walkers * post.steps}
    res["load_average_end"] = os.getloadavg()
    print("posterior", res["posterior"], flush=True)
    out = Path(__file__).parent / "output" / "inverse.json"
    atomic_write_json(out, res)
    f1, f2, p = res["fit_first"], res["fit_second"], res["posterior"]
    print("\n| measurement | wall | CPU | notes |\n|---|---|---|---|")
    print(f"| least squares, first in process (incl. JIT) | {f1['wall_s']:.1f} s | {f1['cpu_s']:.1f} s | {f1['n_starts']} starts, χ² {f1['chi2']:.3g} |")
    print(f"| least squares, compiled | {f2['wall_s']:.1f} s | {f2['cpu_s']:.1f} s | same problem |")
    print(f"| posterior to ≥ 1000 effective samples | {p['wall_s']:.0f} s | {p['cpu_s']:.0f} s | {p['walkers']} walkers × {p['steps']} steps, "
          f"τ_int max {p['tau_int_max']:.0f}, n_eff {p['n_eff']:.0f}, converged {p['converged']} |")
    return res


if __name__ == "__main__":
    main()
