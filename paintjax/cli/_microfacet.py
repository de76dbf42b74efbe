"""`paintjax microfacet`: the analytic single-scatter five-angle table of a sample."""

from __future__ import annotations

import numpy as np

from .._pipeline import flop_index_or_none
from .._validate import Range
from ._common import PAINT_RANGES, add_json_argument, format_optional, print_json

#: The validation layer's ranges (flag → `Range`), checked before any work.
RANGES = {"--shape": PAINT_RANGES["--shape"], "--scale": PAINT_RANGES["--scale"], "--reflectance": Range(0.0, 1.0),
          "--n": Range(1.0, 3.0, lo_open=True, why="coat refractive index")}


def register(sub) -> None:
    p = sub.add_parser(
        "microfacet",
        help="analytic single-scatter (specular microfacet) L* at the five standard angles",
        description="Analytic single-scatter model: mirror platelets with gamma tilt under a flat coat.",
    )
    p.add_argument("--sample", default="silver1", help="reference sample: silver1 or silver2 (default silver1)")
    p.add_argument("--shape", type=float, help="tilt gamma shape (> 0); default: the sample's")
    p.add_argument("--scale", type=float, help="tilt gamma scale in degrees (> 0); default: the sample's")
    p.add_argument("--reflectance", type=float, help="constant platelet reflectance in [0, 1]; default: Fresnel of Al in the binder at 550 nm")
    p.add_argument("--n", type=float, help="coat/binder refractive index in (1, 3]; default: the sample's (1.5)")
    p.add_argument("--no-exit-occlusion", action="store_true", help="do not attenuate exiting light by the platelet layer")
    p.add_argument("--no-hot-spot", action="store_true",
                   help="attenuate the entry and exit paths independently (platelets much narrower than the mean free path) "
                   "instead of correlating them over the sample's platelet widths (default)")
    add_json_argument(p)
    p.set_defaults(func=run)


def compute(sample: str = "silver1", shape=None, scale=None, reflectance=None, n=None, exit_occlusion=True, hot_spot=True) -> dict:
    """Five-angle analytic single-scatter prediction as a plain dict (the CLI's JSON)."""
    from .. import GammaTilt, MirrorBRDF, load_sample, ma98_geometry
    from ..instrument._hot_spot import HotSpot
    from ..instrument._lightness import reflectance_factor_to_lightness
    from ..instrument._single_scatter import microfacet_reflectance_factor

    s = load_sample(sample)
    n = s.binder_index if n is None else n
    tilt = GammaTilt(s.tilt_shape.value if shape is None else shape, s.tilt_scale.value if scale is None else scale)
    geometry = ma98_geometry(45.0)
    platelet = MirrorBRDF(n_binder=n, reflectance=reflectance)
    R = microfacet_reflectance_factor(geometry, tilt, n=n, platelet=platelet, exit_occlusion=exit_occlusion,
                                      hot_spot=HotSpot.for_sample(s) if hot_spot and exit_occlusion else None)
    L = reflectance_factor_to_lightness(R)
    return {
        "sample": s.name,
        "aspecular_deg": np.asarray(geometry.aspecular_deg),
        "tilt_probed_deg": np.asarray(geometry.probed_tilt_deg(n)),
        "reflectance_factor": np.asarray(R),
        "L_star": np.asarray(L),
        "flop_index": flop_index_or_none(L[0], L[2], L[4]),
        "measured_L_star": np.asarray(s.L_star),
        "hot_spot": bool(hot_spot and exit_occlusion),
    }


def run(args) -> int:
    r = compute(args.sample, args.shape, args.scale, args.reflectance, args.n, not args.no_exit_occlusion, not args.no_hot_spot)
    if args.json:
        print_json({k: r[k] for k in ("aspecular_deg", "tilt_probed_deg", "reflectance_factor", "L_star", "flop_index")})
        return 0
    print(f"Analytic single-scatter model, {r['sample']} (45° illumination, mirror platelets, "
          f"{'hot spot over the platelet widths' if r['hot_spot'] else 'independent entry and exit paths'})")
    print(f"{'aspecular':>10} {'tilt probed':>12} {'R factor':>10} {'L*':>8} {'measured':>9}")
    for row in zip(r["aspecular_deg"], r["tilt_probed_deg"], r["reflectance_factor"], r["L_star"], r["measured_L_star"]):
        print(f"{row[0]:>9.0f}° {row[1]:>11.2f}° {row[2]:>10.4f} {row[3]:>8.1f} {row[4]:>9.1f}")
    print(f"flop index: {format_optional(r['flop_index'])}")
    return 0
