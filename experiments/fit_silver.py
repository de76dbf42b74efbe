"""Experiment: infer tilt and roughness of Silver #1 and #2 from their five measured L* values alone.

For each sample: a multi-start Levenberg–Marquardt fit and an emcee posterior (0.3 L* instrument
repeatability + a model-discrepancy scale δ with a half-Cauchy(5 L*) prior), for two variants of
the *analytic single-scatter* forward model (the ray tracer is not wired in yet):

* ``single`` – free shape, scale, σ, τ (+ δ): the bare single-scatter model;
* ``diffuse`` – the same plus a Lambertian floor under the coat (`diffuse`), a crude stand-in for
  the multiple scattering and primer light the single-scatter model lacks.

Writes into experiments/output/fit_silver/ (atomic writes): `summary.json`, and per sample and
variant `{sample}_{variant}_posterior.nc` (ArviZ), `{sample}_{variant}_corner.png` and
`{sample}_{variant}_curve.png` (measured vs fitted five-angle curve). The summary says, per
parameter, whether the independently measured value (brief §2) lies inside the 90 % interval.

``--forward tracer-emulator`` (variant ``tracer``): the forward model is the registered GP
emulator of the ray TRACER (multiple scattering, primer, wave-table machinery with 1-D Kirchhoff
lobes; built once and cached, see `paintjax.inverse._tracer_forward`), free shape, scale, σ, τ (+ δ) on
the tracer box `TRACER_BOX`; the emulator is checked against direct (common-random-number)
tracer runs at `--check-draws` posterior draws. Output in experiments/output/fit_silver_tracer/.

Run: python experiments/fit_silver.py [--quick] [--max-steps 6000] [--variants single,diffuse]
     python experiments/fit_silver.py --forward tracer-emulator [--check-draws 8]
(`PAINTJAX_QUICK=1` is the same as --quick: tiny chains, for smoke tests).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from paintjax import (  # noqa: E402
    AnalyticForward,
    atomic_savefig,
    atomic_write_json,
    corner_plot,
    enable_compilation_cache,
    fit_least_squares,
    load_sample,
    sample_posterior,
    save_netcdf,
)

OUT = Path(__file__).parent / "output" / "fit_silver"
OUT_TRACER = Path(__file__).parent / "output" / "fit_silver_tracer"
TRACER_NAME = ("GP emulator of the ray tracer (tracer-emulator: CRN arrays and rays, 1-D Kirchhoff platelet tables on a (σ, τ) "
               "grid; error_sd = held-out RMS ⊕ CRN-vs-independent-run spread)")
FORWARD_NAME = "analytic single scatter (AnalyticForward, rough platelets: Beckmann limit of the Kirchhoff BRDF)"
VARIANTS = {
    "single": ("shape", "scale", "sigma", "tau"),
    "diffuse": ("shape", "scale", "sigma", "tau", "diffuse"),
    "tracer": ("shape", "scale", "sigma", "tau"),
}
ANGLES = (15, 25, 45, 75, 110)


def quick_mode() -> bool:
    return os.environ.get("PAINTJAX_QUICK", "") not in ("", "0")


def measured_reference(sample) -> dict:
    """Independently measured values (brief §2) with their standard uncertainties."""
    return {
        "shape": (sample.tilt_shape.value, sample.tilt_shape.uncertainty),
        "scale": (sample.tilt_scale.value, sample.tilt_scale.uncertainty),
        "mean_tilt": (sample.mean_tilt_deg, None),
        "sigma": (sample.sigma.value, sample.sigma.uncertainty),
        "tau": (sample.tau.value, sample.tau.uncertainty),
    }


def plot_curve(sample_name, measured, fit, post, path, title):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.2, 3.6))
    ax.errorbar(ANGLES, measured, yerr=0.3, fmt="ko", ms=4, label="measured (±0.3)")
    ax.plot(ANGLES, fit.L_star_fit, "C0s-", ms=4, label="least-squares fit")
    if post is not None:
        ax.fill_between(ANGLES, post.L_star_q05, post.L_star_q95, color="C1", alpha=0.3, label="posterior 90 % (model curve)")
        ax.plot(ANGLES, post.L_star_mean, "C1-", lw=1)
    ax.set_xlabel("aspecular angle [°]")
    ax.set_ylabel("L*")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=8)
    atomic_savefig(fig, path)
    plt.close(fig)


def run_one(forward, name: str, variant: str, *, walkers: int, max_steps: int, min_ess: float, starts: int, out: Path, seed: int = 0,
            check_draws: int = 0) -> dict:
    s = load_sample(name)
    y = np.asarray(s.L_star)
    free = VARIANTS[variant]
    fixed = {"diffuse": 0.0} if ("diffuse" in forward.parameter_names and "diffuse" not in free) else {}
    t0 = time.perf_counter()
    fr = fit_least_squares(forward, y, free=free, fixed=fixed, n_starts=starts, seed=seed)
    t_fit = time.perf_counter() - t0
    post = sample_posterior(forward, y, free=free + ("discrepancy",), fixed=fixed, walkers=walkers, max_steps=max_steps,
                            min_steps=min(500, max_steps), check_every=min(500, max_steps), min_ess=min_ess, init=fr,
                            seed=seed, backend_path=out / f"{name}_{variant}_chain.h5", progress=False)
    save_netcdf(post.idata, out / f"{name}_{variant}_posterior.nc")
    ref = measured_reference(s)
    fig = corner_plot(post, reference={k: v[0] for k, v in ref.items()}, path=out / f"{name}_{variant}_corner.png",
                      title=f"{name}, variant '{variant}' (red: measured)")
    import matplotlib.pyplot as plt

    plt.close(fig)
    model_label = "tracer-emulator" if variant == "tracer" else f"{variant} single-scatter"
    plot_curve(name, y, fr, post, out / f"{name}_{variant}_curve.png", f"{name}: {model_label} model vs measured")
    check = None
    if check_draws > 0:
        check = emulator_vs_tracer(forward, post, check_draws, seed)
    comparison = {}
    for k, (v, u) in ref.items():
        lo, hi = post.interval(k, 0.9)
        comparison[k] = {"measured": v, "measured_uncertainty": u, "posterior_mean": post.mean[k], "q05": lo, "q95": hi,
                         "inside_90": bool(lo <= v <= hi),
                         "lsq": fr.values["shape"] * fr.values["scale"] if k == "mean_tilt" else fr.values.get(k),
                         "lsq_stderr": fr.stderr.get(k)}
    return {
        "sample": name,
        "variant": variant,
        "free": list(free) + ["discrepancy"],
        "fixed": fr.fixed,
        "measured_L_star": y.tolist(),
        "lsq": fr.to_dict() | {"seconds": t_fit},
        "posterior": post.to_dict() | {"discrepancy_mean": post.mean.get("discrepancy"), "discrepancy_q05": post.q05.get("discrepancy"),
                                       "discrepancy_q95": post.q95.get("discrepancy")},
        "comparison": comparison,
        "residual_lsq": (fr.L_star_fit - y).tolist(),
        "residual_posterior_mean": (post.L_star_mean - y).tolist(),
        "emulator_check": check,
    }


def emulator_vs_tracer(forward, post, n: int, seed: int) -> dict:
    """Emulator vs direct tracer runs (common random numbers, what the emulator emulates) at n posterior draws."""
    from paintjax.inverse import direct_tracer, emulator_check

    rng = np.random.default_rng(seed)
    cols = [post.names.index(k) for k in forward.parameter_names]
    draws = post.samples[rng.choice(post.samples.shape[0], n, replace=False)][:, cols]
    direct = direct_tracer(forward)
    t0 = time.perf_counter()
    tr_vals = direct(draws)
    t_tracer = time.perf_counter() - t0
    c = emulator_check(forward, lambda x: tr_vals, draws)
    em_vals = np.asarray(forward(draws))
    d = em_vals - tr_vals
    return {"draws": draws.tolist(), "emulator": em_vals.tolist(), "tracer": tr_vals.tolist(), "rms": np.asarray(c["rms"]).tolist(),
            "max_abs": np.asarray(c["max_abs"]).tolist(), "mean_diff": d.mean(0).tolist(), "error_sd": np.asarray(forward.error_sd).tolist(),
            "within_2_error_sd": float(np.mean(np.abs(d) <= 2 * np.asarray(forward.error_sd))), "tracer_seconds": t_tracer}


def verdict(r: dict) -> str:
    c = r["comparison"]
    lines = [f"{r['sample']} / {r['variant']}: LM χ² = {r['lsq']['chi2']:.3g} ({r['lsq']['status']}); "
             f"posterior discrepancy δ ≈ {r['posterior']['discrepancy_mean']:.2g} L* "
             f"(90 % [{r['posterior']['discrepancy_q05']:.2g}, {r['posterior']['discrepancy_q95']:.2g}]); "
             f"n_eff {r['posterior']['n_eff']:.0f}, {'converged' if r['posterior']['converged'] else 'NOT converged'}"]
    lines.append("   five angles: measured " + ", ".join(f"{v:.1f}" for v in r["measured_L_star"])
                 + " | LSQ fit " + ", ".join(f"{v:.1f}" for v in r["lsq"]["L_star_fit"])
                 + " | residual " + ", ".join(f"{v:+.1f}" for v in r["residual_lsq"]))
    for k, d in c.items():
        lines.append(f"   {k:>9}: measured {d['measured']:.3g}  posterior mean {d['posterior_mean']:.3g}, 90 % [{d['q05']:.3g}, {d['q95']:.3g}]"
                     f"  → measured value {'INSIDE' if d['inside_90'] else 'OUTSIDE'} the 90 % interval")
    return "\n".join(lines)


def main(argv=None, forward_options: dict | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="tiny chains (smoke test)")
    ap.add_argument("--forward", default="analytic", choices=("analytic", "tracer-emulator"),
                    help="analytic single scatter (variants single,diffuse) or the tracer emulator (variant tracer)")
    ap.add_argument("--variants", help="default single,diffuse (analytic) or tracer (tracer-emulator)")
    ap.add_argument("--samples", default="silver1,silver2")
    ap.add_argument("--walkers", type=int, default=32)
    ap.add_argument("--max-steps", type=int, default=None,
                    help="emcee step ceiling (default 6000 analytic, 20000 tracer-emulator, whose τ_int reaches ~220 steps: 50 τ needs ~11 000)")
    ap.add_argument("--min-ess", type=float, default=1000.0)
    ap.add_argument("--starts", type=int, default=8)
    ap.add_argument("--check-draws", type=int, default=8, help="tracer-emulator: direct tracer runs at this many posterior draws")
    ap.add_argument("--out", help=f"output folder (default {OUT} or {OUT_TRACER})")
    args = ap.parse_args(argv)
    quick = args.quick or quick_mode()
    if quick:
        args.walkers, args.max_steps, args.min_ess, args.starts = 12, 100, 0.0, 3
    tracer = args.forward == "tracer-emulator"
    if args.max_steps is None:
        args.max_steps = 20000 if tracer else 6000
    out = Path(args.out or (OUT_TRACER if tracer else OUT))
    variants = args.variants or ("tracer" if tracer else "single,diffuse")
    enable_compilation_cache()
    build = None
    if tracer:
        from paintjax.inverse import make_forward, tracer_info

        t0 = time.perf_counter()
        forward = make_forward("tracer-emulator", VARIANTS["tracer"], **(forward_options or {}))
        build = {k: v for k, v in tracer_info(forward).items() if not k.startswith("seed_spread_L")} | {"seconds_this_process": time.perf_counter() - t0}
    else:
        forward = AnalyticForward()
    results = []
    for name in args.samples.split(","):
        for variant in variants.split(","):
            if variant not in VARIANTS or (variant == "tracer") != tracer:
                raise ValueError(f"variant {variant!r} does not go with --forward {args.forward}")
            r = run_one(forward, name, variant, walkers=args.walkers, max_steps=args.max_steps, min_ess=args.min_ess,
                        starts=args.starts, out=out, check_draws=args.check_draws if tracer else 0)
            results.append(r)
            print(verdict(r), flush=True)
            if r["emulator_check"]:
                c = r["emulator_check"]
                print(f"   emulator − tracer at {len(c['draws'])} posterior draws: RMS {np.round(c['rms'], 2).tolist()}, "
                      f"error_sd {np.round(c['error_sd'], 2).tolist()}", flush=True)
    if tracer:
        note = ("Forward model: the ray tracer through its GP emulator (multiple scattering, primer, flat clearcoat). "
                "The tracer at the measured microstructure is too bright at 45° (BRIEF §2: by 15–20 L* in the original "
                "study), so the fit trades tilt and roughness against that bias; the discrepancy δ says how much is left.")
    else:
        note = ("Analytic single-scatter model. It predicts almost no "
                "light at 75° and 110°, so without the 'diffuse' floor the far angles are badly underpredicted and the "
                "discrepancy δ absorbs tens of L*; tilt and roughness inferred under such a misfit are not trustworthy.")
    summary = {
        "forward_model": TRACER_NAME if tracer else FORWARD_NAME,
        "note": note,
        "emulator": build,
        "quick": quick,
        "settings": {"walkers": args.walkers, "max_steps": args.max_steps, "min_ess": args.min_ess, "starts": args.starts},
        "results": results,
    }
    atomic_write_json(out / "summary.json", summary)
    return summary


if __name__ == "__main__":
    main()
