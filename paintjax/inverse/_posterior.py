"""Bayesian posterior of microstructure parameters given five-angle L* (emcee, ArviZ).

Model: L*_meas,j = L*_model,j(θ) + ε_j + e_j, ε_j ~ Normal(0, σ_instr² + δ²), with σ_instr the
instrument repeatability (0.3 L*), δ the model-discrepancy scale (a free parameter with a
half-Cauchy(5 L*) prior, or fixed) and e_j the forward model's own error, whose law the model states
(`ForwardModel.residual_log_density`): none for the analytic model; for an emulator a multivariate Student-t
over the angles whose scale varies over its box, fitted to its cross-validated errors (`EmulatorError`), plus,
for the tracer emulators, the run-to-run spread as a normal term and the angles' correlation against independent runs. Priors: the weak priors of
`paintjax.inverse._parameters` (log-uniform for tilt shape/scale and roughness σ/τ over their boxes,
uniform for bounded fractions, half-Cauchy for δ) — none centred on the measured values. The
published inputs can enter as data instead (`inputs=`, a `MeasuredInputs`: their likelihood given the
true parameters through models of the measurements that produced them).

Sampling is in the unconstrained coordinates u (the prior carries the log-Jacobian) with
`emcee.EnsembleSampler(vectorize=True)`: the whole ensemble is one batched, compiled forward
call. The walkers start over-dispersed about the posterior's maximum, drawn by adaptive importance
sampling (`paintjax.inverse._walker_start`), so that the R-hat rule compares walkers that started apart. With `pool=` the ensemble is split into one chunk per pool worker and mapped with
`pool.map` (an MPI or multiprocessing pool; each worker compiles its own forward). Chains are
stored in an HDF5 backend so an interrupted run resumes where it stopped; the run stops when
the chain is longer than `n_tau` (≥ 50) integrated autocorrelation times, the τ estimate has
settled (relative change < 5 %), the effective sample size reaches `min_ess` (both emcee's
walkers × steps / τ and ArviZ's bulk ESS of every parameter) and ArviZ's rank-normalised split
R-hat of every parameter is at most `max_rhat` (1.01; walkers taken as chains, after burn-in and
thinning) — or at `max_steps`, reported as not converged. Results: `PosteriorResult` with ArviZ InferenceData
(NetCDF, written atomically) and a corner plot.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from ._chain import MAX_RHAT, MAX_STEPS, burn_thin, chain_diagnostics, check_chain, check_walkers, write_meta
from ._fit import INSTRUMENT_SD, FitResult, _problem, batched_forward
from ._forward import ForwardModel
from ._observations import check_angles, check_instrument_sd, check_measured
from ._walker_start import STARTS, initial_walkers


@dataclasses.dataclass
class PosteriorResult:
    """Outcome of `sample_posterior` (physical units throughout).

    Attributes:
        names: sampled parameter names (plus the derived ``mean_tilt`` = shape × scale in
            `summary` when both are sampled).
        samples: (n, p) draws after burn-in and thinning.
        chain: (steps, walkers, p) full chain.
        mean, q05, q50, q95, tau_int: per-name summaries (τ in steps).
        n_eff: effective sample size, walkers × (steps − burn) / max τ.
        rhat, ess_bulk: per-name ArviZ rank-normalised split R-hat and bulk ESS of the kept draws
            (walkers as chains).
        steps, burn, thin, walkers: run geometry; converged: the stopping rule was met.
        acceptance: mean acceptance fraction; seconds: wall time of this call.
        L_star_mean, L_star_q05, L_star_q95: posterior predictive band of the model curve.
        idata: arviz.InferenceData; backend_path: HDF5 file (or None).
        at_edge: {name: "lower" or "upper"} for parameters whose posterior piles against that edge of
            the prior box (more than `EDGE_MASS` of the draws in the outer `EDGE_BAND` of the box, where a
            flat likelihood puts `EDGE_BAND`): the box, not the data, bounds them there.
    """

    names: tuple[str, ...]
    samples: np.ndarray
    chain: np.ndarray
    mean: dict
    q05: dict
    q50: dict
    q95: dict
    tau_int: dict
    n_eff: float
    rhat: dict
    ess_bulk: dict
    steps: int
    burn: int
    thin: int
    walkers: int
    converged: bool
    acceptance: float
    seconds: float
    L_star_mean: np.ndarray
    L_star_q05: np.ndarray
    L_star_q95: np.ndarray
    measured: np.ndarray
    idata: object = None
    backend_path: str | None = None
    at_edge: dict = dataclasses.field(default_factory=dict)

    def interval(self, name: str, level: float = 0.9) -> tuple[float, float]:
        """Equal-tailed credible interval of a parameter (or ``mean_tilt``)."""
        x = self.draws(name)
        a = 0.5 * (1.0 - level)
        return float(np.quantile(x, a)), float(np.quantile(x, 1.0 - a))

    def draws(self, name: str) -> np.ndarray:
        if name == "mean_tilt":
            return self.draws("shape") * self.draws("scale")
        if name not in self.names:
            raise ValueError(f"unknown parameter {name!r}; sampled: {', '.join(self.names)}")
        return self.samples[:, self.names.index(name)]

    def to_dict(self) -> dict:
        return {
            "mean": dict(self.mean),
            "q05": dict(self.q05),
            "q50": dict(self.q50),
            "q95": dict(self.q95),
            "tau_int": dict(self.tau_int),
            "n_eff": self.n_eff,
            "rhat": dict(self.rhat),
            "ess_bulk": dict(self.ess_bulk),
            "steps": self.steps,
            "burn": self.burn,
            "thin": self.thin,
            "walkers": self.walkers,
            "converged": self.converged,
            "acceptance": self.acceptance,
            "L_star_mean": self.L_star_mean.tolist(),
            "L_star_q05": self.L_star_q05.tolist(),
            "L_star_q95": self.L_star_q95.tolist(),
            "seconds": self.seconds,
            "at_edge": dict(self.at_edge),
        }

    def summary(self) -> str:
        lines = [f"posterior: {self.walkers} walkers × {self.steps} steps (burn {self.burn}, thin {self.thin}); "
                 f"n_eff ≈ {self.n_eff:.0f}; R-hat ≤ {max(self.rhat.values(), default=float('nan')):.3f}; "
                 f"bulk ESS ≥ {min(self.ess_bulk.values(), default=float('nan')):.0f}; {'converged' if self.converged else 'NOT converged'}; acceptance {self.acceptance:.2f}"]
        for n in self.mean:
            lines.append(f"  {n:>12}: mean {self.mean[n]:.4g}, 90% [{self.q05[n]:.4g}, {self.q95[n]:.4g}], τ_int {self.tau_int.get(n, float('nan')):.0f}")
        for n, side in self.at_edge.items():
            lines.append(f"  WARNING: the posterior of {n} piles against the {side} edge of its prior box: the box, not the data, "
                         "bounds it there (widen the box if the physics allows)")
        return "\n".join(lines)


#: emcee proposals (`sample_posterior`'s `moves`).
MOVES = ("stretch", "de")

#: A parameter piles against an edge when more than EDGE_MASS of its draws lie in the outer EDGE_BAND
#: of its box (in the prior's unit coordinate; a flat likelihood puts EDGE_BAND there).
EDGE_BAND, EDGE_MASS = 0.02, 0.10


def edges(spec, samples: np.ndarray) -> dict:
    """{name: "lower" | "upper"} of the parameters (not ``discrepancy``) whose draws pile against an edge of the box."""
    z = np.asarray(spec.to_unit(np.asarray(samples)))
    out = {}
    for i, name in enumerate(spec.names):
        if name == "discrepancy":
            continue
        for side, frac in (("lower", np.mean(z[:, i] < EDGE_BAND)), ("upper", np.mean(z[:, i] > 1 - EDGE_BAND))):
            if frac > EDGE_MASS:
                out[name] = side
    return out


class LogPosterior:
    """Vectorised log posterior in unconstrained coordinates: U (W, p) → (W,) (NumPy in/out).

    Picklable (the compiled functions are rebuilt lazily in each process), so it can be mapped
    over a pool.

    Arguments:
        forward, measured, free, fixed, bounds, instrument_sd, inputs, angles: as in `sample_posterior`.
    """

    def __init__(self, forward: ForwardModel, measured, free, fixed=None, bounds=None, instrument_sd: float = INSTRUMENT_SD, chunk: int = 16,
                 inputs=None, angles=None):
        self.forward = forward
        self.inputs = inputs
        self.chunk = int(chunk)
        m = len(forward.aspecular_deg)
        self.angles = check_angles(angles, m)
        self.measured = check_measured(measured, m, angles=self.angles)
        check_instrument_sd(instrument_sd, m)
        sd = np.asarray(instrument_sd, dtype=float)
        self.instrument_sd = float(sd) if sd.ndim == 0 else sd.tolist()
        self.sd = np.broadcast_to(sd, (m,)).copy()
        self.fixed = dict(fixed or {})
        self.bounds = dict(bounds or {})
        self.spec, self.sub, self.restricted = _problem(forward, free, self.fixed, self.bounds)
        if "discrepancy" in self.fixed:
            d = float(self.fixed["discrepancy"])
            if not (0.0 <= d <= 1e3):
                raise ValueError(f"fixed discrepancy must lie in [0, 1000] L*, got {d!r}")
        self._fns = None

    @property
    def names(self) -> tuple[str, ...]:
        return self.spec.names

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_fns"] = None
        return state

    def _build(self):
        spec, sub = self.spec, self.sub
        cols = np.array([spec.index(n) for n in sub.names])
        d_col = spec.index("discrepancy") if "discrepancy" in spec.names else -1
        d_fixed = float(self.fixed.get("discrepancy", 0.0))
        y, have = jnp.asarray(np.where(self.angles, self.measured, 0.0)), jnp.asarray(self.angles)
        var0 = jnp.asarray(self.sd**2)
        inputs, fixed_inputs = self.inputs, dict(self.restricted.fixed)
        forward, restricted = self.forward, self.restricted

        @jax.jit
        def rest(U, L):
            x = spec.from_unconstrained(U)
            delta = x[:, d_col] if d_col >= 0 else jnp.full(U.shape[0], d_fixed)
            var = var0[None, :] + delta[:, None] ** 2
            ll = forward.residual_log_density(y - L, var, restricted.full(x[:, cols]), have)
            lp = ll + spec.log_prior_unconstrained(U)
            if inputs is not None:  # the published inputs as data (`MeasuredInputs`)
                params = {n: jnp.full(U.shape[0], float(v)) for n, v in fixed_inputs.items()}
                params |= {n: x[:, spec.index(n)] for n in spec.names}
                lp = lp + inputs.log_likelihood(params)
            return jnp.where(jnp.isfinite(lp), lp, -jnp.inf)

        fwd = batched_forward(self.restricted, sub, self.chunk)
        self._fns = (cols, fwd, rest)

    def model_lightness(self, U) -> np.ndarray:
        """L* of the forward model at unconstrained points U (W, p)."""
        if self._fns is None:
            self._build()
        cols, fwd, _ = self._fns
        U = np.atleast_2d(np.asarray(U, dtype=float))
        return fwd(U[:, cols])

    def jax_log_density(self):
        """This log posterior as a JAX function of one unconstrained point, u (p,) → scalar: jit-able and
        differentiable, for gradient-based samplers (NUTS). Needs a jit-able forward model (the analytic
        model, an emulator)."""
        if not self.forward.jittable:
            raise ValueError(f"the forward model {self.forward.fingerprint()[:60]}… is not jit-able: a gradient-based sampler "
                             "needs the analytic model or an emulator")
        if self._fns is None:
            self._build()
        cols, _, rest = self._fns
        spec, restricted = self.spec, self.restricted

        def log_density(u):
            U = jnp.asarray(u)[None, :]
            return rest(U, restricted.evaluate(spec.from_unconstrained(U)[:, cols]))[0]

        return log_density

    def description(self, walkers: int) -> str:
        """What a stored chain must have been sampled for to be resumed: data, model, parameters,
        priors, inputs and walkers (JSON; `check_chain`)."""
        angles = {} if self.angles.all() else {"angles": self.angles.tolist()}  # (absent for all angles: older chains resume)
        return json.dumps(angles | {"names": self.names, "measured": self.measured.tolist(), "forward": self.forward.fingerprint(),
                           "fixed": self.restricted.fixed, "fixed_discrepancy": self.fixed.get("discrepancy"),
                           "bounds": self.spec.fingerprint(), "instrument_sd": self.instrument_sd, "walkers": int(walkers),
                           "inputs": None if self.inputs is None else self.inputs.fingerprint()}, sort_keys=True)

    def __call__(self, U) -> np.ndarray:
        if self._fns is None:
            self._build()
        cols, fwd, rest = self._fns
        U = np.atleast_2d(np.asarray(U, dtype=float))
        L = fwd(U[:, cols])
        return np.asarray(rest(jnp.asarray(U), jnp.asarray(L)), dtype=float)


class _PooledLogPosterior:
    """Split a batch into one chunk per pool worker and map the log posterior over them."""

    def __init__(self, log_posterior: LogPosterior, pool, n_chunks: int):
        self.log_posterior, self.pool, self.n_chunks = log_posterior, pool, max(1, int(n_chunks))

    def __call__(self, U):
        parts = [p for p in np.array_split(np.asarray(U), self.n_chunks) if len(p)]
        return np.concatenate(list(self.pool.map(self.log_posterior, parts)))


def _pool_size(pool) -> int:
    for attr in ("_processes", "size", "_max_workers"):
        v = getattr(pool, attr, None)
        if isinstance(v, int) and v > 0:
            return v
    return 2


def sample_posterior(
    forward: ForwardModel,
    measured,
    *,
    free: Sequence[str] | None = None,
    fixed: Mapping[str, float] | None = None,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    instrument_sd: float = INSTRUMENT_SD,
    walkers: int = 32,
    max_steps: int = MAX_STEPS,
    min_steps: int = 500,
    check_every: int = 250,
    n_tau: float = 50.0,
    min_ess: float = 1000.0,
    max_rhat: float = MAX_RHAT,
    init: FitResult | Mapping[str, float] | None = None,
    seed: int = 0,
    backend_path: str | os.PathLike | None = None,
    resume: bool = True,
    overwrite: bool = False,
    progress: bool = True,
    pool=None,
    inference_data: bool = True,
    inputs=None,
    angles=None,
    start: str = "dispersed",
    moves: str = "stretch",
) -> PosteriorResult:
    """Sample the posterior of the free parameters with emcee (vectorised, resumable).

    Arguments:
        forward: a `ForwardModel` (analytic, emulator; the tracer through an emulator).
        measured: L* per angle.
        free: sampled parameters (default: the forward's inputs except ``diffuse``, plus
            ``discrepancy``).
        fixed: values of the other forward inputs; ``discrepancy`` may be fixed too (e.g. 0).
        bounds: `{name: (lower, upper)}` overrides of the registered bounds.
        instrument_sd: instrument repeatability [L*]: one number, or one per angle.
        angles: which angles hold data (m booleans; default all): the others are left out of the
            likelihood and may be NaN in `measured`.
        walkers: ensemble size (≥ 2·p, even).
        max_steps, min_steps, check_every: chain-length limits and convergence-check period.
        n_tau: required chain length in integrated autocorrelation times (≥ 50 by default).
        min_ess: required effective sample size (emcee's from τ, and ArviZ's bulk ESS of every parameter).
        max_rhat: largest ArviZ split R-hat of any parameter, walkers as chains (≥ 1; inf: no R-hat rule).
        init: where to start the walkers: values (a small ball about them, as given), or a `FitResult` from which
            the maximum of this posterior is sought (with the published inputs' values as a second start); default:
            a least-squares fit, refined likewise.
        start: with `init` a fit or None, "dispersed" (walkers drawn over the posterior about its maximum by
            adaptive importance sampling: over-dispersed starts, which the R-hat rule needs) or "ball" (a small
            ball about the maximum); see `paintjax.inverse._walker_start`.
        moves: emcee proposal: "stretch" (affine-invariant stretch move) or "de" (differential evolution 80 %,
            its snooker variant 20 %).
        seed: seed of the initial ball and of emcee's generator.
        backend_path: HDF5 file for the chain (None: in memory, no resume).
        resume: continue the chain found in `backend_path` when it was sampled for the same data,
            model, parameters, priors and walkers (`check_chain`).
        overwrite: replace a stored chain that cannot be resumed (default: refuse, ValueError).
        progress: tqdm progress bar.
        pool: optional pool with a `map` method (multiprocessing, MPI); the ensemble is split
            over its workers.
        inference_data: build the ArviZ InferenceData (`idata`; skip for speed in bulk studies).
        inputs: the published inputs as data (`MeasuredInputs`): their log-likelihood given the sampled
            parameters is added to the posterior (None: the inputs enter only through the prior box).

    Returns:
        A `PosteriorResult`.
    """
    import emcee

    t0 = time.perf_counter()
    if free is None:
        free = tuple(n for n in forward.parameter_names if n not in (fixed or {}) and n != "diffuse")
        if "discrepancy" not in (fixed or {}):
            free = free + ("discrepancy",)
    walkers = int(walkers)
    from ._fit import CHUNK

    # Same chunk as least squares (one compiled forward) unless half an ensemble is larger.
    lp = LogPosterior(forward, measured, free, fixed, bounds, instrument_sd, chunk=max(CHUNK, walkers // 2), inputs=inputs, angles=angles)
    p = len(lp.names)
    check_walkers(walkers, p)
    if n_tau < 1 or min_steps < 1 or max_steps < min_steps or check_every < 1:
        raise ValueError(f"need n_tau >= 1, 1 <= min_steps <= max_steps, check_every >= 1; got {n_tau}, {min_steps}, {max_steps}, {check_every}")
    if not max_rhat >= 1.0:
        raise ValueError(f"max_rhat must be >= 1 (inf: no R-hat rule), got {max_rhat!r}")
    if start not in STARTS:
        raise ValueError(f"start must be one of {', '.join(STARTS)}, got {start!r}")
    if moves not in MOVES:
        raise ValueError(f"moves must be one of {', '.join(MOVES)}, got {moves!r}")
    fn = lp if pool is None else _PooledLogPosterior(lp, pool, _pool_size(pool))

    backend = None
    meta = lp.description(walkers)
    state = None
    if backend_path is not None:
        backend_path = Path(backend_path)
        resumed = check_chain(backend_path, meta, resume=resume, overwrite=overwrite)
        backend_path.parent.mkdir(parents=True, exist_ok=True)
        backend = emcee.backends.HDFBackend(str(backend_path))
        if not resumed:
            backend.reset(walkers, p)
            write_meta(backend_path, meta)
    proposal = None if moves == "stretch" else [(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)]
    sampler = emcee.EnsembleSampler(walkers, p, fn, vectorize=True, backend=backend, moves=proposal)
    if backend is None or backend.iteration == 0:
        rng = np.random.default_rng(seed)
        u_start = initial_walkers(lp, init, walkers, rng, seed, start)
        sampler.random_state = np.random.RandomState(seed).get_state()
        state = u_start

    converged, old_tau = False, None
    while sampler.iteration < max_steps:
        n = min(check_every, max_steps - sampler.iteration)
        try:
            sampler.run_mcmc(state, n, progress=progress, skip_initial_state_check=True)
        except KeyboardInterrupt:
            kept = ("the chain is not stored (no backend_path)" if backend_path is None else
                    f"the chain in {str(backend_path)!r} is kept: rerun the same command to resume")
            raise KeyboardInterrupt(f"interrupted after {sampler.iteration} steps; {kept}") from None
        state = None
        it = sampler.iteration
        tau = sampler.get_autocorr_time(tol=0)
        ess = walkers * max(it - int(2 * np.max(tau)), 0) / np.max(tau)
        settled = old_tau is not None and np.all(np.abs(old_tau - tau) < 0.05 * tau)
        old_tau = tau
        if it >= min_steps and np.all(n_tau * tau < it) and settled and ess >= min_ess:
            burn, thin = burn_thin(tau, it)
            rhat, ess_bulk = chain_diagnostics(np.asarray(lp.spec.from_unconstrained(sampler.get_chain()[burn::thin])))
            if np.max(rhat) <= max_rhat and np.min(ess_bulk) >= min_ess:
                converged = True
                break
    return _result(sampler, lp, converged, t0, backend_path, inference_data)


def _result(sampler, lp: LogPosterior, converged: bool, t0: float, backend_path, inference_data: bool) -> PosteriorResult:
    import arviz as az

    spec = lp.spec
    it = sampler.iteration
    tau = sampler.get_autocorr_time(tol=0)
    tmax = float(np.max(tau)) if np.all(np.isfinite(tau)) else float(it)
    burn, thin = burn_thin(tau, it)
    chain_u = sampler.get_chain()
    chain = np.asarray(spec.from_unconstrained(chain_u))
    flat_u = sampler.get_chain(discard=burn, thin=thin, flat=True)
    flat = np.asarray(spec.from_unconstrained(flat_u))
    names = spec.names
    draws = {n: flat[:, i] for i, n in enumerate(names)}
    if "shape" in names and "scale" in names:
        draws["mean_tilt"] = draws["shape"] * draws["scale"]
    q = {k: np.quantile(v, [0.05, 0.5, 0.95]) for k, v in draws.items()}
    # Posterior predictive band of the model curve (≤ 400 draws).
    pick = np.linspace(0, flat_u.shape[0] - 1, min(400, flat_u.shape[0])).astype(int)
    Lm = lp.model_lightness(flat_u[pick])
    kept = chain[burn::thin]
    posterior = {n: np.swapaxes(kept[:, :, i], 0, 1) for i, n in enumerate(names)}
    if "mean_tilt" in draws:
        posterior["mean_tilt"] = posterior["shape"] * posterior["scale"]
    lps = np.swapaxes(sampler.get_log_prob()[burn::thin], 0, 1)
    idata = None if not inference_data else az.from_dict(
        posterior=posterior,
        sample_stats={"lp": lps},
        observed_data={"L_star": lp.measured},
        constant_data={"aspecular_deg": np.asarray(lp.forward.aspecular_deg, dtype=float)},
        attrs={"forward": lp.forward.fingerprint(), "instrument_sd": lp.instrument_sd,
               "fixed": json.dumps(lp.restricted.fixed), "tau_int": json.dumps(dict(zip(names, map(float, tau)))),
               "converged": int(converged), "note": "walkers are stored as ArviZ chains (emcee ensemble)"},
    )
    n_eff = float(sampler.nwalkers * max(it - burn, 0) / tmax) if tmax > 0 else 0.0
    rhat, ess_bulk = chain_diagnostics(kept)
    return PosteriorResult(
        names=names,
        samples=flat,
        chain=chain,
        mean={k: float(np.mean(v)) for k, v in draws.items()},
        q05={k: float(v[0]) for k, v in q.items()},
        q50={k: float(v[1]) for k, v in q.items()},
        q95={k: float(v[2]) for k, v in q.items()},
        tau_int={n: float(t) for n, t in zip(names, tau)},
        n_eff=n_eff,
        rhat=dict(zip(names, map(float, rhat))),
        ess_bulk=dict(zip(names, map(float, ess_bulk))),
        steps=int(it),
        burn=burn,
        thin=thin,
        walkers=int(sampler.nwalkers),
        converged=bool(converged),
        acceptance=float(np.mean(sampler.acceptance_fraction)),
        seconds=time.perf_counter() - t0,
        L_star_mean=Lm.mean(0),
        L_star_q05=np.quantile(Lm, 0.05, axis=0),
        L_star_q95=np.quantile(Lm, 0.95, axis=0),
        measured=lp.measured,
        idata=idata,
        backend_path=None if backend_path is None else str(backend_path),
        at_edge=edges(spec, flat),
    )
