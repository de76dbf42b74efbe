"""Benchmark: the hot-spot joint escape G, the analytic model's inner loop under a wavy coat.

`HotSpot.joint_escape` on 10⁶ direction pairs (48 Gauss–Laguerre depth nodes each), with the
library's uniform-grid lookup of the tabulated overlap integral against the same interpolation
located by `jnp.searchsorted` (the straightforward alternative), and the bare `exp` over the same
nodes as the floor; then the analytic single-scatter model of the tracer's thin-mirror test (hot
spot, side walls, 12° wavy coat, 8° apertures). Warm timings (best of 3, after one compiling call).

Run: python benchmarks/hot_spot.py [--pairs 1000000]
"""

from __future__ import annotations

import argparse
import platform
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from paintjax import GammaTilt, HotSpot, MirrorBRDF, ma98_geometry  # noqa: E402
from paintjax.instrument import microfacet_reflectance_factor  # noqa: E402


def best_of(fn, *args, repeats: int = 3) -> float:
    jax.block_until_ready(fn(*args))
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t0)
    return min(times)


def searchsorted_integral(hot: HotSpot, x):
    s, F, rho = hot.separation, hot.overlap_integral, hot.overlap
    xc = jnp.clip(x, s[0], s[-1])
    k = jnp.clip(jnp.searchsorted(s, xc, side="right") - 1, 0, s.shape[0] - 2)
    h = s[k + 1] - s[k]
    t = (xc - s[k]) / h
    h00, h10, h01, h11 = 2 * t**3 - 3 * t**2 + 1, t**3 - 2 * t**2 + t, -2 * t**3 + 3 * t**2, t**3 - t**2
    return h00 * F[k] + h10 * h * rho[k] + h01 * F[k + 1] + h11 * h * rho[k + 1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=1_000_000)
    args = ap.parse_args(argv)
    if args.pairs < 1:
        ap.error(f"--pairs must be a positive integer, got {args.pairs}")
    hot = HotSpot.for_layer((0.99999, 1.0, 1.00001), thickness=0.02, pvc=0.02 / 50.0)
    rng = np.random.default_rng(0)
    wi = rng.normal(size=(args.pairs, 3)); wo = rng.normal(size=(args.pairs, 3))
    wi[:, 2], wo[:, 2] = np.abs(wi[:, 2]) + 0.3, np.abs(wo[:, 2]) + 0.3
    wi, wo = (jnp.asarray(v / np.linalg.norm(v, axis=1, keepdims=True)) for v in (wi, wo))
    library = jax.jit(lambda a, b: hot.joint_escape(a, b, 1.0, 1.0))
    x_nodes = jnp.asarray(np.polynomial.laguerre.laggauss(48)[0])

    def with_search(a, b):  # joint_escape with the searchsorted lookup (swapped in while JAX traces it)
        original = HotSpot._integral
        try:
            HotSpot._integral = searchsorted_integral
            return hot.joint_escape(a, b, 1.0, 1.0)
        finally:
            HotSpot._integral = original

    search = jax.jit(with_search)
    floor = jax.jit(lambda a, b: jnp.sum(jnp.exp(-(a[:, 2:] + b[:, 2:]) * x_nodes), axis=-1))
    same = float(jnp.max(jnp.abs(library(wi, wo) - search(wi, wo))))
    t_lib, t_search, t_floor = best_of(library, wi, wo), best_of(search, wi, wo), best_of(floor, wi, wo)
    geo = ma98_geometry(45.0, (15.0, 25.0, 45.0, 75.0, 110.0), detector_aperture_deg=8.0)

    def model():
        return microfacet_reflectance_factor(geo, GammaTilt(2.29, 2.18), n=1.5, platelet=MirrorBRDF(n_binder=1.5), exit_occlusion=True,
                                             hot_spot=hot, side_walls=0.02, aperture_nodes=12, waviness_deg=12.0)

    t0 = time.perf_counter()
    jax.block_until_ready(model())
    t_first = time.perf_counter() - t0
    t_model = best_of(model)
    print(f"machine: {platform.machine()} {jax.devices()[0].platform}, {jax.local_device_count()} device(s), JAX {jax.__version__}")
    print(f"joint_escape, {args.pairs} pairs × 48 depth nodes: uniform-grid lookup {t_lib:.3f} s, searchsorted lookup {t_search:.3f} s "
          f"({t_search / t_lib:.1f}× slower), bare exp floor {t_floor:.3f} s ({t_lib / t_floor:.1f}× the floor); max |difference| {same:.1e}")
    print(f"analytic thin-mirror model, wavy 12°, 8° apertures, hot spot + side walls: first call {t_first:.2f} s, warm {t_model:.2f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
