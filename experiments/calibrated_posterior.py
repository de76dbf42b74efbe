"""Experiment: posteriors of the two panels with measurement models for the inputs, and a consistency verdict.

* *Forward model.* A Gaussian-process emulator of the ray tracer (`paintjax.inverse.wide_tracer_emulator`,
  the registered forward "tracer-emulator-wide")
  over a box wide enough to hold what the inputs and the L* imply: shape 1.2–12, scale 0.5–5°,
  σ 0.015–0.15 µm, τ 0.25–2.0 µm (BRDF-table grid 8 × 7 over σ, τ; each design run the mean over four reference
  arrays). Held-out error per angle reported.
* *Likelihoods.* L*: instrument repeatability 0.3 ⊕ a model discrepancy δ (normal) plus the emulator's own error
  (Student-t with a scale that varies over the box, fitted to its cross-validated errors, ⊕ the run-to-run spread
  and the bias's variance; the emulator predicts an independent run: the CRN tracer's bias subtracted).
  Inputs (`paintjax.inverse.MeasuredInputs`): the published roughness reading through the virtual
  profilometer (`ReadingModel`, σ read as Rq, or `--definition`) and the published tilt law as a gamma fit to an
  assumed 200 measured platelets (`gamma_fit_sd`).
* *Runs per panel.* (a) L* alone, δ free; (b) L* and inputs, δ free; (c) L* and inputs, δ = 0: the
  hypothesis "inputs and L* agree within the stated errors", judged by a posterior-predictive
  p-value of the L* deviance.
* *The emulator where the posteriors lie.* Direct tracer runs at `--check-draws` draws of each run with free
  inputs, with common random numbers (the GP's own error there) and independent (what a panel is, against
  the likelihood's whole residual law), per angle; and `--arrays` independent runs per draw, whose mean (the
  expected L* over platelet arrays) judges the emulator and the CRN tracer alike. `--checks-only` redoes these
  checks at the draws stored in an earlier summary.

Writes experiments/output/calibrated_posterior/{summary.json, <panel>_*.nc, calibrated_posterior.png}.
Run from the repository root: python experiments/calibrated_posterior.py [--build-only] [--definition local_pv|scan_pv]
[--arrays N] [--checks-only]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from paintjax import atomic_savefig, atomic_write_json, enable_compilation_cache, load_sample, save_netcdf  # noqa: E402
from paintjax.inverse import MAX_STEPS, SIGMA_DEFINITIONS, WIDE_TRACER_BOX, build_reading_model, panel_posteriors, wide_tracer_emulator  # noqa: E402

OUT = Path("experiments/output/calibrated_posterior")
BOX = WIDE_TRACER_BOX
TILT_PLATELETS = 200
ARRAYS = 4  # independent arrays per check draw: their mean is the expected L* the emulator is judged against


def emulator(progress: bool = True):
    t0 = time.perf_counter()
    em = wide_tracer_emulator(progress=progress)
    print(f"emulator ready ({time.perf_counter() - t0:.0f} s): held-out RMS per angle {np.round(em.held_out_rms, 2).tolist()}, "
          f"max {np.round(em.held_out_max, 1).tolist()}; error_sd {np.round(np.asarray(em.error_sd), 2).tolist()}", flush=True)
    return em


def posterior_check_draws(em, runs: list, per_run: int, seed: int) -> np.ndarray:
    """`per_run` draws of each posterior in `runs`, in the emulator's parameter order."""
    rng = np.random.default_rng(seed)
    draws = []
    for r in runs:
        cols = [r.names.index(k) for k in em.parameter_names]
        draws.append(r.samples[rng.choice(r.samples.shape[0], per_run, replace=False)][:, cols])
    return np.concatenate(draws)


def emulator_at_posterior(em, x: np.ndarray, seed: int, arrays: int = ARRAYS) -> dict:
    """The emulator where the posteriors with free inputs lie, at the draws x:
    * its GP against the direct tracer with common random numbers (what the GP emulates; the CRN tracer's bias
      added back), judged by the likelihood's Student-t (`EmulatorError`): the emulator's own error there;
    * the emulator against one independent tracer run per draw (fresh array and rays, seeds 3000 + 1000·seed + i:
      what a measured panel is), judged by the likelihood's whole residual law (Student-t ⊕ run-to-run spread ⊕
      the bias's variance), its central 68 % and 95 % intervals per draw and angle from 4000 draws of the law;
    * the emulator and the CRN tracer against the mean over `arrays` independent runs per draw (seeds + 100·j):
      the expected L* over platelet arrays, which a panel's millimetre-wide spot averages over, with its standard
      error. A single run, CRN or independent, carries its own array's deviation, which is large where the
      platelets are smooth and the tilt law wide, so only the mean says how far the emulator is from the tracer."""
    from paintjax.inverse import direct_tracer, emulator_check, independent_runs

    if not 1 <= arrays <= 10 or len(x) > 100:
        raise ValueError(f"arrays must lie in [1, 10] and the draws number at most 100 (the seeds 3000 + 1000·seed + 100·j + i "
                         f"of one seed's block must not reach the next), got {arrays}, {len(x)}")
    rng = np.random.default_rng(seed)
    z = em.unit_coordinates(x)
    bias = np.zeros((len(x), len(em.angles))) if em.run_to_run is None else np.asarray(em.run_to_run.mean(z))
    t0 = time.perf_counter()
    fn = direct_tracer(em)
    direct = np.asarray(fn(x))
    fresh = np.stack([independent_runs(fn, x, [3000 + seed * 1000 + 100 * j + i for i in range(len(x))])["L"] for j in range(arrays)])
    seconds = time.perf_counter() - t0
    pred = np.asarray(em(x))
    gp = pred + bias
    c = emulator_check(em, lambda _: direct - bias, x)  # = the GP against the CRN tracer
    d = gp - direct
    scale = np.asarray(em.error.scale_at(z))
    law = np.asarray(em.sample_residual(rng, np.zeros((4000 * len(x), len(em.angles))), np.tile(x, (4000, 1)))).reshape(4000, len(x), -1)
    lo68, hi68, lo95, hi95 = np.quantile(law, [0.16, 0.84, 0.025, 0.975], axis=0)
    made = np.all(np.isfinite(fresh[0]), axis=1)
    e = (pred - fresh[0])[made]
    out = {"parameters": list(em.parameter_names), "draws": x.tolist(), "emulator_minus_tracer": d.tolist(), "rms": np.asarray(c["rms"]).tolist(), "max_abs": np.asarray(c["max_abs"]).tolist(),
           "median_abs": np.median(np.abs(d), 0).tolist(), "t_scale_at_draws": np.median(scale, 0).tolist(),
           "within_t_68": float(np.mean(np.abs(d / scale) <= _t_quantile(em.error.df, 0.84))),
           "within_t_95": float(np.mean(np.abs(d / scale) <= _t_quantile(em.error.df, 0.975))),
           "emulator_minus_independent": e.tolist(), "independent_rms": np.sqrt(np.mean(e**2, 0)).tolist(),
           "independent_mean": e.mean(0).tolist(), "independent_max_abs": np.abs(e).max(0).tolist(),
           "within_law_68": float(np.mean((e >= lo68[made]) & (e <= hi68[made]))),
           "within_law_95": float(np.mean((e >= lo95[made]) & (e <= hi95[made]))), "tracer_seconds": seconds}
    if arrays > 1:
        made = np.all(np.isfinite(fresh), axis=(0, 2))
        mean, sd = fresh[:, made].mean(0), fresh[:, made].std(0, ddof=1)
        se = sd / np.sqrt(arrays)
        em_d, crn_d = pred[made] - mean, direct[made] - mean
        out["array_mean"] = {
            "arrays": arrays, "draws_with_arrays": int(made.sum()), "draw_index": np.flatnonzero(made).tolist(), "mean": mean.tolist(), "sd": sd.tolist(), "se": se.tolist(),
            "emulator_minus_mean": em_d.tolist(), "crn_minus_mean": crn_d.tolist(),
            "emulator_rms": np.sqrt(np.mean(em_d**2, 0)).tolist(), "emulator_max_abs": np.abs(em_d).max(0).tolist(),
            "crn_rms": np.sqrt(np.mean(crn_d**2, 0)).tolist(), "crn_max_abs": np.abs(crn_d).max(0).tolist(),
            "sd_rms": np.sqrt(np.mean(sd**2, 0)).tolist(),
            # cells where the emulator is more than 3 L* from the expected L* beyond two standard errors of the mean
            "beyond_3": int(np.sum(np.abs(em_d) - 2.0 * se > 3.0)), "cells": int(em_d.size)}
    return out


def report_check(name: str, chk: dict) -> None:
    print(f"{name}: at {len(chk['draws'])} posterior draws, the GP − CRN tracer: RMS {np.round(chk['rms'], 2).tolist()}, "
          f"max {np.round(chk['max_abs'], 1).tolist()}, within the t law's 68 / 95 % intervals: "
          f"{chk['within_t_68']:.0%} / {chk['within_t_95']:.0%}; the emulator − independent runs: RMS "
          f"{np.round(chk['independent_rms'], 2).tolist()}, mean {np.round(chk['independent_mean'], 2).tolist()}, within the "
          f"likelihood's law's 68 / 95 % intervals: {chk['within_law_68']:.0%} / {chk['within_law_95']:.0%} "
          f"({chk['tracer_seconds']:.0f} s of tracing)", flush=True)
    a = chk.get("array_mean")
    if a:
        print(f"{name}: against the mean of {a['arrays']} independent arrays per draw (spread between arrays, RMS over draws "
              f"{np.round(a['sd_rms'], 2).tolist()}): the emulator RMS {np.round(a['emulator_rms'], 2).tolist()}, max "
              f"{np.round(a['emulator_max_abs'], 1).tolist()} ({a['beyond_3']} of {a['cells']} draw-angle cells beyond 3 L* by more than "
              f"2 SE); the CRN tracer RMS {np.round(a['crn_rms'], 2).tolist()}, max {np.round(a['crn_max_abs'], 1).tolist()}", flush=True)


def plot_checks(out: dict, path: Path) -> Path | None:
    """Per panel and angle, at each check draw: the emulator and the CRN tracer minus the mean of the independent
    arrays (± 2 SE of that mean), draws ordered by σ."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = {n: p["emulator_at_posterior"] for n, p in out["panels"].items() if "array_mean" in p.get("emulator_at_posterior", {})}
    if not panels:
        return None
    angles = (15, 25, 45, 75, 110)
    fig, axes = plt.subplots(len(panels), len(angles), figsize=(15, 3.2 * len(panels)), squeeze=False)
    for row, (name, chk) in zip(axes, panels.items()):
        a = chk["array_mean"]
        sigma = 1000 * np.asarray(chk["draws"])[a["draw_index"], chk["parameters"].index("sigma")]
        order = np.argsort(sigma)
        em, crn, se = (np.asarray(a[k])[order] for k in ("emulator_minus_mean", "crn_minus_mean", "se"))
        for k, ax in enumerate(row):
            pos = np.arange(len(order))
            ax.axhspan(-3, 3, color="0.9", label="±3 L* (goal)")
            ax.errorbar(pos - 0.12, em[:, k], yerr=2 * se[:, k], fmt="o", color="C0", ms=4, capsize=2, label="emulator − array mean (± 2 SE)")
            ax.plot(pos + 0.12, crn[:, k], "s", color="C3", ms=4, label="CRN tracer − array mean")
            ax.axhline(0, color="k", lw=0.6)
            ax.set_xticks(pos, [f"{v:.0f}" for v in sigma[order]], fontsize=7)
            ax.set_xlabel("check draw's σ [nm]", fontsize=8)
            ax.set_title(f"{name}, {angles[k]}°", fontsize=9)
        row[0].set_ylabel(f"L* − mean of {a['arrays']} arrays")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle("The emulator where the posteriors lie, against the tracer's expected L* "
                 "(python experiments/calibrated_posterior.py --checks-only)", fontsize=10)
    fig.tight_layout()
    res = atomic_savefig(fig, path, dpi=120)
    plt.close(fig)
    return res


def checks_only(em, path: Path, seed: int, arrays: int) -> int:
    """Redo `emulator_at_posterior` at the draws stored in `path` (an earlier run's summary) and update it."""
    import json

    if not path.exists():
        raise SystemExit(f"{path} does not exist: run the experiment without --checks-only first")
    out = json.loads(path.read_text())
    for name, panel in out["panels"].items():
        if "emulator_at_posterior" not in panel:
            raise SystemExit(f"{path} has no check draws for {name}: run the experiment with --check-draws > 0")
        chk = emulator_at_posterior(em, np.asarray(panel["emulator_at_posterior"]["draws"]), seed, arrays)
        panel["emulator_at_posterior"] = chk
        report_check(name, chk)
    atomic_write_json(path, out)
    print(f"updated {path}; figure: {plot_checks(out, path.with_name('emulator_at_posterior.png'))}", flush=True)
    return 0


def _t_quantile(df: float, q: float) -> float:
    from scipy.stats import t

    return float(t.ppf(q, df))


def plot(out: dict, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    angles = np.array([15, 25, 45, 75, 110])
    fig, axes = plt.subplots(2, 2, figsize=(11, 8))
    for row, (name, panel) in zip(axes, out["panels"].items()):
        ax = row[0]
        ax.errorbar(angles, panel["measured"], yerr=0.3, fmt="ko", label="measured", zorder=5)
        for (label, run), c, dx in zip(panel["runs"].items(), ("C0", "C1", "C3"), (-1.5, 0.0, 1.5)):
            ch = run["check"]
            lo, mid, hi = (np.asarray(ch[k]) for k in ("L_star_q05", "L_star_q50", "L_star_q95"))
            ax.errorbar(angles + dx, mid, yerr=[mid - lo, hi - mid], fmt="s", color=c, ms=4, capsize=2,
                        label=f"{label}: 90 % predictive (p = {ch['p_value']:.2g})")
        ax.set_xlabel("aspecular angle [deg]"), ax.set_ylabel("L*"), ax.set_title(f"{name}: posterior predictive", fontsize=9)
        ax.legend(fontsize=7)
        ax = row[1]
        for (label, run), c in zip(list(panel["runs"].items())[:2], ("C0", "C1")):
            d = run["draws"]
            ax.plot(1000 * np.asarray(d["sigma"]), np.asarray(d["tau"]), ".", color=c, ms=1.5, alpha=0.4, label=label)
        ax.plot(51, 0.64, "r*", ms=5, label="published reading")
        ax.set_xscale("log"), ax.set_yscale("log")
        ax.set_xlabel("σ [nm]"), ax.set_ylabel("τ [µm]"), ax.set_title(f"{name}: posterior draws of the true σ, τ", fontsize=9)
        ax.legend(fontsize=7, markerscale=3)
    fig.suptitle(f"Posteriors with measurement models for the inputs, σ read as {out['sigma_definition']} "
                 f"(python experiments/calibrated_posterior.py --definition {out['sigma_definition']})", fontsize=10)
    fig.tight_layout()
    res = atomic_savefig(fig, path, dpi=130)
    plt.close(fig)
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--build-only", action="store_true", help="build (or load) the emulator and stop")
    ap.add_argument("--walkers", type=int, default=32)
    ap.add_argument("--max-steps", type=int, default=MAX_STEPS)
    ap.add_argument("--min-ess", type=float, default=1000.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--definition", default="rq", choices=SIGMA_DEFINITIONS,
                    help="how the published σ was read (the profilometer model's σ definition; default rq). Output of "
                         "other readings goes to experiments/output/calibrated_posterior_<definition>/")
    ap.add_argument("--check-draws", type=int, default=4, help="direct tracer runs (CRN and independent) at this many draws of each "
                    "posterior with free inputs, to measure the emulator's error where the posteriors lie (0: skip)")
    ap.add_argument("--arrays", type=int, default=ARRAYS, help="independent tracer runs (fresh arrays) per check draw; with more than "
                    "one, the emulator and the CRN tracer are also compared with their mean, the expected L*")
    ap.add_argument("--checks-only", action="store_true", help="redo only the checks of the emulator where the posteriors lie, at the "
                    "draws stored in an earlier run's summary.json, and update it")
    args = ap.parse_args(argv)
    enable_compilation_cache()
    t0 = time.perf_counter()
    em = emulator()
    if args.build_only:
        return 0
    out_dir = OUT if args.definition == "rq" else OUT.with_name(f"{OUT.name}_{args.definition}")
    if args.checks_only:
        return checks_only(em, out_dir / "summary.json", args.seed, args.arrays)
    reading = build_reading_model(progress=True)
    out = {"box": BOX, "tilt_platelets": TILT_PLATELETS, "sigma_definition": args.definition, "emulator": {
        "held_out_rms": em.held_out_rms, "held_out_max": em.held_out_max, "error_sd": np.asarray(em.error_sd),
        "error_model": {"df": em.error.df, "scale": np.asarray(em.error.scale), "slope": dict(zip(em.spec.names, np.asarray(em.error.slope).tolist())),
                        "seed_spread_sd": list(em.seed_spread_sd)}}, "panels": {}}
    out_dir.mkdir(parents=True, exist_ok=True)
    for name in ("silver1", "silver2"):
        s = load_sample(name)

        def report(label, entry, name=name):
            print(f"{name}: {label}\n{entry['posterior'].summary()}", flush=True)
            print(f"  posterior-predictive p = {entry['check']['p_value']:.3g} ± {entry['check']['p_value_se']:.1g}; input shifts (z) "
                  f"{ {k: round(v['z'], 2) for k, v in entry['input_shift'].items()} }", flush=True)

        result = panel_posteriors(em, s, reading, definition=args.definition, tilt_platelets=TILT_PLATELETS, walkers=args.walkers, max_steps=args.max_steps,
                                  min_ess=args.min_ess, seed=args.seed, on_run=report)
        runs = {}
        for label, entry in ((k, v) for k, v in result.items() if k != "verdict"):
            r = entry["posterior"]
            save_netcdf(r.idata, out_dir / f"{name}_{label.replace('*', '').replace(',', '').replace(' ', '_')}.nc")
            draws = {n: r.draws(n) for n in r.names}
            runs[label] = {"summary": r.to_dict(), "check": entry["check"], "input_shift": entry["input_shift"],
                           "draws": {n: np.asarray(v)[:: max(1, len(v) // 2000)] for n, v in draws.items()}}
        out["panels"][name] = {"measured": s.L_star, "runs": runs, "verdict": result["verdict"]}
        free_runs = [result[k]["posterior"] for k in ("L* alone", "L* and inputs")]
        if args.check_draws > 0:
            chk = emulator_at_posterior(em, posterior_check_draws(em, free_runs, args.check_draws, args.seed), args.seed, args.arrays)
            out["panels"][name]["emulator_at_posterior"] = chk
            report_check(name, chk)
    out["seconds"] = time.perf_counter() - t0
    atomic_write_json(out_dir / "summary.json", out)
    print(f"figures: {plot(out, out_dir / 'calibrated_posterior.png')}, {plot_checks(out, out_dir / 'emulator_at_posterior.png')}; "
          f"done in {out['seconds']:.0f} s", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
