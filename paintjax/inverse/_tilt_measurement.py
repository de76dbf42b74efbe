"""A virtual orientation measurement: what a gamma fit to a finite count of measured platelet tilts reads.

The published tilt laws (shape 2.29 ± 0.05, scale 2.18 ± 0.03° for Silver #1) come from fitting a
gamma law to the tilts of the platelets a microscope measured. Two things decide how far such a fit
can be trusted: how many platelets were measured (the sampling of a finite count), and whether the
measurement sees true tilts (the platelet normal in 3-D) or apparent ones (the trace of the platelet
in a cross-section, tan θ_app = tan θ |cos φ| for a platelet whose tilt direction makes the angle φ
with the section plane). `tilt_fit_distribution` simulates both; `gamma_fit_sd` is the closed-form
(Fisher) sampling SD of a maximum-likelihood gamma fit of true tilts, its large-count check, and
`platelets_for_sd` inverts it: how many platelets a published ± implies if it is sampling alone.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
from jax.scipy.special import polygamma
from scipy import stats

from ..microstructure._tilt import check_gamma_parameters


def apparent_tilt_deg(tilt_deg, section_azimuth_rad):
    """The tilt a cross-section shows: tan θ_app = tan θ |cos φ|, φ = tilt direction − section plane."""
    return np.degrees(np.arctan(np.tan(np.radians(tilt_deg)) * np.abs(np.cos(section_azimuth_rad))))


def fit_gamma(tilts_deg) -> tuple[float, float]:
    """Maximum-likelihood gamma (shape, scale [°]) of measured tilts (location fixed at 0)."""
    t = np.asarray(tilts_deg, float)
    if t.ndim != 1 or t.size < 3 or not np.all(np.isfinite(t)) or np.any(t <= 0):
        raise ValueError(f"tilts_deg must hold at least 3 finite positive tilts, got {t.size} values")
    k, _, theta = stats.gamma.fit(t, floc=0.0)
    return float(k), float(theta)


def gamma_fit_moments(shape, scale, num_platelets):
    """Asymptotic (SD of k̂, SD of θ̂, their correlation) of a maximum-likelihood gamma fit to
    `num_platelets` true tilts (arrays, jittable).

    Fisher information per tilt: [[ψ'(k), 1/θ], [1/θ, k/θ²]], so var k̂ = k / (n (k ψ'(k) − 1)) and
    var θ̂ = θ² ψ'(k) / (n (k ψ'(k) − 1)); corr = −1/√(k ψ'(k)).
    """
    k, th, n = jnp.asarray(shape), jnp.asarray(scale), float(num_platelets)
    t = polygamma(1, k)
    d = k * t - 1.0
    return jnp.sqrt(k / (n * d)), jnp.sqrt(th**2 * t / (n * d)), -1.0 / jnp.sqrt(k * t)


def gamma_fit_sd(shape: float, scale: float, num_platelets: int) -> tuple[float, float, float]:
    """`gamma_fit_moments` for one validated law and count, as floats."""
    check_gamma_parameters(shape, scale)
    if int(num_platelets) != num_platelets or num_platelets < 2:
        raise ValueError(f"num_platelets must be an integer ≥ 2, got {num_platelets!r}")
    return tuple(float(v) for v in gamma_fit_moments(float(shape), float(scale), int(num_platelets)))


def platelets_for_sd(shape: float, scale: float, sd: float, parameter: str = "shape") -> int:
    """The count of true tilts whose gamma fit has the SD `sd` in `parameter` ("shape" or "scale"), sampling alone."""
    if parameter not in ("shape", "scale"):
        raise ValueError(f"parameter must be 'shape' or 'scale', got {parameter!r}")
    one = gamma_fit_sd(shape, scale, 2)[0 if parameter == "shape" else 1] * math.sqrt(2.0)  # SD for one platelet
    return int(math.ceil((one / float(sd)) ** 2))


def tilt_fit_distribution(seed: int, shape: float, scale: float, num_platelets: int, *, section: bool = False,
                          replicates: int = 200) -> dict:
    """Sampling distribution of the gamma fit to `num_platelets` measured tilts drawn from a true law.

    Arguments:
        seed: seed of the NumPy generator (all randomness comes from it).
        shape, scale: the true gamma law (scale in degrees).
        num_platelets: platelets measured per study.
        section: fit apparent tilts seen in cross-sections (random section azimuths) instead of true ones.
        replicates: independent studies simulated.

    Returns:
        dict with the fitted "shape" and "scale" per replicate, their means, SDs and correlation.
    """
    check_gamma_parameters(shape, scale)
    if int(num_platelets) != num_platelets or not 3 <= num_platelets <= 1_000_000:
        raise ValueError(f"num_platelets must be an integer in [3, 1000000], got {num_platelets!r}")
    if int(replicates) != replicates or replicates < 2:
        raise ValueError(f"replicates must be an integer ≥ 2, got {replicates!r}")
    rng = np.random.default_rng(seed)
    fits = []
    for _ in range(int(replicates)):
        t = stats.gamma.rvs(shape, scale=scale, size=int(num_platelets), random_state=rng)
        t = np.minimum(t, 89.9)
        if section:
            t = apparent_tilt_deg(t, rng.uniform(0.0, 2.0 * np.pi, t.size))
            t = np.maximum(t, 1e-6)
        fits.append(fit_gamma(t))
    k, th = np.array(fits).T
    return {"shape": k, "scale": th, "shape_mean": float(k.mean()), "shape_sd": float(k.std(ddof=1)),
            "scale_mean": float(th.mean()), "scale_sd": float(th.std(ddof=1)), "correlation": float(np.corrcoef(k, th)[0, 1])}
