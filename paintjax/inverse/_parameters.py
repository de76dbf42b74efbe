"""Microstructure parameters of the inverse layer: bounds, smooth maps to unconstrained space, priors.

Every parameter lives on a finite interval [lower, upper] and is mapped to the real line by a
logit, either of x itself (`scale="linear"`) or of log x (`scale="log"`):

    z = (x − lo)/(hi − lo)           or   z = (log x − log lo)/(log hi − log lo),
    u = logit(z),                          x = lo + (hi − lo)·sigmoid(u)   (or its log analogue).

The map is smooth and strictly monotone, so least squares and MCMC can work in u without
bounds. Priors are *weak* and stated per parameter (`prior`):

* ``"uniform"`` – flat in x on [lo, hi];
* ``"loguniform"`` – flat in log x on [lo, hi] (scale parameters whose order of magnitude is
  unknown);
* ``"halfcauchy"`` – half-Cauchy with scale `prior_scale`, truncated to [lo, hi] (the model
  discrepancy: favours small values, heavy tail).

None is centred on the independently measured values of the reference samples (brief §2); the
default bounds span roughly one order of magnitude around the physically plausible range
(shape 0.8–12, scale 0.3–10°, σ 0.02–0.2 µm, τ 0.1–2 µm; their log-centres 3.1, 1.7°, 0.063 µm,
0.45 µm are not the measured values). The roughness box also keeps the Beckmann slope parameter
2σ/τ ≥ 0.02, where the analytic model's fixed quadrature over platelet normals stays accurate.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

_PRIORS = ("uniform", "loguniform", "halfcauchy")
_SCALES = ("linear", "log")


@dataclasses.dataclass(frozen=True)
class Parameter:
    """One scalar parameter: name, unit, bounds, unconstrained map and weak prior.

    Arguments:
        name: identifier (used in results, JSON and the CLI).
        lower, upper: finite bounds, lower < upper (lower > 0 for `scale="log"`).
        scale: ``"linear"`` (logit of x) or ``"log"`` (logit of log x).
        prior: ``"uniform"``, ``"loguniform"`` or ``"halfcauchy"`` (see the module docstring).
        default: value used when the parameter is held fixed and no value is given.
        unit: unit string for reports.
        description: one line for reports.
        prior_scale: scale of the half-Cauchy prior (ignored otherwise).
    """

    name: str
    lower: float
    upper: float
    scale: str = "linear"
    prior: str = "uniform"
    default: float = 0.0
    unit: str = ""
    description: str = ""
    prior_scale: float = 1.0

    def __post_init__(self):
        lo, hi = float(self.lower), float(self.upper)
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ValueError(f"parameter {self.name!r}: bounds must be finite with lower < upper, got [{self.lower}, {self.upper}]")
        if self.scale not in _SCALES:
            raise ValueError(f"parameter {self.name!r}: scale must be one of {_SCALES}, got {self.scale!r}")
        if self.prior not in _PRIORS:
            raise ValueError(f"parameter {self.name!r}: prior must be one of {_PRIORS}, got {self.prior!r}")
        if (self.scale == "log" or self.prior == "loguniform") and lo <= 0:
            raise ValueError(f"parameter {self.name!r}: log scale or log-uniform prior needs lower > 0, got {lo}")
        if self.prior == "halfcauchy" and (lo < 0 or self.prior_scale <= 0):
            raise ValueError(f"parameter {self.name!r}: half-Cauchy prior needs lower >= 0 and prior_scale > 0")
        if not (lo <= float(self.default) <= hi):
            raise ValueError(f"parameter {self.name!r}: default {self.default} outside [{lo}, {hi}]")

    def with_bounds(self, lower: float, upper: float) -> "Parameter":
        """Copy with new bounds (the default is clipped into them)."""
        return dataclasses.replace(self, lower=lower, upper=upper, default=float(np.clip(self.default, lower, upper)))


#: Every parameter the inverse layer knows, with its default bounds and prior. A forward model
#: consumes a subset (`ForwardModel.parameter_names`); the fit frees a subset of those.
PARAMETERS: dict[str, Parameter] = {
    p.name: p
    for p in (
        Parameter("shape", 0.8, 12.0, "log", "loguniform", 2.0, "", "tilt gamma shape k"),
        Parameter("scale", 0.3, 10.0, "log", "loguniform", 2.0, "deg", "tilt gamma scale θ (mean tilt = k·θ)"),
        Parameter("sigma", 0.02, 0.2, "log", "loguniform", 0.05, "µm", "platelet roughness RMS height σ"),
        Parameter("tau", 0.1, 2.0, "log", "loguniform", 0.5, "µm", "platelet roughness correlation length τ (1/e)"),
        Parameter("pvc", 0.05, 0.4, "linear", "uniform", 0.2, "", "basecoat pigment volume concentration"),
        Parameter("waviness", 0.0, 15.0, "linear", "uniform", 0.0, "deg", "clearcoat surface waviness: RMS slope angle (`paintjax.optics._interface`)"),
        Parameter("primer_albedo", 0.0, 1.0, "linear", "uniform", 0.3, "", "Lambertian albedo of the grey primer"),
        Parameter("diffuse", 0.0, 0.5, "linear", "uniform", 0.0, "", "Lambertian reflectance factor under the coat (multiple-scattering stand-in)"),
        Parameter("discrepancy", 0.0, 50.0, "linear", "halfcauchy", 0.0, "L*", "model-discrepancy standard deviation", 5.0),
    )
}


def get_parameter(name: str) -> Parameter:
    """The registered `Parameter` called `name` (ValueError listing the known names otherwise)."""
    if name not in PARAMETERS:
        raise ValueError(f"unknown parameter {name!r}; known parameters: {', '.join(PARAMETERS)}")
    return PARAMETERS[name]


def _logit(z):
    return jnp.log(z) - jnp.log1p(-z)


def unit_to_value(a, b, is_log, z, xp=jnp):
    """z ∈ [0, 1] → x on the box whose ends are a, b in its own coordinate (log where `is_log`): the map
    of `ParameterSpec.from_unit`, for code that holds the arrays (`ParameterSpec._a`, `_b`, `_is_log`)
    rather than the spec; `xp` is jax.numpy or NumPy."""
    t = a + (b - a) * z
    return xp.where(is_log, xp.exp(xp.where(is_log, t, 0.0)), t)


class ParameterSpec:
    """An ordered set of free parameters with vectorised maps between x (physical) and u (real line).

    All methods work on arrays whose last axis runs over the parameters (leading dims batch) and
    are jit/vmap/grad friendly. Not a pytree: it is static configuration.

    Arguments:
        parameters: `Parameter` objects or registered names, in order.
    """

    def __init__(self, parameters: Sequence[Parameter | str]):
        params = tuple(get_parameter(p) if isinstance(p, str) else p for p in parameters)
        if not params:
            raise ValueError("parameters must name at least one parameter")
        names = [p.name for p in params]
        if len(set(names)) != len(names):
            raise ValueError(f"parameters must be distinct, got {names}")
        self.parameters = params
        self.names = tuple(names)
        lo = np.array([p.lower for p in params], dtype=float)
        hi = np.array([p.upper for p in params], dtype=float)
        is_log = np.array([p.scale == "log" for p in params])
        self._is_log = is_log
        self._a = np.where(is_log, np.log(np.where(is_log, lo, 1.0)), lo)
        self._b = np.where(is_log, np.log(np.where(is_log, hi, 1.0)), hi)
        self.lower, self.upper = lo, hi

    def __len__(self) -> int:
        return len(self.parameters)

    def __repr__(self) -> str:
        return f"ParameterSpec({', '.join(self.names)})"

    def fingerprint(self) -> str:
        """A stable text description (for cache keys)."""
        return ";".join(f"{p.name}:{p.lower!r}:{p.upper!r}:{p.scale}:{p.prior}:{p.prior_scale!r}" for p in self.parameters)

    def index(self, name: str) -> int:
        return self.names.index(name)

    # --- maps -------------------------------------------------------------------------------
    def to_unit(self, x: Float[ArrayLike, "... p"]) -> Float[Array, "... p"]:
        """x → z ∈ [0, 1] (linear or log coordinate within the bounds)."""
        x = jnp.asarray(x)
        xt = jnp.where(self._is_log, jnp.log(jnp.where(self._is_log, jnp.maximum(x, 1e-300), 1.0)), x)
        return (xt - self._a) / (self._b - self._a)

    def from_unit(self, z: Float[ArrayLike, "... p"]) -> Float[Array, "... p"]:
        """z ∈ [0, 1] → x."""
        return unit_to_value(self._a, self._b, self._is_log, jnp.asarray(z))

    def to_unconstrained(self, x: Float[ArrayLike, "... p"]) -> Float[Array, "... p"]:
        """x (strictly inside the bounds) → u ∈ ℝ^p."""
        return _logit(self.to_unit(x))

    def from_unconstrained(self, u: Float[ArrayLike, "... p"]) -> Float[Array, "... p"]:
        """u ∈ ℝ^p → x inside the bounds (smooth bijection)."""
        return self.from_unit(jax.nn.sigmoid(jnp.asarray(u)))

    def from_unconstrained_np(self, u) -> np.ndarray:
        """NumPy version of `from_unconstrained` (no JAX dispatch; for host-side hot loops)."""
        with np.errstate(over="ignore"):
            z = 1.0 / (1.0 + np.exp(-np.asarray(u, dtype=float)))
        return unit_to_value(self._a, self._b, self._is_log, z, xp=np)

    def log_det_jacobian(self, u: Float[ArrayLike, "... p"]) -> Float[Array, "..."]:
        """log |dx/du| summed over parameters (add to a log density in x to get one in u)."""
        u = jnp.asarray(u)
        log_dz = jax.nn.log_sigmoid(u) + jax.nn.log_sigmoid(-u)
        log_dt = jnp.log(self._b - self._a) + log_dz
        x = self.from_unconstrained(u)
        log_dx = jnp.where(self._is_log, log_dt + jnp.log(jnp.where(self._is_log, x, 1.0)), log_dt)
        return jnp.sum(log_dx, axis=-1)

    # --- priors ------------------------------------------------------------------------------
    def log_prior(self, x: Float[ArrayLike, "... p"]) -> Float[Array, "..."]:
        """Log prior density in x (normalised on [lo, hi]); −inf outside the bounds."""
        x = jnp.asarray(x)
        terms = []
        for i, p in enumerate(self.parameters):
            xi = x[..., i]
            if p.prior == "uniform":
                lp = -jnp.log(p.upper - p.lower) * jnp.ones_like(xi)
            elif p.prior == "loguniform":
                lp = -jnp.log(jnp.maximum(xi, 1e-300)) - math.log(math.log(p.upper / p.lower))
            else:  # truncated half-Cauchy
                s = p.prior_scale
                mass = (2.0 / math.pi) * (math.atan(p.upper / s) - math.atan(p.lower / s))
                lp = math.log(2.0 / (math.pi * s)) - jnp.log1p((xi / s) ** 2) - math.log(mass)
            inside = (xi >= p.lower) & (xi <= p.upper)
            terms.append(jnp.where(inside, lp, -jnp.inf))
        return sum(terms)

    def log_prior_unconstrained(self, u: Float[ArrayLike, "... p"]) -> Float[Array, "..."]:
        """Log prior density of u (the prior in x pushed through the bijection)."""
        u = jnp.asarray(u)
        return self.log_prior(self.from_unconstrained(u)) + self.log_det_jacobian(u)

    def sample_prior(self, key, n: int) -> Float[Array, "n p"]:
        """n draws from the prior (exact for uniform/log-uniform, inverse CDF for half-Cauchy)."""
        z = jax.random.uniform(key, (n, len(self)), minval=1e-9, maxval=1 - 1e-9)
        cols = []
        for i, p in enumerate(self.parameters):
            if p.prior == "uniform":
                cols.append(p.lower + (p.upper - p.lower) * z[:, i])
            elif p.prior == "loguniform":
                cols.append(jnp.exp(math.log(p.lower) + math.log(p.upper / p.lower) * z[:, i]))
            else:
                s = p.prior_scale
                a, b = math.atan(p.lower / s), math.atan(p.upper / s)
                cols.append(s * jnp.tan(a + (b - a) * z[:, i]))
        return jnp.stack(cols, axis=-1)

    # --- validation --------------------------------------------------------------------------
    def check(self, x, what: str = "value") -> np.ndarray:
        """Concrete x as float array; ValueError naming the parameter and its range if outside."""
        a = np.asarray(x, dtype=float)
        if a.shape[-1:] != (len(self),):
            raise ValueError(f"{what} must have {len(self)} entries ({', '.join(self.names)}), got shape {a.shape}")
        for i, p in enumerate(self.parameters):
            v = a[..., i]
            if np.any(~np.isfinite(v)) or np.any(v < p.lower) or np.any(v > p.upper):
                raise ValueError(f"{what} of {p.name} must lie in [{p.lower:g}, {p.upper:g}] {p.unit}".rstrip() + f", got {v!r}")
        return a

    def as_dict(self, x) -> dict[str, float]:
        a = np.asarray(x, dtype=float)
        return {n: float(a[i]) for i, n in enumerate(self.names)}

    def from_dict(self, values: Mapping[str, float]) -> np.ndarray:
        missing = [n for n in self.names if n not in values]
        if missing:
            raise ValueError(f"missing values for parameters {missing}")
        return np.array([float(values[n]) for n in self.names])

    def defaults(self) -> np.ndarray:
        return np.array([p.default for p in self.parameters], dtype=float)

    def center(self) -> np.ndarray:
        """The mid-point of each parameter's (linear or log) range."""
        return np.asarray(self.from_unit(np.full(len(self), 0.5)))


def make_spec(names: Sequence[str], bounds: Mapping[str, tuple[float, float]] | None = None) -> ParameterSpec:
    """A `ParameterSpec` of registered parameters, optionally with overridden bounds.

    Arguments:
        names: registered parameter names (see `PARAMETERS`).
        bounds: optional `{name: (lower, upper)}` overrides.
    """
    bounds = dict(bounds or {})
    unknown = set(bounds) - set(names)
    if unknown:
        raise ValueError(f"bounds given for parameters that are not free: {sorted(unknown)}")
    return ParameterSpec([get_parameter(n).with_bounds(*bounds[n]) if n in bounds else get_parameter(n) for n in names])
