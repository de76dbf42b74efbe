"""Benchmark: build the platelet BRDF table (σ = 51 nm, τ = 640 nm, the default 40 × 20 µm profiles)
from scratch and from the cache, against the LAPACK floor (the bare complex LU factorisations the
solve needs: 2 channels per profile, scipy's zgetrf on the same N) measured in the same run, and
the Kirchhoff control variate's cost (the same profiles solved without it); prints Markdown rows.

Run: .venv/bin/python benchmarks/brdf_table.py [--profiles 40]
"""

from __future__ import annotations

import argparse
import tempfile
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import scipy.linalg  # noqa: E402

from paintjax import TabulatedBRDF, platelet_table_arrays, synthesize_profiles  # noqa: E402
from paintjax.brdf import DEFAULT_INCIDENCE_DEG, DEFAULT_NUM_PROFILES  # noqa: E402
from paintjax.wave import default_spacing, max_incidence_deg, solve_profiles  # noqa: E402


def timed(fn):
    w, c = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - w, time.process_time() - c


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--profiles", type=int, default=DEFAULT_NUM_PROFILES)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as cache:
        print("| case | source | wall | CPU | cache hit |")
        print("|---|---|---|---|---|")
        for source in ("wave", "kirchhoff"):
            kw = dict(source=source, num_profiles=args.profiles, length_um=20.0, cache_dir=cache)
            for case in ("from scratch", "from cache"):
                (arrays, info), wall, cpu = timed(lambda: platelet_table_arrays(0.051, 0.64, **kw))
                print(f"| {case} | {source} | {wall:.2f} s | {cpu:.2f} s | {info['cache_hit']} |", flush=True)
        table = TabulatedBRDF.from_arrays(arrays)
        wi = jnp.broadcast_to(jnp.asarray([0.3, 0.0, (1 - 0.09) ** 0.5]), (100_000, 3))
        sample = jax.jit(lambda t, k, w: t.sample(k, w))
        sample(table, jax.random.PRNGKey(0), wi)[1].block_until_ready()
        (_, wall, cpu) = timed(lambda: sample(table, jax.random.PRNGKey(1), wi)[1].block_until_ready())
        print(f"| 10⁵ samples (jit, warm) | table | {wall:.3f} s | {cpu:.3f} s | – |")
    # floor: the LU factorisations alone (2 channels per profile), same N, complex128
    dx = default_spacing(0.5, 1.5, sigma_um=0.051, tau_um=0.64)
    p = synthesize_profiles(jax.random.PRNGKey(0), 0.051, 0.64, length_um=20.0, spacing_um=dx, num_profiles=args.profiles)
    n = p.x.shape[0]
    a = np.random.default_rng(0).standard_normal((n, n)) + 1j * np.random.default_rng(1).standard_normal((n, n))
    _, floor, floor_cpu = timed(lambda: [scipy.linalg.lu_factor(a) for _ in range(2 * args.profiles)])
    inc = DEFAULT_INCIDENCE_DEG[DEFAULT_INCIDENCE_DEG <= max_incidence_deg()]
    ts = np.linspace(-89.5, 89.5, 359)
    solve_profiles(p, inc, ts)  # compile
    _, plain, plain_cpu = timed(lambda: solve_profiles(p, inc, ts, control_variate=False).sigma.block_until_ready())
    _, cv, cv_cpu = timed(lambda: solve_profiles(p, inc, ts).sigma.block_until_ready())
    print()
    print(f"| wave solve ({args.profiles} profiles, N = {n}, {inc.size} incidences) | wall | CPU | × LAPACK floor (wall) |")
    print("|---|---|---|---|")
    print(f"| LAPACK floor: {2 * args.profiles} × zgetrf | {floor:.2f} s | {floor_cpu:.2f} s | 1 |")
    print(f"| solve, plain mean | {plain:.2f} s | {plain_cpu:.2f} s | {plain / floor:.2f} |")
    print(f"| solve, Kirchhoff control variate | {cv:.2f} s | {cv_cpu:.2f} s | {cv / floor:.2f} |")


if __name__ == "__main__":
    main()
