"""Experiment: does the emulator's error law hold the misses of a calibration study's panels at their truths?

A calibration study (`experiments/coverage.py --forward tracer-emulator-wide`) stores, per synthetic panel, the
truth θ and the panel's data (one independent tracer run, fresh array and rays, plus 0.3 L* of measurement noise).
The likelihood says the residual r = data − emulator(θ) at the truth is a draw of the emulator's error law (the
cross-validated Student-t, the run-to-run spread and the fitted bias's variance) plus the noise. This checks that
claim panel by panel, independently of any posterior: the tail probability p of r under the law, ranked by the
law's own log density (p = P(log p(R) ≤ log p(r)), R drawn from the law at θ, Monte Carlo). If the law is right,
p is uniform: 5 % of panels below 0.05. Too many small p where posteriors missed says the law is too narrow there;
uniform p says the misses come from elsewhere (the posterior's geometry, the prior's edge). Reports p per panel,
the fractions below 0.05 and 0.32 overall and among the panels whose 95 % interval of a parameter missed, and
Spearman's ρ of p with each truth, and (`directional_ranks`) whether the law holds the residual along the directions
that move each parameter: the rank of its linearised least-squares shift among the law's draws, weighted by 1 / RMS²
("directional") and by the law's own Hessian at the truth ("directional_law": the direction the posterior moves). `--independent` asks the same of the independent tracer runs the run-to-run terms
were fitted to (in sample: what the law was made to hold); with `--folds K` each fold's runs are judged by run-to-run
terms refitted to the other folds (out of sample, as fresh panels are).

Writes <study>/error_law_check.json and error_law_check.png, or with --independent
experiments/output/error_law_check/independent.json (atomic).

Run: python experiments/error_law_check.py [--study experiments/output/coverage_tracer_wide_seed2030] [--draws 4000]
     python experiments/error_law_check.py --independent [--folds 5]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402
from scipy import stats  # noqa: E402

from paintjax import atomic_write_json  # noqa: E402
from paintjax.inverse import (  # noqa: E402
    WIDE_TRACER_SETTINGS,
    TracerLStar,
    fit_run_to_run,
    independent_check_design,
    independent_runs,
    make_forward,
)

STUDY = Path(__file__).resolve().parent / "output" / "coverage_tracer_wide_seed2030"
OUT_INDEPENDENT = Path(__file__).resolve().parent / "output" / "error_law_check" / "independent.json"
NOISE_SD = 0.3  # the study's measurement noise [L*]
NAMES = ("shape", "scale", "sigma", "tau")


def tail_probabilities(em, theta, data, noise_var, draws, rng):
    """Residuals data − em(θ) and their tail probabilities under the emulator's error law plus the noise (ranked by
    the law's log density; Monte Carlo with `draws` draws per row)."""
    r = data - np.asarray(em(theta))
    var = np.full_like(r, noise_var)
    logp = np.asarray(em.residual_log_density(r, var, theta))
    p = np.empty(len(r))
    for i in range(len(r)):
        R = em.sample_residual(rng, np.broadcast_to(var[i], (draws, r.shape[1])), np.broadcast_to(theta[i], (draws, theta.shape[1])))
        lp = np.asarray(em.residual_log_density(R, np.broadcast_to(var[i], R.shape), np.broadcast_to(theta[i], (draws, theta.shape[1]))))
        p[i] = (np.sum(lp <= logp[i]) + 1) / (draws + 1)
    return r, p


def directional_ranks(em, theta, r, noise_var, draws, rng) -> dict:
    """Per panel and parameter, the rank among the law's draws of the residual's linearised least-squares shift of that
    parameter: with J the emulator's Jacobian in log θ at the truth and W the weights, the shift is the row of
    (JᵀWJ)⁻¹JᵀW for the parameter times the residual. Two weights, on the same draws: "rms", W = diag(1 / error_sd²);
    "law", W = the Hessian of −log p(r) at r = 0 under the law at the truth (its correlation between the angles, its
    regional scale and the noise: the direction the posterior moves along for small residuals). Uniform if the law
    holds along the directions that move the posterior; the central 68 % of the law's draws should hold 68 % of the
    panels. Returns {"rms": ranks, "law": ranks}, each (panels, parameters)."""
    import jax.numpy as jnp

    m = r.shape[1]
    f = lambda t: em.evaluate(t[None])[0]  # noqa: E731
    rms = np.diag(1.0 / np.asarray(em.error_sd) ** 2)
    ranks = {"rms": np.empty(theta.shape), "law": np.empty(theta.shape)}
    for i, t in enumerate(theta):
        J = np.asarray(jax.jacfwd(f)(jnp.asarray(t))) * t
        nll = lambda x: -em.residual_log_density(x[None], jnp.full((1, m), noise_var), jnp.asarray(t)[None])[0]  # noqa: E731
        R = em.sample_residual(rng, np.full((draws, m), noise_var), np.broadcast_to(t, (draws, t.size)))
        for key, W in (("rms", rms), ("law", np.asarray(jax.hessian(nll)(jnp.zeros(m))))):
            M = np.linalg.solve(J.T @ W @ J, J.T @ W)
            ranks[key][i] = (np.sum(R @ M.T < M @ r[i], axis=0) + 0.5) / (draws + 1)
    return ranks


def directional_summary(ranks) -> dict:
    """Per parameter: the ranks, the fraction in the central 68 %, and their KS p-value against uniform."""
    return {n: {"rank": ranks[:, j].tolist(), "central_68": float(np.mean((ranks[:, j] > 0.16) & (ranks[:, j] < 0.84))),
                "uniform_ks_p": float(stats.kstest(ranks[:, j], "uniform").pvalue)} for j, n in enumerate(NAMES)}


def uniformity(p) -> dict:
    """How far tail probabilities p are from uniform: the fractions below 0.05 and 0.32, the binomial 95 % ranges of
    those counts for a law that holds, and the Kolmogorov–Smirnov p-value against the uniform law."""
    return {"fraction_below": {"0.05": float(np.mean(p < 0.05)), "0.32": float(np.mean(p < 0.32))},
            "binomial_95_range_below_0.05": [int(x) for x in stats.binom(len(p), 0.05).interval(0.95)],
            "binomial_95_range_below_0.32": [int(x) for x in stats.binom(len(p), 0.32).interval(0.95)],
            "uniform_ks_p": float(stats.kstest(p, "uniform").pvalue)}


def describe(p, u: dict) -> str:
    """One line of the counts below 0.05 and 0.32 against their ranges (`uniformity`), and the KS p-value."""
    return (f"p < 0.05 in {np.sum(p < 0.05)} (binomial 95 % range {u['binomial_95_range_below_0.05']}), p < 0.32 in "
            f"{np.sum(p < 0.32)} (range {u['binomial_95_range_below_0.32']}); KS against uniform p = {u['uniform_ks_p']:.3f}")


def check_independent(draws: int, seed: int, folds: int) -> int:
    """The tail probabilities of the emulator's misses of its own independent check runs (no added noise): in sample,
    or (folds > 1) each fold under run-to-run terms refitted to the other folds."""
    import equinox as eqx

    em = make_forward("tracer-emulator-wide", NAMES)
    fn = TracerLStar(WIDE_TRACER_SETTINGS)  # the runs are cached at all its angles
    z, theta, data = [], [], []
    for zb, t, seeds in independent_check_design(em.spec):
        z.append(zb)
        theta.append(t)
        data.append(independent_runs(fn, t, seeds)["L"][:, [fn.angles.index(x) for x in em.angles]])
    z, theta, data = np.concatenate(z), np.concatenate(theta), np.concatenate(data)
    made = np.all(np.isfinite(data), axis=1)  # a θ whose platelets cannot fit the film has no run
    z, theta, data = z[made], theta[made], data[made]
    rng = np.random.default_rng(seed)
    if folds <= 1:
        _, p = tail_probabilities(em, theta, data, 0.0, draws, rng)
    else:
        gp_miss = np.asarray(em(theta)) + np.asarray(em.run_to_run.mean(z)) - data  # the GP's miss, before any bias
        fold = rng.permutation(len(data)) % folds
        p = np.empty(len(data))
        for k in range(folds):
            term = fit_run_to_run(em.error, z[fold != k], gp_miss[fold != k])
            em_k = eqx.tree_at(lambda e: (e.run_to_run, e.error), em, (term, term.law(em.error)))
            _, p[fold == k] = tail_probabilities(em_k, theta[fold == k], data[fold == k], 0.0, draws, rng)
            print(f"fold {k + 1}/{folds} done", flush=True)
    out = {"runs": int(len(p)), "draws": draws, "folds": folds, "p": p.tolist(), **uniformity(p)}
    path = OUT_INDEPENDENT if folds <= 1 else OUT_INDEPENDENT.with_name(f"independent_{folds}fold.json")
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(path, out)
    where = "in sample" if folds <= 1 else f"each of {folds} folds under terms fitted to the others"
    print(f"{len(p)} independent runs ({where}): {describe(p, out)}")
    return 0


def load_study(study: Path) -> dict:
    """The summary of a finished tracer-emulator-wide calibration study over `NAMES` (SystemExit naming the folder if not)."""
    if not (study / "summary.json").is_file():
        raise SystemExit(f"--study {study}: no summary.json there (a finished experiments/coverage.py study folder)")
    summary = json.loads((study / "summary.json").read_text())
    if summary.get("forward") != "tracer-emulator-wide" or tuple(summary.get("free", ())) != NAMES:
        raise SystemExit(f"{study}: not a tracer-emulator-wide study over {NAMES}")
    return summary


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--study", default=str(STUDY), help="folder of a tracer-emulator-wide calibration study (its summary.json)")
    ap.add_argument("--draws", type=int, default=4000, help="Monte Carlo draws of the law per panel")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--independent", action="store_true", help="check the independent runs the run-to-run terms were fitted to")
    ap.add_argument("--folds", type=int, default=1, help="with --independent: K > 1 judges each fold by terms refitted to the others")
    a = ap.parse_args(argv)
    if a.draws < 100:
        raise SystemExit(f"--draws must be at least 100, got {a.draws}")
    if a.folds < 1 or a.folds > 20:
        raise SystemExit(f"--folds must be in [1, 20], got {a.folds}")
    if a.independent:
        return check_independent(a.draws, a.seed, a.folds)
    study = Path(a.study)
    summary = load_study(study)
    rows = summary["rows"]
    em = make_forward("tracer-emulator-wide", NAMES)
    theta = np.array([[r["truth"][n] for n in NAMES] for r in rows])
    data = np.array([r["L_star"] for r in rows])
    r, p = tail_probabilities(em, theta, data, NOISE_SD**2, a.draws, np.random.default_rng(a.seed))
    ranks = directional_ranks(em, theta, r, NOISE_SD**2, a.draws, np.random.default_rng(a.seed + 1))
    missed = {n: np.array([not r_["inside"][f"{n}@0.95"] for r_ in rows]) for n in NAMES}
    out = {"study": str(study.name), "panels": len(rows), "draws": a.draws, "noise_sd": NOISE_SD,
           "p": p.tolist(), "residual": r.tolist(), "angles": [float(x) for x in em.angles],
           **uniformity(p),
           "missed_at_95": {n: {"panels": int(m.sum()), "p": p[m].tolist()} for n, m in missed.items()},
           "spearman_with_truth": {n: dict(zip(("rho", "p"), map(float, stats.spearmanr(p, theta[:, j])))) for j, n in enumerate(NAMES)},
           "directional": directional_summary(ranks["rms"]), "directional_law": directional_summary(ranks["law"])}
    atomic_write_json(study / "error_law_check.json", out)
    print(f"{len(rows)} panels: {describe(p, out)}")
    for n, m in missed.items():
        print(f"  {n}: {m.sum()} missed at 95 %, their p: {np.round(p[m], 3).tolist()}")
    for n, v in out["spearman_with_truth"].items():
        print(f"  Spearman ρ(p, {n}) = {v['rho']:+.2f} (p {v['p']:.2f})")
    for key, how in (("directional", "1 / RMS² weights"), ("directional_law", "the law's weights")):
        for n, v in out[key].items():
            print(f"  {n}: the residual's least-squares shift ({how}) in the law's central 68 % for {v['central_68']:.0%} of panels, "
                  f"KS p {v['uniform_ks_p']:.2f}")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(9, 3.4))
    ax[0].hist(p, bins=10, range=(0, 1), color="0.6", edgecolor="k")
    ax[0].axhline(len(rows) / 10, color="C3", lw=1)
    ax[0].set(xlabel="tail probability p of the residual at the truth", ylabel="panels", title="uniform if the law holds")
    ax[1].scatter(theta[:, 3], p, c=np.log(theta[:, 0]), cmap="viridis", s=18)
    for n, m in missed.items():
        if n == "tau" and m.any():
            ax[1].scatter(theta[m, 3], p[m], facecolor="none", edgecolor="C3", s=60, label="τ missed at 95 %")
    ax[1].set(xscale="log", xlabel="true τ [µm]", ylabel="p", title="colour: ln shape")
    ax[1].set_xticks([0.25, 0.5, 1.0, 2.0], ["0.25", "0.5", "1", "2"])
    ax[1].minorticks_off()
    ax[1].legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    tmp = study / "error_law_check.tmp.png"
    fig.savefig(tmp, dpi=120)
    tmp.replace(study / "error_law_check.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
