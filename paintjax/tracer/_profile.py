"""Where a wavefront step's time goes: the stages of `trace`'s step, each timed on its own on real lane states.

A step of the wavefront (`_chunk_device`) traces the pending NEE shadow rays of all lanes
(`_shadows`: compacted into a buffer, any-hit traversal), refills the dead lanes with new rays
(prefix sum, `_new_ray`), advances every lane by one path step (`_step_one`: grid traversal and slab
tests, then the shading: BRDF sampling, NEE set-up toward every detector, clearcoat, roulette) and
adds the tallies; `steps_per_call` such steps run in one compiled `fori_loop`, and the host reads
back whether any lane is busy after every call.

`profile_wavefront_step` builds the same forward scene as `trace`, runs the real compiled chunk a
few times from fresh rays (lanes at mixed depths, pending shadow rays) and times on that snapshot
each stage as its own jit-compiled function over all lanes, less the cost of a jit call that does
nothing with the same arguments (which the loop pays once per chunk, not per step). Taking turns
with those calls, it runs the tracer's loop for a fixed number of rays and divides the time of its
chunks with a full pool by their steps. What the stages leave of the loop's step is the loop
overhead (refill, tallies, merges, the host's check, XLA's loops), split as far as it can be. All
times warm (compilation excluded), medians of several rounds.
"""

from __future__ import annotations

import dataclasses
import time

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from ..brdf._platelet import MirrorBRDF
from ..instrument._geometry import Geometry
from ..instrument._single_scatter import check_coat_index, check_platelet_medium
from ..microstructure._grid import build_grid
from ..optics._interface import check_waviness
from ._options import TracerOptions
from ._path import _key_from, _new_ray, _new_ray_uniforms, _ray_hash, _shadow_leg, _shadows, _source, _step_one, _uniforms
from ._plain import _step_kinds
from ._scene import _Scene, build_scene
from ._trace import _initial_state, _reverse_shares, _runner, _seed_state

#: The stages of `profile_wavefront_step`, in the order of its table (a stage, then its parts), with their labels.
PROFILE_STAGES = {
    "step": "path step `_step_one`, all lanes",
    "traversal": "traversal + intersection (DDA, slab tests)",
    "brdf": "BRDF: all of the step's calls",
    "brdf_sample": "BRDF sampling",
    "brdf_evaluate": "BRDF evaluation toward the detectors",
    "brdf_pdf": "BRDF pdfs (MIS weights)",
    "other_shading": "other shading (by difference)",
    "shadows": "NEE shadow rays (compaction + any-hit)",
    "loop_overhead": "loop overhead (full − step − shadows)",
    "refill": "new rays for the lanes",
    "host": "host round-trip (busy check)",
    "loop_other": "tallies, merges, XLA loop (by difference)",
    "full_step": "full tracer loop per step (full pool)",
    "loop_all_steps": "tracer loop per step, drain included",
}
#: The stage each stage is a part of (a stage's parts need not add up to it: they are timed on their own).
PROFILE_PARENTS = {"traversal": "step", "brdf": "step", "other_shading": "step", "brdf_sample": "brdf", "brdf_evaluate": "brdf",
                   "brdf_pdf": "brdf", "refill": "loop_overhead", "host": "loop_overhead", "loop_other": "loop_overhead"}
_BRDF_PARTS = ("sample", "evaluate", "pdf")


def _take_turns(fns: dict, args, loop, repeats: int):
    """`repeats` rounds of one timed call of every stage function and one run of the loop, so that a change
    of the machine's load touches them all alike. Each timed call follows an untimed one of the same
    function, as a step follows a step in the loop (the first call after other work runs slower: its
    buffers and caches are cold); one call of each function first compiles.

    Returns (wall seconds of each function's calls, the loop runs' results)."""
    for fn in fns.values():
        jax.block_until_ready(fn(*args))
    times = {name: [] for name in fns}
    loops = []
    for _ in range(repeats):
        for name, fn in fns.items():
            jax.block_until_ready(fn(*args))
            t0 = time.perf_counter()
            jax.block_until_ready(fn(*args))
            times[name].append(time.perf_counter() - t0)
        loops.append(loop())
    return times, loops


def _positive_int(name: str, value, lo: int = 1) -> int:
    try:
        v = int(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be an integer >= {lo}, got {value!r}") from None
    if v < lo or v != value:
        raise ValueError(f"{name} must be an integer >= {lo}, got {value!r}")
    return v


def _brdf_calls(sc: _Scene, parts, d, w_in, k):
    """The platelet BRDF calls one step of a lane makes (`parts` of: one sample, m evaluations toward
    the detectors, the pdfs of the MIS weights), on the lane's direction and its detector directions
    in the paint frame; without "sample", ω_o is the mirror direction."""
    wi = jnp.stack([-d[0], -d[1], jnp.abs(d[2])])
    wi_b = jnp.broadcast_to(wi, w_in.shape)
    out = jnp.zeros((), d.dtype)
    if "sample" in parts:
        wo, s_w = sc.brdf.sample(_key_from(k), wi)
        out = out + jnp.sum(wo) + s_w
    else:
        wo = wi * jnp.array([-1.0, -1.0, 1.0], d.dtype)
    if "evaluate" in parts:
        out = out + jnp.sum(sc.brdf.evaluate(wi_b, w_in))
    if "pdf" in parts and sc.mis:  # the event's and the detectors' sampling densities
        out = out + sc.brdf.pdf(wi, wo) + jnp.sum(sc.brdf.pdf(wi_b, w_in))
    if "pdf" in parts and sc.bidir:  # the reverse densities toward the detectors, both of the sampled direction
        out = out + jnp.sum(sc.brdf.pdf(w_in, wi_b)) + sc.brdf.pdf(wi, wo) + sc.brdf.pdf(wo, wi)
    return out


def _stage_functions(opt: TracerOptions) -> dict:
    """The isolated stages as jit-compiled functions of (scene, lanes' rays, key, single)."""

    def keys(key, rays):
        return jax.vmap(lambda r, t: _ray_hash(key, r, t))(rays[8], rays[6])

    def traversal(sc: _Scene, rays, key, single):  # the step's traversal (same slab limit and cell budget), classified
        return jax.vmap(lambda r: _step_kinds(sc, r))(rays)

    def brdf(parts):
        return lambda sc, rays, key, single: jax.vmap(lambda d, w, k: _brdf_calls(sc, parts, d, w, k))(rays[1], rays[13], keys(key, rays))

    def step(sc: _Scene, rays, key, single):
        return jax.vmap(lambda r, k: _step_one(sc, opt, r, k, single))(rays, keys(key, rays))

    def shadows(sc: _Scene, rays, key, single):
        return _shadows(sc, opt, *rays[-4:])

    def refill(sc: _Scene, rays, key, single):  # what every step computes for all lanes before it merges the dead ones
        dtype = rays[0].dtype
        start = jnp.asarray(0x7FFFFFFF, jnp.uint32)
        ug = jax.vmap(lambda r: _uniforms(_ray_hash(key, r, start), _new_ray_uniforms(sc), dtype))(rays[8])
        return jax.vmap(lambda uu, r: _new_ray(sc, uu, dtype, opt.randomize_azimuth, _source(sc, r)))(ug, rays[8])

    def call(sc: _Scene, rays, key, single):  # touches every argument: a jit call's own cost (dispatch, arguments)
        leaves = jax.tree.leaves((sc, rays, key, single))
        return sum(jnp.ravel(x)[0].astype(jnp.float32) for x in leaves if jnp.size(x))

    fns = {"traversal": traversal, "brdf": brdf(_BRDF_PARTS), "step": step, "shadows": shadows, "refill": refill, "call": call}
    fns.update({f"brdf_{p}": brdf((p,)) for p in _BRDF_PARTS})
    return {name: jax.jit(f) for name, f in fns.items()}


def _busy(state, target: int) -> bool:
    """`trace`'s check after every chunk: a lane alive or a shadow ray pending, or rays left to start."""
    rays = state[0]
    return bool(jnp.any(rays[3]) | jnp.any(rays[-1] != 0)) or int(jnp.min(state[2])) < target


def _loop(run, sc, key, state, target, single):
    """`trace`'s loop for one pass from a fresh state: per chunk call, (seconds in the chunk, seconds of the
    host's check, whether the pool still refilled every dead lane: rays were left to start after the call)."""
    nl = jnp.asarray(target, state[2].dtype)
    calls = []
    while True:
        t0 = time.perf_counter()
        state = jax.block_until_ready(run(sc, key, state, nl, single))
        t1 = time.perf_counter()
        busy = _busy(state, target)
        t2 = time.perf_counter()
        calls.append((t1 - t0, t2 - t1, int(jnp.min(state[2])) < target))  # the last, untimed: not part of `trace`'s check
        if not busy:
            return np.array(calls)


def profile_wavefront_step(
    array,
    geometry: Geometry,
    brdf=None,
    *,
    grid=None,
    n: float = 1.5,
    clearcoat_thickness: float = 50.0,
    primer_albedo: float = 0.3,
    waviness_deg: float = 0.0,
    lanes: int | None = None,
    rays: int | None = None,
    repeats: int = 5,
    warm_calls: int = 2,
    seed: int = 0,
    options: TracerOptions | None = None,
) -> dict:
    """Time the stages of one wavefront step of `trace` (forward pass), warm, on realistic lane states.

    The scene is `trace`'s forward pass for the same arguments (bidirectional MIS weights included
    where `trace` would use them). The lane states are the real chunk's after `warm_calls` calls
    from fresh rays; every stage runs as its own jit-compiled function over all lanes of that snapshot.

    Arguments:
        array, geometry, brdf, grid, n, clearcoat_thickness, primer_albedo, waviness_deg, seed, options: as for `trace`.
        lanes: rays in flight per device, ≥ 8 (default `options.lanes`, i.e. `TracerOptions`' default).
        rays: rays of the full-loop run whose time per step is the reference (default 16 × lanes per device).
        repeats: rounds of one timed call per stage and one run of the loop, taking turns (medians), ≥ 1.
        warm_calls: chunk calls (`steps_per_call` steps each) from fresh rays before the snapshot, ≥ 1.

    Returns:
        dict: "seconds" per stage (`PROFILE_STAGES`, per step of all lanes; an isolated stage's median
        less "call_overhead", that of a jit call that does nothing), their "quartiles" (measured
        stages), "fractions" of "full_step", "labels", "parents" (`PROFILE_PARENTS`), "not_isolated" (what has no number of its own, and
        which number holds its time), "caveats", "counts" (the snapshot's lanes and the work of a
        step) and the settings (lanes, devices, rays, the loop's chunk calls and steps, ...).
        "other_shading", "loop_other" and "loop_overhead" are differences and may come out slightly
        negative from timing noise.
    """
    lanes = _positive_int("lanes", (options or TracerOptions()).lanes if lanes is None else lanes, 8)
    repeats = _positive_int("repeats", repeats)
    warm_calls = _positive_int("warm_calls", warm_calls)
    ndev = len(jax.local_devices())
    rays = _positive_int("rays", 16 * lanes * ndev if rays is None else rays, lanes)
    check_coat_index(n)
    waviness_deg = check_waviness(waviness_deg)
    brdf = MirrorBRDF(n_binder=n) if brdf is None else brdf
    check_platelet_medium(brdf, n)
    opt = dataclasses.replace(options or TracerOptions(), lanes=lanes, batches=lanes)
    cdt = jnp.float64 if (opt.float64 and jax.config.jax_enable_x64) else jnp.float32
    share = _reverse_shares(opt, geometry, brdf, waviness_deg)
    sc = build_scene(array, geometry, brdf, build_grid(array) if grid is None else grid, n=n, clearcoat_thickness=clearcoat_thickness,
                     primer_albedo=primer_albedo, waviness_deg=waviness_deg, dtype=cdt, min_cells=opt.cells_per_step, mis=opt.mis,
                     reverse_share=share)
    m = sc.det_air.shape[0]
    devices = jax.local_devices()
    mesh = Mesh(np.array(devices), ("rays",))
    replicated = NamedSharding(mesh, PartitionSpec())
    idt = jnp.int64 if jax.config.jax_enable_x64 else jnp.int32
    key = jnp.asarray(np.uint32(_seed_state(seed)))
    single = jnp.asarray(False)
    sc_rep, key_rep, single_rep = (jax.device_put(x, replicated) for x in (sc, key, single))

    def fresh():
        state = _initial_state(lanes * ndev, ndev, m, m, cdt, jnp.result_type(float), idt)
        return jax.device_put(state, NamedSharding(mesh, PartitionSpec("rays")))

    run = _runner(mesh, opt)
    state = fresh()
    endless = jnp.asarray(np.iinfo(np.int32).max // ndev, idt)
    for _ in range(warm_calls):  # the real chunk from fresh rays: lanes at mixed depths, shadow rays pending
        state = run(sc_rep, key_rep, state, endless, single_rep)
    lane = jax.device_put(tuple(x[:lanes] for x in state[0]), devices[0])  # one device's lanes
    _busy(state, 0), int(jnp.min(state[2]))  # compiles the host's check

    target = -(-rays // ndev)

    def loop():  # per chunk call: (seconds, host seconds, pool full), of the calls after the snapshot's warm-up
        c = _loop(run, sc_rep, key_rep, fresh(), target, single_rep)
        if not np.any(c[warm_calls:, 2]):
            raise ValueError(f"rays ({rays}) are too few: no chunk call after the first {warm_calls} still had rays to start; "
                             "give more rays (e.g. 16 × lanes per device)")
        return c

    fns = _stage_functions(opt)
    times, loops = _take_turns(fns, (sc, lane, key, single), loop, repeats)
    calls = len(loops[0])
    steps = calls * opt.steps_per_call
    per_step = lambda c: (c[:, 0] + c[:, 1]).sum() / (len(c) * opt.steps_per_call)  # noqa: E731
    # the chunks whose pool stayed full (every dead lane refilled), after the warm-up: the snapshot's regime
    steady = [c[warm_calls:][c[warm_calls:, 2] > 0] for c in loops]
    times["full_step"] = [per_step(c) for c in steady]
    times["host"] = [c[:, 1].mean() / opt.steps_per_call for c in steady]
    times["loop_all_steps"] = [per_step(c) for c in loops]
    call = float(np.median(times.pop("call")))
    net = {name: np.asarray(t) - (call if name in fns else 0.0) for name, t in times.items()}  # an isolated stage less a call's cost
    sec = {name: float(np.median(t)) for name, t in net.items()}
    quartiles = {name: [float(q) for q in np.percentile(t, [25, 75])] for name, t in net.items()}
    sec["other_shading"] = sec["step"] - sec["traversal"] - sec["brdf"]
    sec["loop_overhead"] = sec["full_step"] - sec["step"] - sec["shadows"]
    sec["loop_other"] = sec["loop_overhead"] - sec["refill"] - sec["host"]
    seconds = {k: sec[k] for k in PROFILE_STAGES}

    hit, bottom, top, moving = (np.asarray(x) for x in fns["traversal"](sc, lane, key, single))
    alive = np.asarray(lane[3])
    nstep = np.asarray(lane[6])[alive]
    pending = int(np.sum(np.asarray(lane[-1]) > 0))
    counts = {
        "lanes_alive": float(np.mean(alive)),
        "lanes_platelet_hit": float(np.mean(hit)),
        "lanes_primer": float(np.mean(bottom)),
        "lanes_interface": float(np.mean(top)),
        "lanes_cells_only": float(np.mean(moving)),
        "lane_steps_mean": float(np.mean(nstep)) if nstep.size else 0.0,
        "lane_steps_max": int(np.max(nstep)) if nstep.size else 0,
        "shadow_rays_pending": pending,
        "shadow_rays_per_lane": pending / lanes,
        "shadow_buffer": max(1, min(lanes * m, int(round(opt.shadow_buffer * lanes * m)))),
        "detectors": m,
        "cells_per_step": sc.max_cells,
        "shadow_cells": sc.shadow_cells,
        "shadow_leg_cells": _shadow_leg(sc, opt),
        "cell_capacity": int(sc.cells.shape[1]),
        "slab_tests_per_lane_step": sc.max_cells * int(sc.cells.shape[1]),
        "brdf_calls_per_lane_step": {"sample": 1, "evaluate": m, "pdf": (1 + m) * sc.mis + (m + 2) * sc.bidir},
        "loop_lane_steps_per_ray": steps * lanes / target,
    }
    not_isolated = {
        "compaction": "no number of its own: the shadow rays' compaction (jnp.nonzero into the buffer) is in 'shadows', "
                      "the dead lanes' prefix sum and merges in 'loop_other'",
        "xla_while_loop": "no number of its own: the chunk's fori_loop is in 'loop_other', the traversal's fixed-trip cell "
                          "loop in 'traversal', the shadow passes' while_loop in 'shadows'",
        "tallies": "no number of its own: in 'loop_other' (by difference)",
    }
    caveats = {
        "separate_calls": "each stage is its own jit call, which XLA compiles and fuses on its own: parts need not add up "
                          "to their whole exactly, and 'other_shading' and 'loop_other' are differences",
        "brdf": "timed on the lanes' directions in the paint frame (platelets lie near horizontal), with the calls "
                "`_step_one` makes (`counts.brdf_calls_per_lane_step`), for every lane as the branchless step does",
        "traversal": "timed with the step's slab limit and cell budget (`_step_kinds`); the hit's index and image shift, "
                     "which the shading then reads, may be left out as unused",
        "full_step": "the loop's chunks after the first `warm_calls` whose pool stayed full (every dead lane refilled), as "
                     "in the snapshot; 'loop_all_steps' is the loop's whole time per step, the drain of the pool included",
    }
    full = seconds["full_step"]
    return {
        "seconds": seconds,
        "quartiles": quartiles,
        "call_overhead": call,
        "fractions": {k: v / full for k, v in seconds.items()},
        "labels": dict(PROFILE_STAGES),
        "parents": dict(PROFILE_PARENTS),
        "not_isolated": not_isolated,
        "caveats": caveats,
        "counts": counts,
        "lanes": lanes,
        "devices": ndev,
        "repeats": repeats,
        "warm_calls": warm_calls,
        "rays": target * ndev,
        "loop_calls": calls,
        "loop_steps": steps,
        "loop_steady_calls": len(steady[0]),
        "steps_per_call": opt.steps_per_call,
        "bidirectional": bool(sc.bidir),
        "mis": bool(sc.mis),
        "dtype": jnp.dtype(cdt).name,
        "platform": devices[0].platform,
    }
