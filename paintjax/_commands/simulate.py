"""`paintjax simulate`: five-angle L* of a paint from its microstructure through the ray tracer."""

from __future__ import annotations

import hashlib
import sys
import time
import warnings
from importlib import resources

import numpy as np

from ._common import (add_array_arguments, add_json_argument, add_output_argument, array_overrides, flop_index_or_none, parse_floats,
                      print_json)
from .._cache import enable_compilation_cache
from .._profiles import CORRELATIONS

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
    from .._tracer import check_ray_count

    check_ray_count(max_rays, name="max_rays")


def first_round_rays(target_se: float) -> int:
    """Rays of the adaptive rule's first round for an L* SE target: SE ∝ 1/√rays, so the default
    round scaled by (DEFAULT_TARGET_SE / target)², within [MIN_FIRST_ROUND_RAYS, FIRST_ROUND_RAYS]."""
    n = int(np.ceil(FIRST_ROUND_RAYS * (DEFAULT_TARGET_SE / float(target_se)) ** 2))
    return int(np.clip(n, MIN_FIRST_ROUND_RAYS, FIRST_ROUND_RAYS))


def instrument_geometry(illumination_deg: float = 45.0, aspecular_deg=None, *, detector_aperture_deg: float = 0.0):
    """The virtual instrument of `simulate`: `ma98_geometry` with MA98's angles for its illumination by default
    (the five standard aspecular angles; at 15° illumination −45, −15, 15, 45, 80)."""
    from .._instrument import ASPECULAR_15, STANDARD_ASPECULAR, ma98_geometry

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


def register(sub) -> None:
    p = sub.add_parser(
        "simulate",
        help="ray-trace a sample's microstructure: five-angle L* with standard errors",
        description="Ray-batch Monte Carlo through a generated platelet array under a clearcoat (flat unless --waviness), seen by a virtual "
        "multi-angle spectrophotometer (default: 45° illumination, aspecular 15, 25, 45, 75, 110°; MA98's other angles "
        "with --illumination and --aspecular). Lengths in µm, angles in degrees.",
    )
    p.add_argument("--sample", default="silver1", help="reference sample: silver1 or silver2 (default silver1)")
    p.add_argument("--shape", type=float, help="tilt gamma shape (> 0); default: the sample's")
    p.add_argument("--scale", type=float, help="tilt gamma scale [deg] (> 0); default: the sample's")
    p.add_argument("--sigma", type=float, help="platelet rms roughness σ [µm]; default: the sample's (0.051)")
    p.add_argument("--tau", type=float, help="platelet correlation length τ [µm]; default: the sample's (0.64)")
    p.add_argument("--thickness", type=float, help="basecoat thickness h_b [µm]; default: the sample's (20)")
    add_array_arguments(p)
    p.add_argument("--brdf", choices=BRDFS, default="wave",
                   help="platelet BRDF: wave (hybrid, wave-based table; default), mirror (smooth Al), kirchhoff (analytic Beckmann)")
    p.add_argument("--brdf-method", choices=BRDF_METHODS, default="abel",
                   help="wave table's 2-D → 3-D step: abel (inverse Abel of the shift-invariant lobe; default) or rotate "
                   "(the original study's rotation of the in-plane lobe about the specular direction)")
    p.add_argument("--correlation", choices=CORRELATIONS, default="gaussian",
                   help="autocorrelation of the wave table's synthesised platelet profiles at the given σ, τ (1/e length): "
                   "gaussian (default) or exponential (a non-differentiable surface, so its lobes are not converged in the "
                   "solver's sampling; a trend, not an answer); wave only")
    p.add_argument("--reflectance", type=float, help="constant platelet reflectance in [0, 1] (mirror only); default: Fresnel of Al")
    p.add_argument("--primer-albedo", type=float, default=DEFAULT_PRIMER_ALBEDO,
                   help=f"Lambertian primer albedo in [0, 1] (default {DEFAULT_PRIMER_ALBEDO})")
    p.add_argument("--waviness", type=float, default=0.0, help="clearcoat RMS slope angle [deg] in [0, 15]: a wavy (microfacet dielectric) top surface; default 0 = flat")
    p.add_argument("--illumination", type=float, default=45.0,
                   help="illumination polar angle [deg] in (0, 85] (default 45; an MA98 also illuminates at 15)")
    p.add_argument("--aspecular",
                   help="comma-separated aspecular angles [deg], each leaving the detector within ±85° of the normal; default "
                   "15,25,45,75,110 (at 15° illumination MA98's -45,-15,15,45,80); e.g. --aspecular=-15,15,25,45,75,110 for MA98's six (the = keeps the minus from reading as an option)")
    p.add_argument("--measured",
                   help="comma-separated measured L*, one per aspecular angle, to compare with; default: the sample's "
                   "published values when the geometry is the standard five at 45°")
    p.add_argument("--rays", type=int, help=f"number of rays; default: as many as needed for an L* standard error ≤ {DEFAULT_TARGET_SE}")
    p.add_argument("--seed", type=int, default=0, help="random seed of the array and the rays (default 0)")
    p.add_argument("--single-scatter", action="store_true", help="score only the first scattering event of each path")
    p.add_argument("--spectral", action="store_true",
                   help="trace at 400, 450, …, 700 nm and combine under D65 and the CIE 1964 10° observer, as the instrument "
                   "does (about 7× the time; adds a* and b*); default: one wavelength (0.5 µm for rough platelets)")
    add_output_argument(p, "results/simulate")
    add_json_argument(p)
    p.set_defaults(func=run)


def _source_digest(*modules: str) -> str:
    h = hashlib.sha256()
    for m in modules:
        h.update(resources.files("paintjax").joinpath(m).read_bytes())
    return h.hexdigest()[:16]


def sample_array(sample: str, *, seed: int = 0, shape=None, scale=None, pvc=None, thickness=None, d50=None,
                 platelet_thickness=None):
    """The platelet array of a reference sample (with overrides, see `_common.array_overrides`), cached on disk by content."""
    from .._cache import cached_arrays
    from .._microstructure import PlateletArray, platelet_array_for_sample
    from .._samples import load_sample
    from .._tilt import GammaTilt

    s = load_sample(sample)
    tilt = GammaTilt(s.tilt_shape.value if shape is None else shape, s.tilt_scale.value if scale is None else scale)
    overrides = {"tilt": tilt, **array_overrides(s, pvc=pvc, thickness=thickness, d50=d50, platelet_thickness=platelet_thickness)}
    inputs = {
        "sample": s.name, "seed": int(seed), "shape": float(tilt.shape), "scale": float(tilt.scale_deg),
        "pvc": None if pvc is None else float(pvc), "thickness": None if thickness is None else float(thickness),
        "generator": _source_digest("_microstructure.py", "_sizes.py", "_overlap.py", "_tilt.py"),
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
    from .._brdf import MirrorBRDF

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
        from .._beckmann import BeckmannBRDF

        return BeckmannBRDF(sigma, tau, n_medium=n, **wl)
    try:
        from .._brdf_table import platelet_brdf_table
    except ImportError as err:  # pragma: no cover - depends on the BRDF issue
        raise ValueError(f"brdf 'wave' is unavailable: {err}") from None
    return platelet_brdf_table(sigma, tau, n_medium=n, method=method, correlation=correlation, **wl)


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
    measured=None,
    rays: int | None = None,
    seed: int = 0,
    single_scatter: bool = False,
    target_se: float = DEFAULT_TARGET_SE,
    max_rays: int = 4_000_000,
    options=None,
    spectral: bool = False,
    progress: bool = False,
) -> dict:
    """Multi-angle tracer prediction for a sample with overrides, as the CLI's JSON dict (plus extras).

    `illumination_deg`, `aspecular_deg`: the instrument (`instrument_geometry`; default 45° and the five
    standard angles). `measured`: L* to compare with, one per angle (`measured_lightness`; default the
    sample's published values in their geometry, else none). "flop_index" is None unless the geometry
    has 15°, 45° and 110° at 45° illumination.

    `spectral`: trace at the `SPECTRAL_NODES_NM` wavelengths (platelet BRDF at each, same array and
    seed) and combine them under D65 and the CIE 1964 10° observer (`_spectral`); the result then
    also holds "wavelengths_nm", "spectral_reflectance_factor", "XYZ", "Lab" and "Lab_se". Otherwise one
    wavelength (the BRDF's default). `progress` prints a line to stderr after every round of rays
    (rays so far, the worst L* standard error, seconds) and one per wavelength.
    """
    from .._grid import build_grid
    from .._interface import check_waviness
    from .._microstructure import tilt_ks
    from .._samples import load_sample
    from .._spectral import SPECTRAL_NODES_NM, combine_spectral
    from .._tilt import GammaTilt
    from .._tracer import _check_range, _seed_state, check_ray_count, trace

    t0 = time.perf_counter()
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
    geometry = instrument_geometry(illumination_deg, aspecular_deg)
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
    if aperture:
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

        results.append(trace(array, geometry, platelet, progress=report if progress else None, **kwargs))
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


_JSON_KEYS = ("aspecular_deg", "reflectance_factor", "L_star", "L_star_se", "energy", "rays", "seconds", "resolved", "flop_index")
_SPECTRAL_KEYS = ("wavelengths_nm", "spectral_reflectance_factor", "Lab", "Lab_se")


def _plot(r: dict, folder) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .._io import atomic_savefig

    fig, ax = plt.subplots(figsize=(5.5, 4.2))
    gamma = np.asarray(r["aspecular_deg"])
    if r["measured_L_star"] is not None:
        published = r["inputs"]["measured"] is None  # the sample's values, with the instrument's repeatability
        ax.errorbar(gamma, r["measured_L_star"], yerr=0.3 if published else None, fmt="ko",
                    label=f"measured {r['sample']}" if published else "measured (given)")
    ax.errorbar(gamma, r["L_star"], yerr=r["L_star_se"], fmt="s-", color="C0", label=f"tracer, {r['brdf']} platelets ({r['rays']} rays)")
    ax.set_xlabel("aspecular angle [deg]")
    ax.set_ylabel("L*")
    ax.set_title(f"paintjax simulate: {r['sample']}, {r['illumination_deg']:g}° illumination, seed {r['seed']}")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    path = atomic_savefig(fig, f"{folder}/simulate.png")
    plt.close(fig)
    return str(path)


def run(args) -> int:
    from .._io import atomic_write_json

    enable_compilation_cache()
    r = simulate(
        args.sample, shape=args.shape, scale=args.scale, sigma=args.sigma, tau=args.tau, pvc=args.pvc,
        thickness=args.thickness, d50=args.d50, platelet_thickness=args.platelet_thickness, brdf=args.brdf, brdf_method=args.brdf_method, correlation=args.correlation,
        reflectance=args.reflectance, primer_albedo=args.primer_albedo,
        waviness=args.waviness, illumination_deg=args.illumination,
        aspecular_deg=None if args.aspecular is None else parse_floats(args.aspecular, "--aspecular"),
        measured=None if args.measured is None else parse_floats(args.measured, "--measured"),
        rays=args.rays, seed=args.seed, single_scatter=args.single_scatter, spectral=args.spectral, progress=True,
    )
    r["seed"] = args.seed
    r["inputs"] = {k: getattr(args, k) for k in ("shape", "scale", "sigma", "tau", "pvc", "thickness", "d50", "platelet_thickness", "brdf", "brdf_method", "correlation", "reflectance",
                                                 "primer_albedo", "waviness", "illumination", "aspecular", "measured", "rays", "seed",
                                                 "single_scatter", "spectral")}
    atomic_write_json(f"{args.out}/simulate.json", r)
    png = _plot(r, args.out)
    if args.json:
        print_json({k: r[k] for k in _JSON_KEYS + (_SPECTRAL_KEYS if args.spectral else ())})
        return 0
    print(f"Ray tracer, {r['sample']}: {r['brdf']}{' (in-plane lobe rotated)' if r['brdf_method'] == 'rotate' else ''}{' (exponential profiles)' if r['correlation'] == 'exponential' else ''} platelets, {r['platelets']} (median width {r['platelet_median_width_um']:.1f} µm, {r['platelet_thickness_um']:g} µm thick) in a {r['tile_um'][0]:.0f} × {r['tile_um'][1]:.0f} µm tile"
          f"{', detector aperture %.1f°' % r['aperture_deg'] if r['aperture_deg'] else ''}"
          f"{', single scattering' if args.single_scatter else ''}"
          f"{', spectral (D65, CIE 1964 10°; R factor = Y/100)' if args.spectral else ''}")
    lab, measured = r.get("Lab"), r["measured_L_star"]
    print(f"{r['illumination_deg']:g}° illumination")
    print(f"{'aspecular':>10} {'R factor':>10} {'L*':>8} {'± SE':>6} {'measured':>9}" + (f" {'a*':>6} {'b*':>6}" if lab is not None else ""))
    for j, row in enumerate(zip(r["aspecular_deg"], r["reflectance_factor"], r["L_star"], r["L_star_se"])):
        print(f"{row[0]:>9.0f}° {row[1]:>10.4f} {row[2]:>8.1f} {row[3]:>6.2f} " + (f"{measured[j]:>9.1f}" if measured is not None else f"{'—':>9}")
              + (f" {lab[j][1]:>6.2f} {lab[j][2]:>6.2f}" if lab is not None else "") + ("" if r["resolved"][j] else "  not resolved"))
    if not all(r["resolved"]):
        print("not resolved: light reached that detector in fewer than half the batches, so its L* and SE rest on a few "
              "rare paths; trace more rays (--rays)")
    if r["flop_index"] is not None:
        print(f"flop index: {r['flop_index']:.2f}")
    e = r["energy"]
    print("energy: " + ", ".join(f"{k.replace('_', ' ')} {v:.4f}" for k, v in e.items()) + f" (sum {sum(e.values()):.6f})")
    print(f"{r['rays']} rays in {r['tracing_seconds']:.1f} s tracing ({r['seconds']:.1f} s in all). Plot: {png}; data: {args.out}/simulate.json")
    return 0
