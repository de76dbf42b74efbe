"""A heavy-tailed, regional model of an emulator's own error, fitted to its out-of-sample errors.

An emulator misses the map it emulates by e = L*_emulator − L*_direct. Its cross-validated errors
(leave-one-out and held-out) are far from Gaussian: the tracer emulators' are Student-t with ν ≈ 2.4–4.2,
and about five times larger at the smoothest platelets than at the roughest. `EmulatorError` models
e_j(θ) at angle j as Student-t with ν degrees of freedom and a scale that varies log-linearly over the
box,

    c_j(θ) = c_j · exp(β · (z(θ) − ½)),      z = the unit-cube coordinate of θ in the emulator's box,

fitted by maximum likelihood (`fit_emulator_error`). The likelihood of a measured value adds Gaussian
terms (instrument repeatability, model discrepancy, run-to-run spread) to this error; the sum's density
is the Student-t's scale mixture of normals, p(r) = ∫ N(r; 0, v + c² w) IG(w; ν/2, ν/2) dw, integrated
on a fixed grid in log w (`residual_log_density`); with v = 0 it is the Student-t, with ν → ∞ the normal.

An emulator of a tracer run with common random numbers (one array, one ray stream) also misses what an
independent run gives (another array, other rays): `RunToRun` holds that miss's bias, linear over the box,
and its spread, normal with a log-linear scale, fitted to misses against independent runs (`fit_run_to_run`).
"""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import logsumexp
from jaxtyping import Array, Float

#: The log-w grid of the scale mixture: `MIXTURE_NODES` nodes across the mixing law's bulk (between its
#: `MIXTURE_TAIL` and 1 − `MIXTURE_TAIL` quantiles), then a tail grid out to the w that residuals of
#: `MIXTURE_MAX_SCALES` scales need, its step a sixth of the width of the integrand's peak there (√(2/(ν+1))
#: in log w), so that the density keeps its Student-t tail.
MIXTURE_NODES, MIXTURE_TAIL, MIXTURE_MAX_SCALES = 128, 1e-13, 1e4
#: Degrees of freedom the fit may choose: from Cauchy-like (1) to close to normal (100).
DF_RANGE = (1.0, 100.0)


def _mixture_grid(df: float) -> tuple[np.ndarray, np.ndarray]:
    """(log w nodes, log weights) of the inverse-gamma(ν/2, ν/2) mixing law: trapezoid weights on the
    grid in log w described at `MIXTURE_NODES`, normalised to one."""
    from scipy.stats import invgamma

    law = invgamma(df / 2.0, scale=df / 2.0)
    lo, hi = np.log(law.ppf(MIXTURE_TAIL)), np.log(law.isf(MIXTURE_TAIL))
    u = np.linspace(lo, hi, MIXTURE_NODES)
    top, step = np.log(10.0 * MIXTURE_MAX_SCALES**2 / (df + 1.0)), math.sqrt(2.0 / (df + 1.0)) / 6.0
    if hi < top:
        u = np.r_[u, np.arange(hi + step, top + step, step)]
    width = 0.5 * (np.r_[u[1:], u[-1]] - np.r_[u[0], u[:-1]])
    logw = law.logpdf(np.exp(u)) + u + np.log(width)  # the density of u = log w, times the trapezoid width
    return u, logw - np.logaddexp.reduce(logw)


def regional_scale(base: Float[Array, " m"], slope: Float[Array, " p"], z: Float[Array, "n p"]) -> Float[Array, "n m"]:
    """A per-angle scale that varies log-linearly over the box: base_j · exp(slope · (z − ½)) at unit-cube points z."""
    return jnp.asarray(base)[None, :] * jnp.exp((jnp.asarray(z) - 0.5) @ jnp.asarray(slope))[:, None]


class EmulatorError(eqx.Module):
    """Student-t error of an emulator with a scale that varies over its box (see the module docstring).

    Attributes:
        scale: (m,) Student-t scale c_j per output angle at the centre of the box [L*].
        slope: (p,) β, the change of log c per unit-cube coordinate of each parameter (shared by the angles).
        df: ν, the degrees of freedom (``inf``: normal).
        log_w, log_weight: the mixture grid (`_mixture_grid`), empty for ν = inf.
    """

    scale: Float[Array, " m"]
    slope: Float[Array, " p"]
    df: float = eqx.field(static=True)
    log_w: Float[Array, " k"]
    log_weight: Float[Array, " k"]

    def __init__(self, scale, slope, df: float):
        df = float(df)
        if not (df >= DF_RANGE[0]):
            raise ValueError(f"df must be >= {DF_RANGE[0]:g} (inf for a normal error), got {df!r}")
        self.scale, self.slope, self.df = jnp.asarray(scale, float), jnp.asarray(slope, float), df
        u, lw = (np.zeros(0), np.zeros(0)) if math.isinf(df) else _mixture_grid(df)
        self.log_w, self.log_weight = jnp.asarray(u), jnp.asarray(lw)

    def scale_at(self, z: Float[Array, "n p"]) -> Float[Array, "n m"]:
        """c_j at unit-cube points z."""
        return regional_scale(self.scale, self.slope, z)

    def select(self, rows) -> "EmulatorError":
        """The error model of some output angles (their rows, in that order)."""
        return EmulatorError(self.scale[np.asarray(rows)], self.slope, self.df)

    def residual_log_density(self, r: Float[Array, "n m"], var: Float[Array, "n m"], z: Float[Array, "n p"]) -> Float[Array, "n m"]:
        """log p(r) of r = Normal(0, var) + this error at unit-cube points z (elementwise)."""
        c2 = self.scale_at(z) ** 2
        if math.isinf(self.df):
            v = var + c2
            return -0.5 * (r**2 / v + jnp.log(2.0 * jnp.pi * v))
        v = var[..., None] + c2[..., None] * jnp.exp(self.log_w)
        terms = self.log_weight - 0.5 * (r[..., None] ** 2 / v + jnp.log(2.0 * jnp.pi * v))
        return logsumexp(terms, axis=-1)

    def sample(self, rng: np.random.Generator, var: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Draws of Normal(0, var) + this error at unit-cube points z (NumPy; var and z broadcast to (n, m))."""
        c = np.asarray(self.scale_at(jnp.asarray(z)))
        shape = np.broadcast_shapes(c.shape, np.shape(var))
        w = 1.0 if math.isinf(self.df) else self.df / rng.chisquare(self.df, size=shape)
        return rng.standard_normal(shape) * np.sqrt(var + c**2 * w)


def fit_emulator_error(z: np.ndarray, errors: np.ndarray) -> EmulatorError:
    """Maximum-likelihood `EmulatorError` of out-of-sample errors.

    Arguments:
        z: (n, p) unit-cube points where the errors were measured.
        errors: (n, m) emulator − direct at those points (leave-one-out and held-out).

    Returns:
        `EmulatorError` with per-angle scales, a shared log-linear slope over the box, and ν in `DF_RANGE`.
    """
    from scipy import optimize, stats

    z, e = np.asarray(z, float), np.asarray(errors, float)
    if z.ndim != 2 or e.ndim != 2 or z.shape[0] != e.shape[0] or z.shape[0] < 4 or not np.all(np.isfinite(e)):
        raise ValueError(f"z (n, p) and errors (n, m) must be finite with the same n >= 4, got {z.shape} and {e.shape}")
    n, m = e.shape
    p = z.shape[1]
    floor = 1e-9 * max(float(np.max(np.abs(e))), 1e-12)  # an exact emulator: scales at a tiny floor, not log 0
    zc = z - 0.5

    def unpack(q):
        df = DF_RANGE[0] + (DF_RANGE[1] - DF_RANGE[0]) / (1.0 + np.exp(-q[m + p]))
        return q[:m], q[m:m + p], df

    def nll(q):
        log_c, beta, df = unpack(q)
        s = np.exp(log_c[None, :] + (zc @ beta)[:, None]) + floor
        return -np.sum(stats.t.logpdf(e, df, scale=s))

    q0 = np.r_[np.log(np.median(np.abs(e), axis=0) + floor), np.zeros(p), 0.0]
    best = None
    for start in (q0, np.r_[q0[:m + p], -4.0], np.r_[q0[:m + p], 4.0]):  # ν from ≈ 50, ≈ 2.8 and ≈ 98
        res = optimize.minimize(nll, start, method="L-BFGS-B")
        if best is None or res.fun < best.fun:
            best = res
    log_c, beta, df = unpack(best.x)
    return EmulatorError(np.exp(log_c), beta, df)


#: Prior SD [L*] of each coefficient of a run-to-run bias (its value at the box centre, and its change across the
#: box per parameter): weak against 96 independent runs, it keeps a fit to a handful of runs from chasing noise.
BIAS_PRIOR_SD = 5.0


class RunToRun(eqx.Module):
    """What an emulator of a common-random-number (CRN) tracer misses against independent runs (fresh arrays and
    rays), beyond its cross-validated error law: a bias linear over the box and a normal spread whose scale varies
    log-linearly over the box (`fit_run_to_run`).

    Attributes:
        bias: (p + 1, m) per angle: the bias at the box centre, then its change per unit-cube coordinate [L*].
        bias_cov: (m, p + 1, p + 1) the bias coefficients' covariance (inverse Hessian of the fit).
        sd: (m,) the spread's scale at the box centre [L*]; slope: (p,) its log-linear change (shared by the angles).
    """

    bias: Float[Array, "q m"]
    bias_cov: Float[Array, "m q q"]
    sd: Float[Array, " m"]
    slope: Float[Array, " p"]

    @property
    def bias_se(self) -> Float[Array, "q m"]:
        """Standard errors of `bias` (its coefficients' marginal SDs), laid out as `bias`."""
        return jnp.sqrt(jnp.diagonal(self.bias_cov, axis1=1, axis2=2)).T

    def mean(self, z: Float[Array, "n p"]) -> Float[Array, "n m"]:
        """The bias (emulator of the CRN tracer − independent run) at unit-cube points z."""
        return _design(z) @ self.bias

    def variance(self, z: Float[Array, "n p"]) -> Float[Array, "n m"]:
        """The spread's variance plus the fitted bias's own variance at unit-cube points z."""
        x = _design(z)
        return regional_scale(self.sd, self.slope, z) ** 2 + jnp.einsum("nq,mqr,nr->nm", x, self.bias_cov, x)

    def select(self, rows) -> "RunToRun":
        """The terms of some output angles (their rows, in that order)."""
        rows = np.asarray(rows)
        return RunToRun(self.bias[:, rows], self.bias_cov[rows], self.sd[rows], self.slope)


def _design(z):
    z = jnp.asarray(z)
    return jnp.concatenate([jnp.ones(z.shape[:-1] + (1,)), z - 0.5], axis=-1)


def fit_run_to_run(error: EmulatorError, z: np.ndarray, residuals: np.ndarray) -> RunToRun:
    """Maximum a-posteriori `RunToRun` of an emulator's misses r (n, m) against independent runs at unit-cube
    points z (n, p): r = b(z) + e + ε, e ~ `error` (the emulator's cross-validated law against the CRN tracer it
    was trained on), b(z) = b₀ + B·(z − ½) the CRN tracer's bias against fresh runs (each coefficient with a normal
    prior of SD `BIAS_PRIOR_SD`), ε ~ Normal(0, s_j² exp(2γ·(z − ½))) the run-to-run spread (another array,
    other rays). The bias's covariance is the inverse Hessian at the optimum.
    """
    import jax
    from scipy import optimize

    z, r = np.asarray(z, float), np.asarray(residuals, float)
    if z.ndim != 2 or r.ndim != 2 or z.shape[0] != r.shape[0] or r.shape[1] != error.scale.shape[0] or not np.all(np.isfinite(r)):
        raise ValueError(f"z (n, p) and residuals (n, {error.scale.shape[0]}) must be finite with the same n, got {z.shape} and {r.shape}")
    m, p = r.shape[1], z.shape[1]
    zj, rj, x = jnp.asarray(z), jnp.asarray(r), _design(z)

    def unpack(q):
        return jnp.exp(q[:m]), q[m:m + p], q[m + p:].reshape(p + 1, m)

    @jax.jit
    def objective(q):
        sd, slope, bias = unpack(q)
        var = regional_scale(sd, slope, zj) ** 2
        return -jnp.sum(error.residual_log_density(rj - x @ bias, var, zj)) + 0.5 * jnp.sum((bias / BIAS_PRIOR_SD) ** 2)

    grad = jax.jit(jax.grad(objective))
    start = np.linalg.lstsq(np.asarray(x), r, rcond=None)[0]
    q0 = np.r_[np.log(np.std(r - np.asarray(x) @ start, axis=0) + 1e-9), np.zeros(p), start.ravel()]
    res = optimize.minimize(lambda q: float(objective(jnp.asarray(q))), q0, jac=lambda q: np.asarray(grad(jnp.asarray(q))), method="L-BFGS-B")
    sd, slope, bias = unpack(jnp.asarray(res.x))
    cov = np.linalg.pinv(np.asarray(jax.hessian(objective)(jnp.asarray(res.x))))[m + p:, m + p:]  # rows (k, j): k·m + j
    idx = np.arange(p + 1)[:, None] * m + np.arange(m)[None, :]
    bias_cov = np.stack([cov[np.ix_(idx[:, j], idx[:, j])] for j in range(m)])
    return RunToRun(bias, jnp.asarray(bias_cov), sd, slope)
