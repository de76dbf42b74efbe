"""The measured inputs as data: their likelihood given the true microstructure, and the consistency check.

`MeasuredInputs` turns the published roughness reading and tilt law into a log-likelihood of the
true (σ, τ, shape, scale): the roughness through the virtual profilometer's `ReadingModel` (what the
published procedure reads on a true surface), the tilt law as a maximum-likelihood gamma fit to a
stated count of measured platelets (`gamma_fit_sd`: Fisher covariance at the true law). Added to the
L* likelihood in `sample_posterior(..., inputs=...)`, the posterior weighs what the inputs and the
L* each say. `KnownInputs` is the plain alternative for inputs reported as value ± SD of the true
parameter (a batch file's known-input columns). `posterior_predictive_check` asks whether the L* are
what the posterior expects.
"""

from __future__ import annotations

import equinox as eqx
import numpy as np

from ._fit import evaluate_in_chunks
from ._observations import known_inputs
from ._profilometer import SIGMA_DEFINITIONS, ReadingModel, normal2_log_density
from ._tilt_measurement import gamma_fit_moments


class MeasuredInputs(eqx.Module):
    """Likelihood of a sample's published inputs given the true microstructure (jittable).

    Fields: `reading` (the roughness `ReadingModel`, or None to leave σ, τ to the prior) with the
    published reading `sigma_hat_um`, `tau_hat_um` under the σ `definition`; the published tilt law
    `shape_hat`, `scale_hat` fitted to `tilt_platelets` measured tilts (0: tilt law left to the prior).
    """

    reading: ReadingModel | None
    sigma_hat_um: float = eqx.field(static=True)
    tau_hat_um: float = eqx.field(static=True)
    definition: str = eqx.field(static=True)
    shape_hat: float = eqx.field(static=True)
    scale_hat: float = eqx.field(static=True)
    tilt_platelets: int = eqx.field(static=True)

    def __check_init__(self):
        if self.definition not in SIGMA_DEFINITIONS:
            raise ValueError(f"definition must be one of {SIGMA_DEFINITIONS}, got {self.definition!r}")
        if int(self.tilt_platelets) != self.tilt_platelets or not 0 <= self.tilt_platelets <= 1_000_000:
            raise ValueError(f"tilt_platelets must be an integer in [0, 1000000] (0: no tilt measurement), got {self.tilt_platelets!r}")
        for name in ("sigma_hat_um", "tau_hat_um", "shape_hat", "scale_hat"):
            v = float(getattr(self, name))
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {v!r}")

    @classmethod
    def for_sample(cls, sample, reading: ReadingModel | None, *, definition: str = "rq", tilt_platelets: int = 200) -> MeasuredInputs:
        """The published inputs of a reference sample (`load_sample`)."""
        return cls(reading, float(sample.sigma.value), float(sample.tau.value), definition, float(sample.tilt_shape.value),
                   float(sample.tilt_scale.value), int(tilt_platelets))

    def fingerprint(self) -> str:
        """Identity for chain metadata (a chain sampled with other inputs is not resumed)."""
        nodes = None if self.reading is None else np.round(np.asarray(self.reading.log_tau_hat_mean), 6).tolist()
        return repr((self.sigma_hat_um, self.tau_hat_um, self.definition, self.shape_hat, self.scale_hat, self.tilt_platelets, nodes))

    def start_values(self) -> dict:
        """The published values of the inputs that are data (a sampler's starting guess, not an estimate)."""
        out = {"sigma": self.sigma_hat_um, "tau": self.tau_hat_um} if self.reading is not None else {}
        return out | ({"shape": self.shape_hat, "scale": self.scale_hat} if self.tilt_platelets > 0 else {})

    def log_likelihood(self, params: dict):
        """log p(published inputs | true parameters) for the parameters present in `params` (arrays)."""
        total = 0.0
        if self.reading is not None and "sigma" in params and "tau" in params:
            total = total + self.reading.log_likelihood(params["sigma"], params["tau"], self.sigma_hat_um, self.tau_hat_um, self.definition)
        if self.tilt_platelets > 0 and "shape" in params and "scale" in params:
            sk, st, r = gamma_fit_moments(params["shape"], params["scale"], self.tilt_platelets)
            total = total + normal2_log_density(self.shape_hat - params["shape"], self.scale_hat - params["scale"], sk, st, r)
        return total

    def shift_table(self, draws: dict) -> dict:
        """Each published input against what the posterior implies it should read, in units of its SD.

        Arguments:
            draws: posterior draws per parameter name (arrays).

        Returns:
            per input: the published value, the posterior median of the reading the true parameter would
            give, and z = (published − expected reading) / reading SD, averaged over the draws.
        """
        out = {}
        if self.reading is not None and "sigma" in draws and "tau" in draws:
            s, t = np.asarray(draws["sigma"]), np.asarray(draws["tau"])
            m_r, s_r, m_t, s_t, _ = (np.asarray(v) for v in self.reading.moments(t, self.definition))
            out["sigma"] = {"published": self.sigma_hat_um, "expected_reading": float(np.median(np.exp(np.log(s) + m_r))),
                            "true_median": float(np.median(s)), "z": float(np.mean((np.log(self.sigma_hat_um) - np.log(s) - m_r) / s_r))}
            out["tau"] = {"published": self.tau_hat_um, "expected_reading": float(np.median(np.exp(m_t))), "true_median": float(np.median(t)),
                          "z": float(np.mean((np.log(self.tau_hat_um) - m_t) / s_t))}
        if self.tilt_platelets > 0 and "shape" in draws and "scale" in draws:
            k, th = np.asarray(draws["shape"]), np.asarray(draws["scale"])
            sk, st, _ = (np.asarray(v) for v in gamma_fit_moments(k, th, self.tilt_platelets))
            out["shape"] = {"published": self.shape_hat, "expected_reading": float(np.median(k)), "true_median": float(np.median(k)),
                            "z": float(np.mean((self.shape_hat - k) / sk))}
            out["scale"] = {"published": self.scale_hat, "expected_reading": float(np.median(th)), "true_median": float(np.median(th)),
                            "z": float(np.mean((self.scale_hat - th) / st))}
        return out


class KnownInputs(eqx.Module):
    """Inputs known as value ± SD of the true parameter (Gaussian likelihood; jittable), e.g. a panel's
    measured σ with its uncertainty.

    Arguments:
        values: {name: (value, sd)} in physical units, sd > 0.
    """

    items: tuple = eqx.field(static=True)

    def __init__(self, values):
        self.items = known_inputs(values)

    def fingerprint(self) -> str:
        """Identity for chain metadata."""
        return repr(self.items)

    def start_values(self) -> dict:
        """The known values (a sampler's starting guess)."""
        return {name: v for name, v, _ in self.items}

    def log_likelihood(self, params: dict):
        """Σ log N(value | θ, sd²) over the known inputs present in `params` (arrays)."""
        total = 0.0
        for name, v, sd in self.items:
            if name in params:
                total = total - 0.5 * ((params[name] - v) / sd) ** 2 - float(np.log(np.sqrt(2 * np.pi) * sd))
        return total

    def shift_table(self, draws: dict) -> dict:
        """Each known input against the posterior: z = (value − posterior median) / sd."""
        return {n: {"published": v, "expected_reading": float(np.median(draws[n])), "true_median": float(np.median(draws[n])),
                    "z": float((v - np.median(draws[n])) / sd)} for n, v, sd in self.items if n in draws}


def posterior_predictive_check(result, forward, measured, *, fixed=None, instrument_sd=0.3, max_draws: int = 400,
                               seed: int = 0, angles=None, replicates: int = 500) -> dict:
    """Posterior-predictive check of the L*: are the measured values what the posterior expects?

    For posterior draws θ_i (with their discrepancy δ_i, or the fixed one), the discrepancy statistic is
    the deviance of the measured L* about the model curve, T_i = −2 Σ_j log p(y_j − L_j(θ_i)), under the
    likelihood's residual law (instrument ⊕ δ_i normal, plus the forward model's own error,
    `ForwardModel.residual_log_density`), and p = P(T(y_rep, θ) ≥ T(y, θ)) over the posterior and
    replicated data y_rep from the same law. With a normal law, T is χ² with m degrees of freedom
    given θ_i and p = mean_i P(χ²_m ≥ T_i) exactly; otherwise (an emulator's heavy-tailed error) p is
    counted over `replicates` replicated data sets per draw, as (hits + 1) / (trials + 1). A small p
    (≲ 0.01) says the model with these inputs and errors does not produce data like the measured ones.
    Its Monte Carlo standard error is the spread of the per-draw tail probabilities over the draws
    (which holds the replicates' counting noise too) ÷ √draws; it is conditional on the forward model,
    so it does not hold how p moves when an emulator is rebuilt.

    Forward inputs that were neither sampled nor in `fixed` take their registered defaults, as in the
    posterior. `instrument_sd` may be one per angle; `angles` (m booleans) leaves the others out (m
    is then their count).

    Returns:
        dict with "p_value", its Monte Carlo standard error "p_value_se", "chi2_median" (of T_i), the predictive band "L_star_q05", "L_star_q50",
        "L_star_q95" (replicated data), "draws" used and "replicates" per draw (0: the exact χ² tail).
    """
    import jax.numpy as jnp
    from scipy.stats import chi2 as chi2_dist

    if isinstance(replicates, bool) or int(replicates) != replicates or not 1 <= replicates <= 100_000:
        raise ValueError(f"replicates must be an integer in [1, 100000], got {replicates!r}")
    if isinstance(max_draws, bool) or int(max_draws) != max_draws or max_draws < 2:
        raise ValueError(f"max_draws must be an integer >= 2 (p's standard error needs two draws), got {max_draws!r}")
    names = result.names
    S = np.asarray(result.samples)
    if S.ndim != 2 or S.shape[0] < 2:
        raise ValueError(f"result must hold at least 2 posterior draws (samples of shape (draws, parameters)), got shape {S.shape}")
    rng = np.random.default_rng(seed)
    idx = rng.choice(S.shape[0], size=min(int(max_draws), S.shape[0]), replace=False)
    S = S[idx]
    fixed = dict(fixed or {})
    free = tuple(n for n in names if n in forward.parameter_names)
    # inputs neither sampled nor fixed take their registered defaults, as in the posterior
    restricted = forward.restrict(free, {k: v for k, v in fixed.items() if k in forward.parameter_names})
    theta = np.asarray(restricted.full(S[:, [names.index(n) for n in free]]))
    L = evaluate_in_chunks(forward, theta)
    have = np.ones(L.shape[1], bool) if angles is None else np.asarray(angles, bool)
    y = np.where(have, np.asarray(measured, float), 0.0)
    delta = S[:, names.index("discrepancy")] if "discrepancy" in names else np.full(len(S), float(fixed.get("discrepancy", 0.0)))
    var = np.broadcast_to(np.asarray(instrument_sd, float) ** 2 + delta[:, None] ** 2, L.shape)

    def deviance(resid, var_, theta_):
        return -2.0 * np.asarray(forward.residual_log_density(jnp.asarray(resid), jnp.asarray(var_), jnp.asarray(theta_), jnp.asarray(have)))

    rep = L + forward.sample_residual(rng, var, theta)
    if np.isinf(forward.error_df):  # normal: T − Σ log(2π v) is χ²_m given θ
        v = var + np.asarray(forward.error_sd, float) ** 2
        T = np.sum(np.where(have, (y - L) ** 2 / v, 0.0), axis=1)
        tail = chi2_dist.sf(T, int(have.sum()))
        p, n_rep = float(np.mean(tail)), 0
    else:
        T = deviance(y - L, var, theta)
        n_rep = int(replicates)
        hits = np.zeros(len(T))
        for _ in range(n_rep):
            hits += deviance(forward.sample_residual(rng, var, theta), var, theta) >= T
        tail = hits / n_rep
        p = (float(np.sum(hits)) + 1.0) / (n_rep * len(T) + 1.0)
    se = float(np.std(tail, ddof=1) / np.sqrt(len(T)))
    return {"p_value": p, "p_value_se": se, "chi2_median": float(np.median(T)), "L_star_q05": np.quantile(rep, 0.05, axis=0),
            "L_star_q50": np.quantile(rep, 0.5, axis=0), "L_star_q95": np.quantile(rep, 0.95, axis=0), "draws": int(len(S)),
            "replicates": n_rep}
