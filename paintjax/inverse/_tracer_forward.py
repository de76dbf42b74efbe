"""The ray tracer as a forward map of the inverse layer: θ = (shape, scale, σ, τ) → L* per MA98 angle.

`TracerLStar` is a plain callable θ (batch, 4) → L* (batch, m) that runs `paintjax.tracer._trace.trace`
once per row with **common random numbers** (CRN), so that its output is as smooth in θ as a
Monte Carlo estimate can be:

* *Array.* One reference array per seed is generated (`platelet_array_for_sample`, overlaps
  removed by random sequential addition) at a fixed, well-aligned tilt law `REFERENCE_TILT`.
  For θ every platelet keeps its width, lateral position, azimuth and in-plane rotation; its tilt
  moves by the monotone transport t = F_θ⁻¹(F_ref(t_ref)) (truncated gamma CDFs, so the tilts
  follow the θ law exactly), is lowered where the box would not fit in the film, and its height
  keeps its relative place in the allowed range. That is a smooth function of θ. (Generating a
  fresh array per θ is not: random sequential addition re-orders and re-places platelets, and a
  0.5 % step in shape moved L*15 by several units in a test.) With `TracerSettings.arrays` > 1 an evaluation
  is the mean over that many reference arrays (seeds seed, seed + 1, …, the rays shared equally), so that
  one atypical array counts 1/arrays as much (the wide emulator uses four). Boxes are not de-overlapped again
  after the transport; the bias this causes (brighter at 45–110° where the tilt law is wide) is measured
  against independent runs and removed by the emulators (`paintjax.inverse._error_model.RunToRun`).
* *Rays.* A fixed ray count and seed (the tracer's random numbers are a hash of (seed, ray id,
  step)). Discrete events (a ray hitting a platelet edge or not) still make the far angles
  (75°, 110°) spiky; CRN cannot remove those.
* *Angles.* The five standard angles (15°, 25°, 45°, 75°, 110°) are traced together; other in-plane
  angles of 45° illumination (`TracerSettings.extra_aspecular`, e.g. MA98's −15°) in a second pass
  with the same seed: the same array and the same paths, the detector's own shadow-roulette draws.
  The tracer draws each detector's roulette uniform by its position among the detectors, so adding
  −15° to the first pass would move the others' draws (by ≤ 0.006 L* at two design points); in its own
  pass it leaves the five angles' L* bit for bit as they were.
* *Platelet BRDF.* σ and τ enter through a grid of platelet tables (`paintjax.brdf._grid.platelet_brdf_grid`,
  log σ × log τ, built once per process and cached table by table): by default a table is built at (σ, τ) from the
  nodes' in-plane lobes interpolated there (`BRDFTableGrid.build_at`, `TracerSettings.brdf_between_nodes`), the
  closest to a table built directly (within 3.9 % L1 over the wide box's grid, against 12.7 % for the
  differentiable `at`, which moved L* by up to 3 at the steep corner); its own lobe fit at every point leaves
  steps of ≈ 0.05 L* under 1 % changes, below the tracer's noise. Default `table_source="wave"`: the
  hybrid model's wave-solver tables (30 tables, ≈ 1 min on 2 cores, cached). `"kirchhoff"` builds
  the tables from closed-form 1-D Kirchhoff lobes instead (fast, used by the tests); those inherit
  the Kirchhoff approximation's reflectance above 1 near grazing incidence.

Otherwise the physics of `paintjax simulate --brdf wave` (flat clearcoat 50 µm, n = 1.5, primer
albedo 0.3, PVC 20 %, the samples' size law, zero detector apertures), on a 400 µm tile (about
1400 platelets; the CLI uses 752 µm) at 65 536 rays per evaluation (`TracerSettings`).
Its registered Gaussian-process emulators ("tracer-emulator", "tracer-emulator-wide") are in
`paintjax.inverse._tracer_emulator`.

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
import time
from collections.abc import Sequence

import numpy as np

#: Bump when the meaning of a tracer evaluation changes (physics, settings semantics): emulator
#: cache keys depend on it (the BRDF table version enters the key separately). A change of the
#: random stream alone, which leaves every estimate's expectation as it was, keeps the version:
#: cached and shipped evaluations stay valid estimates of the same quantities, within their
#: standard errors, though no longer reproduced bit for bit (so the lobe samplers' one-uniform
#: component draw and the tables' radial textures, ≤ 2 × 10⁻⁴ relative, kept version 4).
TRACER_FORWARD_VERSION = 5  # 4: the BRDF grid's `at` aligns lobe widths between nodes; 5: the coherent lobe carries R_coh to grazing

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
        rays: rays per evaluation (fixed, so common random numbers hold exactly), shared equally by the arrays.
        seed: seed of the platelet array and of the rays (the CRN seed; with several arrays the first of
            `arrays` consecutive seeds).
        arrays: reference arrays a CRN evaluation averages over (each with its own seed and rays, `rays / arrays`
            of them): L* is the mean of the arrays' L*, so one atypical array moves it by 1/`arrays` as much,
            at the same ray count (independent runs, mode "rsa", stay one array: a panel's realisation).
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
        extra_aspecular: aspecular angles [deg] besides the standard five (45° illumination, e.g. −15),
            traced in a second pass with the same seed (see the module docstring).
        brdf_between_nodes: how the platelet BRDF at (σ, τ) is made from the grid's tables: "build_at"
            (default: a table built from the in-plane lobes interpolated there, `BRDFTableGrid.build_at`;
            over the wide box's grid within 0.4–3.9 % L1 of a table built directly, 3 of 42 cells above 3 %, 2 of them beyond
            the spread of two direct tables from other profiles; platelet tables version 13)
            or "at" (the differentiable interpolation of the tables, `BRDFTableGrid.at`; up to 12.7 %,
            14 cells above 3 %, moving L* by up to 3 at the steep corner: `python
            experiments/grid_interpolation.py --inverse-grid`).
    """

    sample: str = "silver1"
    rays: int = 65536
    seed: int = 0
    arrays: int = 1
    tile_um: float = 400.0
    primer_albedo: float = 0.3
    sigma_nodes: tuple[float, float, int] = (0.02, 0.09, 6)
    tau_nodes: tuple[float, float, int] = (0.45, 1.8, 5)
    table_source: str = "wave"
    lanes: int = 2048
    batches: int = 32
    reverse_share: float = 0.0
    extra_aspecular: tuple[float, ...] = ()
    brdf_between_nodes: str = "build_at"

    def __post_init__(self):
        if int(self.rays) < 1:
            raise ValueError(f"rays must be a positive integer, got {self.rays!r}")
        if not 1 <= int(self.arrays) <= MAX_CRN_ARRAYS or int(self.rays) % int(self.arrays):
            raise ValueError(f"arrays must be an integer in [1, {MAX_CRN_ARRAYS}] that divides rays ({self.rays}), got {self.arrays!r}")
        if self.brdf_between_nodes not in ("build_at", "at"):
            raise ValueError(f"brdf_between_nodes must be 'build_at' or 'at', got {self.brdf_between_nodes!r}")
        if self.table_source not in ("wave", "kirchhoff"):
            raise ValueError(f"table_source must be 'wave' or 'kirchhoff', got {self.table_source!r}")
        for name in ("sigma_nodes", "tau_nodes"):
            lo, hi, n = getattr(self, name)
            if not (0 < lo < hi) or int(n) < 1:
                raise ValueError(f"{name} must be (lower, upper, count) with 0 < lower < upper and count >= 1, got {getattr(self, name)!r}")
        from ..instrument._geometry import MAX_POLAR_DEG, STANDARD_ASPECULAR

        extra = tuple(float(a) for a in self.extra_aspecular)
        if (len(set(extra)) != len(extra) or set(extra) & set(STANDARD_ASPECULAR)
                or not all(abs(45.0 - a) <= MAX_POLAR_DEG for a in extra)):
            raise ValueError(f"extra_aspecular must be distinct aspecular angles in [{45 - MAX_POLAR_DEG:g}, {45 + MAX_POLAR_DEG:g}] "
                             f"other than the standard {list(STANDARD_ASPECULAR)}, got {list(self.extra_aspecular)}")
        object.__setattr__(self, "extra_aspecular", extra)

    @property
    def aspecular(self) -> tuple[float, ...]:
        """Every angle this tracer gives (the standard five and the extra ones), ascending."""
        from ..instrument._geometry import STANDARD_ASPECULAR

        return tuple(sorted(STANDARD_ASPECULAR + self.extra_aspecular))

    @property
    def crn_seeds(self) -> tuple[int, ...]:
        """Seeds of the reference arrays (and their rays) of a CRN evaluation."""
        return tuple(range(int(self.seed), int(self.seed) + int(self.arrays)))

    def nodes(self, name: str) -> np.ndarray:
        lo, hi, n = getattr(self, f"{name}_nodes")
        return np.geomspace(lo, hi, int(n)) if int(n) > 1 else np.array([float(lo)])

    def identity(self) -> str:
        """Text that changes whenever what a tracer evaluation estimates would (for cache keys)."""
        from ..brdf._table import TABLE_VERSION

        d = dataclasses.asdict(self) | {"version": TRACER_FORWARD_VERSION, "table_version": TABLE_VERSION}
        if d["reverse_share"] == 0.0:  # the forward tracer, as before the option existed: same key
            del d["reverse_share"]
        if not d["extra_aspecular"]:  # the five standard angles alone, as before: same key
            del d["extra_aspecular"]
        if d["arrays"] == 1:  # one reference array, as before the option existed: same key
            del d["arrays"]
        return "TracerLStar" + json.dumps(d, sort_keys=True)


#: Most reference arrays one CRN evaluation may average over (`TracerSettings.arrays`).
MAX_CRN_ARRAYS = 64

#: Tilt law (shape, scale [deg]) of the reference arrays that the CRN arrays are transported from
#: (well aligned, so overlap removal and the film-fit redraws rarely act on it).
REFERENCE_TILT = (2.0, 1.5)


class TracerLStar:
    """Callable θ (batch, 4) [shape, scale, σ µm, τ µm] → L* (batch, m) at `angles` through the tracer.

    Common random numbers: every row uses the array seed and the ray seed `settings.seed` (or the
    `seed` argument). The BRDF grid is built (or read from the disk cache) on first use.

    Arguments:
        settings: `TracerSettings`.
        progress: print one line per evaluation.
        angles: output angles, some of `settings.aspecular` (default all); only the passes that
            hold them are traced, and an angle's L* does not depend on which others are asked.
    """

    def __init__(self, settings: TracerSettings | None = None, *, progress: bool = False, angles=None):
        self.settings = settings or TracerSettings()
        self.progress = bool(progress)
        covered = self.settings.aspecular
        self.angles = covered if angles is None else tuple(float(a) for a in angles)
        if not self.angles or len(set(self.angles)) != len(self.angles) or not set(self.angles) <= set(covered):
            raise ValueError(f"angles must be distinct angles of {list(covered)} (TracerSettings.extra_aspecular adds others), "
                             f"got {angles!r}")
        self._grid = None
        self._last_brdf = None
        self._sample = None
        self._reference = {}
        self._views, self._parent = {}, None
        self.evaluations = 0
        self.seconds = 0.0

    def __reduce__(self):
        # Pickled (e.g. into Dask tasks) as a reference: the receiving process keeps one instance per
        # settings (`shared_tracer`), so its BRDF grid, arrays and compiled tracer are built once there.
        return (shared_tracer, (self.settings, self.progress, self.angles))

    def with_angles(self, angles) -> TracerLStar:
        """The same tracer (settings, BRDF grid, arrays) at other output angles (one instance per angles)."""
        key = tuple(float(a) for a in angles)
        if key not in self._views:
            out = TracerLStar(self.settings, progress=self.progress, angles=key)
            out._sample, out._reference, out._parent = self._sample, self._reference, self
            self._views[key] = out
        return self._views[key]

    def passes(self) -> list[tuple[tuple[float, ...], list[int], list[int]]]:
        """The tracer runs per θ: (angles traced together, their output columns, their places in the run)."""
        from ..instrument._geometry import STANDARD_ASPECULAR

        out = []
        for group in (STANDARD_ASPECULAR, self.settings.extra_aspecular):
            hit = [a for a in group if a in self.angles]
            if hit:
                out.append((tuple(group), [self.angles.index(a) for a in hit], [group.index(a) for a in hit]))
        return out

    # -- lazily built pieces -------------------------------------------------------------------
    @property
    def sample(self):
        if self._sample is None:
            from .._samples import load_sample

            self._sample = load_sample(self.settings.sample)
        return self._sample

    def brdf_grid(self):
        """The (σ, τ) grid of platelet BRDF tables (built or read from the cache once)."""
        if self._grid is None and self._parent is not None:
            self._grid = self._parent.brdf_grid()
        if self._grid is None:
            from ..brdf._grid import platelet_brdf_grid

            s = self.settings
            self._grid = platelet_brdf_grid(s.nodes("sigma"), s.nodes("tau"), source=s.table_source, n_medium=self.sample.binder_index)
        return self._grid

    def brdf_at(self, sigma: float, tau: float):
        """The platelet BRDF at (σ, τ) [µm] as `settings.brdf_between_nodes` makes it from the grid (the last one
        kept: the passes of one θ share it)."""
        key = (float(sigma), float(tau))
        if self._last_brdf is None or self._last_brdf[0] != key:
            grid = self.brdf_grid()
            make = grid.build_at if self.settings.brdf_between_nodes == "build_at" else grid.at
            self._last_brdf = (key, make(*key))
        return self._last_brdf[1]

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
    def scene(self, shape: float, scale: float, seed: int, mode: str = "crn"):
        """(platelet array, its uniform grid) at tilt law (shape, scale) for `seed` (see `array`)."""
        from ..microstructure._grid import build_grid

        array = self.array(shape, scale, seed, mode)
        return array, build_grid(array)

    def trace_one(self, shape: float, scale: float, sigma: float, tau: float, *, seed: int | None = None, rays: int | None = None,
                  mode: str = "crn", aspecular=None, brdf=None, scene=None):
        """One tracer run at θ (array by `mode`, see `array`) with detectors at `aspecular` (default the
        standard five) and the platelet BRDF `brdf` (default the grid's table at (σ, τ), `brdf_at`, what the
        forward map uses; another table at the same (σ, τ) for comparisons); `scene` is this θ's and seed's
        (array, grid) when already built (`scene`); returns the `TraceResult`."""
        from ..instrument._geometry import STANDARD_ASPECULAR, ma98_geometry
        from ..tracer._options import TracerOptions
        from ..tracer._trace import trace

        st = self.settings
        seed = st.seed if seed is None else int(seed)
        s = self.sample
        array, grid = self.scene(shape, scale, seed, mode) if scene is None else scene
        brdf = self.brdf_at(sigma, tau) if brdf is None else brdf
        geometry = ma98_geometry(45.0, STANDARD_ASPECULAR if aspecular is None else aspecular, detector_aperture_deg=0.0)
        return trace(array, geometry, brdf, grid=grid, n=s.binder_index, clearcoat_thickness=s.clearcoat_thickness,
                     primer_albedo=st.primer_albedo, rays=int(st.rays if rays is None else rays), seed=seed,
                     options=TracerOptions(lanes=st.lanes, batches=st.batches, reverse_share=st.reverse_share))

    def evaluate(self, theta, *, seed: int | None = None, return_se: bool = False, mode: str = "crn"):
        """L* (batch, m) at `angles` for θ (batch, 4); with `return_se` also the tracer's batch-means SE (of the rays; with
        several arrays, of their mean). `mode` "crn" (default, smooth in θ: the mean over `settings.arrays` reference
        arrays, seeds `seed`, `seed` + 1, …) or "rsa" (one fresh generator array per θ, seed `seed`, all the rays)."""
        from ..tracer._options import EnergyCreationError

        t = self.check(theta)
        st = self.settings
        first = st.seed if seed is None else int(seed)
        # CRN: the mean over the settings' reference arrays, each with its share of the rays; "rsa": one fresh array
        seeds = [first + k for k in range(int(st.arrays))] if mode == "crn" else [first]
        rays = int(st.rays) // len(seeds)
        L = np.empty((t.shape[0], len(self.angles)))
        se = np.empty_like(L)
        for i, row in enumerate(t):
            t0 = time.perf_counter()
            scenes = {s: self.scene(row[0], row[1], s, mode) for s in seeds}  # built once, shared by the passes
            for group, cols, places in self.passes():
                try:
                    runs = [self.trace_one(*row, seed=s, rays=rays, mode=mode, aspecular=group, scene=scenes[s]) for s in seeds]
                except EnergyCreationError as err:
                    raise EnergyCreationError(f"the platelet BRDF at sigma={row[2]:.4g}, tau={row[3]:.4g} µm: {err}; narrow the (sigma, "
                                              "tau) box") from None
                L[i, cols] = np.mean([np.asarray(r.L_star)[places] for r in runs], axis=0)
                se[i, cols] = np.sqrt(np.sum([np.asarray(r.L_star_se)[places] ** 2 for r in runs], axis=0)) / len(runs)
            dt = time.perf_counter() - t0
            self.evaluations += 1
            self.seconds += dt
            if self.progress:
                print(f"  tracer θ=({', '.join(f'{v:.4g}' for v in row)}): L* {np.round(L[i], 1).tolist()} "
                      f"± {np.round(se[i], 2).tolist()} ({dt:.1f} s)", flush=True)
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
        dict with "sd" (m,), "seed_sd" (m,), "L" (rows, seeds, m), "se", "L_crn" (rows, m), "theta", "seeds" (m = len(fn.angles)).
    """
    from .._cache import cached_arrays
    from ..instrument._geometry import STANDARD_ASPECULAR

    theta = np.atleast_2d(np.asarray(theta, float))
    seeds = [int(s) for s in seeds]
    if len(seeds) < 2 or set(fn.settings.crn_seeds) & set(seeds):
        raise ValueError(f"seed_spread needs at least two seeds, all different from the CRN seeds {list(fn.settings.crn_seeds)}")
    inputs = {"identity": fn.settings.identity(), "theta": theta, "seeds": seeds, "version": 2}
    if fn.angles != STANDARD_ASPECULAR:  # the five standard angles keep their key
        inputs["angles"] = list(fn.angles)

    def build():
        L = np.empty((theta.shape[0], len(seeds), len(fn.angles)))
        se = np.empty_like(L)
        for j, s in enumerate(seeds):
            L[:, j], se[:, j] = fn.evaluate(theta, seed=s, return_se=True, mode="rsa")
        return {"L": L, "se": se, "L_crn": fn.evaluate(theta)}

    d, _ = cached_arrays("tracer-seed-spread", inputs, build, folder=cache_dir)
    L, L0 = np.asarray(d["L"]), np.asarray(d["L_crn"])
    sd = np.sqrt(np.mean((L - L0[:, None, :]) ** 2, axis=(0, 1)))
    seed_sd = np.sqrt(np.mean(np.var(L, axis=1, ddof=1), axis=0))
    return {"sd": sd, "seed_sd": seed_sd, "L": L, "se": np.asarray(d["se"]), "L_crn": L0, "theta": theta, "seeds": seeds}


def independent_runs(fn: TracerLStar, theta: Sequence[Sequence[float]], seeds: Sequence[int], *, cache_dir=None) -> dict:
    """One independent tracer run per row of `theta` (fresh generator array and rays, seed `seeds[i]`, as
    `paintjax simulate`): what a measured panel is, against which an emulator of the CRN tracer is judged.
    Cached on disk by content (`cached_arrays`, kind "tracer-independent-runs").

    Returns:
        dict with "L" and "se" (rows, m) at `fn.angles` (NaN rows where θ's platelets cannot fit the film: no
        array exists), "theta", "seeds".
    """
    from .._cache import cached_arrays
    from ..microstructure._array import PlateletFitError

    theta = np.atleast_2d(np.asarray(theta, float))
    seeds = [int(s) for s in seeds]
    if len(seeds) != theta.shape[0] or len(set(seeds)) != len(seeds) or set(fn.settings.crn_seeds) & set(seeds):
        raise ValueError(f"independent_runs needs one distinct seed per row of theta ({theta.shape[0]}), none of the CRN seeds "
                         f"{list(fn.settings.crn_seeds)}")
    inputs = {"identity": fn.settings.identity(), "theta": theta, "seeds": seeds, "angles": list(fn.angles), "version": 1}

    def one(t, s):
        try:
            return fn.evaluate(t[None], seed=s, return_se=True, mode="rsa")
        except PlateletFitError:  # a tilt law whose platelets cannot fit the film has no array: a NaN row
            return np.full((1, len(fn.angles)), np.nan), np.full((1, len(fn.angles)), np.nan)

    def build():
        runs = [one(t, s) for t, s in zip(theta, seeds)]
        return {"L": np.concatenate([r[0] for r in runs]), "se": np.concatenate([r[1] for r in runs])}

    d, _ = cached_arrays("tracer-independent-runs", inputs, build, folder=cache_dir)
    return {"L": np.asarray(d["L"]), "se": np.asarray(d["se"]), "theta": theta, "seeds": seeds}


_SHARED: dict = {}


def shared_tracer(settings: TracerSettings, progress: bool = False, angles=None) -> TracerLStar:
    """This process's `TracerLStar` for these settings and angles (created on first use). A process that
    receives one through pickling (a Dask worker) runs in float64, as the CLI does, and uses the persistent
    compilation cache."""
    key = (settings.identity(), bool(progress), None if angles is None else tuple(angles))
    if key not in _SHARED:
        import jax

        from .._cache import enable_compilation_cache

        jax.config.update("jax_enable_x64", True)
        enable_compilation_cache()
        _SHARED[key] = TracerLStar(settings, progress=progress, angles=angles)
    return _SHARED[key]


def register() -> None:
    """Make the tracer's emulators `--forward` choices (`make_forward`)."""
    from ..instrument._geometry import ASPECULAR_45
    from ._registry import register_forward
    from ._tracer_emulator import tracer_emulator, wide_tracer_emulator

    register_forward(
        "tracer-emulator",
        tracer_emulator,
        "GP emulator of the ray tracer (wave BRDF grid, common random numbers; built once, cached; "
        "error = cross-validated RMS ⊕ seed-to-seed spread)",
    )
    register_forward(
        "tracer-emulator-wide",
        wide_tracer_emulator,
        "'tracer-emulator' over shape 1.2–12, scale 0.5–5°, σ 0.015–0.15 µm, τ 0.25–2 µm, also at −15°, four arrays per run (shipped; "
        "error 3.2–4.6 L* RMS per standard angle, 4.1 at −15°)",
        angles=ASPECULAR_45,
    )
