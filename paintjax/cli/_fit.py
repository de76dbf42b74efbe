"""`paintjax fit`: least squares (and optionally an emcee posterior) of microstructure parameters
from five measured L* values."""

from __future__ import annotations

import time

from .._cache import enable_compilation_cache
from .._validate import SEED, Range
from ..inverse._chain import MAX_RHAT, MAX_STEPS, MAX_WALKERS
from ..inverse._fit import MAX_STARTS
from ._common import add_json_argument, parse_floats, print_json

#: Default forward model: the ray tracer through its wide-box emulator (shipped with the package).
DEFAULT_FORWARD = "tracer-emulator-wide"
#: Default free parameters of least squares for each built-in forward model family.
DEFAULT_FREE = ("shape", "scale", "sigma", "tau", "diffuse")


def parse_fixed(items) -> dict:
    out = {}
    for item in items or []:
        if "=" not in item:
            raise ValueError(f"--fix expects name=value, got {item!r}")
        k, v = item.split("=", 1)
        try:
            out[k.strip()] = float(v)
        except ValueError:
            raise ValueError(f"--fix {k.strip()} must be a number, got {v!r}") from None
    return out


def parse_free(text, default) -> tuple[str, ...]:
    if text is None:
        return tuple(default)
    names = tuple(n.strip() for n in str(text).split(",") if n.strip())
    if not names:
        raise ValueError("--free must name at least one parameter")
    return names


#: The validation layer's ranges of `add_model_arguments`' options (flag → `Range`).
#: Most emcee steps of one run (a chain file of up to a few GB at the default walkers; a stopped run resumes).
MAX_POSTERIOR_STEPS = 10_000_000
MODEL_RANGES = {"--starts": Range(1, MAX_STARTS, integer=True), "--seed": SEED}
#: The validation layer's ranges (flag → `Range`), checked before any model is built (the walkers' count, even and
#: at least twice the sampled parameters, in `check_run_sizes` and `check_walkers`).
RANGES = {**MODEL_RANGES, "--workers": Range(1, None, integer=True), "--max-steps": Range(1, MAX_POSTERIOR_STEPS, integer=True),
          "--min-ess": Range(0.0, None), "--max-rhat": Range(1.0, None), "--tilt-platelets": Range(0, 1_000_000, integer=True)}


def add_model_arguments(p, *, starts: int = 8) -> None:
    from ..inverse._registry import FORWARDS

    p.add_argument("--forward", default=DEFAULT_FORWARD, choices=sorted(FORWARDS),
                   help=f"forward model (default {DEFAULT_FORWARD}): " + "; ".join(f"{k}: {v[1]}" for k, v in FORWARDS.items()))
    p.add_argument("--free", help=f"comma-separated free parameters (default {','.join(DEFAULT_FREE)})")
    p.add_argument("--fix", action="append", metavar="NAME=VALUE", help="hold a parameter at a value (repeatable)")
    p.add_argument("--starts", type=int, default=starts, help=f"least-squares starts (default {starts})")
    p.add_argument("--seed", type=int, default=0, help="seed of starts and sampler (default 0)")


#: API argument → flag, for error messages.
API_FLAGS = {"backend_path": "--chain", "walkers must": "--walkers must", "overwrite=True": "--overwrite", "data must": "--data must", "data file": "--data file",
             "data columns": "--data columns", "data has": "--data has"}


def register(sub) -> None:
    p = sub.add_parser(
        "fit",
        help="infer tilt and roughness from five measured L* (least squares, optional posterior)",
        description="Levenberg–Marquardt fit (Optimistix) of microstructure parameters to five-angle L*; "
        "--posterior adds an emcee posterior (progress bar, HDF5 chain that resumes).",
    )
    add_fit_arguments(p)
    p.set_defaults(func=run)


def add_fit_arguments(p) -> None:
    """The options of `fit` (and of `posterior`, which is `fit --posterior`)."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--sample", help="reference sample whose measured L* to fit: silver1 or silver2 (default silver1)")
    g.add_argument("--measured", help="five L* values at 15,25,45,75,110°, e.g. 143.3,107.2,58.6,37.2,32.1")
    g.add_argument("--data", help="CSV of many panels (id, L* at any three or more of L-15, L15, L25, L45, L75, L110, optional "
                                  "sd-15 … sd110 and known inputs "
                                  "shape, scale, sigma, tau with *_sd); 'example' reads the 3-panel file shipped with the package. "
                                  "One fit (and with --posterior one posterior) per panel on Dask; results in <--out>/fit_panels.csv "
                                  "and .nc, a figure per panel in <--out>/figures (a rerun skips panels already done)")
    p.add_argument("--scheduler", help="address of an existing Dask scheduler for --data (default $DASK_SCHEDULER_ADDRESS, "
                                       "else a local cluster)")
    p.add_argument("--workers", type=int, default=2, help="worker processes of the local Dask cluster for --data (default 2)")
    p.add_argument("--no-figures", action="store_true", help="with --data: no figure per panel")
    add_model_arguments(p)
    p.add_argument("--posterior", action="store_true", help="also sample the posterior with emcee")
    p.add_argument("--walkers", type=int, default=32, help="emcee walkers (default 32)")
    p.add_argument("--max-steps", type=int, default=MAX_STEPS, help=f"largest number of emcee steps (default {MAX_STEPS})")
    p.add_argument("--min-ess", type=float, default=1000.0, help="required effective sample size (default 1000; 0: stop on the autocorrelation-time rule alone)")
    p.add_argument("--max-rhat", type=float, default=MAX_RHAT, help=f"largest split R-hat of any parameter, walkers as chains (default {MAX_RHAT})")
    p.add_argument("--inputs", choices=("none", "rq", "local_pv", "scan_pv"), default=None,
                   help="with --posterior and --sample: add the sample's published inputs as data, the roughness through the "
                   "virtual profilometer with σ read as the given definition (rq: RMS height) and the tilt law as a gamma fit to "
                   "--tilt-platelets measured tilts (docs/input_measurement.md); default rq for a reference sample's posterior, "
                   "none otherwise (none: the L* alone, the inputs only through the prior box)")
    p.add_argument("--tilt-platelets", type=int, default=200,
                   help="platelets behind the published tilt law, for --inputs (default 200, an assumption; 0: tilt law not used)")
    p.add_argument("--chain", help="HDF5 file of the chain (resumes a chain of the same run; default: none)")
    p.add_argument("--overwrite", action="store_true", help="replace a stored --chain that was sampled for another run")
    p.add_argument("--out", help="folder for posterior.nc, corner.png and predictive.png (default: none written)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_json_argument(p)


def compute(args) -> dict:
    from .._samples import load_sample
    from ..inverse._fit import fit_least_squares
    from ..inverse._registry import make_forward

    t0 = time.perf_counter()
    if args.measured is not None:
        measured = parse_floats(args.measured, "--measured", 5)
        label = "measured"
    else:
        s = load_sample(args.sample or "silver1")
        measured, label = list(s.L_star), s.name
    fixed = parse_fixed(args.fix)
    free = parse_free(args.free, [n for n in DEFAULT_FREE if n not in fixed])
    check_run_sizes(args)
    args.inputs = resolve_inputs(args)
    if args.inputs != "none" and not args.posterior:
        raise ValueError("--inputs applies to --posterior (the published inputs enter the posterior as data)")
    if args.inputs != "none" and args.measured is not None:
        raise ValueError("--inputs needs --sample: published inputs belong to a reference sample, not to --measured values")
    if args.no_figures:
        raise ValueError("--no-figures applies to --data")
    if args.overwrite and not args.chain:
        raise ValueError("--overwrite applies to --chain")
    forward = make_forward(args.forward, free, fixed, progress=not args.no_progress and not args.json)
    # Defaults adapt to the model (a mirror model has no σ, τ); explicit --free is taken as given.
    lsq_free = free if args.free is not None else tuple(n for n in free if n in forward.parameter_names or n == "discrepancy")
    if args.posterior:  # every posterior check before the least-squares fit
        post_free, post_fixed, inputs = _posterior_setup(args, forward, measured, lsq_free, fixed)
    fr = fit_least_squares(forward, measured, free=lsq_free, fixed={k: v for k, v in fixed.items() if k in forward.parameter_names},
                           n_starts=args.starts, seed=args.seed)
    out = {
        "sample": label,
        "forward": args.forward,
        "measured": measured,
        "params": fr.values,
        "stderr": fr.stderr,
        "fixed": fr.fixed,
        "L_star_fit": fr.L_star_fit,
        "residuals": fr.residuals,
        "chi2": fr.chi2,
        "status": fr.status,
        "converged": fr.success,
        "at_bound": list(fr.at_bound),
        "dof": fr.dof,
        "covariance_scale": fr.scale2,
        "posterior": None,
        "_fit": fr,
    }
    if args.posterior:
        from ..inverse._panels import STANDARD_ANGLES
        from ..inverse._posterior import sample_posterior
        from ..inverse._posterior_output import corner_plot, predictive_plot, save_netcdf

        pr = sample_posterior(forward, measured, free=post_free, fixed=post_fixed, walkers=args.walkers, max_steps=args.max_steps,
                              min_steps=min(500, args.max_steps), check_every=min(250, args.max_steps), min_ess=args.min_ess, max_rhat=args.max_rhat, init=fr, seed=args.seed,
                              backend_path=args.chain,
                              overwrite=args.overwrite,
                              progress=not args.no_progress and not args.json, inputs=inputs)
        d = pr.to_dict()
        out["posterior"] = {k: d[k] for k in ("mean", "q05", "q50", "q95", "tau_int", "n_eff", "rhat", "ess_bulk", "steps", "converged", "acceptance",
                                              "L_star_mean", "L_star_q05", "L_star_q95")}
        from ..inverse._measured_inputs import posterior_predictive_check

        check = posterior_predictive_check(pr, forward, measured, fixed=post_fixed, seed=args.seed)
        out["posterior"]["predictive_p_value"] = check["p_value"]
        out["posterior"]["predictive_p_value_se"] = check["p_value_se"]
        out["posterior"]["inputs"] = args.inputs
        if inputs is not None:
            out["posterior"]["input_shift"] = inputs.shift_table({n: pr.draws(n) for n in pr.names})
        out["_posterior"] = pr
        if args.out:
            from pathlib import Path

            save_netcdf(pr.idata, Path(args.out) / "posterior.nc")
            corner_plot(pr, path=Path(args.out) / "corner.png", title=f"{label}: posterior ({args.forward})")
            predictive_plot(STANDARD_ANGLES, measured, fit=fr.L_star_fit, band=(check["L_star_q05"], check["L_star_q95"]),
                            path=Path(args.out) / "predictive.png",
                            title=f"{label}: posterior predictive ({args.forward}), p = {check['p_value']:.2g}")
    out["seconds"] = time.perf_counter() - t0
    return out


def _posterior_setup(args, forward, measured, lsq_free, fixed):
    """(free, fixed, inputs) of the posterior, with the walkers and the --chain checked (nothing written)."""
    from .._samples import load_sample
    from ..inverse._chain import check_chain, check_walkers
    from ..inverse._posterior import LogPosterior

    post_free = tuple(n for n in lsq_free if n != "discrepancy")
    post_fixed = {k: v for k, v in fixed.items() if k in forward.parameter_names or k == "discrepancy"}
    if "discrepancy" not in post_fixed:
        post_free = post_free + ("discrepancy",)
    check_walkers(args.walkers, len(post_free))
    inputs = None
    if args.inputs != "none":
        from ..inverse._measured_inputs import MeasuredInputs
        from ..inverse._profilometer import build_reading_model

        rough = {"sigma", "tau"} <= set(forward.parameter_names)  # the roughness reading only where σ, τ are inputs
        reading = build_reading_model(progress=not args.json) if rough else None
        inputs = MeasuredInputs.for_sample(load_sample(args.sample or "silver1"), reading, definition=args.inputs,
                                           tilt_platelets=args.tilt_platelets)
    if args.chain:
        lp = LogPosterior(forward, measured, post_free, post_fixed, inputs=inputs)
        check_chain(args.chain, lp.description(args.walkers), overwrite=args.overwrite)
    return post_free, post_fixed, inputs


def resolve_inputs(args) -> str:
    """--inputs as given, else its default: "rq" (the published inputs as data) for the posterior of a reference
    sample (`--sample`, or no data given: silver1), "none" for --measured values, --data files and plain fits."""
    if args.inputs is not None:
        return args.inputs
    return "rq" if args.posterior and args.measured is None and args.data is None else "none"


def check_run_sizes(args) -> None:
    """--walkers, for one panel and for --data alike (before any work; the other sizes are in `RANGES`)."""
    if args.posterior and (args.walkers < 2 or args.walkers % 2 or args.walkers > MAX_WALKERS):  # the full check (≥ 2 × sampled parameters) follows
        raise ValueError(f"--walkers must be even, >= 2 × the sampled parameters and <= {MAX_WALKERS}, got {args.walkers}")


def example_panels() -> str:
    """Path of the 3-panel example CSV shipped with the package (`--data example`)."""
    from importlib.resources import files

    return str(files("paintjax") / "data" / "panels_example.csv")


def run_batch(args) -> int:
    """`--data`: every panel of the CSV file, one Dask task each."""
    import sys
    from pathlib import Path

    from ..inverse._panels import fit_panels

    if args.inputs not in (None, "none") or args.chain:
        raise ValueError("--inputs and --chain apply to one panel: with --data, give known inputs as columns (sigma, sigma_sd, …)")
    check_run_sizes(args)
    fixed = parse_fixed(args.fix)
    if fixed:
        raise ValueError("--fix with --data is not available: every panel fits the same free parameters")
    free = parse_free(args.free, ("shape", "scale", "sigma", "tau"))
    out = Path(args.out or "results/fit_panels") / "fit_panels.csv"
    data = example_panels() if args.data == "example" else args.data
    posterior = {"walkers": args.walkers, "max_steps": args.max_steps, "min_ess": args.min_ess, "max_rhat": args.max_rhat} if args.posterior else None
    t0 = time.perf_counter()

    def report(row, n, total):
        detail = f"χ² {row['chi2']:.3g}" if row["status"] == "ok" else row["error"]
        if row["status"] == "ok" and "predictive_p" in row:
            se = f" ± {row['predictive_p_se']:.1g}" if "predictive_p_se" in row else ""
            detail += f", posterior-predictive p {row['predictive_p']:.2g}{se}, R-hat ≤ {row['rhat_max']:.3f}"
        eta = (time.perf_counter() - t0) / n * (total - n)
        print(f"[{n}/{total}] {row['id']}: {row['status']} ({detail}); ETA {eta:.0f} s", file=sys.stderr, flush=True)

    rows = fit_panels(data, out, forward=args.forward, free=free, n_starts=args.starts, seed=args.seed, posterior=posterior,
                      figures=not args.no_figures, scheduler=args.scheduler, workers=args.workers,
                      on_result=None if args.no_progress else report)
    if args.json:
        print_json({"results": str(out), "panels": rows})
    else:
        ok = sum(r["status"] == "ok" for r in rows)
        print(f"paintjax fit --data: {ok} of {len(rows)} rows {'sampled' if posterior else 'fitted'}, {len(rows) - ok} with errors; "
              f"results: {out} and {out.with_suffix('.nc')}" + ("" if args.no_figures else f", figures in {out.parent / 'figures'}"))
        for r in rows:
            if r["status"] != "ok":
                print(f"  row {r.get('row', '?')} ({r['id'] or 'no id'}): {r['error']}")
    return 0


def run(args) -> int:
    enable_compilation_cache()
    if args.data:
        return run_batch(args)
    r = compute(args)
    if args.json:
        print_json({k: v for k, v in r.items() if not k.startswith("_")})
        return 0
    fr = r["_fit"]
    print(f"paintjax fit: {r['sample']} with forward model '{r['forward']}'")
    print(fr.summary())
    if r["fixed"]:
        print("  fixed: " + ", ".join(f"{k}={v:g}" for k, v in r["fixed"].items()))
    print(f"{'aspecular':>10} {'measured':>9} {'fit':>8} {'residual':>9}")
    for a, m, f in zip((15, 25, 45, 75, 110), r["measured"], r["L_star_fit"]):
        print(f"{a:>9}° {m:>9.1f} {f:>8.1f} {f - m:>+9.1f}")
    if r["posterior"] is not None:
        print(r["_posterior"].summary())
        post = r["posterior"]
        print(f"posterior-predictive p = {post['predictive_p_value']:.3g} ± {post['predictive_p_value_se']:.1g} (is the measured L* what the posterior expects? "
              f"≲ 0.01: no){'' if post['inputs'] == 'none' else '; published inputs as data (σ read as ' + post['inputs'] + ')'}")
        if "discrepancy" in post["mean"]:
            print(f"  with a sampled model discrepancy δ ≈ {post['mean']['discrepancy']:.3g} L* absorbing misfit; "
                  "--fix discrepancy=0 tests agreement within the stated errors alone")
        for name, v in post.get("input_shift", {}).items():
            print(f"  {name:>6}: published {v['published']:.4g}, the posterior expects a reading of {v['expected_reading']:.4g} (z = {v['z']:+.2f})")
    print(f"time: {r['seconds']:.1f} s")
    return 0 if fr.success else 1
