"""`paintjax gonio`: a paint's full gonio BRDF from the tracer and the car-paint model fitted to it (JSON export)."""

from __future__ import annotations

from .._cache import enable_compilation_cache
from .._validate import SEED, Range
from ..appearance._carpaint import MAX_LOBES
from ..appearance._gonio import DEFAULT_AZIMUTH, DEFAULT_INCIDENCES, DEFAULT_POLAR, DEFAULT_RAYS
from ..tracer._trace import MAX_RAYS
from ._common import (
    ARRAY_RANGES,
    PAINT_RANGES,
    add_array_arguments,
    add_color_table_argument,
    add_json_argument,
    add_output_argument,
    add_paint_arguments,
    parse_color_table,
    parse_distinct,
    print_json,
)

#: The validation layer's ranges (flag → `Range`), checked before any work.
RANGES = {**PAINT_RANGES, **ARRAY_RANGES, "--lobes": Range(1, MAX_LOBES, integer=True), "--rays": Range(32, MAX_RAYS, integer=True),
          "--seed": SEED}


def register(sub) -> None:
    p = sub.add_parser(
        "gonio",
        help="tabulate a paint's BRDF over the hemisphere with the tracer and fit the car-paint model (JSON export)",
        description="Traces the paint at incidences 0–80° with detectors in and out of the plane of incidence (every MA98 geometry "
        "included), then fits a diffuse term and up to three Cook–Torrance (Beckmann, Schlick) lobes under the clearcoat in "
        "CIELAB lightness with Optimistix. Writes the table (CSV), the model (JSON, docs/appearance.md; only when the fit "
        "converged) and a plot. The table is cached on disk; silver1 and silver2 at the defaults ship with the package.",
    )
    add_paint_arguments(p)
    add_array_arguments(p)
    p.add_argument("--brdf", choices=("wave", "kirchhoff"), default="wave", help="platelet BRDF (default wave)")
    p.add_argument("--lobes", type=int, default=MAX_LOBES, help=f"Cook–Torrance lobes, 1 to {MAX_LOBES} (default {MAX_LOBES})")
    p.add_argument("--incidences", help="comma-separated illumination polar angles [deg] in [0, 80]; default "
                   + ",".join(f"{v:g}" for v in DEFAULT_INCIDENCES))
    p.add_argument("--polar", help="comma-separated outgoing polar angles [deg] in [0, 80]; default "
                   + ",".join(f"{v:g}" for v in DEFAULT_POLAR))
    p.add_argument("--azimuth", help="comma-separated outgoing azimuths [deg] in [0, 180] (0: the specular side); default "
                   + ",".join(f"{v:g}" for v in DEFAULT_AZIMUTH))
    add_color_table_argument(p)
    p.add_argument("--rays", type=int, default=DEFAULT_RAYS, help=f"rays per incidence (default {DEFAULT_RAYS})")
    p.add_argument("--seed", type=int, default=0, help="tracer seed (default 0)")
    add_output_argument(p, "results/gonio")
    add_json_argument(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from .._samples import load_sample
    from ..appearance import fit_car_paint, gonio_table, plot_car_paint_fit

    enable_compilation_cache()
    s = load_sample(args.sample)
    table_options = {"rays": args.rays, "seed": args.seed, "brdf": args.brdf}
    for flag, key in (("incidences", "incidences_deg"), ("polar", "polar_deg"), ("azimuth", "azimuth_deg")):
        if getattr(args, flag) is not None:
            table_options[key] = parse_distinct(getattr(args, flag), f"--{flag}")
    color_table = parse_color_table(args.color_table)
    paint = {k: getattr(args, k) for k in ("shape", "scale", "sigma", "tau", "pvc", "d50", "platelet_thickness") if getattr(args, k) is not None}
    table = gonio_table(s.name, progress=True, **table_options, **paint)
    fit = fit_car_paint(table, lobes=args.lobes, coat_index=s.binder_index, color_table=color_table)
    csv = table.save_csv(f"{args.out}/{s.name}_gonio.csv")
    png = plot_car_paint_fit(fit, f"{args.out}/{s.name}_car_paint.png")
    model = f"{args.out}/{s.name}_car_paint.json"
    if fit.converged:
        fit.save(model)
    if args.json:
        print_json(fit.to_dict() | {"exported": fit.converged})
        return 0 if fit.converged else 1
    print(fit.summary())
    print(f"{table.reflectance_factor.size} entries ({table.rays:,} rays per incidence, {table.seconds:.0f} s tracing). Table: {csv}; plot: {png}")
    if not fit.converged:
        print(f"the fit did not converge ({fit.message}): no model was exported")
        return 1
    print(f"model: {model}")
    return 0
