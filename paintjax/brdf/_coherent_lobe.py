"""The narrow lobe that carries a lobe BRDF's coherent reflectance, normalised per incidence.

The coherent part of a platelet BRDF is a diffraction lobe about the specular point: a Gaussian
in direction cosines β of standard deviation s per axis, G_s(ρ) = e^{−ρ²/(2s²)} / (2πs²) with
ρ = |β_o + β_i| (see `paintjax.brdf._analytic`). It must carry exactly the coherent reflectance
R_coh(μ_i) into the unit disk, and stay reciprocal. Near grazing incidence the Gaussian meets the
disk's curved edge and R_coh changes across the lobe, so no factor of one cosine does both. The
lobe is therefore written with a symmetric scale h(μ):

    f_coh(ω_i, ω_o) = h(μ_i) h(μ_o) G_s(|β_o + β_i|),   h(μ_i) ∫_disk G_s h(μ_o) dβ_o = R_coh(μ_i),

reciprocal by construction, with h solved on a grid uniform in μ by the symmetric Sinkhorn
iteration h ← √(h R / K h) (in log h its Jacobian is (I − P)/2 with P the row-stochastic weights of
K h, a smoothing kernel, so the error falls by about 2× per iteration or faster).
K is the disk-clipped Gaussian integral with h interpolated linearly between nodes: polar
Gauss–Legendre rules about the specular point, broken where the circle of radius ρ meets the disk
edge. Away from the edge h² = R_coh to within the lobe's variation of R_coh.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

#: Nodes of the scale h on μ ∈ [0, 1] (uniform: spacing 1/256, fine against the lobe's reach in μ near grazing, ≈ √(2s)).
COHERENT_SCALE_NODES = 257
#: Gaussian radii beyond which the lobe is dropped (e^{−32} of the peak).
_REACH = 8.0
#: Sinkhorn iterations: the error falls by ≥ 2× per iteration.
_ITERATIONS = 48


def coherent_scale_nodes() -> np.ndarray:
    """The cosines μ at which the scale h is solved (uniform on [0, 1])."""
    return np.linspace(0.0, 1.0, COHERENT_SCALE_NODES)


@functools.lru_cache(maxsize=16)
def lobe_kernel(width: float, n_rho: int = 16, n_phi: int = 24) -> np.ndarray:
    """K (M, M): (K h)_i = ∫_disk G_s(|β_o − c_i|) h(μ_o) dβ_o for h linear between the nodes, |c_i| = √(1 − μ_i²).

    Polar coordinates about the specular point c_i; the radial rule is broken at ρ = 1 − |c_i| (where the
    circle starts to leave the disk, with ρ = a + (b − a)u² above it for the square-root onset) and the
    azimuthal rule covers the arc inside the disk, φ ≤ arccos((r² + ρ² − 1) / (2rρ)) from the inward direction.
    """
    s = float(width)
    mu = coherent_scale_nodes()
    m = mu.size
    x, w = np.polynomial.legendre.leggauss(n_rho)
    u, wu = 0.5 * (x + 1.0), 0.5 * w
    xp, wp = np.polynomial.legendre.leggauss(n_phi)
    up, wup = 0.5 * (xp + 1.0), 0.5 * wp
    top = _REACH * s
    rows, cols, vals = [], [], []
    for i, r in enumerate(np.sqrt(np.maximum(1.0 - mu**2, 0.0))):
        edge = 1.0 - r
        if edge >= top:  # the whole circle inside the disk
            rho, drho = top * u, top * wu
        else:
            rho_in, drho_in = edge * u, edge * wu
            rho_out = edge + (top - edge) * u**2
            drho_out = (top - edge) * 2.0 * u * wu
            rho, drho = np.r_[rho_in, rho_out], np.r_[drho_in, drho_out]
        with np.errstate(divide="ignore", invalid="ignore"):
            cos_max = np.where(r * rho > 0, (r**2 + rho**2 - 1.0) / (2.0 * r * rho), -1.0)
        phi_max = np.arccos(np.clip(cos_max, -1.0, 1.0))
        phi = phi_max[:, None] * up  # (ρ, φ) on the arc [0, φ_max]; ×2 for the mirror half
        b2 = r**2 + rho[:, None] ** 2 - 2.0 * r * rho[:, None] * np.cos(phi)
        mu_o = np.sqrt(np.clip(1.0 - b2, 0.0, 1.0))
        gauss = np.exp(-0.5 * (rho / s) ** 2) / (2.0 * np.pi * s**2)
        weight = (2.0 * gauss * rho * drho)[:, None] * phi_max[:, None] * wup
        pos = mu_o.ravel() * (m - 1)
        j = np.clip(np.floor(pos).astype(int), 0, m - 2)
        t = pos - j
        rows += [np.full(j.size, i)] * 2
        cols += [j, j + 1]
        vals += [weight.ravel() * (1.0 - t), weight.ravel() * t]
    kernel = np.zeros((m, m))
    np.add.at(kernel, (np.concatenate(rows), np.concatenate(cols)), np.concatenate(vals))
    return kernel


def coherent_lobe_scale(reflectance: Float[Array, " M"], width: float) -> Float[Array, " M"]:
    """The symmetric scale h on the nodes `coherent_scale_nodes()` for the coherent reflectance there.

    Arguments:
        reflectance: R_coh at the nodes (≥ 0; traced values are fine: jittable and differentiable).
        width: the lobe's standard deviation s per axis in β (static).

    Returns:
        h (M,), with h_i (K h)_i = R_i to round-off (zero where R is zero).
    """
    R = jnp.maximum(jnp.asarray(reflectance), 0.0)
    K = jnp.asarray(lobe_kernel(float(width)), R.dtype)
    tiny = jnp.finfo(R.dtype).tiny

    def step(_, h):
        return jnp.sqrt(h * R / jnp.maximum(K @ h, tiny))

    return jax.lax.fori_loop(0, _ITERATIONS, step, jnp.sqrt(R))


def scale_at(scale: Float[Array, " M"], mu: Float[Array, "..."]) -> Float[Array, "..."]:
    """h(μ), linear between the uniform nodes (μ clipped to [0, 1])."""
    m = scale.shape[0]
    pos = jnp.clip(mu, 0.0, 1.0) * (m - 1)
    j = jnp.clip(jnp.floor(pos).astype(jnp.int32), 0, m - 2)
    t = pos - j
    return scale[j] * (1.0 - t) + scale[j + 1] * t


def coherent_lobe(scale: Float[Array, " M"], width: float, wi: Float[Array, "... 3"], wo: Float[Array, "... 3"]) -> Float[Array, "..."]:
    """f_coh = h(μ_i) h(μ_o) G_s(|β_o + β_i|) [1/sr] (the caller masks directions below the plane)."""
    rho2 = jnp.sum((wi[..., :2] + wo[..., :2]) ** 2, -1)
    g = jnp.exp(-0.5 * rho2 / width**2) / (2.0 * np.pi * width**2)
    return scale_at(scale, wi[..., 2]) * scale_at(scale, wo[..., 2]) * g
