"""A plain `vmap(while_loop)` tracer: the straightforward alternative the wavefront tracer is benchmarked against."""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np

from ._options import LEDGER_KEYS, TracerOptions
from ._path import _new_ray, _new_ray_uniforms, _ray_hash, _step_one, _uniforms
from ._scene import _Scene, _traverse
from ._trace import _seed_state


def plain_trace_seconds(scene: _Scene, options: TracerOptions, seed: int, rays: int, batch: int) -> float:
    """Seconds for `rays` rays traced with one `vmap(while_loop)` per batch of `batch` rays.

    The straightforward alternative to `trace`'s wavefront: the same physics (`_step_one`, the same
    shadow rays and counter-based random numbers), one lane per ray until it ends, so a batch
    waits for its longest path. `benchmarks/tracer.py` compares the two in the same run.

    Arguments:
        scene: from `build_scene`.
        options: the `TracerOptions` of the step.
        seed: the random stream (as `trace`'s seed).
        rays, batch: rays in all and per compiled batch (the first batch compiles and is not timed).

    Returns:
        Wall seconds for the timed batches.
    """
    sc, opt, key = scene, options, jnp.asarray(np.uint32(_seed_state(seed)))
    m = sc.det_air.shape[0]
    dtype = sc.h_b.dtype
    single = jnp.asarray(False)

    def one_ray(rid):
        u = _uniforms(_ray_hash(key, rid, jnp.asarray(0x7FFFFFFF, jnp.uint32)), _new_ray_uniforms(sc), dtype)
        p0, d0, w0, _, c0, s0 = _new_ray(sc, u, dtype)
        ray = (p0, d0, w0, jnp.asarray(True), c0, s0, jnp.asarray(0, jnp.int32), jnp.asarray(0, jnp.int32), rid,
               jnp.asarray(False), jnp.zeros((), dtype), jnp.zeros((), dtype), jnp.zeros(3, dtype), jnp.zeros((m, 3), dtype).at[:, 2].set(1.0), jnp.zeros(m, dtype), jnp.zeros(m, dtype))
        tally = jnp.zeros(2 * m + len(LEDGER_KEYS) + 1, dtype)

        def cond(c):
            r, _ = c
            return r[3] | jnp.any(r[-1] > 0)

        def body(c):
            r, t = c
            org, dirs, lims, vals = r[-4:]
            tb, _, _, _, fin = jax.vmap(lambda dd, tl: _traverse(sc, org, dd, tl, True, sc.shadow_cells))(dirs, lims)
            t = t.at[:m].add(jnp.where(fin & (tb >= lims), vals, 0.0))
            r2, inc = _step_one(sc, opt, r, _ray_hash(key, rid, r[6]), single)
            return r2, t + inc

        return jax.lax.while_loop(cond, body, (ray, tally))[1]

    f = jax.jit(jax.vmap(one_ray))
    jax.block_until_ready(f(jnp.arange(batch, dtype=jnp.int64)))  # compile
    t0 = time.perf_counter()
    for start in range(0, rays, batch):
        jax.block_until_ready(f(jnp.arange(start, start + batch, dtype=jnp.int64)))
    return time.perf_counter() - t0
