"""He–Torrance–Sillion–Greenberg (1991) BRDF of a rough metal: specular + directional-diffuse terms.

X. D. He, K. E. Torrance, F. X. Sillion, D. P. Greenberg, "A comprehensive physical model for
light reflection", Computer Graphics 25(4) (SIGGRAPH 1991) 175–186. For a metal the uniform
(subsurface) diffuse term is zero and is omitted. In the notation of `paintjax.brdf._analytic`
(k = 2πn/λ0 in the medium, c = cosθ_i + cosθ_o, v = k(ω_i + ω_o), v_xy = kρ):

    ρ_dd = |F(χ)|²/π · G S D / (cosθ_i cosθ_o),   G = (|v̂|²/v̂_z)² = 16cos⁴χ / c²,
    D = (π²τ²/(4λ²)) Σ_{m≥1} g^m e^{−g} / (m! m) · e^{−v_xy² τ² / (4m)},   g = (kσ_eff c)²,
    ρ_s (specular, coherent) = |F(θ_i)|² e^{−g(θ_i, θ_i)} S(θ_i)²,

with the shadowing–masking S = S(θ_i) S(θ_o), S(θ) = [1 − ½ erfc(a)] / [Λ(a) + 1],
Λ(a) = ½[e^{−a²}/(a√π) − erfc(a)], a = τ cotθ / (2σ), and the effective roughness
σ_eff = σ / √(1 + z₀²/σ²), √(π/2) z₀ = (σ/4)(K_i + K_o) e^{−z₀²/(2σ²)}, K = tanθ erfc(a).
The directional-diffuse term is thus the Kirchhoff lobe of `BeckmannBRDF` with σ → σ_eff and
multiplied by S; both are reciprocal. Unpolarised (|F|² = mean of the s and p reflectances).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import erfc

from ._analytic import (
    AbstractGaussianMetalBRDF,
    kirchhoff_geometry,
    kirchhoff_series,
)


def _a(mu, sigma_um, tau_um):
    mu = jnp.clip(mu, 1e-12, 1.0)
    sin = jnp.sqrt(jnp.maximum(1.0 - mu**2, 1e-300))
    return tau_um * mu / (2.0 * sigma_um * sin), sin / mu


def shadowing(mu, sigma_um, tau_um):
    """One-direction shadowing factor S(θ) of He et al. (Smith form for Gaussian slopes)."""
    a, _ = _a(jnp.asarray(mu), sigma_um, tau_um)
    lam = 0.5 * (jnp.exp(-(a**2)) / (a * np.sqrt(np.pi)) - erfc(a))
    return (1.0 - 0.5 * erfc(a)) / (lam + 1.0)


def effective_roughness(mu_i, mu_o, sigma_um, tau_um, iterations: int = 60):
    """σ_eff(θ_i, θ_o) [µm] of He et al. (bisection on the monotone z₀ equation)."""
    a_i, t_i = _a(jnp.asarray(mu_i), sigma_um, tau_um)
    a_o, t_o = _a(jnp.asarray(mu_o), sigma_um, tau_um)
    K = t_i * erfc(a_i) + t_o * erfc(a_o)
    rhs = lambda z: np.sqrt(np.pi / 2.0) * z - 0.25 * sigma_um * K * jnp.exp(-(z**2) / (2.0 * sigma_um**2))  # noqa: E731
    lo = jnp.zeros_like(K)
    hi = 0.25 * sigma_um * K / np.sqrt(np.pi / 2.0) + 1e-12

    def body(_, bounds):
        lo, hi = bounds
        mid = 0.5 * (lo + hi)
        pos = rhs(mid) > 0
        return jnp.where(pos, lo, mid), jnp.where(pos, mid, hi)

    lo, hi = jax.lax.fori_loop(0, iterations, body, (lo, hi))
    z0 = 0.5 * (lo + hi)
    return sigma_um / jnp.sqrt(1.0 + (z0 / sigma_um) ** 2)


class HeTorranceBRDF(AbstractGaussianMetalBRDF):
    """He–Torrance (1991) BRDF of a Gaussian metal surface: specular + directional diffuse.

    Arguments:
        sigma_um: rms height σ [µm]; tau_um: correlation length τ [µm].
        wavelength_um: vacuum wavelength [µm]; n_medium: index of the medium above the metal.
        metal_index: complex metal index (default aluminium at λ0).
        coherent: the specular term as "lobe" (default, platelet diffraction lobe) or "delta".
        platelet_width_um, coherent_width: width of the coherent lobe (see `paintjax.brdf._analytic`).
    """

    def incoherent(self, wi, wo):
        ci, co = wi[..., 2], wo[..., 2]
        up = (ci > 0) & (co > 0)
        ci_s, co_s = jnp.where(up, ci, 1.0), jnp.where(up, co, 1.0)
        s_eff = effective_roughness(ci_s, co_s, self.sigma_um, self.tau_um)
        cos_chi, c, _, q2tau2, pre = kirchhoff_geometry(wi, wo, self.k, self.sigma_um, self.tau_um)
        X = (self.k * s_eff * c) ** 2
        S = shadowing(ci_s, self.sigma_um, self.tau_um) * shadowing(co_s, self.sigma_um, self.tau_um)
        f = self.fresnel(cos_chi) * pre * kirchhoff_series(X, q2tau2, self.num_terms) * S
        return jnp.where(up, f, 0.0)

    def coherent_reflectance(self, cos_i):
        mu = jnp.clip(jnp.asarray(cos_i), 1e-12, 1.0)
        s_eff = effective_roughness(mu, mu, self.sigma_um, self.tau_um)
        g = (2.0 * self.k * s_eff * mu) ** 2
        return self.fresnel(mu) * jnp.exp(-g) * shadowing(mu, self.sigma_um, self.tau_um) ** 2

    def coherent_share(self, cos_i):
        mu = jnp.clip(jnp.asarray(cos_i), 1e-12, 1.0)
        s_eff = effective_roughness(mu, mu, self.sigma_um, self.tau_um)
        return jnp.exp(-((2.0 * self.k * s_eff * mu) ** 2))
