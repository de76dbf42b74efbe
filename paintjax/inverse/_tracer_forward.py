"""The ray tracer as a forward map of the inverse layer: θ = (shape, scale, σ, τ) → five-angle L*.

`TracerLStar` is a plain callable θ (batch, 4) → L* (batch, 5) that runs `paintjax.tracer._trace.trace`
once per row with **common random numbers** (CRN), so that its output is as smooth in θ as a
Monte Carlo estimate can be:

* *Array.* One reference array per seed is generated (`platelet_array_for_sample`, overlaps
  removed by random sequential addition) at a fixed, well-aligned tilt law `REFERENCE_TILT`.
  For θ every platelet keeps its width, lateral position, azimuth and in-plane rotation; its tilt
  moves by the monotone transport t = F_θ⁻¹(F_ref(t_ref)) (truncated gamma CDFs, so the tilts
  follow the θ law exactly), is lowered where the box would not fit in the film, and its height
  keeps its relative place in the allowed range. That is a smooth function of θ. (Generating a
  fresh array per θ is not: random sequential addition re-orders and re-places platelets, and a
  0.5 % step in shape moved L*15 by several units in a test.) Boxes are not de-overlapped again
  after the transport; the bias this causes is inside the measured model error below.
* *Rays.* A fixed ray count and seed (the tracer's random numbers are a hash of (seed, ray id,
  step)). Discrete events (a ray hitting a platelet edge or not) still make the far angles
  (75°, 110°) spiky; CRN cannot remove those.
* *Platelet BRDF.* σ and τ enter through the PCHIP-interpolated grid of platelet tables
  (`paintjax.brdf._table.platelet_brdf_grid`, log σ × log τ, built once per process and cached
  table by table), so the BRDF is a continuous, piecewise-smooth function of (σ, τ). Default `table_source="wave"`: the
  hybrid model's wave-solver tables (30 tables, ≈ 1 min on 2 cores, cached). `"kirchhoff"` builds
  the tables from closed-form 1-D Kirchhoff lobes instead (fast, used by the tests); those inherit
  the Kirchhoff approximation's reflectance above 1 near grazing incidence.

Otherwise the physics of `paintjax simulate --brdf wave` (flat clearcoat 50 µm, n = 1.5, primer
albedo 0.3, PVC 20 %, the samples' size law, zero detector apertures), on a 400 µm tile (about
1400 platelets; the CLI uses 752 µm) at 65 536 rays per evaluation (`TracerSettings`).

Registered as ``"tracer-emulator"`` (`paintjax fit --forward tracer-emulator`): a Gaussian-process
emulator (`paintjax.inverse._forward.build_emulator`) of `TracerLStar` over the prior box `TRACER_BOX`
(96 training + 24 held-out tracer runs), built once and cached under a content hash, design
evaluations check-pointed. It is physics-informed: per angle the GP models the tracer minus a
linear function of the analytic single-scatter L* (`AnalyticForward`, diffuse 0), and the
analytic L* at 15°, 25°, 45° are extra GP inputs; against a plain GP on the same design this cuts
the held-out/leave-one-out error at 15° and 25° by about a third and leaves 45–110° unchanged
(`experiments/build_tracer_emulator.py` records both). Its `error_sd` is the emulator's
cross-validated RMS against the same CRN tracer (the 24 held-out errors pooled with the 96
leave-one-out errors; `Emulator.error_sd`) combined in quadrature with the **CRN-vs-independent spread**: the RMS difference between
the CRN evaluation and independent tracer runs (fresh generator arrays and rays, seeds ≠ the CRN
seed) at `SPREAD_THETA` (`seed_spread`) — the error of one finite tile and ray count against
another realisation, including the transport's bias.

Prior box (`TRACER_BOX`, log-uniform in each): shape 1.2–8, scale 0.7–4°, σ 0.02–0.09 µm,
τ 0.45–1.8 µm. Chosen from physics, not from the measured answers: mean tilts shape × scale from
≈ 0.8° (almost perfectly aligned) to ≈ 30° (poorly aligned), platelet roughness from nearly
specular (2kσ ≈ 0.75 at σ = 20 nm, over half the light coherent) to strongly diffusing
(σ = 90 nm, coherent share < 10⁻³ at normal incidence), slopes 2σ/τ from 0.02 to 0.4. Rougher
platelets were left out because the platelet tables of `paintjax.brdf._table` version 7 created energy
between grid nodes (L* > 300 at σ = 0.14, τ = 0.39 µm: the symmetric scale and the lobe were
interpolated separately). Since version 9 the grid re-solves the scale at the interpolated point, so
the albedo is the interpolated reflectance (within 1 % by quadrature, within 3 % of a table built
directly), and tables over σ 0.01–0.30 µm, τ 0.2–2.0 µm conserve energy (tests/test_platelet_brdf_truth.py);
widening this box is the inverse layer's decision (its emulator design would need rebuilding). `trace`
still refuses evaluations that create energy (`_tracer.MAX_CREATED_ENERGY`). Its
log-centres (3.1, 1.67°, 0.042 µm, 0.90 µm) are not the measured values (2.29–2.98, 2.1–2.18°,
0.051 µm, 0.64 µm), which sit at 25–62 % of each log-range. The box is narrower than the
registered parameter bounds so that a design of 120 tracer runs can cover it.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

#: Bump when the meaning of a tracer evaluation changes (physics, settings semantics): emulator
#: cache keys depend on it (the BRDF table version enters the key separately).
TRACER_FORWARD_VERSION = 4  # 4: the BRDF grid's `at` aligns lobe widths between nodes

#: Parameters the tracer forward map consumes, in column order.
TRACER_PARAMETERS = ("shape", "scale", "sigma", "tau")

#: Prior box of the tracer emulator (log-uniform priors inside; see the module docstring).
TRACER_BOX: dict[str, tuple[float, float]] = {
    "shape": (1.2, 8.0),
    "scale": (0.7, 4.0),
    "sigma": (0.02, 0.09),
    "tau": (0.45, 1.8),
}


@dataclasses.dataclass(frozen=True)
class TracerSettings:
    """Settings of one tracer evaluation (all enter the emulator's cache key).

    Arguments:
        sample: reference sample whose non-tilt statistics (PVC, sizes, thicknesses, coat) are used.
        rays: rays per evaluation (fixed, so common random numbers hold exactly).
        seed: seed of the platelet array and of the rays (the CRN seed).
        tile_um: lateral period of the generated array [µm] (the CLI default is 752 µm; the
            tracer rotates the instrument per ray, so a smaller tile mostly costs array variance,
            which the seed-to-seed spread measures).
        primer_albedo: Lambertian primer albedo.
        sigma_nodes, tau_nodes: (lower, upper, count) of the geometric BRDF-grid nodes [µm].
        table_source: "wave" (default: the hybrid wave-based tables) or "kirchhoff" (1-D
            Kirchhoff lobes through the same table/grid machinery; fast, for tests).
        lanes, batches: `TracerOptions` lanes per device and batch-means groups.
        reverse_share: `TracerOptions.reverse_share` (default 0: the forward tracer alone, as the
            emulator's design was built and validated; the CRN noise enters its error model, and
            the bidirectional passes would cost ≈ 2.5× per run).
    """

    sample: str = "silver1"
    rays: int = 65536
    seed: int = 0
    tile_um: float = 400.0
    primer_albedo: float = 0.3
    sigma_nodes: tuple[float, float, int] = (0.02, 0.09, 6)
    tau_nodes: tuple[float, float, int] = (0.45, 1.8, 5)
    table_source: str = "wave"
    lanes: int = 2048
    batches: int = 32
    reverse_share: float = 0.0

    def __post_init__(self):
        if int(self.rays) < 1:
            raise ValueError(f"rays must be a positive integer, got {self.rays!r}")
        if self.table_source not in ("wave", "kirchhoff"):
            raise ValueError(f"table_source must be 'wave' or 'kirchhoff', got {self.table_source!r}")
        for name in ("sigma_nodes", "tau_nodes"):
            lo, hi, n = getattr(self, name)
            if not (0 < lo < hi) or int(n) < 1:
                raise ValueError(f"{name} must be (lower, upper, count) with 0 < lower < upper and count >= 1, got {getattr(self, name)!r}")

    def nodes(self, name: str) -> np.ndarray:
        lo, hi, n = getattr(self, f"{name}_nodes")
        return np.geomspace(lo, hi, int(n)) if int(n) > 1 else np.array([float(lo)])

    def identity(self) -> str:
        """Text that changes whenever a tracer evaluation would (for cache keys)."""
        from ..brdf._table import TABLE_VERSION

        d = dataclasses.asdict(self) | {"version": TRACER_FORWARD_VERSION, "table_version": TABLE_VERSION}
        if d["reverse_share"] == 0.0:  # the forward tracer, as before the option existed: same key
            del d["reverse_share"]
        return "TracerLStar" + json.dumps(d, sort_keys=True)


#: Tilt law (shape, scale [deg]) of the reference arrays that the CRN arrays are transported from
#: (well aligned, so overlap removal and the film-fit redraws rarely act on it).
REFERENCE_TILT = (2.0, 1.5)


class TracerLStar:
    """Callable θ (batch, 4) [shape, scale, σ µm, τ µm] → five-angle L* (batch, 5) through the tracer.

    Common random numbers: every row uses the array seed and the ray seed `settings.seed` (or the
    `seed` argument). The BRDF grid is built (or read from the disk cache) on first use.

    Arguments:
        settings: `TracerSettings`.
        progress: print one line per evaluation.
    """

    def __init__(self, settings: TracerSettings | None = None, *, progress: bool = False):
        self.settings = settings or TracerSettings()
        self.progress = bool(progress)
        self._grid = None
        self._sample = None
        self._reference = {}
        self.evaluations = 0
        self.seconds = 0.0

    def __reduce__(self):
        # Pickled (e.g. into Dask tasks) as a reference: the receiving process keeps one instance per
        # settings (`shared_tracer`), so its BRDF grid, arrays and compiled tracer are built once there.
        return (shared_tracer, (self.settings, self.progress))

    # -- lazily built pieces -------------------------------------------------------------------
    @property
    def sample(self):
        if self._sample is None:
            from .._samples import load_sample

            self._sample = load_sample(self.settings.sample)
        return self._sample

    def brdf_grid(self):
        """The (σ, τ) grid of platelet BRDF tables (built or read from the cache once)."""
        if self._grid is None:
            from ..brdf._grid import platelet_brdf_grid

            s = self.settings
            self._grid = platelet_brdf_grid(s.nodes("sigma"), s.nodes("tau"), source=s.table_source, n_medium=self.sample.binder_index)
        return self._grid

    def check(self, theta) -> np.ndarray:
        t = np.asarray(theta, dtype=float)
        if t.ndim == 1:
            t = t[None]
        if t.ndim != 2 or t.shape[1] != 4:
            raise ValueError(f"theta must have shape (batch, 4) with columns {', '.join(TRACER_PARAMETERS)}, got {np.shape(theta)}")
        if not np.all(np.isfinite(t)) or np.any(t <= 0):
            raise ValueError("theta must be finite and positive (shape, scale [deg], sigma, tau [µm])")
        s = self.settings
        for j, name in ((2, "sigma"), (3, "tau")):
            nodes = s.nodes(name)
            if len(nodes) > 1 and (np.any(t[:, j] < nodes[0] * (1 - 1e-9)) or np.any(t[:, j] > nodes[-1] * (1 + 1e-9))):
                raise ValueError(f"{name} must lie in the BRDF grid range [{nodes[0]:g}, {nodes[-1]:g}] µm, got {t[:, j]}")
        return t

    # -- arrays --------------------------------------------------------------------------------
    def reference_array(self, seed: int):
        """The seed's platelet array at the reference tilt law `REFERENCE_TILT` (random sequential
        addition, overlaps removed), from which every θ's CRN array is transported."""
        if seed not in self._reference:
            from ..microstructure._array import platelet_array_for_sample
            from ..microstructure._tilt import GammaTilt

            self._reference[seed] = platelet_array_for_sample(self.sample.name, seed, tilt=GammaTilt(*REFERENCE_TILT), tile=self.settings.tile_um)
        return self._reference[seed]

    def array(self, shape: float, scale: float, seed: int, mode: str = "crn"):
        """Platelet array at tilt law (shape, scale).

        mode "crn": the reference array of `seed` with every platelet's tilt moved by the monotone
        transport t = F_θ⁻¹(F_ref(t_ref)) (truncated gamma CDFs), its azimuth and in-plane rotation
        kept, its tilt lowered where needed so the box still fits in the film, and its height
        re-centred (same relative position in its allowed range): a smooth function of θ; overlaps
        between boxes are not removed again. mode "rsa": a fresh array from the generator at θ
        (overlaps removed; what `paintjax simulate` uses, but jumps between nearby θ).
        """
        from ..microstructure._array import (
            PlateletArray,
            _frames,
            _tilt_cdf_np,
            _tilt_ppf_np,
            _vertical_half_extent,
            platelet_array_for_sample,
        )
        from ..microstructure._tilt import GammaTilt

        if mode == "rsa":
            return platelet_array_for_sample(self.sample.name, seed, tilt=GammaTilt(float(shape), float(scale)), tile=self.settings.tile_um)
        if mode != "crn":
            raise ValueError(f"mode must be 'crn' or 'rsa', got {mode!r}")
        import jax.numpy as jnp

        ref = self.reference_array(seed)
        centers, normals, axes_u = (np.asarray(a, float) for a in (ref.centers, ref.normals, ref.axes_u))
        w, t, h_b = np.asarray(ref.widths, float), float(ref.thickness), float(ref.basecoat_thickness)
        tilt_ref = np.degrees(np.arccos(np.clip(normals[:, 2], -1.0, 1.0)))
        phi = np.arctan2(normals[:, 1], normals[:, 0])
        e1 = _frames(tilt_ref, phi, np.zeros_like(phi))[1]  # in-plane steepest descent (rotation 0)
        e2 = _frames(tilt_ref, phi, np.full_like(phi, 0.5 * np.pi))[1]  # in-plane horizontal (rotation 90°)
        rot = np.arctan2(np.sum(axes_u * e2, 1), np.sum(axes_u * e1, 1))

        def half_extent(tilt_deg):  # vertical half extent of each box at these tilts (same azimuth, rotation)
            return _vertical_half_extent(*_frames(tilt_deg, phi, rot), w, t)

        tilt = _tilt_ppf_np(GammaTilt(float(shape), float(scale)), _tilt_cdf_np(GammaTilt(*REFERENCE_TILT), tilt_ref))
        # Largest tilt at which each box fits in the film (bisection on the vertical half extent).
        fits = half_extent(tilt) <= 0.5 * h_b
        lo, hi = np.zeros_like(tilt), tilt.copy()
        for _ in range(50):
            mid = 0.5 * (lo + hi)
            ok = half_extent(mid) <= 0.5 * h_b
            lo, hi = np.where(ok, mid, lo), np.where(ok, hi, mid)
        tilt = np.where(fits, tilt, lo)
        n_new, u_new = _frames(tilt, phi, rot)
        hz_ref, hz = half_extent(tilt_ref), half_extent(tilt)
        rel = np.clip((centers[:, 2] - hz_ref) / np.maximum(h_b - 2 * hz_ref, 1e-12), 0.0, 1.0)
        c = centers.copy()
        c[:, 2] = hz + rel * (h_b - 2 * hz)
        return PlateletArray(centers=jnp.asarray(c), normals=jnp.asarray(n_new), axes_u=jnp.asarray(u_new), widths=jnp.asarray(w),
                             thickness=t, tile=tuple(ref.tile), basecoat_thickness=h_b)

    # -- evaluation ----------------------------------------------------------------------------
    def trace_one(self, shape: float, scale: float, sigma: float, tau: float, *, seed: int | None = None, rays: int | None = None,
                  mode: str = "crn"):
        """One tracer run at θ (array by `mode`, see `array`); returns the `TraceResult`."""
        from ..instrument._geometry import STANDARD_ASPECULAR, ma98_geometry
        from ..microstructure._grid import build_grid
        from ..tracer._options import TracerOptions
        from ..tracer._trace import trace

        st = self.settings
        seed = st.seed if seed is None else int(seed)
        s = self.sample
        array = self.array(shape, scale, seed, mode)
        grid = build_grid(array)
        brdf = self.brdf_grid().at(float(sigma), float(tau))
        geometry = ma98_geometry(45.0, STANDARD_ASPECULAR, detector_aperture_deg=0.0)
        return trace(array, geometry, brdf, grid=grid, n=s.binder_index, clearcoat_thickness=s.clearcoat_thickness,
                     primer_albedo=st.primer_albedo, rays=int(st.rays if rays is None else rays), seed=seed,
                     options=TracerOptions(lanes=st.lanes, batches=st.batches, reverse_share=st.reverse_share))

    def evaluate(self, theta, *, seed: int | None = None, return_se: bool = False, mode: str = "crn"):
        """L* (batch, 5) for θ (batch, 4); with `return_se` also the tracer's batch-means SE.
        `mode` "crn" (default, smooth in θ) or "rsa" (fresh generator array per θ)."""
        from ..tracer._options import EnergyCreationError

        t = self.check(theta)
        L = np.empty((t.shape[0], 5))
        se = np.empty((t.shape[0], 5))
        for i, row in enumerate(t):
            t0 = time.perf_counter()
            try:
                r = self.trace_one(*row, seed=seed, mode=mode)
            except EnergyCreationError as err:
                raise EnergyCreationError(f"the platelet BRDF at sigma={row[2]:.4g}, tau={row[3]:.4g} µm: {err}; narrow the (sigma, tau) "
                                          "box") from None
            L[i], se[i] = r.L_star, r.L_star_se
            dt = time.perf_counter() - t0
            self.evaluations += 1
            self.seconds += dt
            if self.progress:
                print(f"  tracer θ=({', '.join(f'{v:.4g}' for v in row)}): L* {np.round(r.L_star, 1).tolist()} "
                      f"± {np.round(r.L_star_se, 2).tolist()} ({dt:.1f} s)", flush=True)
        return (L, se) if return_se else L

    def __call__(self, theta):
        return self.evaluate(theta)


def seed_spread(fn: TracerLStar, theta: Sequence[Sequence[float]], seeds: Sequence[int], *, cache_dir=None) -> dict:
    """Error of the CRN tracer against independent tracer runs, per angle.

    At each row of `theta`: the CRN evaluation (seed `fn.settings.seed`, transported array) and
    independent runs with every seed of `seeds` (fresh generator arrays with overlaps removed, as
    `paintjax simulate`, and fresh rays). "sd" is the RMS of (independent − CRN) over rows and
    seeds: the finite-tile and Monte Carlo error of the CRN model (both its own and the
    independent run's realisation) plus any bias of the transported arrays; "seed_sd" the pooled
    standard deviation among the independent runs alone. Cached on disk by content (`cached_arrays`,
    kind "tracer-seed-spread").

    Returns:
        dict with "sd" (5,), "seed_sd" (5,), "L" (rows, seeds, 5), "se", "L_crn" (rows, 5), "theta", "seeds".
    """
    from .._cache import cached_arrays

    theta = np.atleast_2d(np.asarray(theta, float))
    seeds = [int(s) for s in seeds]
    if len(seeds) < 2 or fn.settings.seed in seeds:
        raise ValueError(f"seed_spread needs at least two seeds, all different from the CRN seed {fn.settings.seed}")
    inputs = {"identity": fn.settings.identity(), "theta": theta, "seeds": seeds, "version": 2}

    def build():
        L = np.empty((theta.shape[0], len(seeds), 5))
        se = np.empty_like(L)
        for j, s in enumerate(seeds):
            L[:, j], se[:, j] = fn.evaluate(theta, seed=s, return_se=True, mode="rsa")
        return {"L": L, "se": se, "L_crn": fn.evaluate(theta)}

    d, _ = cached_arrays("tracer-seed-spread", inputs, build, folder=cache_dir)
    L, L0 = np.asarray(d["L"]), np.asarray(d["L_crn"])
    sd = np.sqrt(np.mean((L - L0[:, None, :]) ** 2, axis=(0, 1)))
    seed_sd = np.sqrt(np.mean(np.var(L, axis=1, ddof=1), axis=0))
    return {"sd": sd, "seed_sd": seed_sd, "L": L, "se": np.asarray(d["se"]), "L_crn": L0, "theta": theta, "seeds": seeds}


_SHARED: dict = {}


def shared_tracer(settings: TracerSettings, progress: bool = False) -> TracerLStar:
    """This process's `TracerLStar` for these settings (created on first use). A process that receives
    one through pickling (a Dask worker) runs in float64, as the CLI does, and uses the persistent
    compilation cache."""
    key = (settings.identity(), bool(progress))
    if key not in _SHARED:
        import jax

        from .._cache import enable_compilation_cache

        jax.config.update("jax_enable_x64", True)
        enable_compilation_cache()
        _SHARED[key] = TracerLStar(settings, progress=progress)
    return _SHARED[key]


#: θ rows and seeds of the seed-spread measurement of the registered model (inside `TRACER_BOX`:
#: a well-aligned and a poorly aligned paint, moderate roughness); seeds differ from the CRN seed 0.
SPREAD_THETA = ((2.0, 1.5, 0.06, 0.7), (4.0, 2.5, 0.09, 0.5))
#: Output columns (15°, 25°, 45°) of the analytic single-scatter model used as extra GP inputs of the
#: tracer emulator: there single scattering carries the signal; at 75°/110° it predicts almost nothing.
ANALYTIC_FEATURES = (0, 1, 2)
SPREAD_SEEDS = (101, 102, 103, 104, 105)


def tracer_emulator(
    free: Sequence[str] = TRACER_PARAMETERS,
    fixed: Mapping[str, float] | None = None,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    *,
    settings: TracerSettings | None = None,
    cache_dir="default",
    n_train: int = 96,
    n_test: int = 24,
    seed: int = 0,
    batch: int = 4,
    spread_theta=SPREAD_THETA,
    spread_seeds=SPREAD_SEEDS,
    progress: bool = False,
    analytic_mean: bool = True,
    client=None,
    **kw,
):
    """Factory of the registered ``"tracer-emulator"``: a GP emulator of `TracerLStar` (cached).

    Arguments:
        free: free parameters (those of the tracer are kept: shape, scale, sigma, tau; others such
            as "diffuse" or "discrepancy" are not inputs of this model and are ignored).
        fixed: values for tracer parameters that are not free (registered defaults otherwise).
        bounds: box overrides (default `TRACER_BOX`).
        settings: `TracerSettings` of the tracer runs.
        cache_dir: emulator cache folder ("default": `default_cache_dir()/emulators`); the BRDF
            tables and the seed-spread record live in the array cache (`$PAINTJAX_CACHE`).
        n_train, n_test, seed, batch: design of `build_emulator`.
        spread_theta, spread_seeds: where and with which seeds the seed-to-seed spread is measured
            (None: not measured, `error_sd` is the cross-validated RMS alone).
        progress: progress bar over the design and one line per tracer run.
        analytic_mean: physics-informed GP (default): the analytic single-scatter model
            (`AnalyticForward`, diffuse 0) is the linear prior mean per angle and its L* at 15°,
            25°, 45° (`ANALYTIC_FEATURES`) are extra GP inputs; False: a plain GP over θ.
        client: a Dask `distributed.Client`: the design's tracer runs are tasks on its workers (each
            worker builds its BRDF grid and compiles the tracer once, `shared_tracer`).

    Returns:
        `TracerEmulator` (an `Emulator` whose `error_sd` includes the seed-to-seed spread).
    """
    from ._analytic import AnalyticForward
    from ._emulator import build_emulator
    from ._forward import CallableForward
    from ._parameters import make_spec

    names = tuple(n for n in free if n in TRACER_PARAMETERS)
    if not names:
        raise ValueError(f"the tracer emulator needs at least one of {', '.join(TRACER_PARAMETERS)} free")
    fixed = {k: float(v) for k, v in (fixed or {}).items() if k in TRACER_PARAMETERS}
    box = {n: tuple(TRACER_BOX[n]) for n in names}
    box.update({k: tuple(v) for k, v in (bounds or {}).items() if k in names})
    spec = make_spec(names, box)
    fn = TracerLStar(settings, progress=progress)
    # Tracer parameters held fixed default to the box's log-centre, not to the measured values.
    held = {n: fixed.get(n, math.sqrt(TRACER_BOX[n][0] * TRACER_BOX[n][1])) for n in TRACER_PARAMETERS if n not in names}
    model = CallableForward(fn, TRACER_PARAMETERS, fn.settings.identity()).restrict(names, held)
    t0 = time.perf_counter()
    # a coarse quadrature (24 × 16 nodes: L* within 0.01 of the default 64 × 48, 3× cheaper) keeps MCMC fast
    mean = AnalyticForward(tilt_nodes=24, azimuth_nodes=16).restrict(names, held | {"diffuse": 0.0}) if analytic_mean else None
    em = build_emulator(model, spec, n_train=n_train, n_test=n_test, seed=seed, cache_dir=cache_dir, batch=batch, progress=progress,
                        mean=mean, mean_features=ANALYTIC_FEATURES if analytic_mean else (), client=client)
    build_seconds = time.perf_counter() - t0
    spread = None
    if spread_theta is not None:
        array_cache = None
        if cache_dir not in ("default", None):
            array_cache = Path(cache_dir)
        spread = seed_spread(fn, spread_theta, spread_seeds, cache_dir=array_cache)
    return _wrap(em, spread, build_seconds=build_seconds, evaluations=fn.evaluations, direct=fn)


#: Emulator key → build/error information and the direct tracer callable (for `emulator_check`).
_INFO: dict[str, dict] = {}
_DIRECT: dict[str, TracerLStar] = {}


def _wrap(em, spread: dict | None, *, build_seconds: float, evaluations: int, direct: TracerLStar):
    from ._emulator import Emulator

    class_ = _tracer_emulator_class()
    fields = {f.name: getattr(em, f.name) for f in dataclasses.fields(Emulator)}
    sd = () if spread is None else tuple(float(v) for v in np.asarray(spread["sd"]))
    out = class_(**fields, seed_spread_sd=sd)
    _INFO[em.key] = {
        "held_out_rms_crn": list(em.held_out_rms),
        "loo_rms_crn": list(em.held_out_loo_rms),
        "cv_rms_crn": np.asarray(Emulator.error_sd.fget(em)).tolist(),
        "held_out_max": em.held_out_max,
        "seed_spread_sd": list(sd) or None,
        "seed_spread_L": None if spread is None else np.asarray(spread["L"]).tolist(),
        "seed_spread_L_crn": None if spread is None else np.asarray(spread["L_crn"]).tolist(),
        "seed_sd_independent": None if spread is None else np.asarray(spread["seed_sd"]).tolist(),
        "error_sd": np.asarray(out.error_sd).tolist(),
        "build_seconds_this_call": build_seconds,
        "tracer_evaluations_this_call": evaluations,
        "key": em.key,
    }
    _DIRECT[em.key] = direct
    return out


_CLASS = None


def _tracer_emulator_class():
    """`TracerEmulator`: an `Emulator` whose `error_sd` is cross-validated RMS ⊕ seed-to-seed spread
    (defined lazily so importing this module does not import the forward layer)."""
    global _CLASS
    if _CLASS is None:
        import equinox as eqx

        from ._emulator import Emulator

        class TracerEmulator(Emulator):
            """GP emulator of the tracer; `error_sd` = sqrt(cross-validated RMS² + seed-to-seed spread²)."""

            seed_spread_sd: tuple = eqx.field(static=True, default=())

            @property
            def error_sd(self):
                held = Emulator.error_sd.fget(self)
                if not self.seed_spread_sd:
                    return held
                return np.sqrt(held**2 + np.asarray(self.seed_spread_sd) ** 2)

            def fingerprint(self):
                return f"Tracer{super().fingerprint()},spread={self.seed_spread_sd}"  # the GP fit too, as Emulator's

        _CLASS = TracerEmulator
    return _CLASS


def tracer_info(emulator) -> dict:
    """Build and error information of a tracer emulator built in this process."""
    return _INFO[emulator.key]


def direct_tracer(emulator) -> TracerLStar:
    """The direct `TracerLStar` behind a tracer emulator built in this process."""
    return _DIRECT[emulator.key]


#: A box that holds what the published inputs read through their measurement models and what the L*
#: prefer (`docs/input_measurement.md`), and the BRDF-table grid that spans it (7 × 7 nodes, ratio ≈ 1.4).
WIDE_TRACER_BOX: dict[str, tuple[float, float]] = {"shape": (1.2, 12.0), "scale": (0.5, 5.0), "sigma": (0.02, 0.15), "tau": (0.25, 2.0)}
WIDE_TRACER_SETTINGS = TracerSettings(sigma_nodes=(0.02, 0.15, 7), tau_nodes=(0.25, 2.0, 7))


def wide_tracer_emulator(free: Sequence[str] = TRACER_PARAMETERS, fixed: Mapping[str, float] | None = None, bounds=None, **kw):
    """`tracer_emulator` over `WIDE_TRACER_BOX` with `WIDE_TRACER_SETTINGS` (registered as ``"tracer-emulator-wide"``;
    about 27 min to build on 2 cores, then cached). Its error per angle is 3.3–4.1 L* (held-out RMS 1.9–3.9, largest 15 L*)."""
    box = dict(WIDE_TRACER_BOX) | dict(bounds or {})
    return tracer_emulator(free, fixed, box, settings=kw.pop("settings", WIDE_TRACER_SETTINGS), **kw)


def register() -> None:
    from ._registry import register_forward

    register_forward(
        "tracer-emulator",
        tracer_emulator,
        "GP emulator of the ray tracer (wave BRDF grid, common random numbers; built once, cached; "
        "error = cross-validated RMS ⊕ seed-to-seed spread)",
    )
    register_forward(
        "tracer-emulator-wide",
        wide_tracer_emulator,
        "'tracer-emulator' over shape 1.2–12, scale 0.5–5°, σ 0.02–0.15 µm, τ 0.25–2 µm (about 27 min to build once; "
        "error 3.3–4.1 L* per angle)",
    )
