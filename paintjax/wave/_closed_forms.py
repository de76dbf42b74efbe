"""Closed-form references for the wave solver: first-order perturbation theory and Kirchhoff.

Both are ensemble averages for a Gaussian-correlated surface, C(x) = σ² exp(−x²/τ²), with the
spectrum W(K) = σ²τ/(2√π) exp(−K²τ²/4) (∫W dK = σ²), in the normalisation of the solver
(∫σ dθ_s = reflected fraction, θ_s > 0 on the specular side, K = k(sinθ_s − sinθ_i)).

* SPM, first order (valid for kσ ≪ 1, small slopes), incoherent part:
  Dirichlet σ = 4k³ cosθ_i cos²θ_s W(K); Neumann σ = 4k³ (1 − sinθ_i sinθ_s)² W(K) / cosθ_i.
* Kirchhoff (tangent plane, stationary phase; kτ ≳ 6, moderate slopes), incoherent part:
  σ = |r(α)|² (1 + cos(θ_i+θ_s))² (k³/cosθ_i) e^{−k²σ²c²} Σ_m [(kσc)^{2m}/m!] /(kc)² τ/(2√(πm))
  e^{−K²τ²/(4m)}, c = cosθ_i + cosθ_s, where r(α) is the Fresnel coefficient of the metal at the
  local (facet) incidence angle α = (θ_i + θ_s)/2 (|r| = 1 for a perfect conductor). The coherent
  (specular) fraction is |r(θ_i)|² exp(−4k²σ²cos²θ_i).
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
from jax.scipy.special import gammaln
from jaxtyping import Array, ArrayLike, Float

from ..optics._aluminium import aluminium_index
from ..optics._fresnel import fresnel_conductor


def _wavenumber(wavelength_um: float, n_medium: float) -> float:
    if not (np.isfinite(wavelength_um) and wavelength_um > 0):
        raise ValueError(f"wavelength_um must be finite and > 0, got {wavelength_um!r}")
    if not (np.isfinite(n_medium) and n_medium > 0):
        raise ValueError(f"n_medium must be finite and > 0, got {n_medium!r}")
    return 2.0 * math.pi * n_medium / wavelength_um


def _angles(incidence_deg, theta_s_deg):
    ti = jnp.radians(jnp.asarray(incidence_deg, dtype=jnp.result_type(float)))[..., :, None]
    ts = jnp.radians(jnp.asarray(theta_s_deg, dtype=jnp.result_type(float)))[..., None, :]
    return ti, ts


def gaussian_spectrum(K, sigma_um: float, tau_um: float):
    """W(K) = σ²τ/(2√π) exp(−K²τ²/4) [µm³]."""
    return sigma_um**2 * tau_um / (2.0 * math.sqrt(math.pi)) * jnp.exp(-(K**2) * tau_um**2 / 4.0)


def spm_sigma(
    incidence_deg: ArrayLike, theta_s_deg: ArrayLike, sigma_um: float, tau_um: float, *,
    wavelength_um: float = 0.5, n_medium: float = 1.5, boundary: str = "dirichlet",
) -> Float[Array, "I S"]:
    """First-order small-perturbation incoherent σ(θ_s) [1/rad], shape (I, S).

    Arguments:
        incidence_deg (I,), theta_s_deg (S,): angles in degrees.
        sigma_um, tau_um: Gaussian roughness statistics.
        boundary: "dirichlet" (PEC TE) or "neumann" (PEC TM).
    """
    k = _wavenumber(wavelength_um, n_medium)
    ti, ts = _angles(incidence_deg, theta_s_deg)
    W = gaussian_spectrum(k * (jnp.sin(ts) - jnp.sin(ti)), sigma_um, tau_um)
    if boundary == "dirichlet":
        return 4.0 * k**3 * jnp.cos(ti) * jnp.cos(ts) ** 2 * W
    if boundary == "neumann":
        return 4.0 * k**3 * (1.0 - jnp.sin(ti) * jnp.sin(ts)) ** 2 * W / jnp.cos(ti)
    raise ValueError(f"boundary must be 'dirichlet' or 'neumann' for first-order SPM, got {boundary!r}")


def metal_reflectance(cos_local, polarization: str, metal_index=None, wavelength_um: float = 0.5, n_medium: float = 1.5):
    """|r|² of the metal in the binder at the local incidence cosine (TE, TM or their mean)."""
    m = aluminium_index(wavelength_um) if metal_index is None else metal_index
    rs, rp, ru = fresnel_conductor(cos_local, n_medium, m)
    table = {"te": rs, "tm": rp, "unpolarized": ru}
    if polarization not in table:
        raise ValueError(f"polarization must be one of {tuple(table)}, got {polarization!r}")
    return table[polarization]


def kirchhoff_sigma(
    incidence_deg: ArrayLike, theta_s_deg: ArrayLike, sigma_um: float, tau_um: float, *,
    wavelength_um: float = 0.5, n_medium: float = 1.5, boundary: str = "pec",
    polarization: str = "unpolarized", metal_index=None,
) -> Float[Array, "I S"]:
    """Kirchhoff (stationary-phase) incoherent σ(θ_s) [1/rad] of a Gaussian surface, shape (I, S).

    Arguments:
        incidence_deg (I,), theta_s_deg (S,): angles in degrees.
        sigma_um, tau_um: Gaussian roughness statistics.
        boundary: "pec" (|r| = 1) or "impedance" (Fresnel of the metal at the facet angle).
        polarization: for the metal Fresnel factor: "te", "tm" or "unpolarized".
        metal_index: complex metal index (default aluminium at λ0).
    """
    if boundary not in ("pec", "dirichlet", "neumann", "impedance"):
        raise ValueError(f"boundary must be 'pec', 'dirichlet', 'neumann' or 'impedance', got {boundary!r}")
    k = _wavenumber(wavelength_um, n_medium)
    ti, ts = _angles(incidence_deg, theta_s_deg)
    c = jnp.cos(ti) + jnp.cos(ts)
    x = (k * sigma_um * c) ** 2
    xmax = float(np.max(np.asarray(x)))
    mmax = int(max(40, xmax + 12.0 * math.sqrt(xmax) + 20))
    m = jnp.arange(1, mmax + 1, dtype=x.dtype)[:, None, None]
    K = k * (jnp.sin(ts) - jnp.sin(ti))
    logp = -x + m * jnp.log(jnp.maximum(x, 1e-300)) - gammaln(m + 1.0)  # Poisson weights
    terms = jnp.exp(logp) * tau_um / (2.0 * jnp.sqrt(jnp.pi * m)) * jnp.exp(-(K**2) * tau_um**2 / (4.0 * m))
    series = jnp.sum(terms, axis=0)
    sig = (1.0 + jnp.cos(ti + ts)) ** 2 * k**3 / jnp.cos(ti) * series / (k * c) ** 2
    if boundary == "impedance":
        sig = sig * metal_reflectance(jnp.cos(0.5 * (ti + ts)), polarization, metal_index, wavelength_um, n_medium)
    return sig


def kirchhoff_coherent_fraction(
    incidence_deg: ArrayLike, sigma_um: float, *, wavelength_um: float = 0.5, n_medium: float = 1.5,
    boundary: str = "pec", polarization: str = "unpolarized", metal_index=None,
) -> Float[Array, " I"]:
    """Coherent (specular) reflected fraction |r(θ_i)|² exp(−4k²σ²cos²θ_i)."""
    k = _wavenumber(wavelength_um, n_medium)
    ti = jnp.radians(jnp.asarray(incidence_deg, dtype=jnp.result_type(float)))
    f = jnp.exp(-4.0 * k**2 * sigma_um**2 * jnp.cos(ti) ** 2)
    if boundary == "impedance":
        f = f * metal_reflectance(jnp.cos(ti), polarization, metal_index, wavelength_um, n_medium)
    return f


def spm_sigma_realisation(profiles, incidence_deg: ArrayLike, theta_s_deg: ArrayLike, *, wavelength_um: float = 0.5,
                          n_medium: float = 1.5, boundary: str = "dirichlet", taper_um: float | None = None) -> Float[Array, "B I S"]:
    """First-order SPM σ(θ_s) of each given profile under the solver's tapered beam, (B, I, S).

    The deterministic counterpart of `spm_sigma`: ψ_s^N = 4k² F ∫ h(x) ψ_inc(x, 0) e^{−ik sinθ_s x} dx with
    F = cosθ_i cosθ_s (Dirichlet) or 1 − sinθ_i sinθ_s (Neumann), normalised like the solver. Its
    ensemble mean is `spm_sigma`; away from the specular beam it is the solver's σ to O((kσ)²).
    """
    from ._beam import incident_field, incident_power

    k = _wavenumber(wavelength_um, n_medium)
    length = profiles.x.shape[0] * profiles.spacing
    g = length / 4.0 if taper_um is None else taper_um
    ti = jnp.radians(jnp.asarray(incidence_deg, dtype=jnp.result_type(float)))
    ts = jnp.radians(jnp.asarray(theta_s_deg, dtype=jnp.result_type(float)))
    x = profiles.x
    inc0 = incident_field(x, jnp.zeros_like(x), ti, k, g)  # (N, I)
    phase = jnp.exp(-1j * k * jnp.sin(ts)[:, None] * x[None, :])  # (S, N)
    integral = jnp.einsum("bn,ni,sn->bis", profiles.h, inc0, phase) * profiles.spacing
    if boundary == "dirichlet":
        F = jnp.cos(ti)[:, None] * jnp.cos(ts)[None, :]
    elif boundary == "neumann":
        F = 1.0 - jnp.sin(ti)[:, None] * jnp.sin(ts)[None, :]
    else:
        raise ValueError(f"boundary must be 'dirichlet' or 'neumann' for first-order SPM, got {boundary!r}")
    amp = 4.0 * k**2 * F * integral
    return jnp.abs(amp) ** 2 / (8.0 * jnp.pi * k * incident_power(ti, k, g))[:, None]
