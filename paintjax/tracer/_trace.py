"""Ray-batch Monte Carlo tracer of a platelet basecoat under a flat or wavy clearcoat: the virtual spectrophotometer.

Scene (paint frame, lengths in µm, brief §3/§7): Lambertian primer at z = 0 (albedo ρ), basecoat
0 < z < h_b holding the platelet boxes of a `PlateletArray` (laterally periodic tile, looked up
through its `UniformGrid`), clearcoat h_b < z < h_b + h_c of the binder's index n, air above.

Transport.
* A collimated beam (optionally a uniform cone of half-angle `illumination_aperture_deg`) enters
  at a uniformly random point of the tile with the flat-interface Fresnel transmittance T_i as a
  deterministic weight; the reflected 1 − T_i goes to the ledger's top reflection.
* Straight rays in the binder. The clearcoat has no scatterers: it is crossed in closed form
  (lateral shift h_c tanθ), so the grid only spans the basecoat.
* At the clearcoat–air interface from inside, the weight is split deterministically: (1 − R)
  leaves (scored by the histogram estimator), R is reflected back (R = 1 under total internal
  reflection above 41.8° for n = 1.5).
* Optional clearcoat waviness (`waviness_deg`, RMS slope angle; `paintjax.optics._interface`): every crossing of
  the surface (entry, internal reflection / exit, and each NEE direction) happens at a facet drawn
  from the visible-normal density of the Gaussian slope distribution (exact inversion, weight 1;
  NEE draws from the slope distribution with the visible-area weight v, which carries Smith's
  masking G1). Reflection and refraction are about the facet; an internal reflection that would
  still travel upward (grazing, rare) is mirrored down (multiple facet scattering and the masking
  of exits are neglected: at grazing detectors exits exceed NEE by about 1/G1, see `paintjax.optics._interface`). Off by default.
* Platelet boxes (centre ± w/2 u ± w/2 v ± t/2 n) are intersected with a slab test. The face
  through which a ray enters decides the scattering normal: the top and bottom faces scatter with
  the platelet BRDF (importance sampled, weight f cos/pdf; the weight lost is the platelet
  absorption). **Edges**: a ray entering through one of the four side faces (area t·w each, a few
  per cent of the hits for t = 1 µm, w ≈ 16 µm) is scattered by the same BRDF about that side
  face's outward normal, i.e. the side walls are aluminium too. Rays starting inside a box (only
  possible where boxes overlap or stick out of the basecoat) pass through it; box parts above h_b
  or below 0 are not seen.
* Lambertian primer at z = 0: weight × ρ, cosine-sampled new direction.
* Russian roulette below a weight threshold; a cap on the steps per ray (counted in the ledger).
* Optional random azimuthal rotation of the whole instrument per ray (an average over rotated
  copies of the tile, which is statistically isotropic): it multiplies the platelet orientations
  a finite tile offers, which matters for narrow platelet lobes.

Estimators (reflectance factor R = π L / E, brief §3).
* Next-event estimation: at every scattering event and for every detector, the non-delta part of
  the BRDF (Lambert for the primer) toward the detector's refracted internal direction ω_j (a
  uniform random direction of the detector's aperture cone when it is finite), a shadow ray to
  the top of the basecoat through the grid, the exit transmittance T_o and the n² radiance
  change: R_j += π w f cos V T_o / (n² cosθ_j) (wavy coat: T_o → v_j T(m_j) and ω_j the refraction
  of the detector direction at a facet m_j drawn for this event). Contributions below `shadow_roulette` go through
  an unbiased roulette, so most negligible shadow rays are never traced.
  Delta parts (mirror platelets, or a BRDF's coherent part with `coherent="delta"`) have no
  finite value: a path whose last event was a delta reflection is scored when it exits, into
  each finite detector aperture (the splat of the deterministic direction), so such BRDFs need
  a finite `detector_aperture_deg`; for pure mirrors the NEE and histogram columns coincide.
* Histogram: exiting weight landing inside a detector's cone of half-angle α,
  R_j += π w_exit / (Ω cosθ_air), Ω = 2π(1 − cos α). Both estimate the cone-averaged radiance.
* Multiple importance sampling (finite cones, flat coat, `TracerOptions.mis`, default on): the
  reported estimate combines NEE (density 1/Ω over the cone) with the BRDF-sampled exits into the
  cone (density q · cosθ_air / (n² cosθ_in), q the platelet BRDF's or the primer's sampling pdf)
  by the balance heuristic, so narrow lobes are scored by whichever strategy finds them; the
  histogram column stays the plain histogram. Point detectors: NEE alone.
* Bidirectional MIS (point detectors, collimated beam, flat coat, `TracerOptions.reverse_share`,
  by default reverse rays only for the detectors far from specular, `REVERSE_SHARE_BY_ASPECULAR`): forward NEE sees a narrow platelet lobe (the coherent diffraction lobe) lit by
  diffuse light (primer, rough lobes) only in rare large spikes; traced from the detector's side
  the same path samples the lobe and closes at the diffuse vertex. Each detector j with a share c_j > 0 gets a reverse
  pass (source at ω_j, one detector at the source: the paint BRDF is reciprocal) and both passes
  weight their NEE by the balance heuristic. For a path x_1 … x_k the ratio of the reverse to the
  forward path density is ρ = (cos_k,j |z_L|)/(cos_1,in |z_j|) · Π_{i≥2} q̃_rev,i / Π_{i<k} q̃_fwd,i
  (q̃ = sampling density per projected solid angle; the beams are uniform over the tile, so their
  projected-area densities give the cosines and the geometric terms cancel); each ray carries the
  running log-ratio, the forward weight is 1/(1 + c_j ρ) (c_j = reverse / forward rays) and the reverse
  pass computes the same for 1/ρ, so the weights sum to one path by path, whatever the densities.
  Paths with a narrow lobe at both ends stay spiky either way.
* Standard errors by batch means over groups of lanes (batch b of every pass summed); L* errors by
  the delta method.
* Energy ledger per incident unit: top reflection + exited + absorbed by platelets + absorbed by
  primer + roulette (net, zero in expectation) + caps = 1 exactly, ray by ray.

Wavefront design. A fixed pool of lanes advances in jit-compiled chunks of `steps_per_call`
steps; a step moves every ray by one event or by at most `cells_per_step` grid cells (3-D DDA,
periodic in x, y; slab tests written per component over per-column gathers, the hot loop). A
lane whose ray has ended is refilled at the next step with the next ray id (prefix sum over the
dead lanes), so lanes stay busy until the pool drains. Shadow rays are deferred by one step:
the active ones of all lanes are compacted into a buffer and traced together (any-hit, in legs of
`shadow_leg_cells` cells; a ray not yet decided resumes in the next pass, recompacted), so their
cost follows the number of useful shadow rays and the cells they really cross, not lanes ×
detectors × the cells to the top. Shapes are static and padded to buckets, and the grid dimensions
are traced values: no recompilation between calls or between similar arrays. Each ray draws its random numbers from a counter-based hash of
(seed, ray id, step) (an integer finaliser, far cheaper to compile and run than threefry per
lane), so the result depends on the seed only, not on the schedule or the device count.
The lanes are split over all local devices with `shard_map`.
"""

from __future__ import annotations

import dataclasses
import time
import warnings
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, PartitionSpec

from .._progress import Heartbeat
from ..brdf._platelet import AbstractPlateletBRDF, MirrorBRDF
from ..instrument._geometry import Geometry
from ..instrument._lightness import reflectance_factor_to_lightness
from ..instrument._single_scatter import check_coat_index, check_platelet_medium
from ..microstructure._grid import build_grid
from ..optics._interface import check_waviness
from ._options import _MAX_GROWTH, LEDGER_KEYS, MAX_CREATED_ENERGY, EnergyCreationError, TracerOptions, detector_reverse_shares
from ._path import _has_delta, _new_ray, _new_ray_uniforms, _ray_hash, _shadows, _source, _step_one, _uniforms
from ._result import TraceResult, resolved_detectors
from ._scene import _Scene, build_scene

# Wavefront driver (one device); shard_map spreads the lanes over devices


def _to_columns(sc: _Scene, rid, x):
    """Per-detector tallies (lanes, m) → output columns: the detectors themselves for one source,
    the ray's source for several (the reverse pool, m = 1: source j scores detector j's column)."""
    P = sc.illum_air.shape[0]
    if P == 1:
        return x
    return jnp.where(jnp.arange(P)[None, :] == _source(sc, rid)[:, None], x[:, :1], 0.0)


def _chunk_device(sc: _Scene, key, state, n_local, single, *, opt: TracerOptions):
    """`steps_per_call` wavefront steps on one device's lanes (refill dead lanes, step all)."""
    ndev = jax.lax.psum(1, "rays")
    dev = jax.lax.axis_index("rays")
    idt = state[2].dtype

    def one_step(_, st):
        rays, tally, next_local = st
        pos, d, w, alive, cph, sph, nstep, nev, rid, spec, q_last, lg, *sh = rays
        dtype = pos.dtype
        nee = _to_columns(sc, rid, _shadows(sc, opt, *sh))  # before the refill: rid is still the shadow rays' ray
        dead = ~alive
        rank = jnp.cumsum(dead.astype(idt)) - 1
        local_id = next_local[0] + rank
        start = dead & (local_id < n_local)
        rid = jnp.where(start, local_id * ndev + dev, rid)
        ug = jax.vmap(lambda r: _uniforms(_ray_hash(key, r, jnp.asarray(0x7FFFFFFF, jnp.uint32)), _new_ray_uniforms(sc), dtype))(rid)
        p0, d0, w0, r0, c0, s0 = jax.vmap(lambda uu, r: _new_ray(sc, uu, dtype, opt.randomize_azimuth, _source(sc, r)))(ug, rid)
        col = start[:, None]
        pos, d = jnp.where(col, p0, pos), jnp.where(col, d0, d)
        w, cph, sph = jnp.where(start, w0, w), jnp.where(start, c0, cph), jnp.where(start, s0, sph)
        nstep = jnp.where(start, 0, nstep)
        nev = jnp.where(start, 0, nev)
        spec = spec & ~start
        alive = alive | start
        next_local = next_local + jnp.sum(start).astype(idt)
        m_out = (tally.shape[1] - len(LEDGER_KEYS)) // 3  # tally: NEE, histogram, ledger, rays (per output column)
        counts = jnp.broadcast_to(_to_columns(sc, rid, jnp.ones((rid.shape[0], 1), tally.dtype)), (rid.shape[0], m_out))
        t_start = jnp.zeros_like(tally).at[:, 2 * m_out].set(r0.astype(tally.dtype)).at[:, -m_out:].set(counts)
        tally = tally + jnp.where(col, t_start, 0.0)
        tally = tally.at[:, : nee.shape[1]].add(nee.astype(tally.dtype))
        kstep = jax.vmap(lambda r, t: _ray_hash(key, r, t))(rid, nstep)
        rays = (pos, d, w, alive, cph, sph, nstep, nev, rid, spec, q_last, lg, *sh)
        rays, inc = jax.vmap(lambda r, k: _step_one(sc, opt, r, k, single))(rays, kstep)
        m, nl = sc.det_air.shape[0], len(LEDGER_KEYS)
        inc = jnp.concatenate([_to_columns(sc, rid, inc[:, :m]), _to_columns(sc, rid, inc[:, m : 2 * m]), inc[:, 2 * m : 2 * m + nl],
                               jnp.zeros((rid.shape[0], m_out), inc.dtype)], axis=1)
        return rays, tally + inc.astype(tally.dtype), next_local

    return jax.lax.fori_loop(0, opt.steps_per_call, one_step, state)


_RUNNERS: dict = {}


def _kernel_options(opt: TracerOptions) -> TracerOptions:
    """`opt` with the fields that only the host reads (scene flags, dtype choice, batch summaries) set
    to fixed values, so that runs differing only in them share one compiled wavefront kernel."""
    return dataclasses.replace(opt, batches=opt.lanes, float64=False, mis=True, reverse_share=0.5)


def _runner(mesh: Mesh, opt: TracerOptions):
    opt = _kernel_options(opt)
    key = (mesh, opt)
    if key not in _RUNNERS:
        spec = PartitionSpec("rays")
        rep = PartitionSpec()
        fn = jax.shard_map(
            lambda sc, k, st, n, single: _chunk_device(sc, k, st, n, single, opt=opt),
            mesh=mesh,
            in_specs=(rep, rep, spec, rep, rep),
            out_specs=spec,
            check_vma=False,
        )
        _RUNNERS[key] = jax.jit(fn, donate_argnums=(2,))
    return _RUNNERS[key]


def _initial_state(lanes_total: int, ndev: int, m: int, m_out: int, dtype, tdtype, idt):
    z = lambda *s, t=dtype: jnp.zeros(s, t)  # noqa: E731
    L = lanes_total
    rays = (z(L, 3), z(L, 3), z(L), jnp.zeros(L, bool), z(L), z(L), jnp.zeros(L, jnp.int32), jnp.zeros(L, jnp.int32),
            jnp.zeros(L, idt), jnp.zeros(L, bool), z(L), z(L), z(L, 3), jnp.zeros((L, m, 3), dtype).at[..., 2].set(1.0), z(L, m), z(L, m))
    tally = z(L, 3 * m_out + len(LEDGER_KEYS), t=tdtype)
    return rays, tally, jnp.zeros(ndev, idt)


# ----------------------------------------------------------------------------------------------
# Public entry point


def _seed_state(seed) -> int:
    try:
        s = int(seed)
    except (TypeError, ValueError):
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}") from None
    if s < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    x = (s * 0x9E3779B97F4A7C15 + 0x2545F491) & 0xFFFFFFFFFFFFFFFF
    return (x ^ (x >> 29) ^ (x >> 47)) & 0xFFFFFFFF


#: Most rays one trace call accepts (≈ 9 h at 30k rays/s on 2 CPU cores).
MAX_RAYS = 1_000_000_000


def check_ray_count(rays, options: TracerOptions | None = None, name: str = "rays") -> None:
    """At least one ray per batch of the batch-means standard error (`TracerOptions.batches`), at most `MAX_RAYS`."""
    batches = (options or TracerOptions()).batches
    try:
        n = int(rays)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be an integer, got {rays!r}") from None
    if n < batches:
        raise ValueError(f"{name} must be at least {batches} (one per batch of the standard error), got {rays!r}")
    if n > MAX_RAYS:
        raise ValueError(f"{name} must be at most {MAX_RAYS:,} (≈ 9 h at 30k rays/s); split the work into runs with different seeds, got {rays!r}")


def _check_range(name, value, lo, hi, lo_open=False):
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    bad = not np.isfinite(v) or v > hi or (v <= lo if lo_open else v < lo)
    if bad:
        lb = "(" if lo_open else "["
        raise ValueError(f"{name} must lie in {lb}{lo:g}, {hi:g}], got {value!r}")
    return v


def _summarise(tally: np.ndarray, m: int, batches: int):
    """Estimates, batch-means SE, per-batch estimates, energy ledger and rays per column of one pass."""
    lanes = tally.shape[0]
    nl = len(LEDGER_KEYS)
    groups = tally.reshape(lanes // batches, batches, -1).sum(axis=0)  # lane l -> batch l mod B
    counts = groups[:, -m:]  # rays per batch and output column (the reverse pool: per source)
    total = tally.sum(axis=0)
    N = np.maximum(total[-m:], 1.0)
    est = total[: 2 * m] / np.tile(N, 2)
    per_batch = groups[:, : 2 * m] / np.tile(np.maximum(counts, 1.0), 2)
    wgt = np.tile(counts / np.maximum(np.mean(counts, axis=0), 1e-300), 2)
    se = np.sqrt(np.sum((wgt * (per_batch - est)) ** 2, axis=0) / (batches * (batches - 1)))
    ledger = total[2 * m : 2 * m + nl] / N[0]
    return est, se, per_batch, ledger, total[-m:]


def _combine(parts, m: int):
    """Forward pass + reverse pool (column j = source j = detector j): estimates, SE (independent
    passes add in quadrature), per-batch sums, the forward pass's energy ledger, rays of all passes."""
    est, se, per_batch, ledger, n = parts[0]
    est, per_batch, var, rays = est.copy(), per_batch.copy(), se**2, int(n[0])
    for e, s, pb, _, n in parts[1:]:
        est[:m] += e[:m]
        per_batch[:, :m] += pb[:, :m]
        var[:m] += s[:m] ** 2
        rays += int(n.sum())
    return est, np.sqrt(var), per_batch, ledger, rays


def lightness_with_se(R, se):
    """L* of reflectance factors and its standard error by the delta method (NumPy)."""
    R = np.asarray(R, dtype=float)
    L = np.asarray(reflectance_factor_to_lightness(jnp.asarray(R)))
    dL = np.asarray(jax.vmap(jax.grad(lambda r: reflectance_factor_to_lightness(r)))(jnp.asarray(np.maximum(R, 1e-12)).reshape(-1))).reshape(R.shape)
    return L, np.abs(dL) * np.asarray(se)


def _reverse_shares(opt: TracerOptions, geometry: Geometry, brdf, waviness_deg: float) -> np.ndarray:
    """Reverse rays per forward ray and detector (rounded, `detector_reverse_shares`). Bidirectional MIS needs
    delta directions at both ends (collimated beam, point detectors), a flat coat and a BRDF without a delta
    part; elsewhere the shares are 0 and the tracer runs forward alone."""
    m = geometry.num_detectors
    if (geometry.detector_aperture_deg == 0 and geometry.illumination_aperture_deg == 0 and not waviness_deg > 0
            and not _has_delta(brdf)):
        return detector_reverse_shares(opt.reverse_share, m, np.asarray(geometry.aspecular_deg, dtype=float))[0]
    return np.zeros(m)


def trace(
    array,
    geometry: Geometry,
    brdf: AbstractPlateletBRDF | None = None,
    *,
    grid=None,
    n: float = 1.5,
    clearcoat_thickness: float = 50.0,
    primer_albedo: float = 0.3,
    waviness_deg: float = 0.0,
    rays: int = 262144,
    seed: int = 0,
    single_scatter: bool = False,
    target_se_lstar: float | None = None,
    max_rays: int | None = None,
    options: TracerOptions | None = None,
    progress: Callable[[int, np.ndarray, float], None] | None = None,
    heartbeat: Callable[[float, float], None] | None = None,
) -> TraceResult:
    """Trace rays through a platelet basecoat under a flat or wavy clearcoat; reflectance factor and L* per detector.

    Arguments:
        array: `PlateletArray` (centres, normals, axes_u, widths, thickness, tile, basecoat_thickness).
        geometry: instrument geometry (`ma98_geometry`, `custom_geometry`); delta platelet BRDFs
            need a finite `detector_aperture_deg`.
        brdf: platelet BRDF (default: aluminium mirror in the binder).
        grid: `UniformGrid` of the array (default: `build_grid(array)`).
        n: clearcoat / binder index in (1, 3].
        clearcoat_thickness: h_c in µm (≥ 0).
        primer_albedo: Lambertian primer albedo ρ in [0, 1].
        waviness_deg: RMS slope angle of a wavy clearcoat surface in [0, 15]° (0: flat; see `paintjax.optics._interface`).
        rays: number of rays, over all passes (bidirectional: 1 + Σ_j `reverse_share`_j rays per
            forward ray; each pass rounded up to a multiple of the device count, so a few more
            than asked: `TraceResult.rays` is the count traced).
        seed: random seed; the result depends on it and on `options`, not on the schedule.
        single_scatter: score only the first scattering event of each path.
        target_se_lstar: if given, keep adding rays until the L* standard error is at most this at
            every detector and every detector is resolved (`resolved_detectors`), or `max_rays` is reached; `rays` is then the first round, and each
            round at most quadruples the rays.
        max_rays: ceiling for `target_se_lstar` (default 64 × rays; rounded up per pass like `rays`).
        options: `TracerOptions`.
        progress: called after every round as `progress(rays, L_star_se, seconds)` (rays traced so
            far, the L* standard errors per detector, seconds since tracing began); None: silent.
        heartbeat: called every `paintjax._progress.HEARTBEAT_SECONDS` inside a round as `heartbeat(fraction
            of the round's rays started, seconds since tracing began)`, for a progress line with an ETA.

    Returns:
        A `TraceResult`. Warns (RuntimeWarning) when light reached a detector in fewer than half the
        batches: its L* and standard error are then not resolved (`TraceResult.resolved`).
    """
    check_coat_index(n)
    _check_range("primer_albedo", primer_albedo, 0.0, 1.0)
    _check_range("clearcoat_thickness", clearcoat_thickness, 0.0, 1e4)
    waviness_deg = check_waviness(waviness_deg)
    opt = options or TracerOptions()
    check_ray_count(rays, opt)
    if target_se_lstar is not None:
        _check_range("target_se_lstar", target_se_lstar, 0.0, 100.0, lo_open=True)
        if max_rays is not None and int(max_rays) < int(rays):
            raise ValueError(f"max_rays must be at least the first round's rays ({int(rays)}), got {max_rays!r}")
        if max_rays is not None:
            check_ray_count(max_rays, opt, "max_rays")
    brdf = MirrorBRDF(n_binder=n) if brdf is None else brdf
    if not isinstance(brdf, AbstractPlateletBRDF):
        raise ValueError(f"brdf must be an AbstractPlateletBRDF, got {type(brdf).__name__}")
    check_platelet_medium(brdf, n)
    if _has_delta(brdf) and geometry.detector_aperture_deg <= 0:
        raise ValueError("geometry.detector_aperture_deg must be > 0 for a platelet BRDF with a delta (mirror or "
                         "coherent='delta') part: a delta sends nothing into an exact direction")
    if grid is None:
        grid = build_grid(array)
    if bool(np.asarray(getattr(grid, "overflow", False))):
        raise ValueError("grid.overflow is set: some cell exceeded its capacity; rebuild the grid with a larger capacity")
    cdt = jnp.float64 if (opt.float64 and jax.config.jax_enable_x64) else jnp.float32
    m = geometry.num_detectors
    shares = _reverse_shares(opt, geometry, brdf, waviness_deg)  # all 0: the forward tracer alone
    common = dict(n=n, clearcoat_thickness=clearcoat_thickness, primer_albedo=primer_albedo, waviness_deg=waviness_deg,
                  dtype=cdt, min_cells=opt.cells_per_step, mis=opt.mis)
    # the forward pass (all detectors) and, bidirectionally, the reverse pool: every detector becomes a
    # source whose one detector is the illumination (reciprocity), its share of rays per forward ray
    passes = [(build_scene(array, geometry, brdf, grid, reverse_share=shares, **common), 1.0)]
    if shares.any():
        passes.append((build_scene(array, geometry, brdf, grid, reverse_share=shares, reverse=True, **common), float(shares.sum())))
    devices = jax.local_devices()
    ndev = len(devices)
    mesh = Mesh(np.array(devices), ("rays",))
    lanes_total = opt.lanes * ndev
    idt = jnp.int64 if jax.config.jax_enable_x64 else jnp.int32
    dtype = jnp.result_type(float)
    run = _runner(mesh, opt)
    from jax.sharding import NamedSharding

    lanes_sharding = NamedSharding(mesh, PartitionSpec("rays"))
    replicated = NamedSharding(mesh, PartitionSpec())
    put = lambda x: jax.device_put(x, replicated)  # noqa: E731
    single = put(jnp.asarray(bool(single_scatter)))
    seed_state = _seed_state(seed)
    live = []  # per pass: scene, key, state, fraction of the forward rays
    for p, (sc, frac) in enumerate(passes):
        key = put(jnp.asarray(np.uint32(seed_state ^ ((0x9E3779B9 * p) & 0xFFFFFFFF))))
        state = jax.device_put(_initial_state(lanes_total, ndev, sc.det_air.shape[0], m, cdt, dtype, idt), lanes_sharding)
        live.append([put(sc), key, state, frac])
    per_forward = sum(frac for _, frac in passes)  # rays of all passes per forward ray
    n_local = -(-int(np.ceil(int(rays) / per_forward)) // ndev)
    limit_local = -(-int(np.ceil(int(max_rays if max_rays is not None else 64 * int(rays)) / per_forward)) // ndev)
    t0 = time.perf_counter()
    pulse = Heartbeat(heartbeat) if heartbeat is not None else None
    while True:
        parts = []
        for item in live:
            sc, key, state, frac = item
            target = max(int(np.ceil(frac * n_local)), -(-sc.wheel.shape[0] // ndev))  # every source with a share gets rays
            nl = put(jnp.asarray(target, idt))
            while True:
                state = run(sc, key, state, nl, single)
                busy = bool(jnp.any(state[0][3]) | jnp.any(state[0][-1] != 0))
                if not busy and int(jnp.min(state[2])) >= target:
                    break
                if pulse is not None and pulse.due():  # the count read only then
                    pulse(min(int(jnp.min(state[2])), target) / target)
            item[2] = state
            parts.append(_summarise(np.asarray(state[1], dtype=float), m, opt.batches))
        est, se, per_batch, ledger, N = _combine(parts, m)
        L, Lse = lightness_with_se(est[:m], se[:m])
        if progress is not None:
            progress(int(N), np.asarray(Lse), time.perf_counter() - t0)
        if target_se_lstar is None:
            break
        # a detector that most batches missed is not converged, whatever its (unreliable) SE
        worst = float(np.max(np.where(resolved_detectors(per_batch[:, :m]), Lse / target_se_lstar, np.inf)))
        if worst <= 1.0 or n_local >= limit_local:
            break
        # rays for the target from this round's SE, at most _MAX_GROWTH× per round: a rare spike in an
        # early, small round inflates its SE estimate, and an uncapped step would overshoot on it
        grow = int(np.ceil(n_local * min(worst**2 * 1.1 - 1.0, _MAX_GROWTH - 1.0)))
        n_local = min(limit_local, n_local + max(grow, opt.lanes))
    seconds = time.perf_counter() - t0
    created = -float(ledger[LEDGER_KEYS.index("absorbed_platelets")])
    # no significance test: creation makes the estimate heavy-tailed (path weights grow per bounce), so
    # its SE is no guide; a lossy BRDF's net absorption is positive, a lossless one's exactly 0
    if not np.all(np.isfinite(ledger)) or created > MAX_CREATED_ENERGY:
        raise EnergyCreationError(
            f"brdf creates energy: the platelets return {created:.3g} of the incident flux more than they "
            f"receive (allowed: {MAX_CREATED_ENERGY:g}), so its albedo exceeds 1 somewhere (an unconverged wave table, or the "
            "Kirchhoff approximation at grazing incidence); the result would be unphysical")
    R, Rse = est[:m], se[:m]  # L, Lse: the last round's
    if target_se_lstar is not None and not (np.all(Lse <= target_se_lstar) and np.all(resolved_detectors(per_batch[:, :m]))):
        warnings.warn(f"the L* standard error target {target_se_lstar:g} was not reached within max_rays ({int(N)} rays traced): "
                      f"worst SE {float(np.max(Lse)):.3g}", RuntimeWarning, stacklevel=2)
    ok = resolved_detectors(per_batch[:, :m])
    if not np.all(ok):
        hits = np.count_nonzero(per_batch[:, :m], axis=0)
        where = ", ".join(f"{g:g}° ({h} of {per_batch.shape[0]} batches)" for g, h, o in
                          zip(np.asarray(geometry.aspecular_deg, dtype=float), hits, ok) if not o)
        warnings.warn(f"light reached these detectors in fewer than half the batches: {where}; their L* and standard "
                      f"errors are not resolved after {int(N)} rays: trace more rays", RuntimeWarning, stacklevel=2)
    return TraceResult(
        aspecular_deg=np.asarray(geometry.aspecular_deg, dtype=float),
        reflectance_factor=R,
        reflectance_factor_se=Rse,
        L_star=L,
        L_star_se=Lse,
        histogram_reflectance_factor=est[m:],
        histogram_se=se[m:],
        energy={k: float(v) for k, v in zip(LEDGER_KEYS, ledger)},
        rays=N,
        seconds=seconds,
        batch_reflectance_factor=per_batch[:, :m],
        batch_histogram=per_batch[:, m:],
    )
