"""Platelet arrays: square aluminium prisms in a laterally periodic basecoat tile.

Generation from statistics (`generate_platelet_array`):

1. **Widths** are drawn one after another from the size law until the platelet volume
   Σ w²t is closest to pvc · Lx · Ly · h_b: the count follows from the PVC, and the achieved
   PVC is within half a platelet volume of the target.
2. **Orientations**: tilt from the gamma law (`GammaTilt`, truncated at 90°), azimuth of the
   normal uniform in [0, 2π), rotation of the square about its normal uniform in [0, π/2)
   (the square's symmetry). Normals point up (n_z ≥ 0).
3. **Top and bottom of the basecoat**: every box lies *entirely* inside [0, h_b] (no platelet
   pokes into the primer or the clearcoat, and the grid, which covers [0, h_b], sees all of
   it). A centre is uniform in the lateral tile and in [h_z, h_b − h_z], h_z the box's vertical
   half extent at its orientation. A platelet too wide to fit at its drawn tilt (2h_z > h_b,
   e.g. a 70 µm platelet tilted 15° in a 20 µm film) gets a fresh orientation from the same
   laws (confinement by the film); the count is reported (`GenerationLog.n_orientation_redrawn`).
4. **Overlap removal** (random sequential addition, hardest platelets first, i.e. in decreasing
   order of the volume they exclude to an average neighbour, which grows with width and tilt):
   each platelet is tried at its drawn position, then, if it overlaps an already placed platelet
   (exact SAT test by default, or the original study's mid-plane Möller test), re-placed at fresh
   uniform positions with the same size and orientation, up to `max_attempts` times. Neighbours
   come from a periodic multi-level column hash; candidate positions are tested in vectorised
   batches, periodic images included. A platelet that exhausts its attempts stays at its drawn
   position and is reported (`GenerationLog.n_failed`, a RuntimeWarning, and the residual
   overlap counts of `array_statistics`). Removal stays clean up to about 25 % PVC for the
   reference statistics (see `MAX_PVC`). Placed platelets are never moved again: each one is
   uniform over the space its predecessors left free (the standard hard-core RSA model).

Randomness comes from one JAX key (an integer seed s means `jax.random.PRNGKey(s)`): the key's
data seed a NumPy PCG64 stream that draws, in a fixed order, sizes, orientations, positions and
re-placements (NumPy avoids per-shape JAX compilation in this irregular, sequential work).
Tilts are drawn exactly as `GammaTilt.sample_deg` does (inverse of the truncated gamma CDF
tabulated on 4097 nodes uniform in √t). Same key → identical array. The geometry work is NumPy
float64; the result is a JAX pytree (float32 leaves unless x64 is enabled).
"""

from __future__ import annotations

import dataclasses
import math
import time
import warnings
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from .._progress import Heartbeat
from .._validate import Range
from ._grid import _ColumnCells
from ._overlap import aabb_half_extents, midplane_overlap, obb_overlap, periodic_overlap
from ._sizes import SizeDistribution, as_size_distribution, positive_finite
from ._tilt import _INV_CDF_POINTS, MAX_TILT_DEG, GammaTilt

#: Largest accepted PVC. Random sequential addition of thin tilted platelets jams far below
#: space filling: for the reference statistics removal (1000 attempts) stays clean up to about
#: 25 %, leaves a few per cent of the platelets overlapping (reported) at 30 % and fails
#: massively beyond; above 40 % the request is rejected as unpackable.
MAX_PVC = 0.4
#: The default tile side is this many times the largest platelet width of the size law.
DEFAULT_TILE_FACTOR = 10.0
OVERLAP_TESTS = ("sat", "midplane", "none")
_MAX_ORIENTATION_ROUNDS = 1000


class PlateletFitError(ValueError):
    """Platelets of these sizes and this tilt law cannot fit in the basecoat at any drawn orientation: no array exists."""


class PlateletArray(eqx.Module):
    """Square platelets (rectangular prisms) in a laterally periodic basecoat tile.

    Platelet k is the box centers[k] ± (w/2) u ± (w/2) v ± (t/2) n with u = axes_u[k],
    n = normals[k], v = n × u, w = widths[k], t = thickness; the tile repeats with periods
    Lx, Ly in x and y. Lengths in µm.

    Fields:
        centers: (N, 3), x ∈ [0, Lx), y ∈ [0, Ly), and the whole box inside [0, h_b] in z.
        normals: (N, 3) unit, n_z ≥ 0.
        axes_u: (N, 3) unit edge direction in the platelet plane.
        widths: (N,) square edge length.
        thickness: static platelet thickness t.
        tile: static (Lx, Ly).
        basecoat_thickness: static h_b.
    """

    centers: Float[Array, "n 3"]
    normals: Float[Array, "n 3"]
    axes_u: Float[Array, "n 3"]
    widths: Float[Array, " n"]
    thickness: float = eqx.field(static=True)
    tile: tuple[float, float] = eqx.field(static=True)
    basecoat_thickness: float = eqx.field(static=True)

    @property
    def count(self) -> int:
        return int(self.widths.shape[0])

    @property
    def axes_v(self) -> Float[Array, "n 3"]:
        """Second edge direction v = n × u."""
        return jnp.cross(self.normals, self.axes_u)

    def box_axes(self) -> Float[Array, "n 3 3"]:
        """(N, 3, 3) box axes as rows (u, v, n)."""
        return jnp.stack([self.axes_u, self.axes_v, self.normals], axis=-2)

    def half_extents(self) -> Float[Array, "n 3"]:
        """(N, 3) half extents (w/2, w/2, t/2) along (u, v, n)."""
        hw = 0.5 * self.widths
        return jnp.stack([hw, hw, jnp.full_like(hw, 0.5 * self.thickness)], axis=-1)

    def aabb_half_extents(self) -> Float[Array, "n 3"]:
        """(N, 3) half extents of each box's axis-aligned bounding box."""
        return jnp.einsum("nk,nkx->nx", self.half_extents(), jnp.abs(self.box_axes()))

    def tilt_deg(self) -> Float[Array, " n"]:
        """Tilt of each platelet from the paint plane [deg]."""
        return jnp.rad2deg(jnp.arccos(jnp.clip(self.normals[:, 2], -1.0, 1.0)))

    def volume(self) -> Float[Array, ""]:
        """Total platelet volume Σ w² t [µm³]."""
        return jnp.sum(self.widths**2) * self.thickness

    def tile_volume(self) -> float:
        """Basecoat volume of the tile Lx · Ly · h_b [µm³]."""
        return self.tile[0] * self.tile[1] * self.basecoat_thickness

    @property
    def pvc(self) -> Float[Array, ""]:
        """Achieved pigment volume concentration (platelet volume over basecoat volume)."""
        return self.volume() / self.tile_volume()

    def nearest_image_centers(self, index: Int[ArrayLike, "..."], points: Float[ArrayLike, "... 3"]) -> Float[Array, "... 3"]:
        """Centre of the lateral periodic image of platelet `index` nearest to `points`."""
        c = self.centers[jnp.asarray(index)]
        d = c[..., :2] - jnp.asarray(points)[..., :2]
        L = jnp.asarray(self.tile, dtype=c.dtype)
        return c.at[..., :2].add(-L * jnp.round(d / L))


@dataclasses.dataclass(frozen=True)
class GenerationLog:
    """What `generate_platelet_array` did (returned with `return_log=True`)."""

    count: int
    pvc_target: float
    pvc: float
    overlap_test: str
    max_attempts: int
    n_replaced: int  # platelets moved at least once
    total_replacements: int  # re-placements summed over platelets
    max_replacements: int  # most re-placements any placed platelet needed
    n_failed: int  # platelets left overlapping after max_attempts
    n_orientation_redrawn: int  # platelets given a new orientation to fit in the film
    seconds: float


def numpy_rng(key_or_seed) -> np.random.Generator:
    """NumPy PCG64 generator seeded from a JAX key's data (an int s stands for PRNGKey(s))."""
    if isinstance(key_or_seed, (int, np.integer)) and not isinstance(key_or_seed, bool):
        if not 0 <= key_or_seed < 2**63:
            raise ValueError(f"seed must be a non-negative integer below 2**63, got {key_or_seed!r}")
        key_or_seed = jax.random.PRNGKey(int(key_or_seed))
    if not isinstance(key_or_seed, (jax.Array, np.ndarray)):
        raise ValueError(f"key_or_seed must be a jax.random key or a non-negative integer seed, got {key_or_seed!r}")
    key = key_or_seed
    if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
        key = jax.random.key_data(key)
    words = np.asarray(key)
    if words.dtype != np.uint32 or words.size == 0:
        raise ValueError(f"key_or_seed must be a jax.random key or a non-negative integer seed, got {key_or_seed!r}")
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence([int(x) for x in words.ravel()])))


def _tilt_cdf_np(tilt: GammaTilt, tilt_deg) -> np.ndarray:
    """`GammaTilt.cdf_deg` in NumPy float64 (same formula)."""
    from scipy.special import gammainc

    k, th = float(tilt.shape), float(tilt.scale_deg)
    x = np.clip(np.asarray(tilt_deg, dtype=float), 0.0, MAX_TILT_DEG)
    return gammainc(k, x / th) / gammainc(k, MAX_TILT_DEG / th)


def _tilt_ppf_np(tilt: GammaTilt, u) -> np.ndarray:
    """Exact inverse of `_tilt_cdf_np` (a smooth function of the law, unlike the sampling table)."""
    from scipy.special import gammainc, gammaincinv

    k, th = float(tilt.shape), float(tilt.scale_deg)
    u = np.clip(np.asarray(u, dtype=float), 1e-12, 1 - 1e-12)
    return np.clip(th * gammaincinv(k, u * gammainc(k, MAX_TILT_DEG / th)), 1e-9, MAX_TILT_DEG)


def _sample_tilt_np(tilt: GammaTilt, rng: np.random.Generator, n: int) -> np.ndarray:
    """Tilts [deg] by the inverse-CDF table of `GammaTilt.sample_deg`, in NumPy."""
    grid = MAX_TILT_DEG * np.linspace(0.0, 1.0, _INV_CDF_POINTS) ** 2
    return np.interp(rng.random(n), _tilt_cdf_np(tilt, grid), grid)


def _as_tilt(tilt) -> GammaTilt:
    if isinstance(tilt, GammaTilt):
        return tilt
    if isinstance(tilt, (tuple, list)) and len(tilt) == 2:
        return GammaTilt(*tilt)
    raise ValueError(f"tilt must be a GammaTilt or (shape, scale_deg), got {tilt!r}")


def _frames(tilt_deg, azimuth, rotation):
    """Unit normals and edge directions u from tilt [deg], azimuth and in-plane rotation [rad]."""
    t = np.deg2rad(tilt_deg)
    st, ct, sp, cp = np.sin(t), np.cos(t), np.sin(azimuth), np.cos(azimuth)
    n = np.stack([st * cp, st * sp, ct], axis=-1)
    e1 = np.stack([ct * cp, ct * sp, -st], axis=-1)  # in-plane, steepest descent
    e2 = np.stack([-sp, cp, np.zeros_like(sp)], axis=-1)  # in-plane, horizontal
    u = np.cos(rotation)[:, None] * e1 + np.sin(rotation)[:, None] * e2
    return n, u


def _vertical_half_extent(n, u, w, t):
    v = np.cross(n, u)
    return 0.5 * w * (np.abs(u[:, 2]) + np.abs(v[:, 2])) + 0.5 * t * np.abs(n[:, 2])


def _draw_widths(rng, sizes: SizeDistribution, target_volume: float, thickness: float) -> np.ndarray:
    """Widths drawn in sequence until the volume is closest to the target."""
    mean_vol = sizes.moment(2) * thickness
    n_expected = target_volume / mean_vol
    widths = np.zeros(0)
    block = int(1.5 * n_expected + 10 * math.sqrt(n_expected) + 16)
    for _ in range(1000):
        widths = np.concatenate([widths, sizes.sample_np(rng, block)])
        cum = np.cumsum(widths**2 * thickness)
        if cum[-1] >= target_volume:
            k = int(np.searchsorted(cum, target_volume))  # cum[k] >= target
            if k > 0 and target_volume - cum[k - 1] < cum[k] - target_volume:
                k -= 1
            return widths[: k + 1]
    raise ValueError("pvc: could not reach the target volume")  # pragma: no cover


def check_pvc(pvc) -> float:
    """`pvc` as a float, or a ValueError unless it is a volume fraction in (0, `MAX_PVC`]."""
    try:
        pvc_f = float(pvc)
    except (TypeError, ValueError) as err:
        raise ValueError(f"pvc must be a number in (0, {MAX_PVC}], got {pvc!r}") from err
    if not (math.isfinite(pvc_f) and 0 < pvc_f <= MAX_PVC):
        raise ValueError(f"pvc must lie in (0, {MAX_PVC}] (volume fraction, not percent), got {pvc!r}")
    return pvc_f


#: Largest tile side [µm] of a generated array (memory and time of the generator, the grid and the tracer).
MAX_TILE_UM = 5000.0
#: Most platelets of a generated array (expected from the PVC, the tile and the width law; the reference samples have ≈ 5,000).
MAX_PLATELETS = 200_000


def generate_platelet_array(
    key_or_seed,
    *,
    pvc: float,
    tilt,
    sizes: SizeDistribution | tuple | None = None,
    thickness: float = 1.0,
    basecoat_thickness: float = 20.0,
    tile: float | tuple[float, float] | None = None,
    overlap_test: str = "sat",
    max_attempts: int = 1000,
    return_log: bool = False,
    heartbeat: Callable[[float, float], None] | None = None,
):
    """Build a platelet array from statistics, with overlaps removed (see the module docstring).

    Arguments:
        key_or_seed: a `jax.random` key or a non-negative integer seed.
        pvc: target pigment volume concentration, in (0, 0.4] (`MAX_PVC`).
        tilt: `GammaTilt` or (shape, scale_deg).
        sizes: width law (`SizeDistribution`), (d10, d50, d90) for a log-normal, or None for the
            default log-normal (D50 16 µm, D10 ≈ 8, D90 ≈ 30).
        thickness: platelet thickness t [µm], > 0 and < basecoat_thickness.
        basecoat_thickness: h_b [µm], > thickness.
        tile: lateral period, a side or (Lx, Ly) [µm]; each side ≥ √2·max_width + t (no platelet
            reaches its own image). Default: 10 × the size law's max_width, rounded up to 1 µm.
        overlap_test: "sat" (exact boxes, default), "midplane" (original study) or "none".
        max_attempts: re-placements allowed per platelet, integer ≥ 0 (default 1000).
        return_log: also return a `GenerationLog`.
        heartbeat: called every `paintjax._progress.HEARTBEAT_SECONDS` during the overlap removal as
            `heartbeat(fraction of the platelets placed, seconds so far)` (e.g. `paintjax._progress.print_progress`).

    Returns:
        PlateletArray, or (PlateletArray, GenerationLog) with `return_log=True`.

    Raises:
        ValueError: naming the parameter, for bad input (PVC outside (0, 0.4] or below half a
            platelet in the tile, non-positive sizes or thickness, basecoat not thicker than a
            platelet, tile below √2·max_width + t, more than `MAX_PLATELETS` platelets expected, unknown
            test, negative attempts, bad seed).
    Warns:
        RuntimeWarning: when platelets still overlap after `max_attempts` re-placements.
    """
    t0 = time.perf_counter()
    tilt = _as_tilt(tilt)
    sizes = as_size_distribution(sizes)
    pvc_f = check_pvc(pvc)
    t = positive_finite("thickness", thickness, "µm")
    h_b = positive_finite("basecoat_thickness", basecoat_thickness, "µm")
    if h_b <= t:
        raise ValueError(f"basecoat_thickness ({h_b} µm) must exceed the platelet thickness ({t} µm)")
    w_max = float(sizes.max_width)
    min_tile = math.sqrt(2.0) * w_max + t
    if tile is None:
        L = (float(math.ceil(DEFAULT_TILE_FACTOR * w_max)),) * 2
    else:
        Ls = (tile, tile) if np.ndim(tile) == 0 else tuple(tile)
        if len(Ls) != 2:
            raise ValueError(f"tile must be a side or (Lx, Ly) [µm], got {tile!r}")
        L = tuple(positive_finite("tile", v, "µm") for v in Ls)
    if max(L) > MAX_TILE_UM:
        raise ValueError(f"tile sides must be at most {MAX_TILE_UM:g} µm (≈ 2 × 10⁵ platelets at PVC 0.1 in a 20 µm basecoat), got {tile!r}")
    if min(L) < min_tile:
        raise ValueError(
            f"tile {L} µm is smaller than the largest platelet allows: each side must be ≥ √2 × the largest width + "
            f"the thickness = {min_tile:.3g} µm (largest width {w_max:.3g} µm) so no platelet reaches its own image"
        )
    expected = pvc_f * L[0] * L[1] * h_b / (sizes.moment(2) * t)
    if expected > MAX_PLATELETS:
        raise ValueError(f"pvc {pvc_f:g} in a {L[0]:g} × {L[1]:g} µm tile holds about {expected:.2g} platelets of this width law "
                         f"and thickness ({t:g} µm), more than {MAX_PLATELETS:,} (memory and time): lower pvc, a smaller tile, or "
                         "thicker or wider platelets")
    if overlap_test not in OVERLAP_TESTS:
        raise ValueError(f"overlap_test must be one of {OVERLAP_TESTS}, got {overlap_test!r}")
    max_attempts = Range(0, None, integer=True).check("max_attempts", max_attempts)

    rng = numpy_rng(key_or_seed)
    volume = L[0] * L[1] * h_b
    widths = _draw_widths(rng, sizes, pvc_f * volume, t)
    n = widths.size
    if n == 0 or widths[0] ** 2 * t > 2 * pvc_f * volume:
        raise ValueError(f"pvc {pvc_f} × tile volume {volume:.4g} µm³ is less than half a platelet; raise pvc or tile")

    # Orientations, redrawn where the box cannot fit in the film.
    def draw_orientations(m):  # tilt, azimuth, rotation about the normal
        td = _sample_tilt_np(tilt, rng, m)
        return _frames(td, 2 * np.pi * rng.random(m), 0.5 * np.pi * rng.random(m))

    normals, axes_u = draw_orientations(n)
    hz = _vertical_half_extent(normals, axes_u, widths, t)
    misfit = np.flatnonzero(2 * hz > h_b)
    n_redrawn = misfit.size
    for _ in range(_MAX_ORIENTATION_ROUNDS):
        if misfit.size == 0:
            break
        nn, uu = draw_orientations(misfit.size)
        normals[misfit], axes_u[misfit] = nn, uu
        hz[misfit] = _vertical_half_extent(nn, uu, widths[misfit], t)
        misfit = misfit[2 * hz[misfit] > h_b]
    else:
        raise PlateletFitError(f"sizes/tilt: {misfit.size} platelet(s) up to {widths[misfit].max():.3g} µm wide do not fit in the "
                               f"basecoat_thickness {h_b} µm at any of {_MAX_ORIENTATION_ROUNDS} drawn orientations")

    # First positions: uniform in the tile, box inside [0, h_b].
    u = rng.random((n, 3))
    centers = np.stack([u[:, 0] * L[0], u[:, 1] * L[1], hz + u[:, 2] * (h_b - 2 * hz)], axis=1)

    R = np.stack([axes_u, np.cross(normals, axes_u), normals], axis=1)
    e = np.stack([0.5 * widths, 0.5 * widths, np.full(n, 0.5 * t)], axis=1)
    replacements = np.zeros(n, dtype=np.int64)
    failed = np.zeros(n, dtype=bool)
    if overlap_test != "none":
        pulse = Heartbeat(heartbeat) if heartbeat is not None else None
        _remove_overlaps(centers, R, e, hz, L, h_b, overlap_test, max_attempts, rng, replacements, failed, pulse)
    if failed.any():
        warnings.warn(
            f"{int(failed.sum())} of {n} platelets still overlap after {max_attempts} re-placements "
            f"(pvc {pvc_f}); they are kept and counted as residual overlaps",
            RuntimeWarning,
            stacklevel=2,
        )

    array = PlateletArray(
        centers=jnp.asarray(centers),
        normals=jnp.asarray(normals),
        axes_u=jnp.asarray(axes_u),
        widths=jnp.asarray(widths),
        thickness=t,
        tile=(float(L[0]), float(L[1])),
        basecoat_thickness=h_b,
    )
    if not return_log:
        return array
    placed = ~failed
    log = GenerationLog(
        count=n,
        pvc_target=pvc_f,
        pvc=float(np.sum(widths**2) * t / volume),
        overlap_test=overlap_test,
        max_attempts=max_attempts,
        n_replaced=int(np.sum(replacements > 0)),
        total_replacements=int(replacements.sum()),
        max_replacements=int(replacements[placed].max(initial=0)),
        n_failed=int(failed.sum()),
        n_orientation_redrawn=int(n_redrawn),
        seconds=time.perf_counter() - t0,
    )
    return array, log


def boolean_platelet_array(
    seed: int,
    count: int,
    *,
    tile: tuple[float, float],
    basecoat_thickness: float,
    width: float,
    thickness: float,
    tilt=None,
    margin: float | None = None,
) -> PlateletArray:
    """Equal square platelets placed independently (overlaps allowed): the Boolean platelet model.

    The scene of the closed-form hot spot (`HotSpot`, exact for horizontal platelets) and of the
    tracer's validation: centres uniform in the tile and in [margin, h_b − margin], tilt from the
    gamma law (the inverse-CDF table of `GammaTilt.sample_deg`, as `generate_platelet_array`) or
    horizontal, azimuth uniform, edge direction uniform about the normal. Mean free depth for horizontal
    platelets: Lx·Ly·h_b / (count·w²).

    Arguments:
        seed: non-negative integer seed of a NumPy `default_rng` stream (centres, tilts,
            azimuths, edge directions, in that order).
        count: number of platelets, integer ≥ 0.
        tile: (Lx, Ly) [µm], each ≥ √2·width + thickness (no platelet reaches its own image).
        basecoat_thickness: h_b [µm], > 2·margin.
        width, thickness: square edge w and thickness t [µm], > 0.
        tilt: None (horizontal), `GammaTilt` or (shape, scale_deg).
        margin: distance of the centres from z = 0 and z = h_b [µm], ≥ 0; default w/2, which keeps
            moderately tilted boxes inside the film (a box's vertical half extent reaches
            ½√(2w² + t²) at 90° tilt, so steep tilt laws can protrude and `build_grid` then refuses
            the array; pass that value for any tilt).

    Returns:
        PlateletArray.
    """
    if isinstance(seed, bool) or int(seed) != seed or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    if isinstance(count, bool) or int(count) != count or count < 0:
        raise ValueError(f"count must be an integer ≥ 0, got {count!r}")
    count = int(count)
    w = positive_finite("width", width, "µm")
    t = positive_finite("thickness", thickness, "µm")
    h_b = positive_finite("basecoat_thickness", basecoat_thickness, "µm")
    if np.ndim(tile) != 1 or len(tile) != 2:
        raise ValueError(f"tile must be (Lx, Ly) [µm], got {tile!r}")
    L = tuple(positive_finite("tile", v, "µm") for v in tile)
    if min(L) < math.sqrt(2.0) * w + t:
        raise ValueError(f"tile {L} µm: each side must be ≥ √2·width + thickness = {math.sqrt(2.0) * w + t:.3g} µm")
    margin = 0.5 * w if margin is None else float(margin)
    if not (math.isfinite(margin) and 0 <= margin < 0.5 * h_b):
        raise ValueError(f"margin must lie in [0, basecoat_thickness/2) = [0, {0.5 * h_b:g}) µm, got {margin!r}")
    rng = np.random.default_rng(int(seed))
    c = np.stack([rng.uniform(0, L[0], count), rng.uniform(0, L[1], count), rng.uniform(margin, h_b - margin, count)], -1)
    tilt_deg = np.zeros(count) if tilt is None else _sample_tilt_np(_as_tilt(tilt), rng, count)
    nrm, u = _frames(tilt_deg, rng.uniform(0, 2 * np.pi, count), rng.uniform(0, 2 * np.pi, count))
    return PlateletArray(centers=jnp.asarray(c.reshape(count, 3)), normals=jnp.asarray(nrm), axes_u=jnp.asarray(u.reshape(count, 3)),
                         widths=jnp.full((count,), w), thickness=t, tile=L, basecoat_thickness=h_b)


def _remove_overlaps(centers, R, e, hz, L, h_b, test, max_attempts, rng, replacements, failed, pulse=None) -> None:
    """Random sequential addition, hardest first; modifies centers/replacements/failed in place.

    Candidate positions of platelet i are tested in vectorised batches: the first holds its
    drawn position and fresh ones, sized from a running mean of the attempts recent platelets
    needed (about two expected successes), later batches double; the first non-overlapping
    candidate in draw order wins, so the drawn position is kept whenever it is free.
    `replacements[i]` is the index of the winner (0: not moved). `pulse`: a `Heartbeat` given the fraction placed.
    """
    h = aabb_half_extents(R, e)
    # Hardest first: order by the volume a platelet excludes to the mean neighbour: plates of
    # widths a, b at random relative rotation have a mean Minkowski area a² + b² + (8/π)ab, and
    # the vertical extents add (v = t cos τ + w sin τ · 2√2/π, rotation-averaged).
    w = 2 * e[:, 0]
    cos_t = np.abs(R[:, 2, 2])
    v = 2 * e[:, 2] * cos_t + w * np.sqrt(np.clip(1 - cos_t**2, 0, None)) * (2 * np.sqrt(2) / np.pi)
    excluded = (w**2 + np.mean(w**2) + (8 / np.pi) * w * np.mean(w)) * (v + np.mean(v))
    order = np.argsort(-excluded, kind="stable")
    cells = _ColumnCells(L, h[:, :2].max(axis=1))
    Lx, Ly = L
    Lv = np.array([Lx, Ly])
    # With every reach h_i + h_j ≤ L/2 only the minimum image can touch (the usual case).
    min_image_only = bool(np.all(2 * h[:, :2].max(axis=0) <= 0.5 * Lv))
    zero = np.zeros(3)
    mean_trials = 1.0
    for placed, i in enumerate(order):
        if pulse is not None:
            pulse(placed / len(order))
        hx, hy = h[i, 0], h[i, 1]
        done = 0  # candidate positions tried so far (the first is the drawn one)
        k = int(min(np.ceil(mean_trials), 1024))
        accepted = False
        while done <= max_attempts:
            k = min(k, max_attempts + 1 - done)
            r = rng.random((k, 3))
            P = np.stack([r[:, 0] * Lx, r[:, 1] * Ly, hz[i] + r[:, 2] * (h_b - 2 * hz[i])], axis=1)
            if done == 0:
                P[0] = centers[i]
            kk, jj = cells.query(P[:, 0], P[:, 1], hx, hy)
            bad = np.zeros(k, dtype=bool)
            if kk.size:
                d = centers[jj] - P[kk]
                d[:, :2] -= Lv * np.round(d[:, :2] / Lv)
                near = np.all(np.abs(d) < h[i] + h[jj], axis=1)
                kk, jj, d = kk[near], jj[near], d[near]
                if kk.size and min_image_only:
                    if test == "sat":
                        hit = obb_overlap(zero, R[i], e[i], d, R[jj], e[jj])
                    else:
                        hit = midplane_overlap(zero, R[i], 2 * e[i, 0], d, R[jj], 2 * e[jj, 0])
                    bad[kk[hit]] = True
                elif kk.size:
                    hit = periodic_overlap(P[kk], R[i], e[i], centers[jj], R[jj], e[jj], L, test)
                    bad[kk[hit]] = True
            good = np.flatnonzero(~bad)
            if good.size:
                g = int(good[0])
                centers[i] = P[g]
                replacements[i] = done + g
                accepted = True
                break
            done += k
            k = 2 * k
        if not accepted:
            failed[i] = True
            replacements[i] = max_attempts
        mean_trials = 0.9 * mean_trials + 0.1 * (replacements[i] + 1)
        cells.insert(int(i), centers[i, 0], centers[i, 1], hx, hy)


def platelet_array_for_sample(name: str, seed=0, **overrides):
    """A platelet array with a reference sample's statistics (`load_sample`).

    Uses the sample's PVC, tilt gamma law, log-normal size law from its D10/D50/D90, platelet
    and basecoat thickness; any keyword of `generate_platelet_array` overrides them.
    """
    from .._samples import load_sample
    from ._sizes import LogNormalSizes

    s = load_sample(name)
    kwargs = dict(
        pvc=s.pvc.value,
        tilt=GammaTilt(s.tilt_shape.value, s.tilt_scale.value),
        sizes=LogNormalSizes.from_quantiles(s.size_d10, s.size_d50, s.size_d90),
        thickness=s.platelet_thickness,
        basecoat_thickness=s.basecoat_thickness,
    )
    kwargs.update(overrides)
    return generate_platelet_array(seed, **kwargs)

