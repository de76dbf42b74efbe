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
* Optional clearcoat waviness (`waviness_deg`, RMS slope angle; `_interface`): every crossing of
  the surface (entry, internal reflection / exit, and each NEE direction) happens at a facet drawn
  from the visible-normal density of the Gaussian slope distribution (exact inversion, weight 1;
  NEE draws from the slope distribution with the visible-area weight v, which carries Smith's
  masking G1). Reflection and refraction are about the facet; an internal reflection that would
  still travel upward (grazing, rare) is mirrored down (multiple facet scattering and the masking
  of exits are neglected: at grazing detectors exits exceed NEE by about 1/G1, see `_interface`). Off by default.
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
  default 0.5): forward NEE sees a narrow platelet lobe (the coherent diffraction lobe) lit by
  diffuse light (primer, rough lobes) only in rare large spikes; traced from the detector's side
  the same path samples the lobe and closes at the diffuse vertex. Each detector j gets a reverse
  pass (source at ω_j, one detector at the source: the paint BRDF is reciprocal) and both passes
  weight their NEE by the balance heuristic. For a path x_1 … x_k the ratio of the reverse to the
  forward path density is ρ = (cos_k,j |z_L|)/(cos_1,in |z_j|) · Π_{i≥2} q̃_rev,i / Π_{i<k} q̃_fwd,i
  (q̃ = sampling density per projected solid angle; the beams are uniform over the tile, so their
  projected-area densities give the cosines and the geometric terms cancel); each ray carries the
  running log-ratio, the forward weight is 1/(1 + cρ) (c = reverse / forward rays) and the reverse
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
the active ones of all lanes are compacted into a buffer and traced together (any-hit, with a
cell budget that reaches the top within the flat coat's critical angle; a wavy coat's steeper
rays resume in later passes), so their cost follows the number of useful shadow
rays, not lanes × detectors. Shapes are static and padded to buckets, and the grid dimensions
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

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, PartitionSpec
from jaxtyping import Array, Float, Int

from ._brdf import AbstractPlateletBRDF, MirrorBRDF, cosine_hemisphere
from ._grid import build_grid, check_grid_matches
from ._instrument import Geometry, refract_into_coat
from ._lightness import reflectance_factor_to_lightness
from ._interface import check_waviness, reflect, refract, sample_facet_normal, sample_visible_facet, seen_through_facet, slope_sd
from ._microfacet import _orthonormal_basis, check_coat_index, check_platelet_medium
from ._optics import fresnel_dielectric

#: Keys of the energy ledger, in order.
LEDGER_KEYS = ("top_reflection", "exited", "absorbed_platelets", "absorbed_primer", "roulette", "caps")
_BIG = 1e30
_MAX_GROWTH = 4.0  # adaptive rounds grow the rays at most this factor

#: Largest net energy (fraction of the incident flux) the platelets may create, i.e. negative
#: platelet absorption in the ledger, before `trace` refuses the result (`EnergyCreationError`).
MAX_CREATED_ENERGY = 0.01


class EnergyCreationError(ValueError):
    """The platelet BRDF returned more light than it received (its albedo exceeds 1 somewhere)."""


class TracerOptions(eqx.Module):
    """Performance and estimator settings of `trace` (all static).

    Arguments:
        lanes: rays in flight per device.
        steps_per_call: steps per jit call (a step = one event or `cells_per_step` cells).
        cells_per_step: grid cells a ray may cross per step (≥ 2). Shadow rays get as many cells
            as a ray toward any detector through a flat coat can cross in the basecoat
            (`_shadow_cell_bound`); a wavy coat's steeper ones resume where they stopped.
        batches: groups of lanes for the batch-means standard errors (≥ 8).
        roulette_weight: Russian roulette below this weight (0 disables roulette).
        max_steps: steps after which a ray is capped (its weight goes to the ledger's caps).
        randomize_azimuth: rotate the instrument by a random azimuth per ray.
        shadow_roulette: NEE contributions (reflectance-factor units per ray) below this are kept
            with probability value/threshold and raised to it (unbiased; 0 disables).
        shadow_buffer: shadow rays traced per pass, as a fraction of lanes × detectors; active
            shadow rays are compacted into this buffer (more passes run when it overflows).
        edges: "scatter" (default): a ray entering a platelet through a side face is scattered by
            the platelet BRDF about that face's normal (aluminium side walls); "absorb": side
            faces absorb (dark, broken edges; also the thin-platelet limit of the analytic model).
        mis: with finite detector apertures and a flat coat, combine NEE with the BRDF-sampled
            exits into each aperture by multiple importance sampling (balance heuristic);
            False: NEE alone (the histogram is always reported on its own as well).
        reverse_share: bidirectional MIS where both ends are delta directions (collimated beam,
            point detectors, flat coat, BRDF without a delta part): per detector a reverse pass
            (reciprocity: the detector is the source, the source the only detector) traces this
            many rays per forward ray, and the NEE of both passes is weighted by the balance
            heuristic over their path densities. 0: the forward tracer alone. It relies on
            reciprocity: of the platelet BRDF (all of paintjax's are) and of the scene, which
            overlapping boxes break (a ray starting inside a box passes through it, one arriving
            from outside does not), so arrays should be overlap-free (`array_statistics`).
        float64: trace in float64 when x64 is enabled (default float32 geometry, which is ample
            for µm-scale boxes in a sub-mm tile and twice as fast; tallies are float64 under x64).

    `batches`, `float64`, `mis` and `reverse_share` are read on the host only (scene flags, dtypes,
    summaries): the compiled kernel is cached without them (`_kernel_options`), so it must not read them.
    """

    lanes: int = eqx.field(static=True, default=2048)
    steps_per_call: int = eqx.field(static=True, default=16)
    cells_per_step: int = eqx.field(static=True, default=3)
    batches: int = eqx.field(static=True, default=32)
    roulette_weight: float = eqx.field(static=True, default=0.05)
    max_steps: int = eqx.field(static=True, default=1000)
    randomize_azimuth: bool = eqx.field(static=True, default=True)
    float64: bool = eqx.field(static=True, default=False)
    shadow_roulette: float = eqx.field(static=True, default=0.02)
    shadow_buffer: float = eqx.field(static=True, default=0.25)
    edges: str = eqx.field(static=True, default="scatter")
    mis: bool = eqx.field(static=True, default=True)
    reverse_share: float = eqx.field(static=True, default=0.5)

    def __check_init__(self):
        for name, v, lo in (("lanes", self.lanes, 1), ("steps_per_call", self.steps_per_call, 1),
                            ("cells_per_step", self.cells_per_step, 2), ("batches", self.batches, 8),
                            ("max_steps", self.max_steps, 1)):
            if int(v) < lo:
                raise ValueError(f"{name} must be an integer >= {lo}, got {v!r}")
        if self.lanes % self.batches:
            raise ValueError(f"lanes ({self.lanes}) must be a multiple of batches ({self.batches})")
        if not (0.0 <= self.shadow_roulette < 10.0):
            raise ValueError(f"shadow_roulette must lie in [0, 10), got {self.shadow_roulette!r}")
        if not (0.0 < self.shadow_buffer <= 1.0):
            raise ValueError(f"shadow_buffer must lie in (0, 1], got {self.shadow_buffer!r}")
        if self.edges not in ("scatter", "absorb"):
            raise ValueError(f"edges must be 'scatter' or 'absorb', got {self.edges!r}")
        if not (0.0 <= self.reverse_share <= 16.0):
            raise ValueError(f"reverse_share must lie in [0, 16], got {self.reverse_share!r}")
        if not (0.0 <= self.roulette_weight < 1.0):
            raise ValueError(f"roulette_weight must lie in [0, 1), got {self.roulette_weight!r}")


class TraceResult(eqx.Module):
    """Reflectance factors, L* and the energy ledger of one tracer run (NumPy arrays, per detector).

    `reflectance_factor` is the NEE estimate (for delta platelets: the aperture splat),
    `histogram_reflectance_factor` the finite-aperture histogram of exiting rays (0 for zero
    apertures). Standard errors are batch means over `batches` groups of lanes (bidirectional:
    of each pass, added in quadrature; `batch_reflectance_factor` is then the forward batch plus
    the reverse pool's batch). `rays` counts the rays of all passes; `energy` is per forward ray.
    `resolved` flags, per detector, whether light reached it in at least half the batches.
    """

    aspecular_deg: np.ndarray
    reflectance_factor: np.ndarray
    reflectance_factor_se: np.ndarray
    L_star: np.ndarray
    L_star_se: np.ndarray
    histogram_reflectance_factor: np.ndarray
    histogram_se: np.ndarray
    energy: dict
    rays: int
    seconds: float
    batch_reflectance_factor: np.ndarray  # (batches, m) NEE estimate of each batch
    batch_histogram: np.ndarray  # (batches, m)

    @property
    def resolved(self) -> np.ndarray:
        """Per detector: did light reach it in at least half the batches (`resolved_detectors`)?"""
        return resolved_detectors(self.batch_reflectance_factor)

    def to_dict(self) -> dict:
        """The `paintjax simulate --json` form."""
        return {
            "aspecular_deg": self.aspecular_deg,
            "reflectance_factor": self.reflectance_factor,
            "reflectance_factor_se": self.reflectance_factor_se,
            "L_star": self.L_star,
            "L_star_se": self.L_star_se,
            "energy": dict(self.energy),
            "rays": self.rays,
            "seconds": self.seconds,
            "resolved": self.resolved,
        }


def resolved_detectors(batch_reflectance_factor) -> np.ndarray:
    """Per detector (last axis): True where at least half the batches (first axis) have a nonzero estimate.

    Where most batches saw no light, the estimate rests on a few rare paths and the batch-means
    standard error (even a zero one) says nothing about its error: such an L* is not resolved.
    """
    b = np.asarray(batch_reflectance_factor)
    return 2 * np.count_nonzero(b, axis=0) >= b.shape[0]


# ----------------------------------------------------------------------------------------------
# Scene


class _Scene(eqx.Module):
    cols: tuple  # (cx, cy, cz, ux, uy, uz, nx, ny, nz, w/2), each padded (N_pad,); padding = dummy
    cells: Int[Array, "ncell_pad C_pad"]  # platelet indices, −1 mapped to a dummy entry
    grid_n: Int[Array, "3"]
    cell_size: Float[Array, "3"]
    tile: Float[Array, "2"]
    half_t: Float[Array, ""]
    h_b: Float[Array, ""]
    h_c: Float[Array, ""]
    n: Float[Array, ""]
    albedo: Float[Array, ""]
    eps: Float[Array, ""]
    illum_air: Float[Array, "P 3"]  # P sources; ray r comes from source r mod P (the reverse pool: one per detector)
    illum_cos_alpha: Float[Array, ""]
    det_air: Float[Array, "m 3"]
    det_cos_alpha: Float[Array, ""]
    brdf: AbstractPlateletBRDF
    slope_sd: Float[Array, ""]  # per-component slope sd of a wavy clearcoat (0 = flat)
    log_reverse_share: Float[Array, "m"]  # bidirectional MIS: log(reverse rays / forward rays) per detector (−inf: off)
    illum_in_z: Float[Array, " P"]  # |z| of the refracted source directions (projected-area factor of the beam)
    max_cells: int = eqx.field(static=True)  # budget of a ray's step
    shadow_cells: int = eqx.field(static=True)  # budget of a shadow ray's leg (enough within the flat coat's critical angle)
    wavy: bool = eqx.field(static=True, default=False)  # draw facet normals at the clearcoat surface
    mis: bool = eqx.field(static=True, default=False)  # NEE + BRDF-sampled exits, balance heuristic
    bidir: bool = eqx.field(static=True, default=False)  # NEE weighted against the reverse (detector-side) tracer


def _bucket(x: int, q: int) -> int:
    return max(q, -(-int(x) // q) * q)


def _pack_platelets(array, dtype, n_pad: int) -> tuple:
    c = np.asarray(array.centers, dtype=float).reshape(-1, 3)
    nrm = np.asarray(array.normals, dtype=float).reshape(-1, 3)
    u = np.asarray(array.axes_u, dtype=float).reshape(-1, 3)
    w = np.asarray(array.widths, dtype=float).reshape(-1)
    packed = np.concatenate([c, u, nrm, w[:, None] / 2], axis=-1)
    dummy = np.array([0.0, 0.0, -1e6, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0])  # far below, zero size: never hit
    packed = np.concatenate([packed, np.broadcast_to(dummy, (n_pad - len(c), 10))], axis=0)
    return tuple(jnp.asarray(packed[:, k], dtype) for k in range(packed.shape[1]))


#: Steepest internal direction of a wavy coat's next-event estimate, as tan θ_in. A facet refracts an air
#: direction to at most the critical angle from its normal, so only steep facets reach beyond the flat
#: coat's tan θ_c = 0.894, at vanishing visible weight: at the largest waviness (15°) no weight lay
#: beyond tan 2.84 for a detector at 85°, nor beyond 3.34 at 89.9° (2·10⁷ facets each). Directions
#: beyond are not scored, which bounds a shadow ray's travel and so its resumptions (`_shadows`).
_WAVY_MAX_TAN_IN = 3.5
_WAVY_MIN_COS_IN = float(1.0 / np.sqrt(1.0 + _WAVY_MAX_TAN_IN**2))


def _shadow_cell_bound(shape, cell, h_b, n) -> int:
    """Cells a ray toward any detector through a flat coat crosses at most from inside the basecoat to its top.

    Any air direction refracts to within the critical angle (sin θ_in ≤ 1/n); fixed by that bound, not
    by the geometry, so geometries share a compilation. A wavy coat's steeper directions resume (`_shadows`).
    """
    nz = shape[2]
    sin_in = 1.0 / n
    lateral = h_b * sin_in / np.sqrt(1.0 - sin_in**2)
    return int(nz + int(np.ceil(lateral / cell[0])) + int(np.ceil(lateral / cell[1])) + 1)


# ----------------------------------------------------------------------------------------------
# Geometry helpers (single ray; vmapped by the callers)


def _rotz(v, c, s):
    """Rotate vectors v (..., 3) about z by the angle with cosine c and sine s (c, s broadcast against v[..., 0])."""
    z = jnp.broadcast_to(v[..., 2], jnp.broadcast_shapes(jnp.shape(c), v.shape[:-1]))
    return jnp.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1], z], axis=-1)


def _cone(axis, cos_alpha, u1, u2):
    """Uniform direction in the cap of half-angle α around `axis` (u1, u2 uniform); α = 0 gives axis."""
    c = 1.0 - u1 * (1.0 - cos_alpha)
    s = jnp.sqrt(jnp.clip(1.0 - c * c, 0.0, 1.0))
    phi = 2.0 * jnp.pi * u2
    t1, t2 = _orthonormal_basis(axis)
    return (s * jnp.cos(phi))[..., None] * t1 + (s * jnp.sin(phi))[..., None] * t2 + c[..., None] * axis


def _refract_in(w_air, n):
    t = w_air[..., :2] / n
    return jnp.concatenate([t, jnp.sqrt(jnp.clip(1.0 - jnp.sum(t * t, -1, keepdims=True), 0.0, 1.0))], axis=-1)


def _to_local(w, t1, t2, nrm):
    return jnp.stack([jnp.sum(w * t1, -1), jnp.sum(w * t2, -1), jnp.sum(w * nrm, -1)], axis=-1)


def _slab(q, ox, oy, oz, dx, dy, dz, half_t):
    """Slab test of rays o + t d (o relative to the box centres) against boxes with columns q.

    Written component by component (no reductions over length-3 axes, per-column gathers):
    this is the hot loop. Returns (t_in, t_out, (tn_u, tn_v, tn_n), (d_u, d_v, d_n)).
    """
    ux, uy, uz, nx, ny, nz, hw = q
    vx, vy, vz = ny * uz - nz * uy, nz * ux - nx * uz, nx * uy - ny * ux
    tns, tfs, das = [], [], []
    for ax, ay, az, h in ((ux, uy, uz, hw), (vx, vy, vz, hw), (nx, ny, nz, half_t)):
        oa = ox * ax + oy * ay + oz * az
        da = dx * ax + dy * ay + dz * az
        da = jnp.where(jnp.abs(da) < 1e-15, jnp.where(da >= 0, 1e-15, -1e-15), da)
        inv = 1.0 / da
        t1 = (-h - oa) * inv
        t2 = (h - oa) * inv
        tns.append(jnp.minimum(t1, t2))
        tfs.append(jnp.maximum(t1, t2))
        das.append(da)
    t_in = jnp.maximum(jnp.maximum(tns[0], tns[1]), tns[2])
    t_out = jnp.minimum(jnp.minimum(tfs[0], tfs[1]), tfs[2])
    return t_in, t_out, tns, das


def _gather(sc: _Scene, j):
    return tuple(col.at[j].get(mode="promise_in_bounds") for col in sc.cols)


def _traverse(sc: _Scene, p, d, t_limit, any_hit: bool, max_cells: int):
    """3-D DDA through at most `max_cells` periodic cells from p along d, up to distance t_limit.

    Single ray (vmapped by the callers); `any_hit` stops at the first occluder
    (shadow rays). p may lie in any periodic image of the tile (a hit point, a shadow ray's
    origin): the walk starts from its image in the tile, and the returned shift is relative to p.
    Returns (t_best, index_best, image shift (2,), t_reached, finished). A hit exists when
    t_best < t_limit; `finished` is False when the cell budget ran out before a decision, and the
    ray must resume at p + t_reached d.
    """
    dtype = p.dtype
    gn = sc.grid_n
    nx, ny, nz = gn[0], gn[1], gn[2]
    cs = sc.cell_size
    Lx, Ly = sc.tile[0], sc.tile[1]
    image_x, image_y = Lx * jnp.floor(p[0] / Lx), Ly * jnp.floor(p[1] / Ly)
    px, py, pz = p[0] - image_x, p[1] - image_y, p[2]
    dx, dy, dz = d[0], d[1], d[2]

    def axis_init(pc, dc, c, n):
        small = jnp.abs(dc) < 1e-15
        i = jnp.clip(jnp.floor(pc / c).astype(jnp.int32), 0, n - 1)
        pos_dir = dc >= 0
        step = jnp.where(pos_dir, 1, -1).astype(jnp.int32)
        bnd = (i + pos_dir.astype(jnp.int32)).astype(dtype) * c
        safe = jnp.where(small, 1.0, dc)
        tmax = jnp.where(small, _BIG, (bnd - pc) / safe)
        tdel = jnp.where(small, _BIG, c / jnp.abs(safe))
        return i, step, tmax.astype(dtype), tdel.astype(dtype)

    ix, sx_, tmx, tdx = axis_init(px, dx, cs[0], nx)
    iy, sy_, tmy, tdy = axis_init(py, dy, cs[1], ny)
    iz, sz_, tmz, tdz = axis_init(pz, dz, cs[2], nz)
    dummy = sc.cols[0].shape[0] - 1

    def body(_, carry):
        ix, iy, iz, tmx, tmy, tmz, tb, jb, bsx, bsy, treach, done = carry
        t_exit = jnp.minimum(jnp.minimum(tmx, tmy), tmz)
        flat = (jnp.mod(ix, nx) * ny + jnp.mod(iy, ny)) * nz + jnp.clip(iz, 0, nz - 1)
        cand = sc.cells.at[flat].get(mode="promise_in_bounds")
        qx, qy, qz, *q = _gather(sc, cand)
        shx = Lx * jnp.round(((ix.astype(dtype) + 0.5) * cs[0] - qx) / Lx)
        shy = Ly * jnp.round(((iy.astype(dtype) + 0.5) * cs[1] - qy) / Ly)
        t_in, t_out, _, _ = _slab(q, px - qx - shx, py - qy - shy, pz - qz, dx, dy, dz, sc.half_t)
        ok = (t_in <= t_out) & (t_in > 0.0) & (t_in < tb)
        tt = jnp.where(ok, t_in, _BIG)
        k = jnp.argmin(tt)
        tk = tt[k]
        better = (tk < _BIG) & ~done
        tb = jnp.where(better, tk, tb)
        jb = jnp.where(better, cand[k], jb)
        bsx = jnp.where(better, shx[k], bsx)
        bsy = jnp.where(better, shy[k], bsy)
        finish = done | (t_exit >= t_limit) | (tb <= t_exit)
        if any_hit:
            finish = finish | (tb < t_limit)
        treach = jnp.where(done, treach, jnp.minimum(t_exit, t_limit))
        mx = (tmx <= tmy) & (tmx <= tmz)
        my = ~mx & (tmy <= tmz)
        mz = ~mx & ~my
        go = ~finish
        ix = jnp.where(go & mx, ix + sx_, ix)
        iy = jnp.where(go & my, iy + sy_, iy)
        iz = jnp.where(go & mz, iz + sz_, iz)
        tmx = jnp.where(go & mx, tmx + tdx, tmx)
        tmy = jnp.where(go & my, tmy + tdy, tmy)
        tmz = jnp.where(go & mz, tmz + tdz, tmz)
        finish = finish | (iz < 0) | (iz >= nz)
        return ix, iy, iz, tmx, tmy, tmz, tb, jb, bsx, bsy, treach, finish

    zero = jnp.zeros((), dtype)
    init = (ix, iy, iz, tmx, tmy, tmz, jnp.asarray(t_limit, dtype), jnp.asarray(dummy, jnp.int32), zero, zero, zero, jnp.asarray(False))
    out = jax.lax.fori_loop(0, max_cells, body, init)
    _, _, _, _, _, _, tb, jb, bsx, bsy, treach, done = out
    return tb, jb, jnp.stack([bsx + image_x, bsy + image_y]), treach, done


def _face_normal(sc: _Scene, j, shift, x_hit, d):
    """Outward normal of the face of box j (image `shift`) through which direction d entered."""
    qx, qy, qz, *q = _gather(sc, j)
    o = x_hit - d
    _, _, tns, das = _slab(q, o[0] - qx - shift[0], o[1] - qy - shift[1], o[2] - qz, d[0], d[1], d[2], sc.half_t)
    ux, uy, uz, nx, ny, nz, _ = q
    u = jnp.stack([ux, uy, uz])
    n = jnp.stack([nx, ny, nz])
    v = jnp.cross(n, u)
    is_u = (tns[0] >= tns[1]) & (tns[0] >= tns[2])
    is_v = ~is_u & (tns[1] >= tns[2])
    axis = jnp.where(is_u, u, jnp.where(is_v, v, n))
    da = jnp.where(is_u, das[0], jnp.where(is_v, das[1], das[2]))
    return -jnp.sign(da) * axis, is_u | is_v


# ----------------------------------------------------------------------------------------------
# One step of one lane


_NU = 8  # uniforms per step besides the per-detector aperture jitter and shadow roulette


def _mix(x):
    """32-bit integer finaliser (Wellons' lowbias32): full avalanche in five cheap operations."""
    x = x ^ (x >> 16)
    x = x * jnp.uint32(0x7FEB352D)
    x = x ^ (x >> 15)
    x = x * jnp.uint32(0x846CA68B)
    return x ^ (x >> 16)


def _ray_hash(seed, rid, step):
    """Counter-based 32-bit state of (seed, ray id, step): the ray's random stream at this step."""
    r = rid.astype(jnp.uint32) if rid.dtype.itemsize <= 4 else (rid.astype(jnp.uint64) ^ (rid.astype(jnp.uint64) >> 32)).astype(jnp.uint32)
    h = _mix(seed ^ _mix(r * jnp.uint32(0x9E3779B9) + jnp.uint32(0x632BE5AB)))
    return _mix(h + _mix(step.astype(jnp.uint32) + jnp.uint32(0x85EBCA6B)))


def _uniforms(h, count: int, dtype):
    """`count` uniforms in [0, 1) from a ray-step state h (24 random bits each)."""
    k = jnp.arange(1, count + 1, dtype=jnp.uint32) * jnp.uint32(0x9E3779B9)
    bits = _mix(h + k)
    return ((bits >> 8).astype(dtype) + 0.5) * (1.0 / 16777216.0)


def _key_from(h):
    """A raw threefry key for the platelet BRDF's own sampler."""
    return jnp.stack([_mix(h ^ jnp.uint32(0xA511E9B3)), _mix(h ^ jnp.uint32(0x63D83595))])


def _new_ray_uniforms(sc: _Scene) -> int:
    return 7 if sc.wavy else 5


def _source(sc: _Scene, rid):
    """Source index of ray `rid` (rays are dealt to the P sources in turn)."""
    return (rid % sc.illum_air.shape[0]).astype(jnp.int32)


def _new_ray(sc: _Scene, u, dtype, randomize_azimuth: bool = True, src=0):
    """Position, direction, weight T, top reflection 1 − T and rotation (cos, sin) of a fresh ray from uniforms u.

    The ray enters through a clearcoat facet m (flat: m = z; wavy: drawn from the visible-normal
    density of the illumination direction).
    """
    phi = 2.0 * jnp.pi * u[4] if randomize_azimuth else jnp.zeros((), dtype)
    c, s = jnp.cos(phi), jnp.sin(phi)
    w_air = _cone(sc.illum_air[src], sc.illum_cos_alpha, u[2], u[3])
    w_air = _rotz(w_air, c, s)
    if sc.wavy:
        mf = sample_visible_facet(w_air, sc.slope_sd, u[5], u[6])
        t, cos_i = refract(-w_air, mf, 1.0 / sc.n)
        d = t / jnp.linalg.norm(t)
    else:
        cos_i = w_air[2]
        d = -_refract_in(w_air, sc.n)
    Ri = fresnel_dielectric(cos_i, 1.0, sc.n)[2]
    pos = jnp.stack([u[0] * sc.tile[0], u[1] * sc.tile[1], sc.h_b - sc.eps])
    cast = lambda x: jnp.asarray(x).astype(dtype)  # noqa: E731
    return cast(pos), cast(d), cast(1.0 - Ri), cast(Ri), cast(c), cast(s)


def _exit_density(q_in, cos_air, cos_in, n):
    """Density per air steradian of an exit direction whose internal direction had density q_in
    per internal steradian (refraction: n² cosθ_in dω_in = cosθ_air dω_air)."""
    return q_in * cos_air / (n**2 * jnp.maximum(cos_in, 1e-12))


def _has_delta(brdf) -> bool:
    """Whether the BRDF's sampler can return its delta (mirror) direction with finite weight."""
    return bool(brdf.is_delta) or getattr(brdf, "coherent", None) == "delta"


def _projected_pdfs(sc: _Scene, hit, wi_loc, wo_loc):
    """Sampling densities per projected solid angle at a vertex, forward (ω_i → ω_o) and reverse (ω_o → ω_i).

    The primer's cosine sampling gives 1/π both ways; a platelet face its BRDF's `pdf`.
    """
    wi_b = jnp.broadcast_to(wi_loc, wo_loc.shape)
    cos_i = jnp.maximum(wi_b[..., 2], 1e-12)
    cos_o = jnp.maximum(wo_loc[..., 2], 1e-12)
    fwd = sc.brdf.pdf(wi_b, wo_loc).astype(cos_i.dtype) / cos_o
    rev = sc.brdf.pdf(wo_loc, wi_b).astype(cos_i.dtype) / cos_i
    return jnp.where(hit, fwd, 1.0 / jnp.pi), jnp.where(hit, rev, 1.0 / jnp.pi)


def _log(x):
    return jnp.log(jnp.maximum(x, 1e-30))


def _reverse_weight(sc: _Scene, src, hit, first, lg, wi_loc, wo_loc_j, w_in):
    """Balance-heuristic weight of this vertex's NEE toward each detector against the reverse tracer.

    For a path x_1 … x_k closed by NEE at x_k, forward (beam → x_1, sampled directions, NEE x_k →
    detector) and reverse (detector beam → x_k, sampled directions, NEE x_1 → source) path densities
    have the ratio ρ = (cos_k,det |z_L|) / (cos_1,in |z_D|) · Π_{i=2..k} q̃_rev,i / Π_{i=1..k−1} q̃_fwd,i
    (q̃ per projected solid angle; the beams' projected-area densities give the cosines, the
    geometric terms cancel). With c = reverse / forward rays, the forward weight is 1 / (1 + c ρ);
    the reverse tracer computes 1 / ρ for the same path, so the two weights sum to one.
    """
    _, rev_j = _projected_pdfs(sc, hit, wi_loc, wo_loc_j)
    cos_in = jnp.maximum(wi_loc[2], 1e-12)
    log_rho = (sc.log_reverse_share + _log(sc.illum_in_z[src]) - _log(w_in[:, 2]) + _log(wo_loc_j[:, 2])
               + jnp.where(first, -_log(cos_in), lg + _log(rev_j)))
    return jax.nn.sigmoid(-jnp.clip(log_rho, -80.0, 80.0))


def _update_log_ratio(sc: _Scene, hit, first, lg, wi_loc, wo_loc, wo_pr):
    """Running log of (1 / cos_1,in) Π_{i≥2} q̃_rev,i / Π q̃_fwd,i after sampling this vertex's direction."""
    wo = jnp.where(hit, wo_loc, wo_pr)
    fwd, rev = _projected_pdfs(sc, hit, wi_loc, wo)
    cos_in = jnp.maximum(wi_loc[2], 1e-12)
    return jnp.where(first, -_log(cos_in), lg + _log(rev)) - _log(fwd)  # finite: `_log` floors its argument


def _step_one(sc: _Scene, opt: TracerOptions, ray, key, single):
    """Advance one lane by one step: its pending shadow rays and its ray. Returns (lane, tally)."""
    pos, d, w, alive, cph, sph, nstep, nev, rid, spec_last, q_last, lg, sh_org, sh_dir, sh_lim, sh_val = ray
    dtype = pos.dtype
    m = sc.det_air.shape[0]
    has_delta = _has_delta(sc.brdf)
    u = _uniforms(key, _NU + 3 * m + (2 + 2 * m if sc.wavy else 0), dtype)
    uf = u[_NU + 3 * m :]  # facet draws of a wavy coat: 2 at the top, 2 per detector
    kb = _key_from(key)
    nee = jnp.zeros(m, dtype)  # NEE is scored by `_shadows` one step later

    # --- traversal to the next event
    dz = d[2]
    t_slab = jnp.where(dz > 0, (sc.h_b - pos[2]) / jnp.where(dz > 0, dz, 1.0),
                       jnp.where(dz < 0, -pos[2] / jnp.where(dz < 0, dz, -1.0), _BIG))
    t_slab = jnp.maximum(t_slab, 0.0).astype(dtype)
    tb, jb, sb, treach, fin = _traverse(sc, pos, d, t_slab, False, sc.max_cells)

    hit = alive & fin & (tb < t_slab)
    top = alive & fin & ~hit & (dz > 0)
    bottom = alive & fin & ~hit & ~(dz > 0)
    moving = alive & ~fin
    event = hit | bottom
    first = nev == 0

    # --- scattering event: platelet face (BRDF) or primer (Lambert)
    x_hit = pos + tb * d
    nf, side = _face_normal(sc, jb, sb, x_hit, d)
    x_bot = jnp.concatenate([pos[:2] + t_slab * d[:2], jnp.zeros(1, dtype)])
    ez = jnp.array([0.0, 0.0, 1.0], dtype)
    n_ev = jnp.where(hit, nf, ez)
    x_ev = jnp.where(hit, x_hit, x_bot)
    t1, t2 = _orthonormal_basis(n_ev)
    wi_loc = _to_local(-d, t1, t2, n_ev)
    wo_loc, s_w = sc.brdf.sample(kb, wi_loc)
    wo_loc = wo_loc.astype(dtype)
    s_w = jnp.where(jnp.isfinite(s_w), s_w, 0.0).astype(dtype)
    wo_pl = wo_loc[0] * t1 + wo_loc[1] * t2 + wo_loc[2] * n_ev
    wo_pr = cosine_hemisphere(u[5], u[6])  # the Lambertian primer
    wo = jnp.where(hit, wo_pl, wo_pr)
    wo = wo / jnp.maximum(jnp.linalg.norm(wo), 1e-30)
    factor = jnp.where(hit, s_w, sc.albedo)
    if opt.edges == "absorb":
        factor = jnp.where(hit & side, 0.0, factor)
    # was the sampled direction the BRDF's delta (mirror / coherent) branch?
    if sc.brdf.is_delta:
        spec = hit
    elif has_delta:
        mirror = wi_loc * jnp.array([-1.0, -1.0, 1.0], dtype)
        spec = hit & (jnp.sum((wo_loc - mirror) ** 2) < 1e-8)
    else:
        spec = jnp.zeros((), bool)
    omega = 2.0 * jnp.pi * (1.0 - sc.det_cos_alpha)  # detector cone solid angle (0: point detectors)

    def sampling_pdf(wo_l, cos_primer):  # per internal sr: platelet BRDF's continuous branches, or the primer's cosine
        return jnp.where(hit, sc.brdf.pdf(jnp.broadcast_to(wi_loc, wo_l.shape), wo_l).astype(dtype), cos_primer / jnp.pi)

    if sc.mis:
        q_ev = sampling_pdf(wo_loc, wo_pr[2])

    # --- next-event estimation: this event's shadow rays are traced in the next step
    origin = x_ev + sc.eps * n_ev
    origin = jnp.concatenate([origin[:2], jnp.clip(origin[2:], sc.eps, sc.h_b)])
    # the non-delta part of every event (primer, platelet lobe)
    uj = u[_NU : _NU + 2 * m].reshape(m, 2)
    w_air = _cone(sc.det_air, sc.det_cos_alpha, uj[:, 0], uj[:, 1])
    w_air = _rotz(w_air, cph, sph)
    if sc.wavy:  # the detector sees the visible facets m_j: v_j T(m_j) L_in(refraction of ω_j at m_j) / n²
        mj = sample_facet_normal(sc.slope_sd, uf[2 : 2 + m], uf[2 + m : 2 + 2 * m])
        w_in, To = seen_through_facet(w_air, mj, sc.n, sc.slope_sd)
        To = jnp.where(w_in[:, 2] > _WAVY_MIN_COS_IN, To, 0.0)  # bounds the shadow rays' travel (no weight there)
        w_in = w_in.at[:, 2].set(jnp.maximum(w_in[:, 2], _WAVY_MIN_COS_IN))
    else:
        w_in = _refract_in(w_air, sc.n)
        To = 1.0 - fresnel_dielectric(w_air[:, 2], 1.0, sc.n)[2]
    wo_loc_j = _to_local(w_in, t1[None], t2[None], n_ev[None])
    f_pl = sc.brdf.evaluate(jnp.broadcast_to(wi_loc, (m, 3)), wo_loc_j).astype(dtype)
    f = jnp.where(hit, f_pl, sc.albedo / jnp.pi)
    cos_o = jnp.maximum(wo_loc_j[:, 2], 0.0)
    val = jnp.pi * w * f * cos_o * To / (sc.n**2 * w_in[:, 2])
    if sc.mis:  # balance heuristic against the BRDF-sampled exit into the same cone direction
        q_j = sampling_pdf(wo_loc_j, w_in[:, 2])
        val = val / (1.0 + omega * _exit_density(q_j, jnp.maximum(w_air[:, 2], 0.0), w_in[:, 2], sc.n))
    score = event & (first | ~single)
    if opt.edges == "absorb":
        score = score & ~(hit & side)
    if sc.bidir:  # balance heuristic against the reverse tracer (source and detector swapped)
        val = val * _reverse_weight(sc, _source(sc, rid), hit, first, lg, wi_loc, wo_loc_j, w_in)
        lg_new = _update_log_ratio(sc, hit, first, lg, wi_loc, wo_loc, wo_pr)
    val = jnp.where(score & jnp.isfinite(val) & (val > 0), val, 0.0)
    if opt.shadow_roulette > 0:  # unbiased roulette on small contributions saves shadow rays
        small = val < opt.shadow_roulette
        val = jnp.where(small, jnp.where(u[_NU + 2 * m : _NU + 3 * m] * opt.shadow_roulette < val, opt.shadow_roulette, 0.0), val)
    new_sh_val = val.astype(dtype)
    new_sh_dir = w_in.astype(dtype)
    new_sh_lim = ((sc.h_b - origin[2]) / w_in[:, 2]).astype(dtype)

    # --- top of the basecoat: clearcoat transit, Fresnel split at the (facet of the) surface, histogram
    cz = jnp.where(top, dz, 1.0)
    shift_c = sc.h_c * d[:2] / cz
    if sc.wavy:  # the facet the ray meets, from the visible-normal density; the reflection stays in the coat
        d_up = jnp.where(top, d, jnp.array([0.0, 0.0, 1.0], dtype))
        mt = sample_visible_facet(d_up, sc.slope_sd, uf[0], uf[1])
        t, cos_t = refract(d_up, -mt, sc.n)
        Rint = fresnel_dielectric(cos_t, sc.n, 1.0)[2]
        ex_air = t / jnp.linalg.norm(t)
        d_ref = reflect(d_up, mt)
        d_ref = d_ref.at[2].set(-jnp.abs(d_ref[2]))  # a reflection still going up (grazing) is mirrored down
    else:
        Rint = fresnel_dielectric(cz, sc.n, 1.0)[2]
        txy = sc.n * d[:2]
        ex_air = jnp.concatenate([txy, jnp.sqrt(jnp.clip(1.0 - jnp.sum(txy * txy), 0.0, 1.0))[None]])
        d_ref = d * jnp.array([1.0, 1.0, -1.0], dtype)
    w_exit = jnp.where(top, w * (1.0 - Rint), 0.0)
    ex_inst = _rotz(ex_air, cph, -sph)
    inside = (jnp.sum(sc.det_air * ex_inst[None], -1) >= sc.det_cos_alpha) & (omega > 0)
    hist = jnp.where(inside & (w_exit > 0), jnp.pi * w_exit / (jnp.maximum(omega, 1e-30) * jnp.maximum(ex_inst[2], 1e-12)), 0.0)
    # the exit's share of the estimate: all of it after a delta reflection (the splat of the
    # deterministic direction into the aperture; NEE cannot see a delta), the balance-heuristic
    # share 1 − (NEE's) after a continuous one under MIS, none otherwise
    if sc.mis:
        pb = omega * _exit_density(q_last, ex_air[2], cz, sc.n)
        share = jnp.where(spec_last, 1.0, pb / (1.0 + pb))
    else:
        share = spec_last.astype(dtype)
    nee = jnp.where(~single | (nev <= 1), share * hist, 0.0)

    # --- new state and ledger
    new_w = jnp.where(event, w * factor, jnp.where(top, w * Rint, w))
    new_d = jnp.where(event, wo, jnp.where(top, d_ref, d))
    new_pos = jnp.where(hit, x_hit + sc.eps * nf, pos)
    new_pos = jnp.where(bottom, jnp.concatenate([x_bot[:2], sc.eps[None]]), new_pos)
    shift_down = sc.h_c * d_ref[:2] / jnp.where(top, -d_ref[2], 1.0)
    new_pos = jnp.where(top, jnp.concatenate([pos[:2] + t_slab * d[:2] + shift_c + shift_down, (sc.h_b - sc.eps)[None]]), new_pos)
    new_pos = jnp.where(moving, pos + (treach + sc.eps) * d, new_pos)
    new_pos = jnp.concatenate([jnp.mod(new_pos[:2], sc.tile), jnp.clip(new_pos[2:], 0.0, sc.h_b)])
    absorbed_pl = jnp.where(hit, w * (1.0 - factor), 0.0)
    absorbed_pr = jnp.where(bottom, w * (1.0 - factor), 0.0)
    # single scattering: a path ends after a non-delta first event (its NEE is scored), at its
    # second event (uncounted, cut before scattering) or at the internal reflection after the
    # first event
    second = event & (nev >= 1)
    # (under MIS the first event's ray goes on to its exit, which carries part of the estimate)
    early = jnp.zeros((), bool) if sc.mis else event & first & ~spec
    cut = single & alive & (second | (top & (nev >= 1)) | early)
    w_cut = jnp.where(cut, jnp.where(second, w, new_w), 0.0)
    absorbed_pl = jnp.where(cut & second, 0.0, absorbed_pl)
    absorbed_pr = jnp.where(cut & second, 0.0, absorbed_pr)
    new_w = jnp.where(cut, 0.0, new_w)
    alive2 = alive & ~cut
    rr = jnp.zeros((), dtype)
    if opt.roulette_weight > 0:
        low = alive2 & (event | top) & (new_w < opt.roulette_weight)
        survive = u[7] * opt.roulette_weight < new_w
        rr = jnp.where(low, jnp.where(survive, new_w - opt.roulette_weight, new_w), 0.0)
        new_w = jnp.where(low, jnp.where(survive, opt.roulette_weight, 0.0), new_w)
        alive2 = alive2 & ~(low & ~survive)
    alive2 = alive2 & (new_w > 0)
    nstep2 = nstep + alive.astype(nstep.dtype)
    capped = alive2 & (nstep2 >= opt.max_steps)
    caps = w_cut + jnp.where(capped, new_w, 0.0)
    alive2 = alive2 & ~capped
    z = jnp.zeros((), dtype)
    ledger = jnp.stack([z, w_exit, absorbed_pl, absorbed_pr, rr, caps])
    ledger = jnp.where(alive, ledger, 0.0)
    hist = jnp.where(alive, hist, 0.0)
    nee = jnp.where(alive, nee, 0.0)
    tally = jnp.concatenate([nee, hist, ledger, jnp.zeros(1, dtype)])
    keep_sh = alive & event
    new_ray = (new_pos.astype(dtype), new_d.astype(dtype), jnp.where(alive2, new_w, 0.0).astype(dtype), alive2, cph, sph,
               nstep2, nev + event.astype(nev.dtype), rid, jnp.where(event, spec, spec_last),
               jnp.where(event, q_ev, q_last).astype(dtype) if sc.mis else q_last,
               jnp.where(event, lg_new, lg).astype(dtype) if sc.bidir else lg, origin.astype(dtype), new_sh_dir,
               new_sh_lim, jnp.where(keep_sh, new_sh_val, 0.0))
    return new_ray, tally


def _shadows(sc: _Scene, opt: TracerOptions, org, sh_dir, sh_lim, sh_val):
    """Trace the pending shadow rays of all lanes (compacted, in passes of a fixed buffer).

    A shadow ray that uses up its cell budget (`_shadow_cell_bound`: only a wavy coat's steeper NEE
    directions can) resumes where it stopped in a later pass, so every shadow ray is decided.
    Returns the NEE increment (lanes, m): the pending values of the visible shadow rays.
    """
    B, m = sh_val.shape
    total = B * m
    S = max(1, min(total, int(round(opt.shadow_buffer * total))))
    dirs = sh_dir.reshape(-1, 3)
    # passes: ceil(total / S) for the first leg of every ray, and as many again per resumption (a
    # ray of tan θ ≤ _WAVY_MAX_TAN_IN needs at most ⌈_WAVY_MAX_TAN_IN / tan θ_c⌉ legs, 3 for n = 1.5
    # against the 5 allowed). A guard against a runaway loop only: a ray still pending when it
    # stops would count as occluded, which the leg bound rules out
    legs = jnp.ceil(_WAVY_MAX_TAN_IN * jnp.sqrt(jnp.maximum(sc.n**2 - 1.0, 1e-12))) + 1.0 if sc.wavy else 1.0
    max_passes = jnp.asarray(legs * (-(-total // S)) + 1).astype(jnp.int32)

    def cond(c):
        return jnp.any(c[2]) & (c[0] < max_passes)

    def body(c):
        it, orgs, pending, lims, vis = c
        idx = jnp.nonzero(pending, size=S, fill_value=total)[0]
        ok = idx < total
        j = jnp.minimum(idx, total - 1)
        tb, _, _, reach, fin = jax.vmap(lambda a, b, c_: _traverse(sc, a, b, c_, True, sc.shadow_cells))(orgs[j], dirs[j], lims[j])
        vis = vis.at[idx].max(ok & fin & (tb >= lims[j]), mode="drop")
        pending = pending.at[idx].set(~fin, mode="drop")  # unfinished: no occluder so far, resume at the reach
        orgs = orgs.at[idx].set(orgs[j] + reach[:, None] * dirs[j], mode="drop")
        lims = lims.at[idx].set(lims[j] - reach, mode="drop")
        return it + 1, orgs, pending, lims, vis

    init = (jnp.asarray(0, jnp.int32), jnp.repeat(org, m, axis=0), (sh_val > 0).reshape(-1), sh_lim.reshape(-1), jnp.zeros(total, bool))
    vis = jax.lax.while_loop(cond, body, init)[-1]
    return jnp.where(vis.reshape(B, m), sh_val, 0.0)


# ----------------------------------------------------------------------------------------------
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


def check_ray_count(rays, options: TracerOptions | None = None, name: str = "rays") -> None:
    """At least one ray per batch of the batch-means standard error (`TracerOptions.batches`)."""
    batches = (options or TracerOptions()).batches
    if int(rays) < batches:
        raise ValueError(f"{name} must be at least {batches} (one per batch of the standard error), got {rays!r}")


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


def build_scene(array, geometry: Geometry, brdf: AbstractPlateletBRDF, grid, *, n: float, clearcoat_thickness: float,
                primer_albedo: float, waviness_deg: float = 0.0, dtype=jnp.float32, min_cells: int = 2, mis: bool = True,
                reverse_share=None, reverse: bool = False) -> _Scene:
    """Pack an array, its grid, the BRDF and the instrument into the tracer's device scene.

    `reverse`: the reverse pool of bidirectional MIS, by reciprocity: one source per detector (at
    the detector's direction) and one detector at the illumination direction; `reverse_share`
    is then the reverse rays per forward ray and detector, as for the forward scene.

    Platelet and cell tables are padded to bucketed sizes and the grid dimensions are traced
    values, so arrays of similar size (e.g. the two reference samples) share one compilation.
    """
    Lx, Ly = (float(x) for x in array.tile)
    h_b = float(array.basecoat_thickness)
    shape = tuple(int(s) for s in grid.shape)
    cell = np.array([Lx / shape[0], Ly / shape[1], h_b / shape[2]])
    check_grid_matches(array, grid)
    cells = np.asarray(grid.cell_platelets)
    n_pl = int(np.asarray(array.widths).reshape(-1).shape[0])
    ncell = shape[0] * shape[1] * shape[2]
    n_pad = _bucket(n_pl + 1, 512)
    table = np.full((_bucket(ncell, 1024), _bucket(cells.shape[1], 4)), n_pad - 1, dtype=np.int32)
    table[:ncell, : cells.shape[1]] = np.where(cells < 0, n_pad - 1, cells)
    eps = max(1e-9, 64.0 * float(jnp.finfo(dtype).eps)) * max(Lx, Ly, h_b)
    arr = lambda x: jnp.asarray(np.asarray(x, dtype=float), dtype)  # noqa: E731
    sources = np.asarray(geometry.illumination_air(), dtype=float)[None]
    detectors = np.asarray(geometry.detectors_air(), dtype=float)
    illum_alpha, det_alpha = geometry.illumination_aperture_deg, geometry.detector_aperture_deg
    if reverse:
        sources, detectors, illum_alpha, det_alpha = detectors, sources, det_alpha, illum_alpha
    share = 0.0 if reverse_share is None else float(reverse_share)
    # log(rays of the other pass / this pass's rays), per detector (forward) or per source (reverse)
    log_share = -1e30 if share <= 0 else float(np.log(1.0 / share if reverse else share))
    src_in = np.asarray(refract_into_coat(jnp.asarray(sources), float(n)))
    return _Scene(
        cols=_pack_platelets(array, dtype, n_pad),
        cells=jnp.asarray(table),
        grid_n=jnp.asarray(shape, jnp.int32),
        cell_size=arr(cell),
        tile=arr([Lx, Ly]),
        half_t=arr(0.5 * float(array.thickness)),
        h_b=arr(h_b),
        h_c=arr(float(clearcoat_thickness)),
        n=arr(float(n)),
        albedo=arr(float(primer_albedo)),
        eps=arr(eps),
        illum_air=arr(sources),
        illum_cos_alpha=arr(np.cos(np.deg2rad(illum_alpha))),
        det_air=arr(detectors),
        det_cos_alpha=arr(np.cos(np.deg2rad(det_alpha))),
        brdf=brdf,
        slope_sd=arr(slope_sd(waviness_deg)),
        log_reverse_share=jnp.full((detectors.shape[0],), log_share, dtype),
        illum_in_z=arr(np.abs(src_in[:, 2])),
        max_cells=int(min_cells),
        shadow_cells=_shadow_cell_bound(shape, cell, h_b, float(n)),
        wavy=waviness_deg > 0.0,
        mis=bool(mis) and det_alpha > 0.0 and not waviness_deg > 0.0,
        bidir=share > 0,
    )


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


def _bidirectional_applies(opt: TracerOptions, geometry: Geometry, brdf, waviness_deg: float) -> bool:
    """Bidirectional MIS needs delta directions at both ends (collimated beam, point detectors), a
    flat coat and a BRDF without a delta part; elsewhere the tracer runs forward alone."""
    return (opt.reverse_share > 0 and geometry.detector_aperture_deg == 0 and geometry.illumination_aperture_deg == 0
            and not waviness_deg > 0 and not _has_delta(brdf))


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
        waviness_deg: RMS slope angle of a wavy clearcoat surface in [0, 15]° (0: flat; see `_interface`).
        rays: number of rays, over all passes (bidirectional: 1 + m·`reverse_share` rays per
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
    share = opt.reverse_share if _bidirectional_applies(opt, geometry, brdf, waviness_deg) else 0.0
    common = dict(n=n, clearcoat_thickness=clearcoat_thickness, primer_albedo=primer_albedo, waviness_deg=waviness_deg,
                  dtype=cdt, min_cells=opt.cells_per_step, mis=opt.mis)
    # the forward pass (all detectors) and, bidirectionally, the reverse pool: every detector becomes a
    # source whose one detector is the illumination (reciprocity), `share` rays per forward ray each
    passes = [(build_scene(array, geometry, brdf, grid, reverse_share=share, **common), 1.0)]
    if share > 0:
        passes.append((build_scene(array, geometry, brdf, grid, reverse_share=share, reverse=True, **common), share * m))
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
    while True:
        parts = []
        for item in live:
            sc, key, state, frac = item
            target = max(int(np.ceil(frac * n_local)), -(-sc.illum_air.shape[0] // ndev))  # every source gets rays
            nl = put(jnp.asarray(target, idt))
            while True:
                state = run(sc, key, state, nl, single)
                busy = bool(jnp.any(state[0][3]) | jnp.any(state[0][-1] != 0))
                if not busy and int(jnp.min(state[2])) >= target:
                    break
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
