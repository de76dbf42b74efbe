"""Radial lobes of a table sampled once on a fine grid, so that the tracer looks them up instead of summing.

A table's lobe at tabulated incidence j is a sum over the K basis widths, L_j(ρ) = Σ_k C_jk e^{−ρ²/w_k²}
(and its sampling density likewise). Summed at every evaluation, the K exponentials are most of a
wavefront step's time. Between tabulated incidences the coefficients are linear in μ, so the lobe is
the same linear blend of two rows L_j(ρ): only the rows need a grid. Each row is stored as log L_j on
RADIAL_NODES points uniform in s = ρ^{1/2} over 0 ≤ ρ ≤ 2 (the largest |β_i + β_o|), which puts
the points closest near the specular point where the narrowest widths live; log L of a Gaussian
is smooth in s everywhere, so a linear interpolation there is accurate to about 10⁻⁵ relative
(`tests/test_brdf_table.py` checks it against the sums).

Which two rows, and the weight between them, comes from an incidence lookup: bins uniform in μ,
each holding the count of tabulated cosines above its lower edge, corrected by one comparison with
the node that may lie inside the bin (the bins are made fine enough for at most one). That
replaces a binary search over the nodes at each of a BRDF call's several interpolations.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

#: Grid points per row of a radial texture.
RADIAL_NODES = 1024
#: Largest offset ρ = |β_i + β_o| of two upward directions.
RHO_MAX = 2.0


def _s_nodes(dtype) -> Float[Array, " R"]:
    return jnp.linspace(0.0, np.sqrt(RHO_MAX), RADIAL_NODES, dtype=dtype)


def log_radial_texture(coef: Float[Array, "J K"], widths: Float[Array, " K"]) -> Float[Array, "J R"]:
    """log Σ_k C_jk e^{−ρ²/w_k²} at the texture's nodes (floored at the dtype's smallest normal number)."""
    coef = jnp.asarray(coef)
    rho2 = _s_nodes(coef.dtype) ** 4
    L = jnp.einsum("jk,rk->jr", coef, jnp.exp(-rho2[:, None] / jnp.asarray(widths, coef.dtype) ** 2))
    return jnp.log(jnp.maximum(L, jnp.finfo(coef.dtype).tiny))


def radial_lookup(texture: Float[Array, "J R"], j0, t, rho2) -> Float[Array, "..."]:
    """(1 − t) L_{j0}(ρ) + t L_{j0+1}(ρ) from a `log_radial_texture`, for ρ² = rho2 (broadcast with j0, t)."""
    R = texture.shape[-1]
    pos = jnp.sqrt(jnp.sqrt(jnp.clip(rho2, 0.0, RHO_MAX**2))) * float((R - 1) / np.sqrt(RHO_MAX))
    i = jnp.clip(jnp.floor(pos).astype(jnp.int32), 0, R - 2)
    f = (pos - i).astype(texture.dtype)
    flat = texture.reshape(-1)

    def row(j):
        base = j * R + i
        return jnp.exp((1.0 - f) * flat[base] + f * flat[base + 1])

    if texture.shape[0] == 1:
        return row(jnp.zeros_like(j0))
    return (1.0 - t) * row(j0) + t * row(j0 + 1)


#: Fewest bins of an incidence lookup (more where tabulated cosines lie closer than two bins).
MIN_MU_BINS = 4096


def incidence_lookup(mu_nodes: Float[Array, " J"]) -> Int[Array, " B"]:
    """For bins uniform in μ over [0, 1], the count of the (descending) tabulated cosines above each bin's lower edge
    (empty for traced nodes: the index then comes from a binary search)."""
    try:  # enough bins that no bin holds two nodes
        nodes = np.asarray(mu_nodes, float)
    except (jax.errors.ConcretizationTypeError, jax.errors.TracerArrayConversionError):  # traced nodes: no lookup
        return jnp.zeros((0,), jnp.int32)
    gap = float(np.min(-np.diff(nodes))) if nodes.size > 1 else 1.0
    if not gap > 0:
        raise ValueError(f"incidence_deg must increase strictly, got cosines {nodes.tolist()}")
    bins = max(MIN_MU_BINS, 2 ** int(np.ceil(np.log2(2.0 / gap))))
    edges = jnp.arange(bins, dtype=jnp.asarray(mu_nodes).dtype) / bins
    return jnp.sum(jnp.asarray(mu_nodes)[None, :] > edges[:, None], -1).astype(jnp.int32)


def lookup_index(mu, mu_nodes: Float[Array, " J"], lookup: Int[Array, " B"]):
    """(j0, t) of μ between the descending nodes j0 and j0 + 1, as `_lobe_basis._interp_index` (clamped at the ends)."""
    J, B = mu_nodes.shape[0], lookup.shape[0]
    mu = jnp.asarray(mu)
    count = lookup[jnp.clip(jnp.floor(mu * B).astype(jnp.int32), 0, B - 1)]
    inside = mu_nodes[jnp.clip(count - 1, 0, J - 1)]  # the smallest node above the bin's lower edge
    count = count - ((count > 0) & (inside <= mu)).astype(count.dtype)  # nodes above μ
    j0 = jnp.clip(count - 1, 0, max(J - 2, 0))
    if J == 1:
        return j0, jnp.zeros_like(mu)
    hi, lo = mu_nodes[j0], mu_nodes[j0 + 1]
    return j0, jnp.clip((hi - mu) / (hi - lo), 0.0, 1.0).astype(mu.dtype)
