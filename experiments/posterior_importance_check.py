"""Experiment: are a calibration study's posteriors the posteriors of their likelihood? An independent sampler.

A calibration study (`experiments/coverage.py --forward tracer-emulator-wide`) draws each panel's posterior with
emcee and counts how often its central intervals hold the truth. When the intervals hold the truth too rarely, either
the likelihood (the emulator and its error law) is too sure, or the sampler did not draw from it. This separates the
two: it recomputes every panel's posterior with a different algorithm, adaptive importance sampling, on the same
log density (the emulator's `residual_log_density` with the study's 0.3 L* of noise and no discrepancy, checked
against `LogPosterior` on a few points), and compares the two posteriors' PIT (posterior CDF at the truth) and
interval verdicts panel by panel.

The importance sampler works in the box's unit coordinates z (log-uniform priors: z uniform on the unit cube):
a shared pool of prior draws gives each panel's first weighted sample; each of `--rounds` rounds fits a proposal
to the previous round's weighted draws, and the last round's `--draws` draws give the posterior (weights
likelihood · prior / proposal). The proposal is a mixture: 0.1 · the prior (defensive: no weight exceeds 10 × the
likelihood, so no tail is missed), 0.2 · one Student-t (ν 5) with the draws' weighted mean and 1.5² × their weighted
covariance, and 0.7 · Student-t kernels at 64 draws resampled by weight with 0.6² × that weighted covariance (they
follow curved posteriors). Each panel's effective sample size (Kish) is reported; the PIT's Monte Carlo SE is about
√(PIT (1 − PIT) / ESS).

`--synthetic N` checks the checker: N truths from the prior, their data drawn from the likelihood's own law
(emulator + `sample_residual` with the noise), so the PITs must be uniform and the intervals hold the truth at
their levels. `--study FOLDER --data model --replicates R` draws R such panels at each of the study's truths: how
often the intervals would hold those truths if the data came from the likelihood's law rather than the tracer (a
set of 50 truths near the box's edges may cover less than the level even under an exact model).

Writes <study>/importance_check.json (`--data model`: importance_check_model.json; `--synthetic`:
experiments/output/importance_check/synthetic.json) and a figure beside it (atomic).

Run: python experiments/posterior_importance_check.py --study experiments/output/coverage_tracer_wide_seed2032_v2
     python experiments/posterior_importance_check.py --study experiments/output/coverage_tracer_wide_seed2032_v2 --data model --replicates 2
     python experiments/posterior_importance_check.py --synthetic 100
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402
from error_law_check import NAMES, load_study  # noqa: E402  the parameters and the study folder's check, shared
from scipy import special, stats  # noqa: E402

from paintjax import atomic_savefig, atomic_write_json  # noqa: E402
from paintjax.inverse import LogPosterior, make_forward  # noqa: E402

NOISE_SD = 0.3  # the study's measurement noise and instrument SD [L*]
LEVELS = (0.68, 0.95)
OUT_SYNTHETIC = Path(__file__).resolve().parent / "output" / "importance_check" / "synthetic.json"
DEFENSIVE = 0.1  # the prior's share of the proposal
PROPOSAL_DF = 5.0
INFLATE = 1.5
GLOBAL_SHARE = 0.2  # the single Student-t's share
KERNEL_BANDWIDTH = 0.6


class Likelihood:
    """log p(y | θ) of one panel as the study's posterior has it, as a function of unit coordinates z (n, 4)."""

    def __init__(self, em, y):
        self.em, self.y = em, np.asarray(y, float)
        self.spec = em.spec

    def of_lightness(self, z, L):
        theta = np.asarray(self.spec.from_unit(z))
        var = np.full(L.shape, NOISE_SD**2)
        return np.asarray(self.em.residual_log_density(self.y - L, var, theta), float)

    def __call__(self, z):
        L = np.asarray(self.em(np.asarray(self.spec.from_unit(z))))
        return self.of_lightness(z, L)

    def check_against_log_posterior(self, z) -> float:
        """Largest |difference| of this log likelihood from `LogPosterior` − log prior (in unconstrained
        coordinates) at z: the study's sampler's density, up to the prior and a constant."""
        lp = LogPosterior(self.em, self.y, free=NAMES, fixed={"discrepancy": 0.0})
        U = np.asarray(lp.spec.to_unconstrained(lp.spec.from_unit(z)))
        ll = lp(U) - np.asarray(lp.spec.log_prior_unconstrained(U))
        return float(np.max(np.abs(ll - self(z))))


def _student_logpdf(z, mean, cov):
    d = z.shape[1]
    chol = np.linalg.cholesky(cov)
    x = np.linalg.solve(chol, (z - mean).T).T
    q = np.sum(x**2, axis=1)
    nu = PROPOSAL_DF
    return (special.gammaln((nu + d) / 2) - special.gammaln(nu / 2) - 0.5 * d * np.log(nu * np.pi)
            - np.sum(np.log(np.diag(chol))) - 0.5 * (nu + d) * np.log1p(q / nu))


def _weighted_moments(z, logw):
    w = np.exp(logw - np.max(logw))
    w /= w.sum()
    mean = w @ z
    cov = (z - mean).T @ ((z - mean) * w[:, None]) + 1e-6 * np.eye(z.shape[1])
    return mean, cov


def kish_ess(logw) -> float:
    w = np.exp(logw - np.max(logw))
    return float(w.sum() ** 2 / np.sum(w**2))


def _proposal(z, logw, rng, components: int):
    """The proposal fitted to weighted draws: the defensive prior, one Student-t over the whole posterior (its
    weighted mean and covariance, inflated), and a kernel mixture of Student-t's at `components` draws resampled
    by weight (bandwidth 0.6 of the covariance's scale: it follows curved posteriors that one Student-t misses)."""
    mean, cov = _weighted_moments(z, logw)
    w = np.exp(logw - np.max(logw))
    centres = z[rng.choice(len(z), size=components, p=w / w.sum())]
    shares = (DEFENSIVE, GLOBAL_SHARE, 1.0 - DEFENSIVE - GLOBAL_SHARE)
    return mean, INFLATE**2 * cov, centres, KERNEL_BANDWIDTH**2 * cov, shares


def _proposal_draw(q, rng, n: int, d: int):
    mean, cov, centres, kcov, shares = q
    which = rng.choice(3, size=n, p=shares)
    loc = np.where((which == 1)[:, None], mean, centres[rng.integers(len(centres), size=n)])
    chol = np.where((which == 1)[:, None, None], np.linalg.cholesky(cov), np.linalg.cholesky(kcov))
    g = rng.chisquare(PROPOSAL_DF, size=n) / PROPOSAL_DF
    t = loc + np.einsum("nij,nj->ni", chol, rng.standard_normal((n, d))) / np.sqrt(g)[:, None]
    return np.where((which == 0)[:, None], rng.random((n, d)), t)


def _proposal_logpdf(q, z):
    mean, cov, centres, kcov, shares = q
    kernel = special.logsumexp(np.stack([_student_logpdf(z, c, kcov) for c in centres]), axis=0) - np.log(len(centres))
    return special.logsumexp(np.stack([np.zeros(len(z)), _student_logpdf(z, mean, cov), kernel]), axis=0, b=np.array(shares)[:, None])


def importance_posterior(lik: Likelihood, z0, ll0, rng, rounds: int, adapt_draws: int, draws: int, components: int = 64):
    """Adaptive importance sampling of one panel's posterior in unit coordinates, started from the prior pool
    (z0, its log likelihoods ll0). Returns (z, log weights) of the last round."""
    z, logw = z0, ll0  # prior draws: weight = likelihood
    for r in range(rounds + 1):
        q = _proposal(z, logw, rng, components)
        z = _proposal_draw(q, rng, draws if r == rounds else adapt_draws, z0.shape[1])
        inside = np.all((z > 0) & (z < 1), axis=1)  # outside the box the prior, and so the weight, is 0
        # the likelihood at every draw (clipped into the box) keeps the array shapes, so nothing recompiles
        logw = np.where(inside, lik(np.clip(z, 1e-9, 1 - 1e-9)) - _proposal_logpdf(q, z), -np.inf)
    return z, logw


def weighted_quantile(x, w, q):
    o = np.argsort(x)
    c = np.cumsum(w[o])
    c /= c[-1]
    return np.interp(q, c, x[o])


def summarise(lik: Likelihood, z, logw, truth) -> dict:
    """PIT and central-interval verdicts of the weighted posterior at the truth (values, not unit coordinates)."""
    theta = np.asarray(lik.spec.from_unit(z))
    w = np.exp(logw - np.max(logw))
    out = {"ess": kish_ess(logw), "pit": {}, "inside": {}}
    for j, n in enumerate(NAMES):
        out["pit"][n] = float(np.sum(w * (theta[:, j] < truth[j])) / w.sum())
        for lv in LEVELS:
            lo, hi = weighted_quantile(theta[:, j], w, [(1 - lv) / 2, (1 + lv) / 2])
            out["inside"][f"{n}@{lv}"] = bool(lo <= truth[j] <= hi)
    return out


def run(em, truths, data, rng, a, label):
    spec = em.spec
    z0 = rng.random((a.pool, len(NAMES)))
    t0 = time.time()
    L0 = np.asarray(em(np.asarray(spec.from_unit(z0))))
    print(f"prior pool of {a.pool} emulator runs: {time.time() - t0:.0f} s", flush=True)
    check = Likelihood(em, data[0]).check_against_log_posterior(z0[:64])
    if not check < 1e-8:
        raise SystemExit(f"the importance sampler's log likelihood differs from LogPosterior's by {check:.3g}")
    rows = []
    for i, (t, y) in enumerate(zip(truths, data)):
        lik = Likelihood(em, y)
        t1 = time.time()
        ll0 = lik.of_lightness(z0, L0)
        z, logw = importance_posterior(lik, z0, ll0, rng, a.rounds, a.adapt_draws, a.draws)
        row = summarise(lik, z, logw, t) | {"truth": dict(zip(NAMES, map(float, t))), "prior_pool_ess": kish_ess(ll0)}
        rows.append(row)
        print(f"{label} panel {i + 1}/{len(truths)}: ESS {row['ess']:.0f} ({time.time() - t1:.0f} s), PIT "
              + " ".join(f"{row['pit'][n]:.3f}" for n in NAMES), flush=True)
    return rows, check


def coverage(rows, n) -> dict:
    return {f"{lv}": {n_: int(sum(r["inside"][f"{n_}@{lv}"] for r in rows)) for n_ in NAMES}
            | {"binomial_95_range": [int(x) for x in stats.binom(n, lv).interval(0.95)]} for lv in LEVELS}


def model_data(em, truths, rng):
    """L* drawn from the likelihood's own law at the truths: the emulator plus a draw of its error law and the noise."""
    var = np.full((len(truths), len(em.angles)), NOISE_SD**2)
    return np.asarray(em(truths)) + em.sample_residual(rng, var, truths)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--study", help="folder of a finished tracer-emulator-wide calibration study (its summary.json)")
    ap.add_argument("--data", choices=("study", "model"), default="study",
                    help="with --study: the study's L* (default), or L* drawn from the likelihood's law at its truths")
    ap.add_argument("--replicates", type=int, default=1, help="with --data model: panels drawn per truth")
    ap.add_argument("--synthetic", type=int, default=0, help="N > 0: N truths from the prior, their L* from the likelihood's law")
    ap.add_argument("--pool", type=int, default=100_000, help="shared prior draws")
    ap.add_argument("--rounds", type=int, default=2, help="adaptation rounds")
    ap.add_argument("--adapt-draws", type=int, default=10_000, help="draws per adaptation round")
    ap.add_argument("--draws", type=int, default=30_000, help="draws of the last round")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    if (a.study is None) == (a.synthetic <= 0):
        raise SystemExit("give either --study FOLDER or --synthetic N (N > 0)")
    if not 1 <= a.replicates <= 20 or (a.replicates > 1 and a.data != "model"):
        raise SystemExit(f"--replicates must be in [1, 20], and above 1 only with --data model; got {a.replicates}")
    for name in ("pool", "adapt_draws", "draws"):
        if getattr(a, name) < 1000:
            raise SystemExit(f"--{name.replace('_', '-')} must be at least 1000, got {getattr(a, name)}")
    if not 0 <= a.rounds <= 10:
        raise SystemExit(f"--rounds must be in [0, 10], got {a.rounds}")
    em = make_forward("tracer-emulator-wide", NAMES)
    if tuple(em.spec.names) != NAMES or any(p.prior != "loguniform" or p.scale != "log" for p in em.spec.parameters):
        raise SystemExit("the importance sampler assumes log-uniform priors on a log-scaled box over shape, scale, σ, τ")
    rng = np.random.default_rng(a.seed)
    if a.study:
        study = Path(a.study)
        summary = load_study(study)
        truths = np.array([[r["truth"][n] for n in NAMES] for r in summary["rows"]])
        if a.data == "study":
            data = np.array([r["L_star"] for r in summary["rows"]])
            out_path = study / "importance_check.json"
        else:
            truths = np.repeat(truths, a.replicates, axis=0)
            data, summary = model_data(em, truths, rng), None
            out_path = study / "importance_check_model.json"
    else:
        truths = np.asarray(em.spec.sample_prior(jax.random.key(a.seed), a.synthetic))
        data, summary = model_data(em, truths, rng), None
        out_path = OUT_SYNTHETIC
    rows, check = run(em, truths, data, rng, a, "study" if summary is not None else "model-drawn")
    n = len(rows)
    out = {"study": a.study, "data": "study" if summary is not None else "model", "replicates": a.replicates, "synthetic": a.synthetic,
           "panels": n, "pool": a.pool, "rounds": a.rounds, "adapt_draws": a.adapt_draws, "draws": a.draws, "seed": a.seed, "defensive": DEFENSIVE, "proposal_df": PROPOSAL_DF, "inflate": INFLATE,
           "max_difference_from_log_posterior": check, "ess_min": min(r["ess"] for r in rows),
           "ess_median": float(np.median([r["ess"] for r in rows])), "coverage": coverage(rows, n),
           "pit_ks_p": {m: float(stats.kstest([r["pit"][m] for r in rows], "uniform").pvalue) for m in NAMES}, "rows": rows}
    print(f"ESS min {out['ess_min']:.0f}, median {out['ess_median']:.0f}")
    for lv in LEVELS:
        c = out["coverage"][f"{lv}"]
        print(f"{lv:.0%} intervals (importance sampling): " + ", ".join(f"{m} {c[m]}" for m in NAMES) + f" of {n} (range {c['binomial_95_range']})")
    print("PIT KS p: " + ", ".join(f"{m} {out['pit_ks_p'][m]:.3f}" for m in NAMES))
    if summary is not None:
        mc = {m: np.array([r["pit"][m] for r in summary["rows"]]) for m in NAMES}
        imp = {m: np.array([r["pit"][m] for r in rows]) for m in NAMES}
        ess = np.array([r["ess"] for r in rows])
        neff = np.array([r["n_eff"] for r in summary["rows"]])
        out["against_emcee"] = {}
        for m in NAMES:
            d = imp[m] - mc[m]
            se = np.sqrt(np.clip(imp[m] * (1 - imp[m]), 1e-4, None) * (1 / ess + 1 / neff))
            flips = {f"{lv}": int(sum(r["inside"][f"{m}@{lv}"] != s["inside"][f"{m}@{lv}"] for r, s in zip(rows, summary["rows"])))
                     for lv in LEVELS}
            out["against_emcee"][m] = {"pit_difference_rms": float(np.sqrt(np.mean(d**2))), "pit_difference_mean": float(d.mean()),
                                       "z_rms": float(np.sqrt(np.mean((d / se) ** 2))), "verdicts_differing": flips}
            print(f"  {m}: PIT(importance) − PIT(emcee) RMS {np.sqrt(np.mean(d**2)):.3f} (mean {d.mean():+.3f}, RMS in Monte Carlo SE "
                  f"{out['against_emcee'][m]['z_rms']:.2f}); verdicts that differ: {flips}")
    out_path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out_path, out)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, len(NAMES), figsize=(12, 3.2))
    for j, m in enumerate(NAMES):
        p = [r["pit"][m] for r in rows]
        if summary is not None:
            ax[j].scatter([r["pit"][m] for r in summary["rows"]], p, s=14)
            ax[j].plot([0, 1], [0, 1], "k:", lw=1)
            ax[j].set(xlabel="PIT, emcee (the study)", ylabel="PIT, importance sampling", title=m)
        else:
            ax[j].hist(p, bins=10, range=(0, 1), color="0.6", edgecolor="k")
            ax[j].axhline(n / 10, color="C3", lw=1)
            ax[j].set(xlabel="PIT", ylabel="panels", title=f"{m} (uniform if calibrated)")
    fig.tight_layout()
    atomic_savefig(fig, out_path.with_suffix(".png"), dpi=110)
    print(f"wrote {out_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
