"""`paintjax render`: a paint's fitted car-paint model on a sphere in Mitsuba 3 (the optional extra `paintjax[render]`)."""

from __future__ import annotations

import os

from .._cache import enable_compilation_cache
from .._samples import sample_names
from .._validate import Range
from ._common import add_color_table_argument, parse_color_table

#: The validation layer's ranges (flag → `Range`), checked before Mitsuba is loaded.
RANGES = {"--resolution": Range(16, 4096, "pixels", integer=True), "--spp": Range(1, 65536, integer=True),
          "--seed": Range(0, 2**32 - 1, integer=True)}


def register(sub) -> None:
    p = sub.add_parser(
        "render",
        help="render a paint's fitted car-paint model on a sphere in Mitsuba 3 (pip install paintjax[render])",
        description="Renders a sphere with the car-paint BRDF fitted to the paint's simulated gonio table (`paintjax gonio`) under the "
        "package's sky environment and sun (docs/appearance.md). A sample's model is fitted from its cached gonio table "
        "(silver1 and silver2 ship); --model renders an exported JSON file; --compare renders two side by side.",
    )
    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument("--sample", help=f"reference sample: {' or '.join(sample_names())}")
    what.add_argument("--model", help="an exported car-paint JSON file (paintjax gonio)")
    what.add_argument("--compare", nargs=2, metavar=("A", "B"), help="two samples or JSON files, rendered side by side")
    p.add_argument("--out", dest="image", required=True, help="output image, .png or .exr (written atomically)")
    p.add_argument("--resolution", type=int, default=512, help="image height and width in pixels per paint, 16 to 4096 (default 512)")
    p.add_argument("--spp", type=int, default=64, help="samples per pixel, 1 to 65536 (default 64)")
    p.add_argument("--variant", help="Mitsuba variant; default: llvm_ad_rgb where Dr.Jit finds LLVM ≥ 17 (e.g. Debian's libllvm19), "
                   "else scalar_rgb (about 60× slower), or $PAINTJAX_MITSUBA_VARIANT")
    p.add_argument("--seed", type=int, default=0, help="render seed (default 0)")
    add_color_table_argument(p)
    p.set_defaults(func=run)


def _model(source: str, color_table=None):
    """A sample's fitted model (refused unless the fit converged) or an exported JSON file's model, with its label."""
    from ..appearance import car_paint_for_sample, load_car_paint

    if source in sample_names():
        fit = car_paint_for_sample(source, color_table=color_table, progress=True)
        if not fit.converged:
            raise ValueError(f"the car-paint fit of {source} did not converge ({fit.message}); nothing to render")
        print(fit.summary().splitlines()[0].replace("car-paint fit", f"{source} car-paint fit"))
        return fit.model, source
    if not source.endswith(".json"):
        raise ValueError(f"--sample/--compare take {' or '.join(sample_names())} or an exported .json file, got {source!r}")
    model, doc = load_car_paint(source)
    if not doc.get("fit", {}).get("converged", True):
        raise ValueError(f"{source} holds a fit that did not converge; refusing to render it")
    return model, os.path.splitext(os.path.basename(source))[0]


def run(args) -> int:
    import sys

    from ..render import default_variant, render_comparison, render_paint, require_mitsuba

    color_table = parse_color_table(args.color_table)
    variant = args.variant or default_variant()
    require_mitsuba(variant)  # a missing extra or an unknown variant fails before any work
    if variant.startswith("scalar") and args.resolution**2 * args.spp > 2**22:
        print(f"note: rendering with {variant} (one Python call per path) takes minutes at this size; install LLVM 17 or newer "
              "(Debian: apt-get install libllvm19) for llvm_ad_rgb", file=sys.stderr)
    enable_compilation_cache()
    options = {"resolution": args.resolution, "spp": args.spp, "variant": variant, "seed": args.seed}
    if args.compare:
        models = dict(_model(source, color_table)[::-1] for source in args.compare)
        if len(models) != 2:
            raise ValueError(f"--compare needs two different paints, got {args.compare}")
        result = render_comparison(models, args.image, **options)
    else:
        model, _ = _model(args.sample or args.model, color_table)
        result = render_paint(model, args.image, **options)
    print(f"rendered {args.image} ({args.resolution}×{args.resolution}, {args.spp} spp, {variant}) in {result['seconds']:.1f} s")
    return 0
