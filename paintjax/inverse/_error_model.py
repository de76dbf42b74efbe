"""A heavy-tailed, regional, correlated model of an emulator's own error, fitted to its out-of-sample errors.

An emulator misses the map it emulates by e = L*_emulator − L*_direct, one value per output angle. Its
cross-validated errors (leave-one-out and held-out) are far from Gaussian: the tracer emulators' are
Student-t with ν ≈ 2.4–4.2, about five times larger at the smoothest platelets than at the roughest, and
large at all angles of the same θ together. `EmulatorError` models the vector e(θ) as a multivariate
Student-t: one mixing variable w per θ, shared by the angles,

    e | w ~ Normal(0, w · D R D),   w ~ InverseGamma(ν/2, ν/2),   D = diag(c_j(θ)),
    c_j(θ) = c_j · exp(β · (z(θ) − ½)),      z = the unit-cube coordinate of θ in the emulator's box,

with a correlation matrix R between the angles, fitted by maximum a-posteriori (`fit_emulator_error`; an
LKJ prior of shape `CORRELATION_PRIOR_ETA` on R). Each angle's marginal is the Student-t of scale c_j. The
likelihood of a measured curve adds Gaussian terms (instrument repeatability, model discrepancy,
run-to-run spread: a diagonal V) to this error; the sum's density is the scale mixture
p(r) = ∫ N(r; 0, V + w D R D) IG(w; ν/2, ν/2) dw, integrated on a fixed grid in log w
(`residual_log_density`), with one eigendecomposition per θ: with B = V^-½ D R D V^-½ = Q Λ Qᵀ,
log N = −½ Σ_i [log(1 + w λ_i) + y_i² / (1 + w λ_i)] − ½ log det(2π V), y = Qᵀ V^-½ r. With V = 0 it is
the multivariate Student-t, with ν → ∞ the normal. Angles left out of a measurement are marginalised
(their rows and columns dropped), so the density is that of the angles measured.

An emulator of a tracer run with common random numbers (one array, one ray stream) also misses what an
independent run gives (another array, other rays): `RunToRun` holds that miss's bias, linear over the box,
its spread, normal with a log-linear scale, and the correlation between the angles and the degrees of freedom
of the whole miss, fitted to misses against independent runs (`fit_run_to_run`; ν chosen by cross-validation,
so that the law holds runs it was not fitted to).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import logsumexp
from jaxtyping import Array, Bool, Float

#: The log-w grid of the scale mixture: `MIXTURE_NODES` nodes across the mixing law's bulk (between its
#: `MIXTURE_TAIL` and 1 − `MIXTURE_TAIL` quantiles), then a tail grid out to the w that residuals of
#: `MIXTURE_MAX_SCALES` scales at every angle need, its step a sixth of the width of the integrand's peak there
#: (√(2/(ν+m)) in log w for m angles), so that the density keeps its Student-t tail.
MIXTURE_NODES, MIXTURE_TAIL, MIXTURE_MAX_SCALES = 128, 1e-13, 1e4
#: Degrees of freedom the fit may choose: from Cauchy-like (1) to close to normal (100).
DF_RANGE = (1.0, 100.0)
#: Shape η of the LKJ prior p(R) ∝ det(R)^(η−1) on the correlation between the angles: η = 2 keeps a fit to a
#: handful of points away from singular R and is weak against a hundred.
CORRELATION_PRIOR_ETA = 2.0
#: Normal variances below this fraction of c_j² are raised to it (a relative change of the scale of 10⁻¹⁰), so that
#: V^-½ exists where no normal term is added.
VAR_FLOOR = 1e-10


def _mixture_grid(df: float, m: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """(log w nodes, log weights) of the inverse-gamma(ν/2, ν/2) mixing law for m angles: trapezoid weights on
    the grid in log w described at `MIXTURE_NODES`, normalised to one."""
    from scipy.stats import invgamma

    law = invgamma(df / 2.0, scale=df / 2.0)
    lo, hi = np.log(law.ppf(MIXTURE_TAIL)), np.log(law.isf(MIXTURE_TAIL))
    u = np.linspace(lo, hi, MIXTURE_NODES)
    top, step = np.log(10.0 * m * MIXTURE_MAX_SCALES**2 / (df + m)), math.sqrt(2.0 / (df + m)) / 6.0
    if hi < top:
        u = np.r_[u, np.arange(hi + step, top + step, step)]
    width = 0.5 * (np.r_[u[1:], u[-1]] - np.r_[u[0], u[:-1]])
    logw = law.logpdf(np.exp(u)) + u + np.log(width)  # the density of u = log w, times the trapezoid width
    return u, logw - np.logaddexp.reduce(logw)


def regional_scale(base: Float[Array, " m"], slope: Float[Array, " p"], z: Float[Array, "n p"]) -> Float[Array, "n m"]:
    """A per-angle scale that varies log-linearly over the box: base_j · exp(slope · (z − ½)) at unit-cube points z."""
    return jnp.asarray(base)[None, :] * jnp.exp((jnp.asarray(z) - 0.5) @ jnp.asarray(slope))[:, None]


def correlation_from_unconstrained(q, m: int):
    """A correlation matrix (m, m) from m(m−1)/2 free numbers: the strict lower triangle of a unit-diagonal L,
    R = the correlation of L Lᵀ (any q gives a valid R; q = 0 gives the identity)."""
    L = jnp.eye(m).at[jnp.tril_indices(m, -1)].set(q)
    S = L @ L.T
    d = jnp.sqrt(jnp.diagonal(S))
    return S / d[:, None] / d[None, :]


def _lkj_log_prior(R) -> Float[Array, ""]:
    return (CORRELATION_PRIOR_ETA - 1.0) * jnp.linalg.slogdet(R)[1]


class EmulatorError(eqx.Module):
    """Multivariate Student-t error of an emulator with a scale that varies over its box (module docstring).

    Attributes:
        scale: (m,) Student-t scale c_j per output angle at the centre of the box [L*].
        slope: (p,) β, the change of log c per unit-cube coordinate of each parameter (shared by the angles).
        correlation: (m, m) R, the correlation between the angles' errors.
        df: ν, the degrees of freedom (``inf``: normal).
        log_w, log_weight: the mixture grid (`_mixture_grid`), empty for ν = inf.
    """

    scale: Float[Array, " m"]
    slope: Float[Array, " p"]
    correlation: Float[Array, "m m"]
    df: float = eqx.field(static=True)
    log_w: Float[Array, " k"]
    log_weight: Float[Array, " k"]

    def __init__(self, scale, slope, df: float, correlation=None):
        df = float(df)
        if not (df >= DF_RANGE[0]):
            raise ValueError(f"df must be >= {DF_RANGE[0]:g} (inf for a normal error), got {df!r}")
        self.scale, self.slope, self.df = jnp.atleast_1d(jnp.asarray(scale, float)), jnp.asarray(slope, float), df
        m = self.scale.shape[0]
        if correlation is None:
            correlation = np.eye(m)
        self.correlation = jnp.asarray(correlation, float)
        if self.correlation.shape != (m, m):
            raise ValueError(f"correlation must be ({m}, {m}) for {m} angles, got {self.correlation.shape}")
        u, lw = (np.zeros(0), np.zeros(0)) if math.isinf(df) else _mixture_grid(df, m)
        self.log_w, self.log_weight = jnp.asarray(u), jnp.asarray(lw)

    def scale_at(self, z: Float[Array, "n p"]) -> Float[Array, "n m"]:
        """c_j at unit-cube points z."""
        return regional_scale(self.scale, self.slope, z)

    def select(self, rows) -> "EmulatorError":
        """The error model of some output angles (their rows, in that order)."""
        rows = np.asarray(rows)
        return EmulatorError(self.scale[rows], self.slope, self.df, self.correlation[np.ix_(rows, rows)])

    def with_df(self, df: float) -> "EmulatorError":
        """This law with another ν (not traceable: a new ν needs a new mixture grid)."""
        return EmulatorError(self.scale, self.slope, df, self.correlation)

    def with_correlation(self, correlation) -> "EmulatorError":
        """This law with another correlation between the angles (traceable: the mixture grid is kept)."""
        return eqx.tree_at(lambda e: e.correlation, self, jnp.asarray(correlation, float))

    @eqx.filter_jit
    def residual_log_density(self, r: Float[Array, "n m"], var: Float[Array, "n m"], z: Float[Array, "n p"],
                             have: Bool[Array, "n m"] | None = None) -> Float[Array, " n"]:
        """log p(r) of the vector r = Normal(0, diag(var)) + this error at unit-cube points z, over the angles in
        `have` (broadcast to r; default all), the others marginalised. One eigendecomposition per row."""
        c = self.scale_at(z)
        r = jnp.asarray(r)
        shape = jnp.broadcast_shapes(r.shape, jnp.shape(var), c.shape)
        r, c = jnp.broadcast_to(r, shape), jnp.broadcast_to(c, shape)
        h = jnp.ones(shape, bool) if have is None else jnp.broadcast_to(jnp.asarray(have, bool), shape)
        m = shape[-1]
        v = jnp.where(h, jnp.maximum(jnp.broadcast_to(jnp.asarray(var, float), shape), VAR_FLOOR * c**2), 1.0)
        a = jnp.where(h, c / jnp.sqrt(v), 0.0)
        # angles left out: distinct negative placeholders on the diagonal keep the eigenvalues apart (and eigh's
        # derivative finite); their y is 0 and their λ < 0 marks them out of the sums
        ghost = jnp.where(h, 0.0, -(1.0 + jnp.arange(m, dtype=v.dtype)))
        B = a[..., :, None] * self.correlation * a[..., None, :] + ghost[..., :, None] * jnp.eye(m)
        lam, Q = jnp.linalg.eigh(B)
        y = jnp.einsum("...ji,...j->...i", Q, jnp.where(h, r, 0.0) / jnp.sqrt(v))
        seen = lam >= 0.0
        lam = jnp.where(seen, lam, 0.0)
        const = -0.5 * jnp.sum(jnp.where(h, jnp.log(2.0 * jnp.pi * v), 0.0), axis=-1)
        if math.isinf(self.df):
            return const - 0.5 * jnp.sum(jnp.where(seen, jnp.log1p(lam) + y**2 / (1.0 + lam), 0.0), axis=-1)
        t = 1.0 + lam[..., None] * jnp.exp(self.log_w)
        terms = self.log_weight - 0.5 * jnp.sum(jnp.where(seen[..., None], jnp.log(t) + y[..., None] ** 2 / t, 0.0), axis=-2)
        return const + logsumexp(terms, axis=-1)

    def sample(self, rng: np.random.Generator, var: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Draws of Normal(0, diag(var)) + this error at unit-cube points z, one row per point (NumPy; var and z
        broadcast to (n, m)): one mixing variable per row, correlated normals across the angles."""
        c = np.asarray(self.scale_at(jnp.asarray(z)))
        shape = np.broadcast_shapes(c.shape, np.shape(var))
        w = np.ones(shape[:-1] + (1,)) if math.isinf(self.df) else self.df / rng.chisquare(self.df, size=shape[:-1] + (1,))
        chol = np.linalg.cholesky(np.asarray(self.correlation, float))
        e = rng.standard_normal(shape) @ chol.T
        return e * c * np.sqrt(w) + rng.standard_normal(shape) * np.sqrt(np.broadcast_to(var, shape))


def fit_emulator_error(z: np.ndarray, errors: np.ndarray) -> EmulatorError:
    """Maximum a-posteriori `EmulatorError` of out-of-sample errors (flat priors on the scales, the slope and ν;
    the LKJ prior on the correlation).

    Arguments:
        z: (n, p) unit-cube points where the errors were measured.
        errors: (n, m) emulator − direct at those points (leave-one-out and held-out).

    Returns:
        `EmulatorError` with per-angle scales, a shared log-linear slope over the box, ν in `DF_RANGE` and the
        correlation between the angles.
    """
    from jax.scipy.special import gammaln
    from scipy import optimize

    z, e = np.asarray(z, float), np.asarray(errors, float)
    if z.ndim != 2 or e.ndim != 2 or z.shape[0] != e.shape[0] or z.shape[0] < 4 or not np.all(np.isfinite(e)):
        raise ValueError(f"z (n, p) and errors (n, m) must be finite with the same n >= 4, got {z.shape} and {e.shape}")
    n, m = e.shape
    p = z.shape[1]
    floor = 1e-9 * max(float(np.max(np.abs(e))), 1e-12)  # an exact emulator: scales at a tiny floor, not log 0
    zc, ej = jnp.asarray(z - 0.5), jnp.asarray(e)

    def unpack(q):
        df = DF_RANGE[0] + (DF_RANGE[1] - DF_RANGE[0]) * jax.nn.sigmoid(q[m + p])
        return q[:m], q[m:m + p], df, correlation_from_unconstrained(q[m + p + 1:], m)

    @jax.jit
    def objective(q):
        log_c, beta, df, R = unpack(q)
        s = jnp.exp(log_c[None, :] + (zc @ beta)[:, None]) + floor
        u = ej / s
        quad = jnp.sum(u * jnp.linalg.solve(R, u.T).T, axis=1)
        logdet = jnp.linalg.slogdet(R)[1]
        ll = (gammaln((df + m) / 2) - gammaln(df / 2) - 0.5 * m * jnp.log(df * jnp.pi) - 0.5 * logdet
              - jnp.sum(jnp.log(s), axis=1) - 0.5 * (df + m) * jnp.log1p(quad / df))
        return -jnp.sum(ll) - _lkj_log_prior(R)

    grad = jax.jit(jax.grad(objective))
    q0 = np.r_[np.log(np.median(np.abs(e), axis=0) + floor), np.zeros(p), 0.0, np.zeros(m * (m - 1) // 2)]
    best = None
    for g in (0.0, -4.0, 4.0):  # ν from ≈ 50, ≈ 2.8 and ≈ 98
        start = q0.copy()
        start[m + p] = g
        res = optimize.minimize(lambda q: float(objective(jnp.asarray(q))), start, jac=lambda q: np.asarray(grad(jnp.asarray(q))),
                                method="L-BFGS-B")
        if best is None or res.fun < best.fun:
            best = res
    log_c, beta, df, R = unpack(jnp.asarray(best.x))
    return EmulatorError(np.exp(np.asarray(log_c)), np.asarray(beta), float(df), np.asarray(R))


#: Prior SD [L*] of each coefficient of a run-to-run bias (its value at the box centre, and its change across the
#: box per parameter): weak against 96 independent runs, it keeps a fit to a handful of runs from chasing noise.
BIAS_PRIOR_SD = 5.0
#: The degrees of freedom `fit_run_to_run` chooses among for the law against independent runs, by cross-validated
#: (`RUN_TO_RUN_FOLDS`-fold) log predictive density of the held-out misses: the cross-validated law's ν is fitted to
#: the GP's misses of its own CRN runs, and a miss against an independent run (another array, other rays) can have a
#: heavier tail.
RUN_TO_RUN_DF_GRID, RUN_TO_RUN_FOLDS = (1.5, 2.0, 2.5, 3.0, 4.0, 6.0, 10.0), 5


class RunToRun(eqx.Module):
    """What an emulator of a common-random-number (CRN) tracer misses against independent runs (fresh arrays and
    rays), beyond its cross-validated error law: a bias linear over the box, a normal spread whose scale varies
    log-linearly over the box, and the correlation between the angles and the degrees of freedom of the error law's
    part of the miss (`fit_run_to_run`).

    Attributes:
        bias: (q, m) per angle: the bias at the box centre, then its change per unit-cube coordinate, then for each
            axis of `curved` its coefficients of (z_k − ½)² and (z_k − ½)³ [L*] (q = 1 + p + 2·len(curved)).
        bias_cov: (m, q, q) the bias coefficients' covariance (inverse Hessian of the fit).
        sd: (m,) the spread's scale at the box centre [L*]; slope: (p,) its log-linear change (shared by the angles).
        correlation: (m, m) the correlation between the angles of the error law's part of the miss against an
            independent run (it replaces the cross-validated law's, `law`).
        df: () ν of the error law's part of the miss against an independent run (it replaces the cross-validated
            law's, `law`).
        df_grid, df_score: (k,) the ν tried and each one's cross-validated log predictive density of the misses
            (empty when ν was given).
        curved: the unit-cube axes whose bias bends (square and cube terms; static, () for a linear bias).
    """

    bias: Float[Array, "q m"]
    bias_cov: Float[Array, "m q q"]
    sd: Float[Array, " m"]
    slope: Float[Array, " p"]
    correlation: Float[Array, "m m"]
    df: Float[Array, ""]
    df_grid: Float[Array, " k"]
    df_score: Float[Array, " k"]
    curved: tuple[int, ...] = eqx.field(static=True, default=())

    @property
    def bias_se(self) -> Float[Array, "q m"]:
        """Standard errors of `bias` (its coefficients' marginal SDs), laid out as `bias`."""
        return jnp.sqrt(jnp.diagonal(self.bias_cov, axis1=1, axis2=2)).T

    def law(self, error: EmulatorError) -> EmulatorError:
        """The cross-validated error law `error` with the correlation and ν fitted against independent runs (not
        traceable: a new ν needs a new mixture grid)."""
        return error.with_df(float(self.df)).with_correlation(self.correlation)

    def mean(self, z: Float[Array, "n p"]) -> Float[Array, "n m"]:
        """The bias (emulator of the CRN tracer − independent run) at unit-cube points z."""
        return _design(z, self.curved) @ self.bias

    def variance(self, z: Float[Array, "n p"]) -> Float[Array, "n m"]:
        """The spread's variance plus the fitted bias's own variance at unit-cube points z."""
        x = _design(z, self.curved)
        return regional_scale(self.sd, self.slope, z) ** 2 + jnp.einsum("nq,mqr,nr->nm", x, self.bias_cov, x)

    def select(self, rows) -> "RunToRun":
        """The terms of some output angles (their rows, in that order)."""
        rows = np.asarray(rows)
        return RunToRun(self.bias[:, rows], self.bias_cov[rows], self.sd[rows], self.slope, self.correlation[np.ix_(rows, rows)],
                        self.df, self.df_grid, self.df_score, self.curved)


def _design(z, curved: tuple[int, ...] = ()):
    """The bias's regressors at unit-cube points z (n, p): 1, z − ½, then (z_k − ½)² and (z_k − ½)³ per axis k of `curved`."""
    u = jnp.asarray(z) - 0.5
    bent = [u[..., k:k + 1] ** e for k in curved for e in (2, 3)]
    return jnp.concatenate([jnp.ones(u.shape[:-1] + (1,)), u, *bent], axis=-1)


def _unpack_run_to_run(q, m: int, p: int, curved: tuple[int, ...]):
    w = 1 + p + 2 * len(curved)
    nb = w * m
    return (jnp.exp(q[:m]), q[m:m + p], q[m + p:m + p + nb].reshape(w, m), correlation_from_unconstrained(q[m + p + nb:], m))


def _run_to_run_row_log_density(q, law: EmulatorError, z, r, curved: tuple[int, ...]):
    """log p of each miss r (n, m) at unit-cube points z (n, p) under the run-to-run terms packed in q and `law`."""
    m, p = r.shape[1], z.shape[1]
    sd, slope, bias, R = _unpack_run_to_run(q, m, p, curved)
    have = jnp.isfinite(r)  # an angle a run lacks (NaN) is marginalised
    miss = jnp.where(have, r, 0.0) - _design(z, curved) @ bias
    return law.with_correlation(R).residual_log_density(miss, regional_scale(sd, slope, z) ** 2, z, have)


def _run_to_run_loss(q, law: EmulatorError, weight, z, r, curved: tuple[int, ...]):
    """The negative log posterior of the run-to-run terms packed in q given the misses with weight 1 (0: held out)."""
    m, p = r.shape[1], z.shape[1]
    _, _, bias, R = _unpack_run_to_run(q, m, p, curved)
    ll = _run_to_run_row_log_density(q, law, z, r, curved)
    return -jnp.sum(weight * ll) + 0.5 * jnp.sum((bias / BIAS_PRIOR_SD) ** 2) - _lkj_log_prior(R)


_loss_and_grad = eqx.filter_jit(eqx.filter_value_and_grad(_run_to_run_loss))
_row_log_density = eqx.filter_jit(_run_to_run_row_log_density)
_loss_hessian = eqx.filter_jit(jax.hessian(_run_to_run_loss))


def _fit_run_to_run_terms(law: EmulatorError, z, r, weight, curved: tuple[int, ...]) -> np.ndarray:
    """The MAP of the run-to-run terms (packed) under `law` from the misses with weight 1."""
    from scipy import optimize

    m, p = r.shape[1], z.shape[1]
    x, wt, rn = np.asarray(_design(z, curved)), np.asarray(weight, float), np.asarray(r)
    use = np.isfinite(rn) & (wt[:, None] > 0)  # per angle, the runs that have it and are not held out
    # (an angle no training run has, possible in a fold of a few runs with gaps: no bias, unit spread to start from)
    start = np.stack([np.linalg.lstsq(x[use[:, j]], rn[use[:, j], j], rcond=None)[0] if use[:, j].any() else np.zeros(x.shape[1])
                      for j in range(m)], axis=1)
    spread = [np.std(rn[use[:, j], j] - x[use[:, j]] @ start[:, j]) if use[:, j].any() else 1.0 for j in range(m)]
    q0 = np.r_[np.log(np.asarray(spread) + 1e-9), np.zeros(p), start.ravel(), np.zeros(m * (m - 1) // 2)]
    wj = jnp.asarray(wt)

    def fun(q):
        v, g = _loss_and_grad(jnp.asarray(q), law, wj, z, r, curved)
        return float(v), np.asarray(g)

    return optimize.minimize(fun, q0, jac=True, method="L-BFGS-B").x


def _cross_validated_df(error: EmulatorError, z, r, grid: np.ndarray, folds: int, seed: int, curved: tuple[int, ...]) -> np.ndarray:
    """Each ν of `grid`'s summed log density of the held-out misses, over `folds` random folds (`seed`), under the
    terms fitted to the other folds."""
    fold = np.random.default_rng(seed).permutation(r.shape[0]) % folds
    score = np.zeros(grid.size)
    for i, nu in enumerate(grid):
        law = error.with_df(nu)
        for k in range(folds):
            q = _fit_run_to_run_terms(law, z, r, fold != k, curved)
            score[i] += float(jnp.sum(_row_log_density(jnp.asarray(q), law, z[fold == k], r[fold == k], curved)))
    return score


def fit_run_to_run(error: EmulatorError, z: np.ndarray, residuals: np.ndarray, df: float | None = None,
                   df_grid=RUN_TO_RUN_DF_GRID, folds: int = RUN_TO_RUN_FOLDS, seed: int = 0, curved: Sequence[int] = ()) -> RunToRun:
    """Maximum a-posteriori `RunToRun` of an emulator's misses r (n, m) against independent runs at unit-cube
    points z (n, p): r = b(z) + e + ε, e ~ `error` (the emulator's cross-validated law against the CRN tracer it
    was trained on) with its correlation between the angles refitted and its ν chosen anew, b(z) = b₀ + B·(z − ½)
    (+ c_k (z_k − ½)² + d_k (z_k − ½)³ for each axis k of `curved`) the CRN tracer's bias against fresh runs (each
    coefficient with a normal prior of SD `BIAS_PRIOR_SD`),
    ε ~ Normal(0, s_j² exp(2γ·(z − ½))) the run-to-run spread (another array, other rays), the correlation with the
    LKJ prior of `fit_emulator_error`. The bias's covariance is the inverse Hessian at the optimum.

    Arguments:
        error: the emulator's cross-validated `EmulatorError`.
        z, residuals: the unit-cube points (n, p) of the independent runs and the emulator's misses there (n, m;
            NaN where a run lacks an angle: that angle is marginalised out of its row's density).
        df: ν of the law against the runs; default: the one of `df_grid` whose terms, fitted to all folds but one,
            give the held-out fold's misses the highest log density, summed over `folds` random folds (`seed`;
            leave-one-out when there are fewer misses than folds; with one miss, `error`'s own ν).
        curved: the unit-cube axes along which the bias bends (square and cube terms); default none (linear).

    Returns:
        `RunToRun` with the fitted terms, ν, and each tried ν's cross-validated log predictive density.
    """
    z, r = np.asarray(z, float), np.asarray(residuals, float)
    if z.ndim != 2 or r.ndim != 2 or z.shape[0] != r.shape[0] or r.shape[1] != error.scale.shape[0] or not np.all(np.isfinite(z)):
        raise ValueError(f"z (n, p) finite and residuals (n, {error.scale.shape[0]}) with the same n, got {z.shape} and {r.shape}")
    n, m, p = r.shape[0], r.shape[1], z.shape[1]
    curved = tuple(int(k) for k in curved)
    if len(set(curved)) != len(curved) or not all(0 <= k < p for k in curved):
        raise ValueError(f"curved must name distinct unit-cube axes in [0, {p - 1}], got {curved}")
    have = np.isfinite(r)
    if np.any(np.isinf(r)) or not np.all(have.any(axis=1)) or not np.all(have.any(axis=0)):
        raise ValueError("residuals: NaN marks an angle a run lacks; every run needs a finite angle and every angle a finite "
                         "miss, and none may be infinite")
    zj, rj = jnp.asarray(z), jnp.asarray(r)
    grid, score = np.zeros(0), np.zeros(0)
    if df is None:
        grid = np.asarray(df_grid, float)
        if grid.ndim != 1 or grid.size < 1 or not np.all(grid >= DF_RANGE[0]):
            raise ValueError(f"df_grid must be a non-empty sequence of ν >= {DF_RANGE[0]:g}, got {df_grid!r}")
        if not folds >= 2:
            raise ValueError(f"folds must be >= 2, got {folds}")
        if n >= 2:
            score = _cross_validated_df(error, zj, rj, grid, min(int(folds), n), seed, curved)
            df = float(grid[np.argmax(score)])
        else:  # one miss: nothing to hold out
            df, grid = error.df, np.zeros(0)
    elif not df >= DF_RANGE[0]:
        raise ValueError(f"df must be >= {DF_RANGE[0]:g} (inf for a normal law), got {df!r}")
    law = error.with_df(df)
    ones = jnp.ones(n)
    q = jnp.asarray(_fit_run_to_run_terms(law, zj, rj, ones, curved))
    sd, slope, bias, R = _unpack_run_to_run(q, m, p, curved)
    w = bias.shape[0]
    nb = w * m
    hess = _loss_hessian(q, law, ones, zj, rj, curved)
    cov = np.linalg.pinv(np.asarray(hess))[m + p:m + p + nb, m + p:m + p + nb]  # rows (k, j): k·m + j
    idx = np.arange(w)[:, None] * m + np.arange(m)[None, :]
    bias_cov = np.stack([cov[np.ix_(idx[:, j], idx[:, j])] for j in range(m)])
    return RunToRun(bias, jnp.asarray(bias_cov), sd, slope, R, jnp.asarray(float(df)), jnp.asarray(grid), jnp.asarray(score), curved)
