"""Rough platelet profiles: seeded synthesis, measured line scans, processing and statistics.

A profile is a height h(x) [µm] on a uniform grid. Synthesised profiles are periodic Gaussian
random processes with a Gaussian, C(x) = σ² exp(−x²/τ²), or exponential, C(x) = σ² exp(−|x|/τ),
autocorrelation (τ is the 1/e correlation length in both cases); their derivatives h', h'' come
from the same spectrum, so the wave solver sees a consistent surface. A Gaussian surface is smooth;
an exponential one is not differentiable: its slope and curvature variances diverge, so the
sampled profiles are rough down to the grid step and their rms slope grows with the sampling
(28° / 37° / 47° at 12 / 24 / 48 points per wavelength for σ = 51 nm, τ = 640 nm). Lobes from
exponential profiles are therefore not converged in the sampling; they show the trend of a
rougher short-scale surface, not a converged answer. Measured line scans
(two columns, x and height) are loaded in any length unit, resampled to a uniform grid, freed of
curvature by a Gaussian filter (cutoff 50 % of the scan length, ISO 16610-21 weighting, second-order
regression so that the ends are unbiased) and levelled
by their end points, as in the profilometry of the reference study.
"""

from __future__ import annotations

import os

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, PRNGKeyArray

CORRELATIONS = ("gaussian", "exponential")
UNITS_TO_UM = {"m": 1e6, "mm": 1e3, "um": 1.0, "µm": 1.0, "nm": 1e-3}
#: Minimum number of samples per 1/e correlation length accepted for a measured scan.
MIN_POINTS_PER_CORRELATION = 10


class Profiles(eqx.Module):
    """A batch of profiles on one uniform grid, with derivatives (lengths in µm).

    Attributes:
        x: grid abscissae, centred on 0, spacing `spacing`.
        h, dh, d2h: heights, slopes and curvatures h'' for each profile.
        spacing: grid step Δx (static).
        covariance: for synthesised profiles, the exact covariance of the generating process at
            lags 0, Δx, …, (N−1)Δx (periodic: Cov(h_n, h_m) = covariance[(n − m) mod N]); None for
            measured or hand-made profiles. The wave solver uses it for its Kirchhoff control variate.
    """

    x: Float[Array, " N"]
    h: Float[Array, "B N"]
    dh: Float[Array, "B N"]
    d2h: Float[Array, "B N"]
    spacing: float = eqx.field(static=True)
    covariance: Float[Array, " N"] | None = None

    @property
    def num_profiles(self) -> int:
        return int(self.h.shape[0])

    @property
    def length(self) -> float:
        return float(self.x.shape[0] * self.spacing)


def _check_positive(name: str, value, upper: float | None = None) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}") from None
    if not np.isfinite(v) or v <= 0 or (upper is not None and v > upper):
        rng = f"(0, {upper}]" if upper is not None else "> 0"
        raise ValueError(f"{name} must be finite and {rng} µm, got {value!r}")
    return v


def spectrum(k: Float[Array, "..."], sigma_um: float, tau_um: float, correlation: str = "gaussian") -> Float[Array, "..."]:
    """One-sided-normalised power spectrum W(K) with ∫ W dK over all K = σ² [µm³].

    Gaussian: W = σ²τ/(2√π) exp(−K²τ²/4). Exponential: W = σ²τ/(π(1 + K²τ²)).
    """
    if correlation == "gaussian":
        return sigma_um**2 * tau_um / (2.0 * jnp.sqrt(jnp.pi)) * jnp.exp(-(k**2) * tau_um**2 / 4.0)
    if correlation == "exponential":
        return sigma_um**2 * tau_um / (jnp.pi * (1.0 + k**2 * tau_um**2))
    raise ValueError(f"correlation must be one of {CORRELATIONS}, got {correlation!r}")


def grid(length_um: float, spacing_um: float) -> tuple[np.ndarray, float]:
    """Uniform grid of ⌈L/Δx⌉ (even) points centred on 0; returns (x, Δx adjusted to fit L)."""
    n = int(np.ceil(length_um / spacing_um))
    n += n % 2
    dx = length_um / n
    return (np.arange(n) - (n - 1) / 2.0) * dx, dx


def synthesize_profiles(
    key: PRNGKeyArray,
    sigma_um: float,
    tau_um: float,
    *,
    length_um: float,
    spacing_um: float,
    num_profiles: int = 1,
    correlation: str = "gaussian",
) -> Profiles:
    """Seeded periodic Gaussian random profiles with the requested statistics (FFT synthesis).

    Arguments:
        key: jax.random key (all randomness comes from it).
        sigma_um: RMS height σ > 0 [µm].
        tau_um: 1/e correlation length τ > 0 [µm].
        length_um: profile length L [µm]; must exceed 4τ.
        spacing_um: requested grid step (adjusted so that an even number of steps fills L).
        num_profiles: number of independent realisations B ≥ 1.
        correlation: "gaussian" or "exponential".

    Returns:
        `Profiles` with h, h', h'' evaluated spectrally (exact for the synthesised process).
    """
    sigma_um = _check_positive("sigma_um", sigma_um)
    tau_um = _check_positive("tau_um", tau_um)
    length_um = _check_positive("length_um", length_um)
    spacing_um = _check_positive("spacing_um", spacing_um)
    if correlation not in CORRELATIONS:
        raise ValueError(f"correlation must be one of {CORRELATIONS}, got {correlation!r}")
    if int(num_profiles) != num_profiles or num_profiles < 1:
        raise ValueError(f"num_profiles must be an integer ≥ 1, got {num_profiles!r}")
    if length_um < 4.0 * tau_um:
        raise ValueError(f"length_um must be ≥ 4·tau_um = {4 * tau_um} µm, got {length_um!r}")
    if spacing_um > tau_um / 2.0:
        raise ValueError(f"spacing_um must be ≤ tau_um/2 = {tau_um / 2} µm to resolve the roughness, got {spacing_um!r}")
    x, dx = grid(length_um, spacing_um)
    n = x.shape[0]
    kk = 2.0 * jnp.pi * jnp.fft.rfftfreq(n, d=dx)
    amp = jnp.sqrt(2.0 * jnp.pi * spectrum(kk, sigma_um, tau_um, correlation) / dx)
    noise = jax.random.normal(key, (int(num_profiles), n), dtype=jnp.result_type(float))
    z = jnp.fft.rfft(noise, axis=-1) * amp
    h = jnp.fft.irfft(z, n=n, axis=-1)
    dh = jnp.fft.irfft(1j * kk * z, n=n, axis=-1)
    d2h = jnp.fft.irfft(-(kk**2) * z, n=n, axis=-1)
    covariance = jnp.fft.irfft(amp**2, n=n)  # circulant covariance with eigenvalues amp²
    return Profiles(jnp.asarray(x), h, dh, d2h, float(dx), covariance)


def autocorrelation(h) -> np.ndarray:
    """Biased autocorrelation estimate (about the mean) at lags 0, Δx, 2Δx, … (non-periodic).

    NumPy on the host: measured scans come in every length, and a JAX FFT would compile per length.
    """
    h = np.asarray(h, dtype=float)
    n = h.shape[-1]
    f = np.fft.rfft(h - h.mean(axis=-1, keepdims=True), n=2 * n, axis=-1)
    return np.fft.irfft(np.abs(f) ** 2, n=2 * n, axis=-1)[..., :n] / n


def profile_statistics(h, spacing_um: float) -> dict:
    """σ_RMS (about the mean) and the 1/e autocorrelation length τ of one or more profiles.

    Arguments:
        h: heights [µm], shape (N,) or (B, N).
        spacing_um: uniform grid step.

    Returns:
        dict with "sigma_um" and "tau_um" (arrays of shape h.shape[:-1]); τ is interpolated linearly
        between the lags that bracket C(τ)/C(0) = 1/e.
    """
    h = np.asarray(h, dtype=float)
    if not np.all(np.isfinite(h)):
        raise ValueError("h must be finite (no NaN or inf heights)")
    c = autocorrelation(h)
    sig = np.sqrt(c[..., 0])
    rho = c / c[..., :1]
    below = rho < np.exp(-1.0)
    if not np.all(np.any(below, axis=-1)):
        raise ValueError("profile too short: its autocorrelation never falls below 1/e")
    i = np.argmax(below, axis=-1)
    r0 = np.take_along_axis(rho, (i - 1)[..., None], -1)[..., 0]
    r1 = np.take_along_axis(rho, i[..., None], -1)[..., 0]
    tau = spacing_um * ((i - 1) + (r0 - np.exp(-1.0)) / (r0 - r1))
    return {"sigma_um": sig, "tau_um": tau}


# ----------------------------------------------------------------------------- measured line scans


class LineScan(eqx.Module):
    """A measured (or any given) line scan in µm: strictly increasing x, finite heights."""

    x: np.ndarray
    h: np.ndarray


def _validate_scan(x, h) -> tuple[np.ndarray, np.ndarray]:
    x = np.asarray(x, dtype=float)
    h = np.asarray(h, dtype=float)
    if x.ndim != 1 or h.shape != x.shape:
        raise ValueError(f"x and h must be 1-D of equal length, got shapes {x.shape} and {h.shape}")
    if x.size < 16:
        raise ValueError(f"a line scan needs at least 16 points, got {x.size}")
    if np.any(np.isnan(x)) or np.any(np.isnan(h)):
        raise ValueError(f"line scan contains NaN values ({int(np.isnan(x).sum() + np.isnan(h).sum())} of them); clean or drop them first")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(h))):
        raise ValueError("line scan contains infinite values")
    d = np.diff(x)
    if np.all(d < 0):
        x, h, d = x[::-1], h[::-1], -d[::-1]
    if not np.all(d > 0):
        raise ValueError("x must be strictly monotonic (no repeated or back-tracking abscissae)")
    return x, h


def load_line_scan(path: str | os.PathLike, *, units: str = "um") -> LineScan:
    """Load a two-column text/CSV line scan (x, height; header lines and extra columns ignored).

    Arguments:
        path: file with whitespace-, comma- or semicolon-separated columns.
        units: length unit of both columns: "m", "mm", "um" (or "µm") or "nm".

    Returns:
        `LineScan` in µm (reversed if x was decreasing).
    """
    if units not in UNITS_TO_UM:
        raise ValueError(f"units must be one of {sorted(UNITS_TO_UM)}, got {units!r}")
    if os.path.isdir(path):
        raise ValueError(f"profile must be a two-column text file, but {os.fspath(path)!r} is a folder")
    if not os.path.isfile(path):
        raise ValueError(f"profile file not found: {os.fspath(path)!r}")
    rows = []
    with open(path, encoding="utf-8") as fh:
        for line in fh:
            parts = line.replace(",", " ").replace(";", " ").replace("\t", " ").split()
            if not parts or parts[0].startswith("#"):
                continue
            try:
                vals = [float(p) for p in parts[:2]]
            except ValueError:
                if rows:
                    raise ValueError(f"{path}: non-numeric row after data: {line.strip()!r}") from None
                continue  # header
            if len(vals) < 2:
                raise ValueError(f"{path}: every row needs two columns (x, height), got {line.strip()!r}")
            rows.append(vals)
    if not rows:
        raise ValueError(f"{path}: no numeric rows found")
    a = np.asarray(rows) * UNITS_TO_UM[units]
    x, h = _validate_scan(a[:, 0], a[:, 1])
    return LineScan(x, h)


def gaussian_filter_mean_line(x: np.ndarray, h: np.ndarray, cutoff_um: float, order: int = 2) -> np.ndarray:
    """Gaussian mean line with cutoff λc (50 % transmission of a sine of wavelength λc).

    Weights s(t) = exp(−π(t/(αλc))²), α = √(ln2/π) (ISO 16610-21). With `order` = 0 this is the
    plain weighted average (renormalised inside the scan at the ends); with `order` = 2 (default)
    it is the Gaussian regression filter (ISO 16610-31 style): a weighted local quadratic fit,
    which reproduces a parabolic bow exactly, ends included — what curvature removal needs.
    """
    if order not in (0, 1, 2):
        raise ValueError(f"order must be 0, 1 or 2, got {order!r}")
    alpha = np.sqrt(np.log(2.0) / np.pi)
    t = x[None, :] - x[:, None]
    w = np.exp(-np.pi * (t / (alpha * cutoff_um)) ** 2)
    if order == 0:
        return (w @ h) / w.sum(axis=1)
    ts = t / cutoff_um
    basis = np.stack([ts**j for j in range(order + 1)], axis=-1)  # (n, n, p)
    a = np.einsum("ij,ijp,ijq->ipq", w, basis, basis)
    b = np.einsum("ij,ijp,j->ip", w, basis, h)
    return np.linalg.solve(a, b[..., None])[:, 0, 0]


def process_line_scan(
    scan: LineScan, *, cutoff_fraction: float = 0.5, spacing_um: float | None = None, check_tau: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """The measured-platelet processing: uniform resampling, curvature removal, end-point levelling.

    Arguments:
        scan: the raw scan (µm).
        cutoff_fraction: Gaussian-filter cutoff as a fraction of the scan length, in (0, 1].
        spacing_um: uniform step (default: the median spacing of the scan).
        check_tau: reject scans with fewer than 10 points per correlation length.

    Returns:
        (x, h) on the uniform grid, with x starting at 0 and h levelled so that both ends are 0.
    """
    if not (0.0 < cutoff_fraction <= 1.0):
        raise ValueError(f"cutoff_fraction must lie in (0, 1], got {cutoff_fraction!r}")
    x, h = _validate_scan(scan.x, scan.h)
    raw_step = float(np.median(np.diff(x)))
    step = raw_step if spacing_um is None else _check_positive("spacing_um", spacing_um)
    length = x[-1] - x[0]
    n = int(np.floor(length / step + 1e-9)) + 1
    xu = x[0] + step * np.arange(n)
    from scipy.interpolate import CubicSpline

    hu = CubicSpline(x, h)(xu)
    rough = hu - gaussian_filter_mean_line(xu, hu, cutoff_fraction * length)
    rough = rough - (rough[0] + (rough[-1] - rough[0]) * (xu - xu[0]) / (xu[-1] - xu[0]))
    if check_tau:
        tau = float(profile_statistics(rough, step)["tau_um"])
        if tau / raw_step < MIN_POINTS_PER_CORRELATION:
            raise ValueError(
                f"line scan undersampled: {tau / raw_step:.1f} points per correlation length "
                f"(τ = {tau:.4g} µm, spacing {raw_step:.4g} µm); need ≥ {MIN_POINTS_PER_CORRELATION}"
            )
    return xu - xu[0], rough


def profiles_from_heights(x: np.ndarray, h: np.ndarray, spacing_um: float) -> Profiles:
    """Resample one given profile (µm) onto a centred uniform grid of step ≈ spacing_um (cubic spline).

    The spline's first and second derivatives give h' and h''. The profile is used as given
    (no filtering); call `process_line_scan` first for measured data.
    """
    from scipy.interpolate import CubicSpline

    x, h = _validate_scan(x, h)
    spacing_um = _check_positive("spacing_um", spacing_um)
    length = float(x[-1] - x[0])
    xg, dx = grid(length, spacing_um)
    spline = CubicSpline(x - x[0] - length / 2.0, h)
    xs = np.clip(xg, -length / 2.0, length / 2.0)
    return Profiles(
        jnp.asarray(xg),
        jnp.asarray(spline(xs))[None],
        jnp.asarray(spline(xs, 1))[None],
        jnp.asarray(spline(xs, 2))[None],
        float(dx),
    )
