"""Fresnel optics of flat interfaces: dielectric (with total internal reflection) and metal.

All functions are elementwise over leading batch dimensions, jit/vmap/grad friendly, and take
the cosine of the incidence angle measured from the interface normal on the incident side.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float


def _check_index(name: str, value) -> None:
    import numpy as np

    try:
        v = np.asarray(value, dtype=float)
    except (TypeError, ValueError):  # traced values are not checked
        return
    if np.any(~np.isfinite(v)) or np.any(v <= 0):
        raise ValueError(f"{name} must be a finite refractive index > 0, got {value!r}")


def snell_cos(cos_i: ArrayLike, n1: ArrayLike, n2: ArrayLike) -> Float[Array, "..."]:
    """Cosine of the refraction angle, or NaN-free 0 under total internal reflection.

    Arguments:
        cos_i: cosine of the incidence angle (0..1].
        n1, n2: refractive indices of the incident and transmitted media.

    Returns:
        cos θ_t (0 where the wave is totally internally reflected).
    """
    cos_i = jnp.clip(jnp.abs(jnp.asarray(cos_i)), 0.0, 1.0)
    sin2_t = (n1 / n2) ** 2 * (1.0 - cos_i**2)
    return jnp.sqrt(jnp.clip(1.0 - sin2_t, 0.0, 1.0))


def fresnel_dielectric(
    cos_i: ArrayLike, n1: ArrayLike, n2: ArrayLike
) -> tuple[Float[Array, "..."], Float[Array, "..."], Float[Array, "..."]]:
    """Power reflectances (R_s, R_p, R_unpolarised) of a flat dielectric interface.

    Total internal reflection (n1 > n2 beyond the critical angle) returns 1 for all three.
    The transmittance is 1 − R (lossless interface).

    Arguments:
        cos_i: cosine of the incidence angle in medium n1.
        n1, n2: real refractive indices.

    Returns:
        (R_s, R_p, (R_s + R_p)/2).
    """
    _check_index("n1", n1)
    _check_index("n2", n2)
    cos_i = jnp.clip(jnp.abs(jnp.asarray(cos_i)), 0.0, 1.0)
    sin2_t = (n1 / n2) ** 2 * (1.0 - cos_i**2)
    tir = sin2_t >= 1.0
    cos_t = jnp.sqrt(jnp.where(tir, 0.5, 1.0 - sin2_t))
    rs = (n1 * cos_i - n2 * cos_t) / (n1 * cos_i + n2 * cos_t)
    rp = (n2 * cos_i - n1 * cos_t) / (n2 * cos_i + n1 * cos_t)
    Rs = jnp.where(tir, 1.0, rs**2)
    Rp = jnp.where(tir, 1.0, rp**2)
    return Rs, Rp, 0.5 * (Rs + Rp)


def fresnel_conductor(
    cos_i: ArrayLike, n1: ArrayLike, n2_complex: ArrayLike
) -> tuple[Float[Array, "..."], Float[Array, "..."], Float[Array, "..."]]:
    """Power reflectances (R_s, R_p, R_unpolarised) of a metal of complex index n + ik.

    Arguments:
        cos_i: cosine of the incidence angle in the dielectric of real index n1.
        n1: real index of the incident medium (e.g. 1.5 for the binder).
        n2_complex: complex index of the metal (k > 0 for absorption, exp(−iωt) convention).

    Returns:
        (R_s, R_p, (R_s + R_p)/2).
    """
    cos_i = jnp.clip(jnp.abs(jnp.asarray(cos_i)), 0.0, 1.0).astype(jnp.result_type(float))
    n2 = jnp.asarray(n2_complex, dtype=jnp.result_type(complex))
    sin2_i = 1.0 - cos_i**2
    cos_t = jnp.sqrt(1.0 - (n1 / n2) ** 2 * sin2_i + 0j)
    rs = (n1 * cos_i - n2 * cos_t) / (n1 * cos_i + n2 * cos_t)
    rp = (n2 * cos_i - n1 * cos_t) / (n2 * cos_i + n1 * cos_t)
    Rs = jnp.abs(rs) ** 2
    Rp = jnp.abs(rp) ** 2
    return Rs, Rp, 0.5 * (Rs + Rp)


def coat_internal_diffuse_reflectance(n: float, quadrature_points: int = 2048) -> float:
    """Hemispherical (cosine-weighted) internal reflectance r_i of a flat coat of index n.

    r_i = ∫ R(θ) 2 cosθ sinθ dθ over the hemisphere inside the coat (≈ 0.596 for n = 1.5).
    """
    import numpy as np

    _check_index("n", n)
    x, w = np.polynomial.legendre.leggauss(quadrature_points)
    mu_c = np.sqrt(1.0 - 1.0 / n**2) if n > 1 else 0.0  # below mu_c: total internal reflection
    mu = mu_c + 0.5 * (x + 1.0) * (1.0 - mu_c)
    _, _, R = fresnel_dielectric(mu, n, 1.0)
    return float(mu_c**2 + np.sum(0.5 * (1.0 - mu_c) * w * np.asarray(R) * 2.0 * mu))
