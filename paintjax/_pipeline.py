"""The forward pipeline: a paint's inputs → platelet array, platelet BRDF and virtual instrument → five-angle L*.

`simulate` assembles a paint from a reference sample and any overrides (tilt law, roughness, PVC,
film and platelet sizes), builds or loads its platelet array and platelet BRDF, traces it in the
virtual spectrophotometer and returns the L* with standard errors and the energy ledger. The CLI's
`paintjax simulate` and `paintjax table1` are thin shells over it.
"""

from __future__ import annotations

import hashlib
import inspect
import math
import sys
import time
import warnings
from importlib import resources

import numpy as np

from ._progress import print_progress
from ._validate import SEED, Range, check_args
from .instrument._geometry import MAX_POLAR_DEG
from .microstructure._array import MAX_PVC
from .optics._interface import MAX_WAVINESS_DEG
from .wave._checks import LOBE_RANGES
from .wave._profiles import CORRELATIONS


def flop_index_or_none(L15, L45, L110) -> float | None:
    """The flop index, or None where the formula is undefined (no light at 45°, L*15 < L*110)."""
    from .instrument._lightness import flop_index

    v = float(flop_index(L15, L45, L110))
    return v if math.isfinite(v) else None


#: Allowed median platelet width for `--d50` [µm]: the reference samples' platelets are 10–30 µm
#: across; beyond 50 µm the widest platelets (≈ 4.7 × D50) no longer fit a 20 µm film at their tilts.
D50_RANGE_UM = (1.0, 50.0)

#: The valid ranges of a simulated paint's tilt law and roughness (σ and τ as the wave tables accept them) and of
#: its array overrides (`array_overrides`), keyed by argument; the CLI checks the same ranges under its flags.
PAINT_RANGES = {"shape": Range(0.0, None, lo_open=True, why="tilt gamma shape"), "scale": Range(0.0, None, "degrees", lo_open=True),
                "sigma": LOBE_RANGES["sigma_um"], "tau": LOBE_RANGES["tau_um"]}
ARRAY_RANGES = {"pvc": Range(0.0, MAX_PVC, lo_open=True), "d50": Range(*D50_RANGE_UM, "µm"),
                "platelet_thickness": Range(0.0, None, "µm", lo_open=True)}
#: The most independent arrays `simulate` averages.
MAX_ARRAYS = 64
#: `simulate`'s scalar arguments, checked before any table, array or trace (the ray count by `check_ray_count`).
SIMULATE_RANGES = {**PAINT_RANGES, "thickness": Range(0.0, None, "µm", lo_open=True), **ARRAY_RANGES,
                   "reflectance": Range(0.0, 1.0), "primer_albedo": Range(0.0, 1.0), "waviness": Range(0.0, MAX_WAVINESS_DEG, "degrees"),
                   "illumination_deg": Range(0.0, MAX_POLAR_DEG, "degrees", lo_open=True), "seed": SEED,
                   "arrays": Range(1, MAX_ARRAYS, integer=True)}


def array_overrides(s, *, pvc=None, thickness=None, d50=None, platelet_thickness=None) -> dict:
    """Validated `generate_platelet_array` keywords for the array overrides of sample `s`.

    `thickness` is the basecoat's; `d50` rescales the sample's log-normal width law to that median
    (same spread in ln w, so D10, D90 and the default tile scale with it; `D50_RANGE_UM`);
    `platelet_thickness` is t, which must stay below the basecoat thickness (given or the sample's).
    """
    from .microstructure._array import check_pvc
    from .microstructure._sizes import LogNormalSizes, positive_finite

    out = {}
    if pvc is not None:
        out["pvc"] = check_pvc(pvc)
    if thickness is not None:
        out["basecoat_thickness"] = positive_finite("thickness", thickness, "µm")
    if d50 is not None:
        lo, hi = D50_RANGE_UM
        if not lo <= positive_finite("d50", d50, "µm") <= hi:
            raise ValueError(f"d50 (median platelet width) must lie in [{lo:g}, {hi:g}] µm, got {d50!r}")
        k = float(d50) / s.size_d50
        out["sizes"] = LogNormalSizes.from_quantiles(k * s.size_d10, float(d50), k * s.size_d90)
    if platelet_thickness is not None:
        out["thickness"] = positive_finite("platelet_thickness", platelet_thickness, "µm")
    t = out.get("thickness", s.platelet_thickness)
    h_b = out.get("basecoat_thickness", s.basecoat_thickness)
    if t >= h_b:
        name = "platelet_thickness" if platelet_thickness is not None else "thickness"
        raise ValueError(f"{name}: the platelets (t = {t:g} µm) must be thinner than the basecoat (thickness {h_b:g} µm)")
    return out


BRDFS = ("wave", "mirror", "kirchhoff")
BRDF_METHODS = ("abel", "rotate")
#: Primer albedo used when none is given: a mid-grey automotive primer (assumption; the basecoat
#: hides it, so it moves L* by well under one unit for the reference samples).
DEFAULT_PRIMER_ALBEDO = 0.3
#: Detector aperture half-angle [deg] used for delta (mirror) platelets, which need a finite one.
MIRROR_APERTURE_DEG = 2.0
#: Default precision when no ray count is given: L* standard error at every angle.
DEFAULT_TARGET_SE = 0.5
#: First round of the adaptive rule at the default precision (Silver #1's hybrid column reaches SE 0.5
#: there, seed 0), and the smallest first round (32 batches of 512 rays for the batch-means SE).
FIRST_ROUND_RAYS, MIN_FIRST_ROUND_RAYS = 131072, 16384


def check_adaptive(target_se: float, max_rays: int) -> None:
    """Validate the adaptive rule's L* SE target (0, 10] and its ray ceiling (≥ one ray per batch)."""
    if not (0.0 < float(target_se) <= 10.0):
        raise ValueError(f"target_se must lie in (0, 10] L* units, got {target_se!r}")
    from .tracer._trace import check_ray_count

    check_ray_count(max_rays, name="max_rays")


def first_round_rays(target_se: float) -> int:
    """Rays of the adaptive rule's first round for an L* SE target: SE ∝ 1/√rays, so the default
    round scaled by (DEFAULT_TARGET_SE / target)², within [MIN_FIRST_ROUND_RAYS, FIRST_ROUND_RAYS]."""
    n = int(np.ceil(FIRST_ROUND_RAYS * (DEFAULT_TARGET_SE / float(target_se)) ** 2))
    return int(np.clip(n, MIN_FIRST_ROUND_RAYS, FIRST_ROUND_RAYS))


def instrument_geometry(illumination_deg: float = 45.0, aspecular_deg=None, *, detector_aperture_deg: float = 0.0):
    """The virtual instrument of `simulate`: `ma98_geometry` with MA98's angles for its illumination by default
    (the five standard aspecular angles; at 15° illumination −45, −15, 15, 45, 80)."""
    from .instrument._geometry import ASPECULAR_15, STANDARD_ASPECULAR, ma98_geometry

    if aspecular_deg is None:
        aspecular_deg = ASPECULAR_15 if float(illumination_deg) == 15.0 else STANDARD_ASPECULAR
    return ma98_geometry(illumination_deg, aspecular_deg, detector_aperture_deg=detector_aperture_deg)


def measured_lightness(sample, geometry, measured=None):
    """The L* to compare with: `measured` (one finite value per detector), else the sample's published
    values when the geometry is theirs (45° illumination, their aspecular angles), else None."""
    gamma = np.asarray(geometry.aspecular_deg, dtype=float)
    if measured is None:
        theirs = float(geometry.illumination_polar_deg) == 45.0 and gamma.tolist() == list(sample.aspecular_deg)
        return np.asarray(sample.L_star, dtype=float) if theirs else None
    m = np.asarray(measured, dtype=float).ravel()
    if m.shape != gamma.shape or not np.all(np.isfinite(m)):
        raise ValueError(f"measured must hold {gamma.size} finite L* values, one per aspecular angle {gamma.tolist()}, got {measured!r}")
    return m


def geometry_flop_index(geometry, L):
    """Flop index from L* at 15°, 45° and 110° aspecular under 45° illumination; None if the geometry
    lacks one or the formula is undefined (no light at 45°)."""
    gamma = np.asarray(geometry.aspecular_deg, dtype=float).tolist()
    if float(geometry.illumination_polar_deg) != 45.0 or not all(a in gamma for a in (15.0, 45.0, 110.0)):
        return None
    return flop_index_or_none(*(L[gamma.index(a)] for a in (15.0, 45.0, 110.0)))


def _source_digest(*modules: str) -> str:
    h = hashlib.sha256()
    for m in modules:
        h.update(resources.files("paintjax").joinpath(m).read_bytes())
    return h.hexdigest()[:16]


def sample_array(sample: str, *, seed: int = 0, shape=None, scale=None, pvc=None, thickness=None, d50=None,
                 platelet_thickness=None):
    """The platelet array of a reference sample (with overrides, see `_common.array_overrides`), cached on disk by content."""
    from ._cache import cached_arrays
    from ._samples import load_sample
    from .microstructure._array import PlateletArray, platelet_array_for_sample
    from .microstructure._tilt import GammaTilt

    s = load_sample(sample)
    tilt = GammaTilt(s.tilt_shape.value if shape is None else shape, s.tilt_scale.value if scale is None else scale)
    overrides = {"tilt": tilt, **array_overrides(s, pvc=pvc, thickness=thickness, d50=d50, platelet_thickness=platelet_thickness)}
    inputs = {
        "sample": s.name, "seed": int(seed), "shape": float(tilt.shape), "scale": float(tilt.scale_deg),
        "pvc": None if pvc is None else float(pvc), "thickness": None if thickness is None else float(thickness),
        "generator": _source_digest("microstructure/_array.py", "microstructure/_sizes.py", "microstructure/_overlap.py", "microstructure/_tilt.py"),
    }
    # keys only when given, so the default arrays keep their cache entries; the size law by its parameters
    if "sizes" in overrides:
        law = overrides["sizes"]
        inputs["sizes"] = [law.d50, law.sigma, law.truncation]
    if platelet_thickness is not None:
        inputs["platelet_thickness"] = overrides["thickness"]

    def build():
        a = platelet_array_for_sample(s.name, seed, **overrides)
        return {"centers": np.asarray(a.centers), "normals": np.asarray(a.normals), "axes_u": np.asarray(a.axes_u),
                "widths": np.asarray(a.widths), "thickness": np.asarray(a.thickness), "tile": np.asarray(a.tile),
                "basecoat_thickness": np.asarray(a.basecoat_thickness)}

    d, _ = cached_arrays("platelet-array", inputs, build)
    import jax.numpy as jnp

    return PlateletArray(
        centers=jnp.asarray(d["centers"]), normals=jnp.asarray(d["normals"]), axes_u=jnp.asarray(d["axes_u"]),
        widths=jnp.asarray(d["widths"]), thickness=float(d["thickness"]), tile=tuple(float(x) for x in d["tile"]),
        basecoat_thickness=float(d["basecoat_thickness"]),
    )


def platelet_brdf(kind: str, *, sigma: float, tau: float, n: float, reflectance=None, wavelength_um=None, method: str = "abel",
                  correlation: str = "gaussian"):
    """The platelet BRDF of a `--brdf` choice (the wave table is built or read from the cache).

    `wavelength_um` None keeps each BRDF's default wavelength (wave and Kirchhoff 0.5 µm, mirror 0.55 µm).
    `method`: the wave table's 2-D → 3-D step, "abel" (default) or "rotate" (the original study's
    axisymmetric rotation of the in-plane lobe); wave only. `correlation`: autocorrelation of the
    wave table's synthesised profiles, "gaussian" (default) or "exponential"; wave only.
    """
    from .brdf._platelet import MirrorBRDF

    if kind not in BRDFS:
        raise ValueError(f"brdf must be one of {BRDFS}, got {kind!r}")
    if method not in BRDF_METHODS:
        raise ValueError(f"brdf_method must be one of {BRDF_METHODS}, got {method!r}")
    if method != "abel" and kind != "wave":
        raise ValueError("brdf_method applies to --brdf wave only (the wave table's 2-D → 3-D step)")
    if correlation not in CORRELATIONS:
        raise ValueError(f"correlation must be one of {CORRELATIONS}, got {correlation!r}")
    if correlation != "gaussian" and kind != "wave":
        raise ValueError("correlation applies to --brdf wave only (the Kirchhoff BRDF is the Gaussian-surface closed form)")
    wl = {} if wavelength_um is None else {"wavelength_um": float(wavelength_um)}
    if kind == "mirror":
        return MirrorBRDF(n_binder=n, reflectance=reflectance, **wl)
    if reflectance is not None:
        raise ValueError("reflectance applies to --brdf mirror only (rough BRDFs take their reflectance from Al optics)")
    if kind == "kirchhoff":
        from .brdf._analytic import BeckmannBRDF

        return BeckmannBRDF(sigma, tau, n_medium=n, **wl)
    try:
        from .brdf._table import platelet_brdf_table
    except ImportError as err:  # pragma: no cover - depends on the BRDF issue
        raise ValueError(f"brdf 'wave' is unavailable: {err}") from None
    return platelet_brdf_table(sigma, tau, n_medium=n, method=method, correlation=correlation, **wl)


def _mean_over_arrays(runs: list[dict], seconds: float) -> dict:
    """`simulate`'s result for several independent arrays: the mean of every per-angle number, and L*'s standard
    error from the arrays' spread (which holds the rays' noise too)."""
    out = dict(runs[0])
    n = len(runs)

    def stacked(key):
        return np.asarray([r[key] for r in runs], float)

    for key in ("reflectance_factor", "L_star", "Lab", "XYZ", "spectral_reflectance_factor", "histogram_reflectance_factor"):
        if out.get(key) is not None:
            out[key] = stacked(key).mean(axis=0)
    L = stacked("L_star")
    sd = L.std(axis=0, ddof=1)
    out["L_star_se"] = sd / np.sqrt(n)
    out["L_star_array_sd"] = sd
    out["L_star_rays_se"] = np.sqrt(np.sum(stacked("L_star_se") ** 2, axis=0)) / n
    out["L_star_per_array"] = L
    for key in ("reflectance_factor", "Lab"):
        if out.get(key) is not None:
            out[f"{key}_se"] = stacked(key).std(axis=0, ddof=1) / np.sqrt(n)
    out["energy"] = {k: float(np.mean([r["energy"][k] for r in runs])) for k in out["energy"]}
    out["resolved"] = np.all([np.asarray(r["resolved"]) for r in runs], axis=0)
    flop = [r["flop_index"] for r in runs]
    out["flop_index"] = None if None in flop else float(np.mean(flop))
    out["rays"] = int(sum(r["rays"] for r in runs))
    out["tracing_seconds"] = float(sum(r["tracing_seconds"] for r in runs))
    out["seconds"] = seconds
    out["arrays"] = n
    out["platelets"] = int(round(np.mean([r["platelets"] for r in runs])))
    out["tilt_ks"] = min((r["tilt_ks"] for r in runs), key=lambda k: k["p"])
    return out


def simulate(
    sample: str = "silver1",
    *,
    shape=None,
    scale=None,
    sigma=None,
    tau=None,
    pvc=None,
    thickness=None,
    d50=None,
    platelet_thickness=None,
    brdf: str = "wave",
    brdf_method: str = "abel",
    correlation: str = "gaussian",
    reflectance=None,
    primer_albedo: float = DEFAULT_PRIMER_ALBEDO,
    waviness: float = 0.0,
    illumination_deg: float = 45.0,
    aspecular_deg=None,
    geometry=None,
    measured=None,
    rays: int | None = None,
    seed: int = 0,
    single_scatter: bool = False,
    target_se: float = DEFAULT_TARGET_SE,
    max_rays: int = 4_000_000,
    options=None,
    spectral: bool = False,
    progress: bool = False,
    arrays: int = 1,
) -> dict:
    """Multi-angle tracer prediction for a sample with overrides, as the CLI's JSON dict (plus extras).

    `arrays`: the number of independent platelet arrays traced (seeds `seed`, `seed` + 1, …; `MAX_ARRAYS` at
    most). With one, "L_star_se" is the rays' standard error in that one array; an array of a finite tile is one
    draw of the microstructure, and its L* scatters from array to array beyond that (several L* at 15° for wide tilt
    laws of smooth platelets). With more, every number is the mean over the arrays and "L_star_se" its standard
    error from their spread ("L_star_array_sd"; "L_star_rays_se" the rays' part, "L_star_per_array" each array's).

    `illumination_deg`, `aspecular_deg`: the instrument (`instrument_geometry`; default 45° and the five
    standard angles); `geometry`: any `Geometry` instead (`custom_geometry`: out-of-plane detectors, other
    incidences; its apertures are kept). `measured`: L* to compare with, one per angle (`measured_lightness`; default the
    sample's published values in their geometry, else none). "flop_index" is None unless the geometry
    has 15°, 45° and 110° at 45° illumination.

    `spectral`: trace at the `SPECTRAL_NODES_NM` wavelengths (platelet BRDF at each, same array and
    seed) and combine them under D65 and the CIE 1964 10° observer (`paintjax.tracer._spectral`); the result then
    also holds "wavelengths_nm", "spectral_reflectance_factor", "XYZ", "Lab" and "Lab_se". Otherwise one
    wavelength (the BRDF's default). `progress` prints a line to stderr after every round of rays
    (rays so far, the worst L* standard error, seconds) and one per wavelength.
    """
    from ._samples import load_sample
    from .instrument._geometry import Geometry
    from .microstructure._grid import build_grid
    from .microstructure._statistics import tilt_ks
    from .microstructure._tilt import GammaTilt
    from .optics._interface import check_waviness
    from .tracer._spectral import SPECTRAL_NODES_NM, combine_spectral
    from .tracer._trace import _check_range, _seed_state, check_ray_count, trace

    t0 = time.perf_counter()
    given = dict(shape=shape, scale=scale, sigma=sigma, tau=tau, pvc=pvc, thickness=thickness, d50=d50, platelet_thickness=platelet_thickness,
                 reflectance=reflectance, primer_albedo=primer_albedo, waviness=waviness, illumination_deg=illumination_deg, seed=seed,
                 arrays=arrays)
    check_args(given, SIMULATE_RANGES, optional=("shape", "scale", "sigma", "tau", "pvc", "thickness", "d50", "platelet_thickness", "reflectance"))
    if int(arrays) > 1:
        # every other argument as given, one array per seed
        kw = {k: v for k, v in locals().items() if k in inspect.signature(simulate).parameters and k not in ("sample", "seed", "arrays")}
        runs = []
        for i in range(int(arrays)):
            if progress:
                print(f"  array {i + 1} of {int(arrays)} (seed {int(seed) + i})", file=sys.stderr, flush=True)
            runs.append(simulate(sample, **kw, seed=int(seed) + i, arrays=1))
        return _mean_over_arrays(runs, time.perf_counter() - t0)
    s = load_sample(sample)
    # every cheap check before any table or array is built
    if rays is not None:
        check_ray_count(rays, options)
    else:
        check_adaptive(target_se, max_rays)
    array_overrides(s, pvc=pvc, thickness=thickness, d50=d50, platelet_thickness=platelet_thickness)
    tilt = GammaTilt(s.tilt_shape.value if shape is None else shape, s.tilt_scale.value if scale is None else scale)
    _check_range("primer_albedo", primer_albedo, 0.0, 1.0)
    check_waviness(waviness)
    _seed_state(seed)
    if brdf == "mirror" and (sigma is not None or tau is not None):
        raise ValueError("sigma and tau apply to --brdf wave or kirchhoff only (mirror platelets are smooth)")
    custom = geometry is not None
    if custom and not isinstance(geometry, Geometry):
        raise ValueError(f"geometry must be a paintjax Geometry (ma98_geometry, custom_geometry), got {type(geometry).__name__}")
    if custom and aspecular_deg is not None:
        raise ValueError("give either geometry or aspecular_deg, not both")
    geometry = geometry if custom else instrument_geometry(illumination_deg, aspecular_deg)
    measured_L = measured_lightness(s, geometry, measured)
    n = s.binder_index
    sigma = s.sigma.value if sigma is None else sigma
    tau = s.tau.value if tau is None else tau
    wavelengths_um = [w / 1000.0 for w in SPECTRAL_NODES_NM] if spectral else [None]
    platelets = [platelet_brdf(brdf, sigma=sigma, tau=tau, n=n, reflectance=reflectance, wavelength_um=w, method=brdf_method,
                               correlation=correlation)
                 for w in wavelengths_um]
    array = sample_array(s.name, seed=seed, shape=shape, scale=scale, pvc=pvc, thickness=thickness, d50=d50,
                         platelet_thickness=platelet_thickness)
    ks = tilt_ks(array, tilt)
    if ks[1] < 1e-3:  # the generator redraws orientations that do not fit the film
        warnings.warn(f"the array's tilts do not follow the gamma law asked for (KS D = {ks[0]:.3f}, p = {ks[1]:.1e}): the basecoat "
                      f"({float(array.basecoat_thickness):g} µm, --thickness) is too thin for these platelets' widths and tilts, so "
                      "steep orientations were redrawn", RuntimeWarning, stacklevel=2)
    grid = build_grid(array)
    aperture = MIRROR_APERTURE_DEG if platelets[0].is_delta else 0.0
    if custom:
        aperture = geometry.detector_aperture_deg
    elif aperture:
        geometry = instrument_geometry(illumination_deg, aspecular_deg, detector_aperture_deg=aperture)
    kwargs = dict(grid=grid, n=n, clearcoat_thickness=s.clearcoat_thickness, primer_albedo=primer_albedo, waviness_deg=waviness, seed=seed,
                  single_scatter=single_scatter, options=options)
    if rays is None:  # the adaptive rule per wavelength: each run's SE ≤ target bounds the combination's
        kwargs.update(rays=min(first_round_rays(target_se), int(max_rays)), target_se_lstar=target_se, max_rays=max_rays)
    else:
        kwargs.update(rays=int(rays))
    results = []
    for w, platelet in zip(wavelengths_um, platelets):
        label = f"{s.name} {brdf}" + (f" {1000 * w:.0f} nm" if spectral else "")

        def report(n_rays, Lse, seconds, label=label):
            goal = f" (target {target_se:g})" if rays is None else ""
            print(f"  {label}: {n_rays:,} rays, worst L* SE {float(np.max(Lse)):.2f}{goal}, {seconds:.1f} s", file=sys.stderr, flush=True)

        beat = print_progress(label, "of this round's rays started", "left in this round") if progress else None
        results.append(trace(array, geometry, platelet, progress=report if progress else None, heartbeat=beat, **kwargs))
        if spectral and progress:
            print(f"  {label}: L* {np.round(results[-1].L_star, 1).tolist()}", file=sys.stderr, flush=True)
    res, spectrum = combine_spectral(results, SPECTRAL_NODES_NM) if spectral else (results[0], {})
    out = res.to_dict()
    out.update(spectrum)
    out["seconds"] = time.perf_counter() - t0
    out["tracing_seconds"] = res.seconds
    out["sample"] = s.name
    out["brdf"] = brdf
    out["brdf_method"] = brdf_method
    out["correlation"] = correlation
    out["aperture_deg"] = aperture
    out["waviness_deg"] = float(waviness)
    out["spectral"] = bool(spectral)
    out["illumination_deg"] = float(geometry.illumination_polar_deg)
    out["histogram_reflectance_factor"] = res.histogram_reflectance_factor
    out["flop_index"] = geometry_flop_index(geometry, res.L_star)
    out["measured_L_star"] = measured_L
    out["platelets"] = int(np.asarray(array.widths).shape[0])
    out["platelet_median_width_um"] = float(np.median(np.asarray(array.widths)))
    out["platelet_thickness_um"] = float(array.thickness)
    out["tile_um"] = list(array.tile)
    out["tilt_ks"] = {"D": ks[0], "p": ks[1]}
    return out
