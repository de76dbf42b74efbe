"""`paintjax simulate`: five-angle L* of a paint from its microstructure through the ray tracer (`paintjax.simulate`)."""

from __future__ import annotations

import numpy as np

from .._cache import enable_compilation_cache
from .._pipeline import BRDF_METHODS, BRDFS, DEFAULT_PRIMER_ALBEDO, DEFAULT_TARGET_SE, SIMULATE_RANGES, simulate
from .._validate import Range
from ..tracer._trace import MAX_RAYS
from ..wave._profiles import CORRELATIONS
from ._common import (
    add_array_arguments,
    add_json_argument,
    add_output_argument,
    add_paint_arguments,
    as_flags,
    parse_distinct,
    parse_floats,
    print_json,
)


def register(sub) -> None:
    p = sub.add_parser(
        "simulate",
        help="ray-trace a sample's microstructure: five-angle L* with standard errors",
        description="Ray-batch Monte Carlo through a generated platelet array under a clearcoat (flat unless --waviness), seen by a virtual "
        "multi-angle spectrophotometer (default: 45° illumination, aspecular 15, 25, 45, 75, 110°; MA98's other angles "
        "with --illumination and --aspecular). Lengths in µm, angles in degrees.",
    )
    add_paint_arguments(p)
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
    p.add_argument("--arrays", type=int, default=1,
                   help="independent platelet arrays to trace (seeds SEED, SEED+1, …) and average: L* is their mean and its SE comes "
                   "from their spread, which a finite tile's one array does not show (several L* at 15° for wide tilt laws of smooth "
                   "platelets); default 1: one array, SE from its rays alone")
    p.add_argument("--single-scatter", action="store_true", help="score only the first scattering event of each path")
    p.add_argument("--spectral", action="store_true",
                   help="trace at 400, 450, …, 700 nm and combine under D65 and the CIE 1964 10° observer, as the instrument "
                   "does (about 7× the time; adds a* and b*); default: one wavelength (0.5 µm for rough platelets)")
    add_output_argument(p, "results/simulate")
    add_json_argument(p)
    p.set_defaults(func=run)


#: The validation layer's ranges (flag → `Range`), checked before any work (the ray count's lower end, one per
#: batch of the standard error, is the tracer's default `TracerOptions.batches`).
RANGES = {**as_flags(SIMULATE_RANGES, {"illumination_deg": "--illumination"}), "--rays": Range(32, MAX_RAYS, integer=True)}
#: `simulate`'s API argument names as the messages of its deeper checks use them → its flags.
API_FLAGS = {"aspecular_deg": "--aspecular", "illumination_deg": "--illumination", "platelet_thickness": "--platelet-thickness",
             "thickness:": "--thickness:", "brdf_method": "--brdf-method", "correlation applies": "--correlation applies",
             "measured must": "--measured must", "sigma_um": "--sigma", "tau_um": "--tau",
             "lower pvc, a smaller tile, or thicker or wider platelets": "lower --pvc, or a larger --platelet-thickness or --d50"}
_JSON_KEYS = ("aspecular_deg", "reflectance_factor", "L_star", "L_star_se", "energy", "rays", "seconds", "resolved", "flop_index")
_SPECTRAL_KEYS = ("wavelengths_nm", "spectral_reflectance_factor", "Lab", "Lab_se")
_ARRAYS_KEYS = ("arrays", "L_star_array_sd", "L_star_rays_se", "L_star_per_array")


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
    arrays = f", mean of {r['arrays']} arrays" if r.get("arrays", 1) > 1 else ""
    ax.errorbar(gamma, r["L_star"], yerr=r["L_star_se"], fmt="s-", color="C0", label=f"tracer, {r['brdf']} platelets ({r['rays']} rays{arrays})")
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
        aspecular_deg=None if args.aspecular is None else parse_distinct(args.aspecular, "--aspecular"),
        measured=None if args.measured is None else parse_floats(args.measured, "--measured"),
        rays=args.rays, seed=args.seed, single_scatter=args.single_scatter, spectral=args.spectral, progress=True, arrays=args.arrays,
    )
    r["seed"] = args.seed
    r["inputs"] = {k: getattr(args, k) for k in ("shape", "scale", "sigma", "tau", "pvc", "thickness", "d50", "platelet_thickness", "brdf", "brdf_method", "correlation", "reflectance",
                                                 "primer_albedo", "waviness", "illumination", "aspecular", "measured", "rays", "seed",
                                                 "arrays", "single_scatter", "spectral")}
    atomic_write_json(f"{args.out}/simulate.json", r)
    png = _plot(r, args.out)
    if args.json:
        print_json({k: r[k] for k in _JSON_KEYS + (_SPECTRAL_KEYS if args.spectral else ()) + (_ARRAYS_KEYS if args.arrays > 1 else ())})
        return 0
    print(f"Ray tracer, {r['sample']}: {r['brdf']}{' (in-plane lobe rotated)' if r['brdf_method'] == 'rotate' else ''}{' (exponential profiles)' if r['correlation'] == 'exponential' else ''} platelets, {r['platelets']} (median width {r['platelet_median_width_um']:.1f} µm, {r['platelet_thickness_um']:g} µm thick) in a {r['tile_um'][0]:.0f} × {r['tile_um'][1]:.0f} µm tile"
          f"{', detector aperture %.1f°' % r['aperture_deg'] if r['aperture_deg'] else ''}"
          f"{', single scattering' if args.single_scatter else ''}"
          f"{', spectral (D65, CIE 1964 10°; R factor = Y/100)' if args.spectral else ''}")
    lab, measured = r.get("Lab"), r["measured_L_star"]
    print(f"{r['illumination_deg']:g}° illumination")
    several = args.arrays > 1
    if several:
        print(f"mean of {args.arrays} independent arrays (seeds {args.seed}–{args.seed + args.arrays - 1}); SE from their spread")
    print(f"{'aspecular':>10} {'R factor':>10} {'L*':>8} {'± SE':>6}" + (f" {'array SD':>9}" if several else "") + f" {'measured':>9}"
          + (f" {'a*':>6} {'b*':>6}" if lab is not None else ""))
    for j, row in enumerate(zip(r["aspecular_deg"], r["reflectance_factor"], r["L_star"], r["L_star_se"])):
        print(f"{row[0]:>9.0f}° {row[1]:>10.4f} {row[2]:>8.1f} {row[3]:>6.2f} " + (f"{r['L_star_array_sd'][j]:>9.2f} " if several else "")
              + (f"{measured[j]:>9.1f}" if measured is not None else f"{'—':>9}")
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
