"""`paintjax design`: microstructure parameters that reach a target five-angle L* curve."""

from __future__ import annotations

import sys

from .._cache import enable_compilation_cache
from .._validate import Range
from ._common import add_json_argument, parse_floats, print_json
from ._fit import MODEL_RANGES, add_model_arguments, parse_fixed, parse_free

DEFAULT_FREE = ("shape", "scale", "sigma", "tau")
#: The validation layer's ranges (flag → `Range`), checked before the forward model is built.
RANGES = {**MODEL_RANGES, "--tolerance": Range(0.0, None, "L*", lo_open=True)}


def register(sub) -> None:
    p = sub.add_parser(
        "design",
        help="inverse design: parameters whose predicted five-angle L* reaches a target",
        description="Weighted multi-start least squares to a target L* curve at 15,25,45,75,110°. "
        "Exit status 0 when reached within --tolerance, 1 (with the closest reachable curve) otherwise.",
    )
    p.add_argument("--target", required=True, help="five target L* values, e.g. 140,110,60,35,30")
    p.add_argument("--weights", help="five non-negative weights (default 1,1,1,1,1; 0 ignores an angle)")
    p.add_argument("--tolerance", type=float, default=1.0, help="largest acceptable |ΔL*| per weighted angle (default 1)")
    add_model_arguments(p, starts=16)
    add_json_argument(p)
    p.set_defaults(func=run)


def compute(args):
    from ..inverse._design import design_to_target
    from ..inverse._registry import make_forward

    target = parse_floats(args.target, "--target", 5)
    weights = None if args.weights is None else parse_floats(args.weights, "--weights", 5)
    fixed = parse_fixed(args.fix)
    free = parse_free(args.free, [n for n in DEFAULT_FREE if n not in fixed])
    forward = make_forward(args.forward, free, fixed, progress=not args.json)
    if args.free is None:  # defaults adapt to the model; explicit --free is taken as given
        free = tuple(n for n in free if n in forward.parameter_names)
    return design_to_target(forward, target, weights=weights, free=free,
                            fixed={k: v for k, v in fixed.items() if k in forward.parameter_names},
                            tolerance=args.tolerance, n_starts=args.starts, seed=args.seed)


def run(args) -> int:
    enable_compilation_cache()
    r = compute(args)
    if args.json:
        print_json(r.to_dict() | {"forward": args.forward})
        return 0 if r.feasible else 1
    print(f"paintjax design with forward model '{args.forward}'")
    print(("REACHED: " if r.feasible else "NOT REACHABLE: ") + r.message, file=sys.stdout if r.feasible else sys.stderr)
    print(f"{'aspecular':>10} {'target':>8} {'predicted':>10} {'residual':>9}")
    for a, t, L in zip(r.aspecular_deg, r.target, r.L_star):
        print(f"{a:>9.0f}° {t:>8.1f} {L:>10.1f} {L - t:>+9.1f}")
    print(f"flop index: predicted {r.flop_index:.2f}, target {r.target_flop_index:.2f}")
    print("parameters: " + ", ".join(f"{k}={v:.4g}" for k, v in r.params.items()))
    if r.fixed:
        print("fixed: " + ", ".join(f"{k}={v:g}" for k, v in r.fixed.items()))
    return 0 if r.feasible else 1
