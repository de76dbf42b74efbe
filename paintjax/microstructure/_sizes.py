"""Platelet size (square edge width) distributions.

The *width* of a platelet is the edge length of its square face, in µm; a size analysis'
"diameter" is taken as that width. Every distribution has a bounded support
[`min_width`, `max_width`] (the default tile and the tile check use `max_width`) and is
sampled by inverse-CDF interpolation on a dense table, like `GammaTilt`.

* `LogNormalSizes`: log-normal number distribution of widths, truncated at ±`truncation`
  standard deviations of ln w (default ±3σ, 99.73 % of the mass). The default,
  `default_sizes()`, has D50 = 16 µm and σ fitted to D10 = 8 µm, D90 = 30 µm (least squares
  in ln w: D10 ≈ 8.3 µm, D90 ≈ 31.0 µm), support [3.4, 75.2] µm.
* `PolynomialCDFSizes`: a measured CDF fitted as a polynomial F(w) = Σ c_k w^k (increasing
  powers, w in µm) on [min_width, max_width].
* `TabulatedCDFSizes`: an empirical CDF tabulated at increasing widths, linear in between
  (uniform density inside each bin).

All parameters are validated on construction (concrete values); errors name the parameter.
"""

from __future__ import annotations

import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.special as sps
from jax.scipy.special import ndtr, ndtri
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray

_TABLE_POINTS = 4097
_Z90 = 1.2815515655446004  # standard normal 90 % quantile
#: Tolerance on the end values F(min_width) = 0, F(max_width) = 1 of a user CDF before it is
#: rescaled affinely to hit them exactly.
CDF_END_TOLERANCE = 0.02


def positive_finite(name: str, value, unit: str = "") -> float:
    """`value` as a float, or a ValueError naming `name` unless it is finite and > 0."""
    what = f"{name} must be a positive finite number{f' [{unit}]' if unit else ''}, got {value!r}"
    try:
        v = float(value)
    except (TypeError, ValueError) as err:
        raise ValueError(what) from err
    if not math.isfinite(v) or v <= 0:
        raise ValueError(what)
    return v


class SizeDistribution(eqx.Module):
    """Base class: a distribution of platelet widths [µm] on a bounded support.

    Subclasses provide `ppf` (inverse CDF) and `cdf`; sampling, quantiles and moments follow.
    """

    min_width: float = eqx.field(static=True)
    max_width: float = eqx.field(static=True)

    def cdf(self, width: ArrayLike) -> Float[Array, "..."]:  # pragma: no cover - abstract
        raise NotImplementedError

    def ppf(self, q: ArrayLike) -> Float[Array, "..."]:  # pragma: no cover - abstract
        raise NotImplementedError

    def ppf_np(self, q) -> np.ndarray:  # pragma: no cover - abstract
        """`ppf` in NumPy float64 (used by the array generator, free of JAX dispatch)."""
        raise NotImplementedError

    def sample(self, key: PRNGKeyArray, n: int) -> Float[Array, " n"]:
        """n independent widths [µm] (inverse-CDF sampling)."""
        return self.ppf(_uniform(key, n))

    def sample_np(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """n independent widths [µm] from a NumPy generator (inverse-CDF sampling, float64)."""
        return self.ppf_np(rng.random(n))

    def quantile(self, q: ArrayLike) -> Float[Array, "..."]:
        """Width below which a fraction q of the platelets (by number) lie; D50 = quantile(0.5)."""
        return self.ppf(q)

    def moment(self, k: int) -> float:
        """E[w^k] in µm^k, by the midpoint rule on the inverse CDF (65 536 nodes)."""
        u = (np.arange(65536) + 0.5) / 65536
        return float(np.mean(self.ppf_np(u) ** k))


class LogNormalSizes(SizeDistribution):
    """Log-normal widths: ln w ~ N(ln d50, sigma²), truncated at ±`truncation`·sigma.

    Arguments:
        d50: median width [µm], > 0.
        sigma: standard deviation of ln w, in (0, 3].
        truncation: half-width of the support in units of sigma, in [1, 8] (default 3).
    """

    d50: float = eqx.field(static=True)
    sigma: float = eqx.field(static=True)
    truncation: float = eqx.field(static=True)

    def __init__(self, d50: float = 16.0, sigma: float | None = None, truncation: float = 3.0):
        d50 = positive_finite("d50", d50)
        sigma = math.log(30.0 / 8.0) / (2 * _Z90) if sigma is None else sigma
        sigma = positive_finite("sigma", sigma)
        if sigma > 3.0:
            raise ValueError(f"sigma (of ln width) must lie in (0, 3], got {sigma!r}")
        truncation = positive_finite("truncation", truncation)
        if not 1.0 <= truncation <= 8.0:
            raise ValueError(f"truncation must lie in [1, 8] standard deviations, got {truncation!r}")
        self.d50, self.sigma, self.truncation = d50, sigma, truncation
        self.min_width = d50 * math.exp(-truncation * sigma)
        self.max_width = d50 * math.exp(truncation * sigma)

    @classmethod
    def from_quantiles(cls, d10: float, d50: float, d90: float, truncation: float = 3.0) -> "LogNormalSizes":
        """Log-normal with median `d50` and sigma fitted (least squares in ln w) to D10 and D90.

        Raises:
            ValueError: unless 0 < d10 < d50 < d90.
        """
        d10, d50, d90 = (positive_finite(n, v) for n, v in (("d10", d10), ("d50", d50), ("d90", d90)))
        if not d10 < d50 < d90:
            raise ValueError(f"size quantiles must satisfy d10 < d50 < d90, got d10={d10}, d50={d50}, d90={d90}")
        return cls(d50, math.log(d90 / d10) / (2 * _Z90), truncation)

    def ppf_np(self, q) -> np.ndarray:
        p_lo = float(sps.ndtr(-self.truncation))
        z = sps.ndtri(p_lo + (1.0 - 2.0 * p_lo) * np.asarray(q, dtype=float))
        return np.clip(self.d50 * np.exp(self.sigma * z), self.min_width, self.max_width)

    def _params(self):
        return tuple(float(v) for v in (self.d50, self.sigma, self.truncation, self.min_width, self.max_width))

    def cdf(self, width: ArrayLike) -> Float[Array, "..."]:
        return _lognormal_cdf(jnp.asarray(width, dtype=jnp.result_type(float)), *self._params())

    def ppf(self, q: ArrayLike) -> Float[Array, "..."]:
        return _lognormal_ppf(jnp.asarray(q, dtype=jnp.result_type(float)), *self._params())


@jax.jit
def _lognormal_cdf(w, d50, sigma, truncation, lo, hi):
    p_lo = ndtr(-truncation)
    w = jnp.clip(w, lo, hi)
    return jnp.clip((ndtr(jnp.log(w / d50) / sigma) - p_lo) / (1.0 - 2.0 * p_lo), 0.0, 1.0)


@jax.jit
def _lognormal_ppf(q, d50, sigma, truncation, lo, hi):
    p_lo = ndtr(-truncation)
    z = ndtri(p_lo + (1.0 - 2.0 * p_lo) * q)
    return jnp.clip(d50 * jnp.exp(sigma * z), lo, hi)


@functools.partial(jax.jit, static_argnums=1)
def _uniform(key, n):
    return jax.random.uniform(key, (n,), dtype=jnp.result_type(float))


def default_sizes() -> LogNormalSizes:
    """The default width law of the reference samples: log-normal, D50 16 µm, D10 ≈ 8, D90 ≈ 30."""
    return LogNormalSizes.from_quantiles(8.0, 16.0, 30.0)


class _TableSizes(SizeDistribution):
    """A CDF tabulated at increasing widths, linear in between (shared by the user-CDF laws)."""

    table_widths: Float[Array, " m"]
    table_cdf: Float[Array, " m"]

    def cdf(self, width: ArrayLike) -> Float[Array, "..."]:
        return _interp(jnp.asarray(width, dtype=self.table_widths.dtype), self.table_widths, self.table_cdf)

    def ppf_np(self, q) -> np.ndarray:
        return np.interp(np.asarray(q, dtype=float), np.asarray(self.table_cdf, float), np.asarray(self.table_widths, float))

    def ppf(self, q: ArrayLike) -> Float[Array, "..."]:
        return _interp(jnp.asarray(q, dtype=self.table_cdf.dtype), self.table_cdf, self.table_widths)


_interp = jax.jit(jnp.interp)


def _check_cdf_table(name: str, widths: np.ndarray, cdf: np.ndarray) -> np.ndarray:
    """Validate a tabulated CDF; returns it rescaled affinely to run exactly from 0 to 1."""
    if np.any(~np.isfinite(cdf)):
        raise ValueError(f"{name}: the CDF contains non-finite values")
    steps = np.diff(cdf)
    scale = max(float(np.max(np.abs(cdf))), 1.0)
    bad = np.flatnonzero(steps < -1e-12 * scale)
    if bad.size:
        i = int(bad[0])
        raise ValueError(
            f"{name}: the CDF must be non-decreasing, but it falls from {cdf[i]:.6g} at width {widths[i]:.6g} µm "
            f"to {cdf[i + 1]:.6g} at {widths[i + 1]:.6g} µm"
        )
    lo, hi = float(cdf[0]), float(cdf[-1])
    if abs(lo) > CDF_END_TOLERANCE or abs(hi - 1.0) > CDF_END_TOLERANCE:
        raise ValueError(
            f"{name}: the CDF must run from 0 at the smallest width to 1 at the largest "
            f"(tolerance {CDF_END_TOLERANCE}), got {lo:.6g} and {hi:.6g}"
        )
    if hi - lo <= 0:
        raise ValueError(f"{name}: the CDF is constant")
    return np.maximum.accumulate((cdf - lo) / (hi - lo))


class TabulatedCDFSizes(_TableSizes):
    """An empirical width CDF tabulated at increasing widths (linear interpolation in between).

    Arguments:
        widths: (m,) strictly increasing widths [µm], all > 0, m ≥ 2.
        cdf: (m,) non-decreasing CDF values from 0 (at widths[0]) to 1 (at widths[-1]); ends
            off by at most 0.02 are rescaled affinely to exactly 0 and 1.
    """

    def __init__(self, widths: ArrayLike, cdf: ArrayLike):
        w = np.asarray(widths, dtype=float).ravel()
        c = np.asarray(cdf, dtype=float).ravel()
        if w.size < 2 or w.shape != c.shape:
            raise ValueError(f"widths and cdf must be 1-D of equal length ≥ 2, got {w.shape} and {c.shape}")
        if np.any(~np.isfinite(w)) or np.any(w <= 0):
            raise ValueError("widths must be positive finite platelet sizes [µm]")
        if np.any(np.diff(w) <= 0):
            raise ValueError("widths must be strictly increasing")
        c = _check_cdf_table("cdf", w, c)
        self.table_widths = jnp.asarray(w)
        self.table_cdf = jnp.asarray(c)
        self.min_width, self.max_width = float(w[0]), float(w[-1])


class PolynomialCDFSizes(_TableSizes):
    """A width CDF given as a polynomial F(w) = Σ_k c_k w^k (increasing powers, w in µm).

    The polynomial must be non-decreasing on [min_width, max_width], with F(min_width) ≈ 0 and
    F(max_width) ≈ 1 (within 0.02; it is then rescaled affinely to hit both exactly). It is
    tabulated on 4097 points and sampled by inverse interpolation.

    Arguments:
        coefficients: c_0, c_1, ... (increasing powers), at least two.
        min_width, max_width: the support [µm], 0 < min_width < max_width.
    """

    coefficients: tuple[float, ...] = eqx.field(static=True)

    def __init__(self, coefficients, min_width: float, max_width: float):
        c = np.asarray(coefficients, dtype=float).ravel()
        if c.size < 2 or np.any(~np.isfinite(c)):
            raise ValueError(f"coefficients must be ≥ 2 finite numbers (increasing powers), got {coefficients!r}")
        lo = positive_finite("min_width", min_width)
        hi = positive_finite("max_width", max_width)
        if hi <= lo:
            raise ValueError(f"max_width must exceed min_width, got min_width={lo}, max_width={hi}")
        w = np.linspace(lo, hi, _TABLE_POINTS)
        F = np.polynomial.polynomial.polyval(w, c)
        self.coefficients = tuple(float(x) for x in c)
        F = _check_cdf_table("coefficients", w, F)
        self.table_widths = jnp.asarray(w)
        self.table_cdf = jnp.asarray(F)
        self.min_width, self.max_width = lo, hi


def as_size_distribution(sizes) -> SizeDistribution:
    """Coerce `sizes` (None → default log-normal, a SizeDistribution, or (d10, d50, d90))."""
    if sizes is None:
        return default_sizes()
    if isinstance(sizes, SizeDistribution):
        return sizes
    if isinstance(sizes, (tuple, list)) and len(sizes) == 3:
        return LogNormalSizes.from_quantiles(*sizes)
    raise ValueError(f"sizes must be a SizeDistribution, (d10, d50, d90) or None, got {sizes!r}")
