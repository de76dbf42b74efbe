"""The clearcoat–air interface: flat, or wavy (a microfacet dielectric with Gaussian slopes).

Waviness is long-wavelength (µm to mm) relief of the clearcoat surface, far larger than the
wavelength, so it acts by geometric optics: every crossing of the interface happens at a locally
tilted flat facet of normal m. The slopes (∂h/∂x, ∂h/∂y) are independent zero-mean Gaussians;
the waviness is given as the RMS slope *angle* ϑ (degrees): tan ϑ = RMS of |∇h|, so each slope
component has standard deviation tan ϑ / √2 (the Beckmann distribution with α = tan ϑ).

A direction ω (pointing away from the surface on the side it arrives from) sees the facets in
proportion to their projected area: the visible-normal density is D_ω(m) = ⟨ω·m⟩₊ D(m) / cosθ_ω
with Smith's masking G1(ω) as the normalisation. The tracer and the analytic model draw m from
the slope distribution and carry the importance weight

    v(ω, m) = G1(ω) ⟨ω·m⟩₊ / (cosθ_ω · m_z),          E_D[v] = 1 exactly,

so one mechanism covers both the flat coat (ϑ = 0: m = z, v = 1) and the wavy one. Where a ray
actually crosses the surface (entry, internal reflection or exit) the tracer instead draws m
exactly from the visible-normal density (`sample_visible_facet`, weight 1), so energy is
accounted ray by ray; next-event estimation uses the weighted draw. Radiance
crossing a facet obeys L/n² invariance times the facet's Fresnel transmittance, so a detector in
direction ω_a sees E_m[v(ω_a, m) T(m) L_in(ω_in(m))] / n² with ω_in the refraction of ω_a at m;
this is reciprocal (it is symmetric in source and detector).

Limitation (multiple facet scattering neglected): a ray that crosses the surface is not tested
for masking on its way out, so an exit refracted toward ω_a leaves with probability 1, whereas the
NEE weight carries Smith's G1(ω_a). At grazing detectors the exits (the histogram estimator, the
ledger's exited share) therefore exceed the NEE estimate by about 1/G1(ω_a): G1 = 0.999 / 0.976 /
0.69 at 65° / 75° / 85° for a 15° RMS slope (0.9996 / 0.89 at 75° / 85° for 8°; 1 at MA98's angles,
≤ 65°, for ≤ 8°). The reported reflectance factor is the NEE one.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

#: Largest accepted RMS slope angle [deg]: beyond it masking and multiple facet scattering,
#: which this model neglects, stop being small corrections.
MAX_WAVINESS_DEG = 15.0


def check_waviness(waviness_deg) -> float:
    """Validate an RMS slope angle [deg] in [0, MAX_WAVINESS_DEG]; returns it as a float."""
    try:
        v = float(waviness_deg)
    except (TypeError, ValueError):
        raise ValueError(f"waviness_deg must be a number, got {waviness_deg!r}") from None
    if not (np.isfinite(v) and 0.0 <= v <= MAX_WAVINESS_DEG):
        raise ValueError(f"waviness_deg (clearcoat RMS slope angle) must lie in [0, {MAX_WAVINESS_DEG:g}] deg, got {waviness_deg!r}")
    return v


def slope_sd(waviness_deg: float) -> float:
    """Standard deviation of each slope component for an RMS slope angle [deg]."""
    return float(np.tan(np.deg2rad(waviness_deg)) / np.sqrt(2.0))


def facet_normal(slope_x: Float[Array, "..."], slope_y: Float[Array, "..."]) -> Float[Array, "... 3"]:
    """Unit upward normal of a facet with slopes (∂h/∂x, ∂h/∂y)."""
    m = jnp.stack([-slope_x, -slope_y, jnp.ones_like(slope_x)], axis=-1)
    return m / jnp.linalg.norm(m, axis=-1, keepdims=True)


def sample_facet_normal(sd, u1: Float[Array, "..."], u2: Float[Array, "..."]) -> Float[Array, "... 3"]:
    """Facet normal with Gaussian slopes of per-component standard deviation `sd` (Box–Muller of u1, u2 ∈ (0, 1))."""
    r = sd * jnp.sqrt(-2.0 * jnp.log(u1))
    phi = 2.0 * jnp.pi * u2
    return facet_normal(r * jnp.cos(phi), r * jnp.sin(phi))


def smith_masking(omega: Float[Array, "... 3"], sd) -> Float[Array, "..."]:
    """Smith masking G1(ω) of the Gaussian-slope (Beckmann, α = √2·sd) surface seen from ω."""
    alpha = jnp.sqrt(2.0) * sd
    c = jnp.abs(omega[..., 2])
    s = jnp.sqrt(jnp.clip(1.0 - c * c, 0.0, 1.0))
    big = alpha * s <= 1e-6 * c  # flat coat or normal incidence: no masking
    a = jnp.where(big, 1.0, c / jnp.where(big, 1.0, alpha * s))
    from jax.scipy.special import erf

    g = 2.0 / (1.0 + erf(a) + jnp.exp(-a * a) / (a * jnp.sqrt(jnp.pi)))
    return jnp.where(big, 1.0, g)


def visible_weight(omega: Float[Array, "... 3"], m: Float[Array, "... 3"], sd) -> Float[Array, "..."]:
    """Importance weight v = G1(ω) ⟨ω·m⟩₊ / (cosθ_ω m_z) of facet m drawn from the slope distribution, seen from ω.

    ω is the direction the facet is seen from (either side of the mean plane: only |cosθ_ω| enters);
    m is the upward facet normal (m_z > 0), and a facet facing away from ω (ω·m ≤ 0) gets weight 0. With Smith's
    masking G1 the weight has mean exactly 1 over the slope distribution (the visible projected
    area equals the projected area of the mean plane).
    """
    return smith_masking(omega, sd) * jnp.maximum(jnp.sum(omega * m, -1), 0.0) / (jnp.abs(omega[..., 2]) * m[..., 2])


def sample_visible_facet(omega: Float[Array, "... 3"], sd, u1: Float[Array, "..."], u2: Float[Array, "..."],
                         iterations: int = 32) -> Float[Array, "... 3"]:
    """Facet normal drawn exactly from the visible-normal density seen from ω (ω_z > 0), weight 1.

    In the frame rotated so that ω = (s, 0, c), the slope along ω's azimuth has the density
    ∝ (c − s·sd·z)₊ φ(z) (z in units of sd), whose CDF is ∝ c Φ(z) + s·sd·φ(z) in closed form and
    is inverted by bisection; the cross slope is an independent Gaussian. This is the exact
    visible-normal sampling of the Gaussian-slope surface (its normaliser is 1/G1).
    """
    from jax.scipy.special import ndtr, ndtri

    c = omega[..., 2]
    s = jnp.sqrt(jnp.clip(1.0 - c * c, 0.0, 1.0))
    cos_phi = jnp.where(s > 0, omega[..., 0] / jnp.where(s > 0, s, 1.0), 1.0)
    sin_phi = jnp.where(s > 0, omega[..., 1] / jnp.where(s > 0, s, 1.0), 0.0)
    b = s * sd
    z_hi = jnp.minimum(c / jnp.maximum(b, 1e-30), 10.0)
    phi_pdf = lambda z: jnp.exp(-0.5 * z * z) / jnp.sqrt(2.0 * jnp.pi)  # noqa: E731
    cdf = lambda z: c * ndtr(z) + b * phi_pdf(z)  # noqa: E731
    target = u1 * cdf(z_hi)

    def bisect(_, lohi):
        lo, hi = lohi
        mid = 0.5 * (lo + hi)
        below = cdf(mid) < target
        return jnp.where(below, mid, lo), jnp.where(below, hi, mid)

    lo, hi = jax.lax.fori_loop(0, iterations, bisect, (jnp.full_like(z_hi, -10.0), z_hi))
    p_along = sd * 0.5 * (lo + hi)
    p_cross = sd * ndtri(u2)
    return facet_normal(p_along * cos_phi - p_cross * sin_phi, p_along * sin_phi + p_cross * cos_phi)


def refract(d: Float[Array, "... 3"], m: Float[Array, "... 3"], eta) -> tuple[Float[Array, "... 3"], Float[Array, "..."]]:
    """Refraction of the propagation direction d at a facet with normal m facing it (d·m < 0).

    Arguments:
        d: unit propagation direction.
        m: unit facet normal on the incident side.
        eta: n_incident / n_transmitted.

    Returns:
        (t, cos_i): the transmitted propagation direction (meaningless under total internal
        reflection, where the caller's Fresnel factor is 1) and the cosine of incidence.
    """
    cos_i = -jnp.sum(d * m, -1, keepdims=True)
    cos_t = jnp.sqrt(jnp.clip(1.0 - eta**2 * (1.0 - cos_i**2), 0.0, 1.0))
    return eta * d + (eta * cos_i - cos_t) * m, cos_i[..., 0]


def reflect(d: Float[Array, "... 3"], m: Float[Array, "... 3"]) -> Float[Array, "... 3"]:
    """Mirror reflection of the propagation direction d at a facet of normal m."""
    return d - 2.0 * jnp.sum(d * m, -1, keepdims=True) * m


def seen_through_facet(w_air: Float[Array, "... 3"], m: Float[Array, "... 3"], n, sd) -> tuple[Float[Array, "... 3"], Float[Array, "..."]]:
    """What an air direction w_air (pointing away from the coat) sees through facet m of a coat of index n.

    Returns:
        (ω_in, v T): the internal direction that refracts into w_air, pointing away from the layer
        (unit), and the facet's visible weight times its Fresnel transmittance (Smith-normalised,
        slope standard deviation `sd`).
    """
    from ._fresnel import fresnel_dielectric

    t, cos_i = refract(-w_air, m, 1.0 / n)
    return -t / jnp.linalg.norm(t, axis=-1, keepdims=True), visible_weight(w_air, m, sd) * (1.0 - fresnel_dielectric(cos_i, 1.0, n)[2])


def gauss_hermite_facets(waviness_deg: float, nodes: int) -> tuple[np.ndarray, np.ndarray]:
    """Tensor Gauss–Hermite quadrature of the slope distribution: (normals (q, 3), weights (q,) summing to 1)."""
    if waviness_deg == 0.0:
        return np.array([[0.0, 0.0, 1.0]]), np.ones(1)
    x, w = np.polynomial.hermite_e.hermegauss(int(nodes))
    sd = slope_sd(waviness_deg)
    sx, sy = np.meshgrid(x * sd, x * sd, indexing="ij")
    m = np.stack([-sx.ravel(), -sy.ravel(), np.ones(sx.size)], axis=-1)
    m /= np.linalg.norm(m, axis=-1, keepdims=True)
    ww = np.outer(w, w).ravel()
    return m, ww / ww.sum()
