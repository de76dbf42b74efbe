"""Least-squares fits of microstructure parameters to five-angle L* (Optimistix Levenberg–Marquardt).

Residuals are standardised, r_j = w_j (L*_model,j − L*_meas,j) / s_j with s_j² = σ_instr² +
error_sd_j² (instrument repeatability, 0.3 L* by default, plus the forward model's own error, e.g. an
emulator's held-out RMS), and minimised over the unconstrained coordinates u of the free
parameters (`ParameterSpec`). Several starts (scrambled Sobol points of the prior box, plus an
optional user start) run as one vmapped solve with ``throw=False``; failed or non-finite starts
are recorded, and the lowest χ² over all starts wins: a start that stopped at the step limit while
still going downhill is continued from where it stopped (`continuations`), not discarded.

Covariance: J = ∂r/∂x at the optimum in *physical* units (chain rule through the bijection),
C = s² (JᵀJ)⁺ with s² = max(1, χ²/(n − p)) when n > p and s² = 1 otherwise (the Birge-ratio
inflation: if the residuals exceed the stated noise, the noise is scaled up, never down).
Parameters the data do not identify (fewer weighted angles than free parameters, or a flat
direction: the numerical null space of the column-normalised J) get infinite variance and a
RuntimeWarning, not the pseudo-inverse's zero. A `discrepancy` parameter is not fitted by least
squares (it is a variance): when freed it is estimated afterwards over the weighted angles as
δ̂² = max(0, Σ(L*_model − L*_meas)²/max(n − p, 1) − σ_instr² − mean e²), e the forward model's own
error (an emulator's `error_sd`; 0 for the analytic model), as the posterior's likelihood adds them.

Known inputs (`priors`, e.g. a measured σ with its uncertainty) add one residual each, (x − v)/u in
physical units, after the angles: the fit is then the maximum a posteriori estimate under those
Gaussian terms, they count as data in the degrees of freedom, and the Jacobian carries their rows.
"""

from __future__ import annotations

import dataclasses
import threading
import time
import warnings
from collections.abc import Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .._optx import result_message
from .._validate import SEED, Range, check_args
from ._forward import ForwardModel, Restricted, _jit_evaluate
from ._observations import check_instrument_sd, check_measured, prior_arrays
from ._parameters import ParameterSpec, make_spec, unit_to_value

INSTRUMENT_SD = 0.3
#: |u| beyond which a parameter counts as at the edge of its box (unit-cube coordinate within 1e-4 of 0 or 1).
_U_EDGE = float(np.log(1e4 - 1.0))


@dataclasses.dataclass
class FitResult:
    """Outcome of `fit_least_squares`.

    Attributes:
        names: free parameter names.
        values, stderr: best-fit values and standard errors per name (physical units).
        covariance: covariance of the forward-model parameters (not `discrepancy`) in physical units, in the
            order of `names` without it (scaling in the module docstring; inf where not identified).
        L_star_fit, L_star_measured: model and measured L* per angle.
        residuals: L_star_fit − L_star_measured (L* units).
        standardized_residuals: the least-squares residual vector at the optimum (the angles, then one
            per known input of `priors`, in the order of `names`).
        chi2, dof, scale2: χ², n − p and the covariance inflation s².
        success: whether the best start converged; status: Optimistix result message.
        n_starts, n_converged: starts tried and converged; starts: per-start (values, χ², status).
        at_bound: free parameters whose optimum lies on the edge of their box.
        fixed: values of the fixed forward parameters; discrepancy: δ̂ (if freed) or None.
        seconds: wall time including compilation.
    """

    names: tuple[str, ...]
    values: dict
    stderr: dict
    covariance: np.ndarray
    L_star_fit: np.ndarray
    L_star_measured: np.ndarray
    residuals: np.ndarray
    standardized_residuals: np.ndarray
    chi2: float
    dof: int
    scale2: float
    success: bool
    status: str
    n_starts: int
    n_converged: int
    starts: list
    fixed: dict
    discrepancy: float | None
    seconds: float
    aspecular_deg: np.ndarray = dataclasses.field(default_factory=lambda: np.asarray([]))
    at_bound: list = dataclasses.field(default_factory=list)

    @property
    def x(self) -> np.ndarray:
        return np.array([self.values[n] for n in self.names])

    def to_dict(self) -> dict:
        return {
            "params": dict(self.values),
            "stderr": dict(self.stderr),
            "fixed": dict(self.fixed),
            "L_star_fit": self.L_star_fit.tolist(),
            "L_star_measured": self.L_star_measured.tolist(),
            "residuals": self.residuals.tolist(),
            "chi2": self.chi2,
            "dof": self.dof,
            "covariance_scale": self.scale2,
            "success": self.success,
            "status": self.status,
            "n_starts": self.n_starts,
            "n_converged": self.n_converged,
            "discrepancy": self.discrepancy,
            "at_bound": list(self.at_bound),
            "p_value": self.p_value,
            "verdict": self.fit_verdict(),
            "seconds": self.seconds,
        }

    def summary(self) -> str:
        lines = [f"least squares: {'converged' if self.success else 'NOT converged'} ({self.status}); "
                 f"{self.n_converged}/{self.n_starts} starts converged; χ² = {self.chi2:.3g} for {self.dof} dof"]
        for n in self.names:
            flag = "   (at bound: stderr from the local Jacobian only)" if n in self.at_bound else ""
            lines.append(f"  {n:>12} = {self.values[n]:.4g} ± {self.stderr[n]:.2g}{flag}")
        if self.discrepancy is not None:
            lines.append(f"  {'discrepancy':>12} ≈ {self.discrepancy:.3g} L* (moment estimate)")
        lines.append("  " + self.fit_verdict())
        return "\n".join(lines)

    @property
    def p_value(self) -> float | None:
        """P(χ² ≥ observed) for the fit's degrees of freedom under the stated noise; None without dof."""
        from scipy.stats import chi2 as chi2_dist

        return float(chi2_dist.sf(self.chi2, self.dof)) if self.dof > 0 else None

    def fit_verdict(self) -> str:
        """One plain sentence on whether the model fits the data and what the standard errors mean."""
        if self.dof <= 0:
            return (f"{self.dof} degrees of freedom: as many free parameters as weighted angles, so the fit can follow any data and "
                    "its χ² cannot test the model; the standard errors are not inflated (fix parameters, or use the posterior)")
        p = self.p_value
        if p < 0.01:
            return (f"the model does NOT fit these data within their stated noise (χ² = {self.chi2:.3g} for {self.dof} dof, p = {p:.2g}); "
                    f"the standard errors are inflated by √(χ²/dof) = {np.sqrt(self.scale2):.3g}, which assumes the misfit is noise")
        return f"the fit is consistent with the stated noise (χ² = {self.chi2:.3g} for {self.dof} dof, p = {p:.2g})"


def _problem(forward: ForwardModel, free, fixed, bounds):
    if free is not None:
        stray = sorted(set(bounds or {}) - set(free))
        if stray:
            raise ValueError(f"bounds given for parameters that are not free: {stray}")
    if hasattr(forward, "spec"):  # emulator: default to its training box
        bounds = {p.name: (p.lower, p.upper) for p in forward.spec.parameters} | dict(bounds or {})
    free = tuple(free) if free is not None else tuple(n for n in forward.parameter_names if n not in (fixed or {}) and n != "diffuse")
    spec_free = [n for n in free if n != "discrepancy"]
    spec = make_spec(free, {k: v for k, v in (bounds or {}).items() if k in free}) if free else None
    if spec is None:
        raise ValueError("free must name at least one parameter")
    sub = make_spec(spec_free, {k: v for k, v in (bounds or {}).items() if k in spec_free}) if spec_free else None
    if sub is None:
        raise ValueError("free must include at least one forward-model parameter (not only discrepancy)")
    fixed = {k: v for k, v in dict(fixed or {}).items()}
    restricted = Restricted(forward, tuple(spec_free), {k: v for k, v in fixed.items() if k != "discrepancy"})
    if hasattr(forward, "spec"):  # emulator: stay inside its training box
        for p in sub.parameters:
            q = forward.spec.parameters[forward.spec.index(p.name)]
            if p.lower < q.lower - 1e-12 or p.upper > q.upper + 1e-12:
                raise ValueError(f"bounds of {p.name} [{p.lower:g}, {p.upper:g}] exceed the emulator's training box [{q.lower:g}, {q.upper:g}]")
        for name, v in restricted.fixed.items():  # the emulator would clip them into its box without a word
            if name in forward.spec.names:
                q = forward.spec.parameters[forward.spec.index(name)]
                if not (q.lower - 1e-12 <= v <= q.upper + 1e-12):
                    raise ValueError(f"fixed value of {name} must lie in the emulator's training box [{q.lower:g}, {q.upper:g}], got {v!r}")
    return spec, sub, restricted


def _unidentified(Jx: np.ndarray, rtol: float = 1e-9) -> np.ndarray:
    """Parameters with a component in the numerical null space of the (column-normalised) Jacobian."""
    col = np.linalg.norm(Jx, axis=0)
    if not np.all(np.isfinite(Jx)):
        return np.ones(Jx.shape[1], bool)
    Jn = Jx / np.where(col > 0, col, 1.0)
    _, sv, vt = np.linalg.svd(Jn, full_matrices=True)
    rank = int(np.sum(sv > rtol * max(float(sv.max(initial=0.0)), 1e-300)))
    return (np.linalg.norm(vt[rank:], axis=0) > 1e-6) | (col == 0)


#: Most least-squares starts of one fit (each is a compiled solve; the default is 8).
MAX_STARTS = 1024
#: Most Levenberg–Marquardt steps per round of one start (the compiled solve counts them in 32-bit integers; a fit
#: that needs more is not converging).
MAX_LM_STEPS = 1_000_000
#: The ranges of `fit_least_squares`' integer settings, checked before any work.
FIT_RANGES = {"n_starts": Range(1, MAX_STARTS, integer=True), "max_steps": Range(1, MAX_LM_STEPS, integer=True),
              "continuations": Range(0, None, integer=True), "seed": SEED}


def fit_least_squares(
    forward: ForwardModel,
    measured,
    *,
    free: Sequence[str] | None = None,
    fixed: Mapping[str, float] | None = None,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    instrument_sd: float = INSTRUMENT_SD,
    weights=None,
    n_starts: int = 8,
    x0: Mapping[str, float] | None = None,
    seed: int = 0,
    max_steps: int = 200,
    continuations: int = 3,
    rtol: float = 1e-6,
    atol: float = 1e-6,
    jacobian: str = "fd",
    priors: Mapping[str, tuple[float, float]] | None = None,
) -> FitResult:
    """Levenberg–Marquardt fit of the free parameters to measured L*, multi-start.

    Arguments:
        forward: a jit-able `ForwardModel` (analytic or emulator).
        measured: L* per angle of `forward.aspecular_deg`.
        free: parameters to fit (default: all forward inputs except ``diffuse``); may include
            ``discrepancy`` (moment estimate, see module docstring).
        fixed: values of other forward inputs (defaults: registered defaults).
        bounds: `{name: (lower, upper)}` overrides of the registered bounds.
        instrument_sd: instrument repeatability [L*], > 0: one number, or one per angle.
        weights: optional non-negative weight per angle multiplying the standardised residual.
        n_starts: number of starts (≥ 1).
        x0: optional extra start (physical values of the free parameters).
        seed: seed of the start design.
        max_steps, rtol, atol: Optimistix LM settings.
        continuations: at most this many further rounds of `max_steps` for the lowest-χ² start when it
            stopped at the step limit away from the box edge (its status says so).
        jacobian: ``"fd"`` (central differences of the compiled batched forward; default, no
            extra compilation, works for non-differentiable forwards) or ``"ad"`` (jacfwd).
        priors: known inputs `{name: (value, sd)}` of free parameters (physical units, sd > 0), each
            a Gaussian term of the objective (module docstring).

    Returns:
        A `FitResult`.
    """
    t0 = time.perf_counter()
    m = len(forward.aspecular_deg)
    y = check_measured(measured, m)
    check_instrument_sd(instrument_sd, m)
    settings = {"n_starts": n_starts, "max_steps": max_steps, "continuations": continuations, "seed": seed}
    settings |= check_args(settings, FIT_RANGES, optional=())
    n_starts, max_steps, continuations, seed = (settings[k] for k in FIT_RANGES)
    w = np.ones(m) if weights is None else np.asarray(weights, dtype=float).reshape(-1)
    if w.shape != (m,) or np.any(~np.isfinite(w)) or np.any(w < 0) or not np.any(w > 0):
        raise ValueError(f"weights must be {m} finite non-negative numbers, not all zero, got {weights!r}")
    spec, sub, restricted = _problem(forward, free, fixed, bounds)
    s = np.sqrt(np.asarray(instrument_sd, dtype=float) ** 2 + np.asarray(forward.error_sd) ** 2)
    pv, pw = prior_arrays(sub.names, priors)
    args = (jnp.asarray(y), jnp.asarray(w), jnp.asarray(s), jnp.asarray(sub._a), jnp.asarray(sub._b), jnp.asarray(sub._is_log),
            jnp.asarray(pv), jnp.asarray(pw))

    from scipy.stats import qmc

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # Sobol balance needs powers of 2; we only need spread
        z = qmc.Sobol(len(sub), scramble=True, seed=seed).random(int(n_starts))
    z = np.clip(0.05 + 0.9 * z, 1e-6, 1 - 1e-6)  # keep starts off the very edges of the box
    u0 = np.log(z) - np.log1p(-z)
    if x0 is not None:
        xs = sub.check(sub.from_dict(x0), "x0")
        eps = 1e-9 * (sub.upper - sub.lower)
        u0 = np.concatenate([np.asarray(sub.to_unconstrained(np.clip(xs, sub.lower + eps, sub.upper - eps)))[None], u0])
    solve, residual, jac = _compiled(len(sub), m, max_steps, rtol, atol)
    fwd, value_and_jac = _host_functions(restricted, sub, jacobian)
    with _ACTIVE_LOCK:
        _ACTIVE["f"], _ACTIVE["fj"] = fwd, value_and_jac
        u_all, codes = solve(jnp.asarray(u0), args)
        u_all, codes = np.array(u_all), np.array(codes).reshape(-1)
        r_all = np.array(jax.vmap(residual, in_axes=(0, None))(jnp.asarray(u_all), args))
        # The lowest χ² over *all* starts, converged or not: a start that ran out of steps while still
        # going downhill is continued (up to `continuations` more rounds of max_steps) rather than dropped.
        continued = np.zeros(len(u_all), dtype=int)
        for _ in range(int(continuations)):
            chi2_all = np.sum(r_all**2, axis=1)
            lowest = int(np.argmin(np.where(np.isfinite(chi2_all), chi2_all, np.inf)))
            if codes[lowest] not in (1, 7) or (np.abs(u_all[lowest]) > _U_EDGE).any():
                break
            u2, c2 = solve(jnp.asarray(u_all[lowest][None]), args)
            u_all[lowest], codes[lowest] = np.asarray(u2)[0], int(np.asarray(c2).reshape(-1)[0])
            r_all[lowest] = np.asarray(residual(jnp.asarray(u_all[lowest]), args))
            continued[lowest] += 1
        # Jacobians are taken at u clipped to the edge band: at a boundary optimum (u → ±∞) the
        # logit map's derivative underflows to 0 and ∂r/∂x could not be recovered from ∂r/∂u.
        u_jac_all = np.clip(u_all, -_U_EDGE, _U_EDGE)
        if jacobian == "ad":
            Ju_ad = [np.asarray(jac(jnp.asarray(u), args)) for u in u_jac_all]
    chi2_all = np.sum(r_all**2, axis=1)
    # A start that ran out of steps while walking a parameter to the edge of its box (u → ±∞, where
    # the logit map flattens) has converged to a boundary optimum: accept it and say so.
    edge = np.abs(u_all) > _U_EDGE
    stalled = np.isin(codes, (1, 7)) & edge.any(axis=1)
    ok = ((codes == 0) | stalled) & np.isfinite(chi2_all)
    starts = []
    for u, c, k, e, st in zip(u_all, chi2_all, codes, edge, stalled):
        msg = result_message(int(k))
        if st:
            msg = "converged to the bound of " + ", ".join(n for n, flag in zip(sub.names, e) if flag)
        starts.append({"x": sub.as_dict(np.asarray(sub.from_unconstrained(u))), "chi2": float(c), "status": msg})
    for i in np.flatnonzero(continued):
        starts[i]["status"] += f" (continued {continued[i]} × {max_steps} steps from the step limit)"
    finite = np.flatnonzero(np.isfinite(chi2_all))
    if finite.size == 0:
        raise ValueError("every least-squares start failed (non-finite residuals); check the measured values and bounds")
    best = int(finite[np.argmin(chi2_all[finite])])
    u_best, u_jac = u_all[best], u_jac_all[best]
    x_best = np.asarray(sub.from_unconstrained(u_best))
    # Jacobian in physical units: ∂r/∂x = ∂r/∂u · (∂x/∂u)^-1 (the bijection is elementwise).
    if jacobian == "ad":
        Ju = Ju_ad[best][:m]
    else:  # central differences (step 1e-5 in u)
        hs = 1e-5
        E = np.eye(len(sub)) * hs
        Y = fwd(np.concatenate([u_jac[None] + E, u_jac[None] - E]))
        Ju = ((Y[: len(sub)] - Y[len(sub):]) / (2 * hs)).T * (w / s)[:, None]
    dxdu = np.diag(np.asarray(jax.jacfwd(sub.from_unconstrained)(jnp.asarray(u_jac))))
    Jx = np.concatenate([Ju / dxdu[None, :], np.diag(pw)[pw > 0]])  # the known inputs' rows: ∂((x − v)/u)/∂x
    n_eff = int(np.sum(w > 0) + np.sum(pw > 0))
    dof = n_eff - len(sub)
    chi2 = float(chi2_all[best])
    scale2 = max(1.0, chi2 / dof) if dof > 0 else 1.0
    cov = scale2 * np.linalg.pinv(Jx.T @ Jx)
    unidentified = _unidentified(Jx)
    if unidentified.any():  # directions the data do not constrain: infinite variance, not pinv's zero
        cov[unidentified, :] = np.inf
        cov[:, unidentified] = np.inf
        warnings.warn(f"the data do not identify {', '.join(n for n, u in zip(sub.names, unidentified) if u)} "
                      f"({n_eff} weighted angles for {len(sub)} free parameters, or a flat direction): their standard "
                      "errors are infinite; fix some parameters or add angles", RuntimeWarning, stacklevel=2)
    L_fit = fwd(u_best[None])[0]
    res = L_fit - y
    values = sub.as_dict(x_best)
    stderr = {n: float(np.sqrt(max(cov[i, i], 0.0))) for i, n in enumerate(sub.names)}
    at_bound = [n for n, flag in zip(sub.names, edge[best]) if flag]
    disc = None
    if "discrepancy" in spec.names:
        used = w > 0  # unweighted residuals: δ is a variance in L*², whatever the weights
        e2 = np.broadcast_to(np.asarray(forward.error_sd, dtype=float) ** 2, res.shape)
        i2 = np.broadcast_to(np.asarray(instrument_sd, dtype=float) ** 2, res.shape)
        disc = float(np.sqrt(max(0.0, np.sum(res[used] ** 2) / max(dof, 1) - float(np.mean(i2[used])) - float(np.mean(e2[used])))))
        values["discrepancy"] = disc
        stderr["discrepancy"] = float("nan")
    return FitResult(
        names=spec.names,
        values={n: values[n] for n in spec.names},
        stderr={n: stderr[n] for n in spec.names},
        covariance=cov,
        L_star_fit=L_fit,
        L_star_measured=y,
        residuals=res,
        standardized_residuals=r_all[best],
        chi2=chi2,
        dof=dof,
        scale2=scale2,
        success=bool(ok[best]),
        status=starts[best]["status"],
        n_starts=len(u0),
        n_converged=int(ok.sum()),
        starts=starts,
        fixed=dict(restricted.fixed),
        discrepancy=disc,
        seconds=time.perf_counter() - t0,
        aspecular_deg=np.asarray(forward.aspecular_deg),
        at_bound=at_bound,
    )


_COMPILED: dict = {}


_ACTIVE: dict = {}
_ACTIVE_LOCK = threading.RLock()


def _host_functions(restricted: Restricted, sub: ParameterSpec, jacobian: str):
    """NumPy functions of u for one problem: the value, and the value with the Jacobian.

    Values come from `batched_forward`; the Jacobian either by forward-mode AD (``"ad"``,
    compiled separately) or by one-sided differences in u with step 1e-6 (``"fd"``: no extra
    compilation; also works for forwards JAX cannot differentiate, e.g. a tracer with common
    random numbers).
    """
    k = len(sub)
    m = len(restricted.model.aspecular_deg)
    fwd = batched_forward(restricted, sub)
    if jacobian == "ad":
        j_batch = jax.jit(jax.vmap(jax.jacfwd(lambda u: restricted.evaluate(sub.from_unconstrained(u)[None])[0])))

        def value_and_jac(U):
            return fwd(U), np.asarray(j_batch(U))
    elif jacobian == "fd":
        h = 1e-6

        def value_and_jac(U):
            E = np.eye(k) * h
            P = np.concatenate([U[:, None, :], U[:, None, :] + E[None]], axis=1).reshape(-1, k)
            Y = fwd(P).reshape(U.shape[0], k + 1, m)
            return Y[:, 0], np.transpose((Y[:, 1:] - Y[:, :1]) / h, (0, 2, 1))
    else:
        raise ValueError(f"jacobian must be 'ad' or 'fd', got {jacobian!r}")
    return fwd, value_and_jac


def _callback_map(k: int, m: int):
    """u ↦ L* as a `custom_jvp` whose value and Jacobian come from the *active* problem's host
    functions through `jax.pure_callback`.

    Optimistix then traces only this small wrapper, and one compiled solver per (k, m, settings)
    serves every problem in the process (the problem is looked up at call time, under a lock). The
    JVP rule takes the value and the Jacobian from one callback: two callbacks that XLA runs at once,
    each running the forward model's own compiled code, can take every thread of the CPU pool and
    wait on each other.
    """
    dtype = jnp.result_type(float)

    def host_f(u):
        u = np.asarray(u)
        return _ACTIVE["f"](u.reshape(-1, k)).astype(dtype).reshape(u.shape[:-1] + (m,))

    def host_fj(u):
        u = np.asarray(u)
        y, J = _ACTIVE["fj"](u.reshape(-1, k))
        return y.astype(dtype).reshape(u.shape[:-1] + (m,)), J.astype(dtype).reshape(u.shape[:-1] + (m, k))

    @jax.custom_jvp
    def F(u):
        return jax.pure_callback(host_f, jax.ShapeDtypeStruct(u.shape[:-1] + (m,), dtype), u, vmap_method="expand_dims")

    @F.defjvp
    def F_jvp(primals, tangents):
        (u,), (t,) = primals, tangents
        y, J = jax.pure_callback(host_fj, (jax.ShapeDtypeStruct(u.shape[:-1] + (m,), dtype),
                                           jax.ShapeDtypeStruct(u.shape[:-1] + (m, k), dtype)), u, vmap_method="expand_dims")
        return y, J @ t

    return F


#: Batch size of the compiled forward; calls are padded to a multiple of it (one compilation).
CHUNK = 16
_FORWARDS: dict = {}


def evaluate_in_chunks(model: ForwardModel, T, chunk: int = CHUNK) -> np.ndarray:
    """L* (n, m) of a model at full θ rows T (n, p), in fixed-size chunks (the last padded), so one
    compiled executable per model class and chunk size serves every batch."""
    T = np.asarray(T, dtype=float)
    n = T.shape[0]
    pad = (-n) % chunk
    if pad:
        T = np.concatenate([T, np.repeat(T[-1:], pad, axis=0)])
    if model.jittable:
        out = [np.asarray(_jit_evaluate(model, jnp.asarray(T[i:i + chunk]))) for i in range(0, T.shape[0], chunk)]
    else:
        out = [np.asarray(model.evaluate(T[i:i + chunk])) for i in range(0, T.shape[0], chunk)]
    return np.concatenate(out)[:n]


def batched_forward(restricted: Restricted, sub: ParameterSpec, chunk: int = CHUNK):
    """NumPy function U (n, k) unconstrained → L* (n, m).

    The free-to-full mapping runs in NumPy; the model sees full θ in fixed-size chunks (padded),
    so one compiled executable per model class and chunk size serves every problem — any choice
    of free and fixed parameters, least squares, posterior and design alike.
    """
    key = (restricted.fingerprint(), sub.fingerprint(), chunk)
    if key in _FORWARDS:
        return _FORWARDS[key][1]
    model = restricted.model
    cols = np.array(restricted._cols)
    vals = np.asarray(restricted._vals, dtype=float)

    def fwd(U):
        U = np.asarray(U, dtype=float)
        X = sub.from_unconstrained_np(U)
        T = np.where(cols >= 0, X[:, np.maximum(cols, 0)], vals[None, :])
        return evaluate_in_chunks(model, T, chunk)

    if len(_FORWARDS) > 32:
        _FORWARDS.clear()
    _FORWARDS[key] = (model, fwd)
    return fwd


def _compiled(k: int, m: int, max_steps: int, rtol: float, atol: float):
    """(vmapped LM solve, residual, Jacobian of the residual) for k parameters and m angles,
    compiled once per process and setting; they evaluate the active problem (see `_callback_map`)."""
    key = (int(k), int(m), int(max_steps), float(rtol), float(atol))
    if key in _COMPILED:
        return _COMPILED[key]
    F = _callback_map(k, m)

    def residual(u, args):
        ys, ws, ss, a, b, is_log, pv, pw = args
        x = unit_to_value(a, b, is_log, jax.nn.sigmoid(u))  # the physical values (`ParameterSpec.from_unconstrained`)
        return jnp.concatenate([ws * (F(u) - ys) / ss, pw * (x - pv)])

    solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol)

    def one(u, args):
        sol = optx.least_squares(residual, solver, u, args, max_steps=max_steps, throw=False)
        return sol.value, sol.result._value

    _COMPILED[key] = (jax.jit(jax.vmap(one, in_axes=(0, None))), jax.jit(residual), jax.jit(jax.jacfwd(residual)))
    return _COMPILED[key]
