"""Benchmark: build the platelet BRDF table (σ = 51 nm, τ = 640 nm, ten 20 µm profiles) from scratch
and from the cache; prints one Markdown row per case.

Run: .venv/bin/python benchmarks/brdf_table.py [--profiles 10]
"""

from __future__ import annotations

import argparse
import tempfile
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402

from paintjax import TabulatedBRDF, platelet_table_arrays  # noqa: E402


def timed(fn):
    w, c = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - w, time.process_time() - c


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--profiles", type=int, default=10)
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


if __name__ == "__main__":
    main()
