"""Benchmark: emcee (the default sampler) against NUTS (BlackJAX) through the differentiable emulator.

The problem is `paintjax fit --sample silver1 --posterior --inputs rq`: Silver #1's five L*, the
shipped tracer emulator (its Student-t error model in the likelihood), the published roughness and
tilt law as data, δ free (five parameters). Both samplers start from the same least-squares fit.

* emcee: `sample_posterior` with its stopping rule (≥ 50 τ_int, τ settled, ≥ `--min-ess` samples, split R-hat ≤ 1.01), 32 walkers.
* NUTS: `--chains` chains of BlackJAX's NUTS on `LogPosterior.jax_log_density` (unconstrained
  coordinates), each with Stan's window adaptation (`--warmup` steps) then `--draws` draws.

Both are judged by ArviZ on their draws (walkers or chains as chains; emcee's after its burn-in and thinning,
as its stopping rule judges them): the smallest bulk ESS and the
largest R-hat over the parameters, and wall time including compilation, so the figure of merit is
bulk ESS per second. The posteriors are compared by their 5/50/95 % quantiles.

Writes benchmarks/output/nuts_vs_emcee.json (atomic) and prints a Markdown table.
Needs the `bench` extra (`pip install -e '.[bench]'`, BlackJAX).

Run: python benchmarks/nuts_vs_emcee.py [--chains 4] [--warmup 500] [--draws 1000]
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from paintjax import atomic_write_json, fit_least_squares, load_sample, make_forward, sample_posterior  # noqa: E402
from paintjax.inverse import LogPosterior, MeasuredInputs, build_reading_model  # noqa: E402


def cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def diagnostics(draws: np.ndarray, names) -> dict:
    """Bulk ESS and R-hat per parameter (ArviZ) of draws (chains, draws, p)."""
    import arviz as az

    idata = az.from_dict(posterior={n: draws[..., i] for i, n in enumerate(names)})
    ess, rhat = az.ess(idata, method="bulk"), az.rhat(idata)
    q = {n: np.quantile(draws[..., i], [0.05, 0.5, 0.95]).tolist() for i, n in enumerate(names)}
    return {"ess_bulk": {n: float(ess[n]) for n in names}, "rhat": {n: float(rhat[n]) for n in names}, "quantiles": q,
            "ess_bulk_min": float(min(ess[n] for n in names)), "rhat_max": float(max(rhat[n] for n in names))}


def run_nuts(lp: LogPosterior, u0: np.ndarray, chains: int, warmup: int, draws: int, seed: int) -> np.ndarray:
    """NUTS chains (window adaptation, then draws) from u0; returns physical draws (chains, draws, p)."""
    import blackjax

    logdensity = lp.jax_log_density()

    @jax.jit
    def one_chain(key, u_start):
        k_warm, k_draw = jax.random.split(key)
        (state, params), _ = blackjax.window_adaptation(blackjax.nuts, logdensity).run(k_warm, u_start, num_steps=warmup)
        step = blackjax.nuts(logdensity, **params).step

        def body(s, k):
            s, _ = step(k, s)
            return s, s.position

        _, positions = jax.lax.scan(body, state, jax.random.split(k_draw, draws))
        return positions

    keys = jax.random.split(jax.random.PRNGKey(seed), chains)
    rng = np.random.default_rng(seed)
    U = np.stack([np.asarray(one_chain(k, u0 + 1e-2 * rng.standard_normal(u0.shape))) for k in keys])
    return np.asarray(lp.spec.from_unconstrained(U.reshape(-1, U.shape[-1]))).reshape(U.shape)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--chains", type=int, default=4)
    ap.add_argument("--warmup", type=int, default=500)
    ap.add_argument("--draws", type=int, default=1000)
    ap.add_argument("--walkers", type=int, default=32)
    ap.add_argument("--min-ess", type=float, default=1000.0)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    sample = load_sample("silver1")
    forward = make_forward("tracer-emulator-wide", ("shape", "scale", "sigma", "tau"), {})
    inputs = MeasuredInputs.for_sample(sample, build_reading_model(progress=False))
    free = ("shape", "scale", "sigma", "tau", "discrepancy")
    res = {"machine": f"{platform.machine()} {os.cpu_count()} cores, {platform.python_implementation()} {platform.python_version()}, "
                      f"JAX {jax.__version__} {jax.default_backend()}", "load_average_start": os.getloadavg(), "problem": "silver1, L* and inputs (rq), δ free"}
    fr = fit_least_squares(forward, sample.L_star, free=free[:-1], seed=a.seed)

    t, c = time.perf_counter(), cpu()
    post = sample_posterior(forward, sample.L_star, free=free, walkers=a.walkers, min_ess=a.min_ess, init=fr, inputs=inputs, seed=a.seed,
                            progress=False, inference_data=False)
    wall, cpu_s = time.perf_counter() - t, cpu() - c
    # (walkers, draws, p), physical units: the draws the package keeps and its stopping rule judges (after burn-in and
    # thinning); R-hat of the unthinned draws is reported too (`rhat_unthinned_max`)
    phys = post.chain[post.burn::post.thin].transpose(1, 0, 2)
    res["emcee"] = {"wall_s": wall, "cpu_s": cpu_s, "walkers": post.walkers, "steps": post.steps, "converged": post.converged,
                    "log_posterior_evaluations": post.walkers * post.steps, "burn": post.burn, "thin": post.thin,
                    "rhat_unthinned_max": diagnostics(post.chain[post.burn:].transpose(1, 0, 2), free)["rhat_max"]} | diagnostics(phys, free)
    print("emcee", {k: v for k, v in res["emcee"].items() if k != "quantiles"}, flush=True)

    lp = LogPosterior(forward, sample.L_star, free, inputs=inputs)
    x0 = np.array([fr.values[n] for n in free[:-1]] + [max(fr.values.get("discrepancy", 0.0), 0.5)])
    t, c = time.perf_counter(), cpu()
    draws = run_nuts(lp, np.asarray(lp.spec.to_unconstrained(x0)), a.chains, a.warmup, a.draws, a.seed)
    wall, cpu_s = time.perf_counter() - t, cpu() - c
    res["nuts"] = {"wall_s": wall, "cpu_s": cpu_s, "chains": a.chains, "warmup": a.warmup, "draws": a.draws} | diagnostics(draws, free)
    print("nuts", {k: v for k, v in res["nuts"].items() if k != "quantiles"}, flush=True)
    res["load_average_end"] = os.getloadavg()
    out = Path(__file__).parent / "output" / "nuts_vs_emcee.json"
    atomic_write_json(out, res)
    e, n = res["emcee"], res["nuts"]
    print("\n| sampler | wall (incl. compile) | bulk ESS min | R-hat max | bulk ESS / s |\n|---|---|---|---|---|")
    print(f"| emcee, {e['walkers']} walkers × {e['steps']} steps | {e['wall_s']:.0f} s | {e['ess_bulk_min']:.0f} | {e['rhat_max']:.3f} | "
          f"{e['ess_bulk_min'] / e['wall_s']:.1f} |")
    print(f"| NUTS, {n['chains']} chains × ({n['warmup']} warm-up + {n['draws']}) | {n['wall_s']:.0f} s | {n['ess_bulk_min']:.0f} | "
          f"{n['rhat_max']:.3f} | {n['ess_bulk_min'] / n['wall_s']:.1f} |")
    for name in free:
        print(f"  {name:>12}: emcee {np.round(e['quantiles'][name], 4).tolist()}  NUTS {np.round(n['quantiles'][name], 4).tolist()}")
    return res


if __name__ == "__main__":
    main()
