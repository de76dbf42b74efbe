"""The incident Thorsos beam: its field, gradient and power on a profile, and the largest incidence it stays a beam at.

A tapered plane wave of taper g (Thorsos 1988) keeps a finite illuminated length; its correction
(1 + 2tan²θ)/(2k²g²cos²θ) bounds the incidence (`max_incidence_deg`), and its incident power
normalises the scattering cross-sections.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

#: Largest accepted Thorsos-beam correction (1 + 2tan²θ)/(2k²g²cos²θ) (beam still a beam; at 0.1
#: the flat-metal reflectance is already 4 % off).
MAX_BEAM_CORRECTION = 0.02

def beam_correction(incidence_rad, k: float, taper_um: float):
    """The Thorsos-beam term (1 + 2tan²θ)/(2k²g²cos²θ) (must stay ≪ 1)."""
    c = np.cos(incidence_rad)
    return (1.0 + 2.0 * np.tan(incidence_rad) ** 2) / (2.0 * k**2 * taper_um**2 * c**2)


def max_incidence_deg(length_um: float = 20.0, wavelength_um: float = 0.5, n_medium: float = 1.5, taper_um=None) -> float:
    """Largest incidence angle [deg] accepted for this surface (beam correction ≤ `MAX_BEAM_CORRECTION`)."""
    k = 2.0 * np.pi * n_medium / wavelength_um
    g = length_um / 4.0 if taper_um is None else taper_um
    th = np.linspace(0.0, np.pi / 2 - 1e-6, 20001)
    ok = beam_correction(th, k, g) <= MAX_BEAM_CORRECTION
    if not ok.any():
        g_min = 1.0 / (k * np.sqrt(2.0 * MAX_BEAM_CORRECTION))
        raise ValueError(f"taper_um must be at least {g_min:.3g} µm here (the Thorsos beam is no beam below it), got {g!r}")
    return float(np.degrees(th[ok][-1]))


def incident_power(incidence_rad, k, taper_um):
    """Power of the tapered beam crossing the mean plane, g√(π/2) cosθ [1 − correction]."""
    return taper_um * jnp.sqrt(jnp.pi / 2.0) * jnp.cos(incidence_rad) * (1.0 - beam_correction_jnp(incidence_rad, k, taper_um))


def beam_correction_jnp(incidence_rad, k, taper_um):
    c = jnp.cos(incidence_rad)
    return (1.0 + 2.0 * jnp.tan(incidence_rad) ** 2) / (2.0 * k**2 * taper_um**2 * c**2)


def incident_field(x, h, incidence_rad, k, taper_um):
    """Thorsos tapered plane wave on the surface points, (N,) × (I,) → (N, I)."""
    th = jnp.asarray(incidence_rad)[None, :]
    xx = x[:, None] + h[:, None] * jnp.tan(th)
    c = jnp.cos(th)
    w = (2.0 * xx**2 / taper_um**2 - 1.0) / (k * taper_um * c) ** 2
    phase = k * (x[:, None] * jnp.sin(th) - h[:, None] * c) * (1.0 + w)
    return jnp.exp(1j * phase - xx**2 / taper_um**2)


def incident_gradient(x, h, incidence_rad, k, taper_um):
    """(∂ψ_inc/∂x, ∂ψ_inc/∂z) of the Thorsos beam on the surface points, each (N, I) (autodiff)."""

    def one(xi, zi):
        return incident_field(xi[None], zi[None], incidence_rad, k, taper_um)[0]

    def parts(xi, zi):
        fr = jax.jacfwd(lambda a, b: jnp.real(one(a, b)), argnums=(0, 1))(xi, zi)
        fi = jax.jacfwd(lambda a, b: jnp.imag(one(a, b)), argnums=(0, 1))(xi, zi)
        return fr[0] + 1j * fi[0], fr[1] + 1j * fi[1]

    return jax.vmap(parts)(x, h)
