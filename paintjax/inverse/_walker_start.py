"""Where an emcee ensemble starts: the posterior's mode, and walkers spread over the posterior about it.

The stopping rule's R-hat compares walkers; it can only see an ensemble that has not explored the posterior if the
walkers start apart — over-dispersed with respect to the posterior (Gelman & Rubin 1992). Walkers started in a
small ball about one least-squares optimum agree with one another long before they have explored a flat ridge of
good fits, and their intervals then depend on where on the ridge the optimum happened to lie. The default start
(``start="dispersed"``) therefore draws the walkers from the posterior itself, approximately, by adaptive
importance sampling (population Monte Carlo, Cappé et al. 2004) with proposals twice as wide as the posterior
seen so far: a round from the prior, a round from a multivariate Student-t about the mode with the Laplace
approximation's covariance, then rounds from Student-t's about the weighted draws with their covariance. Walkers are picked without replacement in proportion to their importance weights (Gumbel top-k over the
deterministic-mixture weights of all rounds, Owen & Zhou 2000). ``start="ball"`` is the small ball about the mode.

Everything here works in the posterior's unconstrained coordinates u (`LogPosterior.spec`).
"""

from __future__ import annotations

import math

import jax
import numpy as np

from ._fit import FitResult, fit_least_squares

#: The walkers' starts: "dispersed" (over the posterior, by adaptive importance sampling) or "ball" (about the mode).
STARTS = ("dispersed", "ball")

#: Importance-sampling rounds (the first from the prior) and the draws per round (at least `DRAWS_PER_WALKER` per walker).
ROUNDS, MIN_DRAWS, DRAWS_PER_WALKER = 4, 512, 32

#: Proposal: Student-t with DF degrees of freedom, its scale WIDEN × the Laplace approximation's or the weighted draws'
#: standard deviation (over-dispersed).
DF, WIDEN = 4.0, 2.0

#: Laplace approximation: central differences of step HESSIAN_STEP; variances along its axes kept within
#: [MIN_VARIANCE, MAX_VARIANCE] (the upper bound ≈ the prior's own spread in unconstrained coordinates, used where the
#: posterior is flat or not concave).
HESSIAN_STEP, MIN_VARIANCE, MAX_VARIANCE = 1e-3, 1e-10, 4.0

#: Radius of the small ball (unconstrained coordinates).
BALL = 1e-2


def initial_walkers(lp, init, walkers: int, rng, seed: int, start: str = "dispersed") -> np.ndarray:
    """The walkers' starting points (walkers, p) in unconstrained coordinates.

    Arguments:
        lp: the `LogPosterior`.
        init: a user's values (a dict: a small ball about them, as given), or a `FitResult` or None: the maximum of
            this posterior is sought from that least-squares fit (one is made when None) and, when the published
            inputs are data, from their values too (`posterior_mode`); the walkers then start as `start` says.
        walkers: ensemble size.
        rng: NumPy generator of the draws.
        seed: seed of the least-squares fit made when `init` is None.
        start: "dispersed" (default) or "ball" (see the module).

    Returns:
        (walkers, p) points with finite log posterior.
    """
    if start not in STARTS:
        raise ValueError(f"start must be one of {', '.join(STARTS)}, got {start!r}")
    spec = lp.spec
    if init is None or isinstance(init, FitResult):
        fr = init if init is not None else fit_least_squares(
            lp.forward, np.where(lp.angles, lp.measured, 50.0), free=[n for n in spec.names], fixed=dict(lp.fixed), bounds=lp.bounds,
            instrument_sd=lp.sd, weights=lp.angles.astype(float), seed=seed)
        starts = [dict(fr.values)]
        if lp.inputs is not None:
            starts.append(dict(fr.values) | {k: v for k, v in lp.inputs.start_values().items() if k in spec.names})
        mode = posterior_mode(lp, [start_point(spec, v) for v in starts])
        return ball(lp, mode, walkers, rng) if start == "ball" else dispersed(lp, mode, walkers, rng)[0]
    values = dict(init)  # a user's dict: names and ranges checked, not silently mended
    unknown = sorted(set(values) - set(spec.names) - set(lp.fixed))
    if unknown:
        raise ValueError(f"init names {unknown} are not parameters of this posterior (free: {', '.join(spec.names)})")
    for prm in spec.parameters:
        if prm.name in values:
            v = float(values[prm.name])
            if not (math.isfinite(v) and prm.lower <= v <= prm.upper):
                raise ValueError(f"init value of {prm.name} must lie in [{prm.lower:g}, {prm.upper:g}] {prm.unit}".rstrip()
                                 + f", got {values[prm.name]!r}")
    return ball(lp, start_point(spec, values), walkers, rng)


def start_point(spec, values: dict) -> np.ndarray:
    """Unconstrained point of `values` (defaults for the missing; δ at least 0.5; a value on a bound nudged inside,
    where the transform maps it to ±inf)."""
    x = []
    for prm in spec.parameters:
        v = float(values.get(prm.name, prm.default))
        if prm.name == "discrepancy":
            v = max(v, 0.5)
        span = prm.upper - prm.lower
        x.append(float(np.clip(v, prm.lower + 1e-3 * span, prm.upper - 1e-3 * span)))
    return np.asarray(spec.to_unconstrained(np.array(x)), float)


def posterior_mode(lp, starts: list) -> np.ndarray:
    """The best of `starts` (unconstrained points) by log posterior, refined by Nelder–Mead on −log p
    (at most 200 evaluations per parameter), then brought back inside as `start_point` does."""
    from scipy.optimize import minimize

    U = np.stack(starts)
    values = np.where(np.isfinite(v := lp(U)), v, -np.inf)
    best = U[int(np.argmax(values))]

    def cost(u):
        v = float(lp(u[None, :])[0])
        return -v if np.isfinite(v) else np.inf

    res = minimize(cost, best, method="Nelder-Mead", options={"maxfev": 200 * len(best), "xatol": 1e-3, "fatol": 1e-3})
    u = res.x if np.isfinite(res.fun) and res.fun <= -np.max(values) else best
    spec = lp.spec
    return start_point(spec, dict(zip(spec.names, np.asarray(spec.from_unconstrained(u), float))))


def ball(lp, u0: np.ndarray, walkers: int, rng) -> np.ndarray:
    """`walkers` points in a small ball about u0 with finite log posterior (a point without one is put at u0)."""
    U = u0[None, :] + BALL * rng.standard_normal((walkers, u0.size))
    bad = ~np.isfinite(lp(U))
    if bad.any():
        U[bad] = u0
    return U


def _t_logpdf(U: np.ndarray, loc: np.ndarray, chol: np.ndarray) -> np.ndarray:
    """Log density of the multivariate Student-t (DF, location `loc`, scale matrix chol cholᵀ) at the rows of U."""
    p = loc.size
    z = np.linalg.solve(chol, (U - loc).T).T
    m = np.sum(z * z, axis=1)
    return (math.lgamma(0.5 * (DF + p)) - math.lgamma(0.5 * DF) - 0.5 * p * math.log(DF * math.pi)
            - np.sum(np.log(np.diag(chol))) - 0.5 * (DF + p) * np.log1p(m / DF))


def _t_draws(rng, loc: np.ndarray, chol: np.ndarray, n: int) -> np.ndarray:
    g = rng.chisquare(DF, size=(n, 1)) / DF
    return loc + (rng.standard_normal((n, loc.size)) @ chol.T) / np.sqrt(g)


def laplace_covariance(lp, mode: np.ndarray) -> np.ndarray:
    """Inverse of the negative Hessian of the log posterior at `mode` (central differences, one batched call), its
    variances kept within [MIN_VARIANCE, MAX_VARIANCE] along its eigenvectors."""
    p, h = mode.size, HESSIAN_STEP
    E = np.eye(p) * h
    pts = [mode]
    for i in range(p):
        pts += [mode + E[i], mode - E[i]]
        for j in range(i + 1, p):
            pts += [mode + E[i] + E[j], mode + E[i] - E[j], mode - E[i] + E[j], mode - E[i] - E[j]]
    f = np.asarray(lp(np.stack(pts)), float)
    H, k = np.zeros((p, p)), 1
    for i in range(p):
        H[i, i] = (f[k] - 2 * f[0] + f[k + 1]) / h**2
        k += 2
        for j in range(i + 1, p):
            H[i, j] = H[j, i] = (f[k] - f[k + 1] - f[k + 2] + f[k + 3]) / (4 * h**2)
            k += 4
    lam, vec = np.linalg.eigh(-np.where(np.isfinite(H), H, 0.0))
    var = np.where(lam > 0, 1.0 / np.where(lam > 0, lam, 1.0), MAX_VARIANCE)
    return (vec * np.clip(var, MIN_VARIANCE, MAX_VARIANCE)) @ vec.T


def _weighted_covariance(U: np.ndarray, logw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    w = np.exp(logw - np.max(logw))
    w /= w.sum()
    mean = w @ U
    d = U - mean
    return mean, (d * w[:, None]).T @ d


def dispersed(lp, mode: np.ndarray, walkers: int, rng) -> tuple[np.ndarray, dict]:
    """Walkers drawn approximately from the posterior by adaptive importance sampling (see the module).

    Arguments:
        lp: the `LogPosterior`; mode: its maximum (unconstrained); walkers: how many; rng: NumPy generator.

    Returns:
        ((walkers, p) distinct points with finite log posterior, diagnostics: the draws, and the importance
        sampling's effective sample size over all rounds).
    """
    spec = lp.spec
    n = max(MIN_DRAWS, DRAWS_PER_WALKER * walkers)
    key = jax.random.key(int(rng.integers(2**31)))
    draws = [np.asarray(spec.to_unconstrained(spec.sample_prior(key, n)), float)]
    proposals = [None]  # None: the prior
    laplace = laplace_covariance(lp, mode)
    for r in range(ROUNDS):
        U = np.concatenate(draws)
        logp = np.asarray(lp(U), float)
        logq = np.stack([np.asarray(spec.log_prior_unconstrained(U), float) if q is None else _t_logpdf(U, *q) for q in proposals])
        logq = np.logaddexp.reduce(logq, axis=0) - math.log(len(proposals))  # deterministic mixture of the rounds
        logw = np.where(np.isfinite(logp) & np.isfinite(logq), logp - logq, -np.inf)
        if r == ROUNDS - 1:
            break
        # round 1 about the mode (Laplace), later rounds about the weighted draws (a small share of the Laplace
        # covariance keeps the scale positive definite when a few draws carry the weight)
        centre, cov = (mode, laplace) if r == 0 else _weighted_covariance(U, logw)
        chol = np.linalg.cholesky(WIDEN**2 * (cov + 1e-3 * laplace))
        proposals.append((centre, chol))
        draws.append(_t_draws(rng, centre, chol, n))
    ok = np.isfinite(logw)
    if ok.sum() < walkers:
        raise RuntimeError(f"only {int(ok.sum())} of {U.shape[0]} importance draws have a finite log posterior; "
                           f"{walkers} walkers need as many (start='ball' starts about the mode instead)")
    w = np.exp(logw - np.max(logw))
    ess = float(w.sum() ** 2 / np.sum(w**2))
    pick = np.argsort(-(logw + rng.gumbel(size=logw.size)))[:walkers]  # Gumbel top-k: weighted, without replacement
    return U[pick], {"draws": int(U.shape[0]), "importance_ess": ess}
