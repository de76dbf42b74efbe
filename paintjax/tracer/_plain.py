"""A plain `vmap(while_loop)` tracer: the straightforward alternative the wavefront tracer is benchmarked against.

`plain_trace_counts` runs the same tracer with counters of its work per path (segments, events,
shadow rays), for per-unit-of-work comparisons with other tracers (`benchmarks/peer_mitsuba.py`).
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np

from ._options import _BIG, LEDGER_KEYS, TracerOptions
from ._path import _new_ray, _new_ray_uniforms, _ray_hash, _step_one, _uniforms
from ._scene import _Scene, _traverse
from ._trace import _seed_state

#: Per-path work counters of `plain_trace_counts`, in the order of its per-ray count vectors.
COUNT_KEYS = ("steps", "segments", "platelet_events", "primer_events", "interface_events", "shadow_rays", "nee_candidates",
              "kernel_events")


def _step_kinds(sc: _Scene, ray):
    """What the lane's next `_step_one` does: (platelet hit, primer, clearcoat interface, cells only).

    The same traversal `_step_one` makes (same slab limit, same cell budget), repeated for counting.
    """
    pos, d, alive = ray[0], ray[1], ray[3]
    dz = d[2]
    t_slab = jnp.where(dz > 0, (sc.h_b - pos[2]) / jnp.where(dz > 0, dz, 1.0),
                       jnp.where(dz < 0, -pos[2] / jnp.where(dz < 0, dz, -1.0), _BIG))
    t_slab = jnp.maximum(t_slab, 0.0).astype(pos.dtype)
    tb, _, _, _, fin = _traverse(sc, pos, d, t_slab, False, sc.max_cells)
    hit = alive & fin & (tb < t_slab)
    top = alive & fin & ~hit & (dz > 0)
    bottom = alive & fin & ~hit & ~(dz > 0)
    return hit, bottom, top, alive & ~fin


def _ray_program(sc: _Scene, opt: TracerOptions, seed: int, count: bool = False):
    """`jit(vmap(one_ray))`: ray ids → per-ray tallies (NEE, histogram, ledger, 1), and with `count` per-ray counters."""
    key = jnp.asarray(np.uint32(_seed_state(seed)))
    m = sc.det_air.shape[0]
    dtype = sc.h_b.dtype
    single = jnp.asarray(False)

    def one_ray(rid):
        u = _uniforms(_ray_hash(key, rid, jnp.asarray(0x7FFFFFFF, jnp.uint32)), _new_ray_uniforms(sc), dtype)
        p0, d0, w0, _, c0, s0 = _new_ray(sc, u, dtype, opt.randomize_azimuth)
        ray = (p0, d0, w0, jnp.asarray(True), c0, s0, jnp.asarray(0, jnp.int32), jnp.asarray(0, jnp.int32), rid,
               jnp.asarray(False), jnp.zeros((), dtype), jnp.zeros((), dtype), jnp.zeros(3, dtype),
               jnp.zeros((m, 3), dtype).at[:, 2].set(1.0), jnp.zeros(m, dtype), jnp.zeros(m, dtype))
        tally = jnp.zeros(2 * m + len(LEDGER_KEYS) + 1, dtype)

        def cond(c):
            r = c[0]
            return r[3] | jnp.any(r[-1] > 0)

        def body(c):
            r, t = c[0], c[1]
            org, dirs, lims, vals = r[-4:]
            tb, _, _, _, fin = jax.vmap(lambda dd, tl: _traverse(sc, org, dd, tl, True, sc.shadow_cells))(dirs, lims)
            t = t.at[:m].add(jnp.where(fin & (tb >= lims), vals, 0.0))
            r2, inc = _step_one(sc, opt, r, _ray_hash(key, rid, r[6]), single)
            if not count:
                return r2, t + inc
            hit, bottom, top, _ = _step_kinds(sc, r)
            one = lambda b: b.astype(jnp.int32)  # noqa: E731
            inc_c = jnp.stack([one(r[3]), one(hit | bottom | top), one(hit), one(bottom), one(top),
                               jnp.sum(vals > 0).astype(jnp.int32), m * one(hit | bottom), jnp.zeros((), jnp.int32)])
            return r2, t + inc, c[2] + inc_c

        init = (ray, tally) + ((jnp.zeros(len(COUNT_KEYS), jnp.int32),) if count else ())
        out = jax.lax.while_loop(cond, body, init)
        if not count:
            return out[1]
        return out[1], out[2].at[-1].set(out[0][7])  # kernel_events: the tracer's own event counter

    return jax.jit(jax.vmap(one_ray))


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
    f = _ray_program(scene, options, seed)
    jax.block_until_ready(f(jnp.arange(batch, dtype=jnp.int64)))  # compile
    t0 = time.perf_counter()
    for start in range(0, rays, batch):
        jax.block_until_ready(f(jnp.arange(start, start + batch, dtype=jnp.int64)))
    return time.perf_counter() - t0


def plain_trace_counts(scene: _Scene, options: TracerOptions, seed: int, rays: int, batch: int = 2048) -> dict:
    """The work of `rays` paths of the plain tracer (ray ids 0 … rays − 1, as `trace` with one device), counted per path.

    Same physics and random numbers as `plain_trace_seconds` and `trace` (forward pass); the counters
    add a second traversal per step to classify it, so this is for counting, not timing.

    Counters (`COUNT_KEYS`, per path): steps (kernel steps of a live ray: an event, the interface, or
    `cells_per_step` cells of a longer segment); segments (straight pieces, each ending at a platelet,
    the primer or the clearcoat surface; the coat transit is closed-form, so an internal reflection
    there is one segment up, and the next one down); platelet_events, primer_events, interface_events
    (segment ends by kind); shadow_rays (NEE shadow rays traced: pending value > 0 after the shadow
    roulette, what the wavefront tracer's compacted buffer traces); nee_candidates (detectors ×
    scattering events: the shadow rays without the roulette and zero values); kernel_events (the
    tracer's own event counter, `_step_one`'s; equals platelet + primer events).

    Returns:
        dict: rays, per_path (mean of each counter), totals (sums), per_ray ((rays, len(COUNT_KEYS))
        counters), tally (summed per-ray tallies: NEE per detector, histogram per detector, the energy
        ledger without its top reflection) and reflectance_factor (the NEE / MIS estimate per
        detector, as `trace` reports it for the same seed and rays on one device).
    """
    f = _ray_program(scene, options, seed, count=True)
    rays, batch = int(rays), max(1, min(int(batch), int(rays)))
    tallies, counts = [], []
    for start in range(0, rays, batch):
        t, c = f(jnp.arange(start, start + batch, dtype=jnp.int64))
        keep = min(batch, rays - start)
        tallies.append(np.asarray(t, dtype=float)[:keep].sum(axis=0))
        counts.append(np.asarray(c, dtype=np.int64)[:keep])
    per_ray = np.concatenate(counts, axis=0)
    tally, total = np.sum(tallies, axis=0), per_ray.sum(axis=0)
    m = scene.det_air.shape[0]
    return {
        "rays": rays,
        "per_path": {k: float(v) / rays for k, v in zip(COUNT_KEYS, total)},
        "totals": {k: int(v) for k, v in zip(COUNT_KEYS, total)},
        "per_ray": per_ray,
        "tally": tally[: 2 * m + len(LEDGER_KEYS)],
        "reflectance_factor": tally[:m] / rays,
    }
