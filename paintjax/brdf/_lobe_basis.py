"""The radial lobe basis of the platelet tables: Gaussian widths, fits, continuation and normalisation.

A table's 3-D lobe at each incidence is a non-negative sum of Gaussians in the projected offset
from specular (`fit_radial_lobe`: inverse Abel transform or rotation of the in-plane cut); outside
the in-plane reach it is continued in roughness (`continue_lobe`); `normalisation_tensor` and
`symmetric_scale` make the table reciprocal and energy-conserving.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from scipy.optimize import nnls
from scipy.special import erf

from ._analytic import disk_quadrature

#: Default fixed Gaussian widths (β units) of the lobe basis.
DEFAULT_NUM_WIDTHS = 36
_MIN_WIDTH, _MAX_WIDTH = 0.012, 2.5
#: In-plane points closer to grazing than this cosine are not used by the lobe fit.
COS_MIN = 0.1
#: Relative-error fits: passes with weights from the fitted model after the first (data-weighted) one.
REWEIGHT_PASSES = 2
#: Ridge of the lobe fits, relative to each basis function's own (weighted) norm.
RIDGE = 1e-6


def _lobe_widths(num_widths: int = DEFAULT_NUM_WIDTHS) -> np.ndarray:
    return np.geomspace(_MIN_WIDTH, _MAX_WIDTH, num_widths)


def usable_widths(widths, min_width: float) -> np.ndarray:
    """Mask of the basis widths a lobe fit may use: those ≥ `min_width` and the one just below it, so that
    the two widths bracketing `min_width` can represent a lobe of exactly that width (the narrowest
    Kirchhoff term 2/(kτ), which the lobe becomes at grazing) and the fitted lobe varies continuously
    with τ instead of jumping by a basis step."""
    first = int(np.searchsorted(widths, min_width))
    return np.arange(len(widths)) >= max(first - 1, 0)


def fit_radial_lobe(u, p, weights, widths, method: str = "abel", min_width: float = 0.0, *, floor=None, reweight: int = REWEIGHT_PASSES):
    """Radial 2-D lobe coefficients of in-plane data p at distances u from the specular point.

    Model: p(u) ≈ Σ_k C_k B_k(u) with B_k = √π w_k e^{−u²/w_k²} (abel: the projection of
    L(ρ) = Σ C_k e^{−ρ²/w_k²}) or e^{−u²/w_k²} (rotate: the in-plane cut of L). Non-negative least
    squares with a tiny ridge on each coefficient, relative to its basis function's weighted norm (a
    ridge relative to the largest column, as tables before version 11 had, is 10⁶ times stronger on
    the narrow widths, whose columns are small: it kept lobes of τ ≳ 1 µm from their narrowest
    width and made them up to 30 % too low at the peak); basis widths below `min_width` are not used.

    Row weights: `weights` as given when `floor` is None. With `floor` (scalar or per row) the fit is
    in relative error down to the floor: row weights `weights / (ref + floor)`, ref = max(p, 0) in the
    first pass and the fitted model in `reweight` further passes (iteratively reweighted least
    squares). Weights taken from noisy data themselves bias the fit low — points that fluctuate down
    weigh more: for the speckle of an N-profile average (Gamma(N) statistics) by (N − 2)/N, 20 %
    for 10 profiles, uniformly over the lobe — weights from the smooth model do not.

    Returns:
        (coefficients C (K,), weighted relative rms residual).
    """
    A = np.exp(-(u[:, None] ** 2) / widths**2) * usable_widths(widths, min_width)
    if method == "abel":
        A = A * (np.sqrt(np.pi) * widths)
    ref = np.maximum(p, 0.0)
    for _ in range(1 + (0 if floor is None else int(reweight))):
        w = weights if floor is None else weights / (ref + floor)
        Aw = A * w[:, None]
        ridge = np.diag(RIDGE * np.linalg.norm(Aw, axis=0))
        c, _ = nnls(np.vstack([Aw, ridge]), np.concatenate([p * w, np.zeros(len(widths))]), maxiter=50 * len(widths))
        ref = A @ c
    resid = float(np.sqrt(np.mean(((A @ c - p) * w) ** 2)) / max(np.sqrt(np.mean((p * w) ** 2)), 1e-300))
    return c, resid


#: Smallest half-width in μ̄ of a node's data window (pools ~±14° about normal incidence).
MIN_WINDOW_MU = 0.03


def _hat(mu, mu_nodes, j):
    """Triangular data weight of node j in μ̄: reaches the neighbouring nodes, at least ±MIN_WINDOW_MU
    (near normal incidence the nodes crowd in μ and a node alone would see only |u| ≲ 0.08 of its
    lobe — too little for an inverse Abel transform); constant beyond the last node."""
    J = mu_nodes.size
    up = max(mu_nodes[j - 1] - mu_nodes[j] if j > 0 else 0.0, MIN_WINDOW_MU)
    down = max(mu_nodes[j] - mu_nodes[j + 1] if j < J - 1 else 0.0, MIN_WINDOW_MU)
    d = mu - mu_nodes[j]
    h = np.where(d >= 0, 1.0 - d / up, 1.0 - (-d) / down)
    if j == 0:
        h = np.where(d >= 0, 1.0, h)
    if j == J - 1:
        h = np.where(d < 0, 1.0, h)
    return np.clip(h, 0.0, 1.0)


def geometric_factor(rho2, c, xp=jnp):
    """Kirchhoff geometric (obliquity) factor G = (ρ² + c²)² / (4c²) = 4cos⁴χ / c² of a direction pair.

    ρ² = |β_i + β_o|², c = cosθ_i + cosθ_o, so ρ² + c² = |ω_i + ω_o|² = 4cos²χ. It is Beckmann's F₃²cos²θ_i
    in 3-D and reduces to (1 + cos(θ_i + θ_s))² / c² in the plane of incidence (ρ = |u|): the same
    function of (ρ, c) in 2-D and 3-D. Normalised to 1 at the specular point of normal incidence.
    """
    return (rho2 + c**2) ** 2 / xp.maximum(4.0 * c**2, 1e-300)


#: Smallest share of a node's projected lobe that its in-plane data must reach (else: continued).
MIN_COVERAGE = 0.99
#: Smallest range of c = 2μ̄ over the covered nodes for which (kσ)² is estimated and lobes continued.
MIN_C_SPAN = 0.2


def in_plane_reach(c, cos_min: float = COS_MIN) -> np.ndarray:
    """Largest distance |u| from the specular point that an in-plane pair with μ_i + μ_o = c
    (both cosines > cos_min, same side of the normal) reaches: |sinθ_a − sinθ_b| at the ends."""
    c = np.atleast_1d(np.asarray(c, float))
    mu_a = np.clip(np.minimum(c - cos_min, 1.0), cos_min, 1.0)
    mu_b = np.clip(c - mu_a, cos_min, 1.0)
    return np.where(c > 2 * cos_min, np.abs(np.sqrt(1 - mu_a**2) - np.sqrt(1 - mu_b**2)), 0.0)


class HankelKernel(NamedTuple):
    """Quadrature of the radial lobe's 2-D Fourier pair: r nodes with their 1-D weights `w_line`, the ρ
    grid, and K with L(ρ) = K @ g(r) = ∫ g(r) J0(2πρr) 2πr dr."""

    r: np.ndarray
    w_line: np.ndarray
    rho: np.ndarray
    K: np.ndarray


def _hankel_pair(widths, rho_max: float = 2.2, n_panels: int = 80, n_gl: int = 16) -> HankelKernel:
    """The `HankelKernel` for lobes on these basis widths; the basis e^{−ρ²/w²} has g(r) = πw² e^{−π²w²r²}."""
    from scipy.special import j0

    r_max = 5.0 / (np.pi * widths.min())
    x, w = np.polynomial.legendre.leggauss(n_gl)
    edges = np.linspace(0.0, r_max, n_panels + 1)
    half = 0.5 * np.diff(edges)[:, None]
    r = ((edges[:-1, None] + half) + half * x).ravel()
    w_line = (half * w).ravel()
    rho = np.linspace(0.0, rho_max, 441)
    return HankelKernel(r, w_line, rho, j0(2.0 * np.pi * rho[:, None] * r[None, :]) * (w_line * 2.0 * np.pi * r))


def continue_lobe(coef_ref, widths, X_ref: float, X_new: float, kernel, min_width: float = 0.0):
    """Radial lobe at another q_z by the generalised Harvey–Shack (Kirchhoff) surface transfer function.

    The lobe's 2-D Fourier transform (an autocovariance-like function of lateral distance r) is
    g(r) = A e^{−X} (e^{X γ(r)} − 1), X = (kσc)², γ(0) = 1. From the reference lobe (X_ref) take
    A = g(0)/(1 − e^{−X_ref}) and γ(r) = ln(1 + e^{X_ref} g/A)/X_ref, evaluate g at X_new, transform
    back and fit the Gaussian basis (relative weights down to 1 % of the peak, non-negative).
    """
    rho = kernel.rho
    L = kernel.K @ _continued_transforms(coef_ref, widths, X_ref, X_new, kernel)[:, 0]
    if not np.any(L != 0):
        return np.zeros_like(coef_ref)
    c, _ = fit_radial_lobe(rho, L, np.ones_like(L), widths, "rotate", min_width, floor=0.01 * max(L.max(), 1e-300))
    return c


def _continued_transforms(coef_ref, widths, X_ref, X_new, kernel):
    """The 2-D Fourier transform g(r) of the lobe continued from X_ref to each X_new (`continue_lobe`),
    on the kernel's r nodes. Shape (r, len(X_new)); zeros when the reference lobe is empty."""
    r = kernel.r
    X_new = np.atleast_1d(np.asarray(X_new, float))[None, :]
    g_ref = np.sum(coef_ref * np.pi * widths**2 * np.exp(-(np.pi**2) * widths**2 * r[:, None] ** 2), -1)
    A = g_ref[0] / -np.expm1(-X_ref)
    if not A > 0:
        return np.zeros((r.size, X_new.size))
    gamma = 1.0 + np.log(np.maximum(np.exp(-X_ref) + np.maximum(g_ref, 0.0) / A, 1e-300)) / X_ref  # ln(1 + e^X g/A)/X without overflow
    return A * (np.exp(-X_new * (1.0 - gamma[:, None])) - np.exp(-X_new))


def _roughness(mu, R_coh, R_inc, coef, widths, ref: int, kernel, reach):
    """(kσ)² of the surface, for continuing the lobe of node `ref` in q_z, from the tabulated incidences:
    cosines μ (J,), coherent and incoherent reflectance (J,), lobe coefficients `coef` (J, K) fitted
    from the in-plane data, and each node's in-plane reach in u (`in_plane_reach`).

    From the coherent fraction R_coh/R = e^{−(2kσμ)²} (least squares in its logarithm over the nodes up
    to `ref` where it lies in [1e-4, 0.9]). Without a usable coherent part (kσ ≳ 1.5), from the q_z
    dependence of the lobe itself: the (kσ)² on a fine grid for which the lobe of node `ref`, continued
    to every other node's q_z (the transfer function of `continue_lobe`), best matches in projection
    the lobe fitted there — the in-plane data — over the u that node's data reach (peak-normalised L1),
    including the nodes beyond `ref` whose data see only the lobe's middle: there the lobe narrows as
    c = 2μ̄ falls once (kσc)² ≫ 1 (width ∝ c) and stops narrowing when (kσc)² ≲ 1, which is what fixes
    (kσ)². Tables before version 11 fitted the lobe *integrals* A(1 − e^{−(kσ)²(2μ)²}), which are flat
    once (kσc)² ≫ 1, and settled near (kσ)² = 4 for any rougher surface (8 for σ 0.15 µm, 32 for σ 0.3 µm
    in the binder), so continued lobes were up to 2× too low at the peak near grazing.

    Only for lobes of an unknown surface: tables built for a surface use its (kσ)² (`_kroughness2`),
    since where the data barely constrain it (kσ ≳ 4) this estimate is not smooth in σ and τ.
    """
    frac = R_coh[: ref + 1] / np.maximum(R_coh[: ref + 1] + R_inc[: ref + 1], 1e-300)
    use = (frac >= 1e-4) & (frac <= 0.9)
    if np.any(use):
        m = np.asarray(mu, float)[: ref + 1][use]
        return float(np.sum(m**2 * -np.log(frac[use])) / (4.0 * np.sum(m**4)))
    r, w_line = kernel.r, kernel.w_line
    c = 2.0 * np.asarray(mu, float)
    others = np.nonzero((np.arange(c.size) != ref) & (reach > 0) & np.any(coef > 0, -1))[0]
    t = np.linspace(0.0, 1.0, 101)
    u = np.minimum(reach[others], 2.2)[:, None] * t  # (N, U)
    fitted = np.sum(coef[others][:, None, :] * np.sqrt(np.pi) * widths * np.exp(-(u[..., None] ** 2) / widths**2), -1)
    fitted = fitted / np.maximum(fitted[:, :1], 1e-300)
    cosines = 2.0 * np.cos(2.0 * np.pi * u[..., None] * r) * w_line  # (N, U, r): P(u) = 2∫ g(r) cos(2πur) dr
    grid = np.geomspace(1e-2, 300.0, 161)
    cost = []
    for g in grid:
        G = _continued_transforms(coef[ref], widths, g * c[ref] ** 2, g * c[others] ** 2, kernel)  # (r, N)
        P = np.einsum("nur,rn->nu", cosines, G)
        P = P / np.maximum(P[:, :1], 1e-300)
        cost.append(np.sum(np.mean(np.abs(P - fitted), -1)))
    return float(grid[int(np.argmin(cost))])


def continue_uncovered(coef, widths, mu_nodes, R_coh, R_inc, kroughness2: float | None, min_width: float = 0.0):
    """Nodes whose in-plane data do not reach their lobe (both directions near grazing, small c) take the lobe of the
    last node covered to `MIN_COVERAGE`, continued to their q_z (generalised Harvey–Shack, `continue_lobe`), blended
    with the continuation from the next node by how far that node is above the threshold, so that a table is
    continuous where a node's coverage crosses it as σ or τ change: w = (cov_ref − 0.99)/(cov_ref − cov_next) → 0 as the
    reference's coverage falls to 99 %, → 1 on the other side of the switch. `kroughness2`: the surface's (kσ)² in
    the medium, None: estimated from the lobes (`_roughness`).

    Returns:
        (coef with the continued rows replaced, each node's coverage, which nodes were continued).
    """
    J = coef.shape[0]
    c_nodes = 2.0 * mu_nodes
    mass = coef * np.pi * widths**2  # ∫ L d²ρ per basis term
    coverage = np.sum(mass * erf(in_plane_reach(c_nodes)[:, None] / widths), -1) / np.maximum(mass.sum(-1), 1e-300)
    last = int(np.argmax(coverage))  # near normal incidence a node pools a window of μ̄ (see _hat)
    while last + 1 < J and coverage[last + 1] >= MIN_COVERAGE:
        last += 1
    continued = np.zeros(J, bool)
    if not (coverage[last] >= MIN_COVERAGE and last < J - 1 and c_nodes[0] - c_nodes[last] >= MIN_C_SPAN):
        return coef, coverage, continued
    kernel = _hankel_pair(widths)
    if kroughness2 is None:
        kroughness2 = _roughness(mu_nodes, R_coh, R_inc, coef, widths, last, kernel, in_plane_reach(c_nodes))

    def continued_from(ref):  # every node beyond `ref` takes ref's lobe continued to its q_z
        out = coef.copy()
        for j in range(ref + 1, J):
            out[j] = continue_lobe(coef[ref], widths, kroughness2 * c_nodes[ref] ** 2, kroughness2 * c_nodes[j] ** 2, kernel, min_width)
        return out

    w = (coverage[last] - MIN_COVERAGE) / max(coverage[last] - coverage[last + 1], 1e-300)
    blended = last + 2 < J and 0.0 < w
    continued[last + 1:] = True
    return ((1.0 - w) * continued_from(last) + w * continued_from(last + 1) if blended else continued_from(last)), coverage, continued


def _interp_index(mu, mu_nodes_desc, xp=jnp):
    """(j0, t): μ between tabulated nodes j0, j0+1 (nodes in ascending incidence, i.e. descending μ)."""
    J = mu_nodes_desc.shape[0]
    idx = xp.interp(mu, mu_nodes_desc[::-1], xp.arange(J - 1, -1, -1, dtype=mu_nodes_desc.dtype))
    j0 = xp.clip(xp.floor(idx).astype(xp.int32), 0, max(J - 2, 0))
    return j0, idx - j0


def _interp_rows(values, j0, t):
    """Linear interpolation of values (J, ...) at (j0, t) broadcast over leading dims."""
    if values.shape[0] == 1:
        return values[jnp.zeros_like(j0)]
    tt = t.reshape(t.shape + (1,) * (values.ndim - 1))
    return (1.0 - tt) * values[j0] + tt * values[j0 + 1]


def normalisation_tensor(mu_nodes, widths) -> np.ndarray:
    """T (J, J, J, K) with ∫_disk f_inc(ω_j, ω_o) cosθ_o dω_o = Σ_l a_j a_l Σ_mk T[j, l, m, k] C[m, k].

    f_inc = a(μ_i) a(μ_o) G L(ρ; μ̄)/(μ_i μ_o) is linear in the lobe coefficients C (J, K), which
    are interpolated linearly in μ̄ between nodes m, and in a(μ_o), interpolated between nodes l: the
    disk quadrature (`disk_quadrature`) about each tabulated incidence j gives the tensor once, so the
    normalisation kernel K = T·C of any coefficients (e.g. interpolated across a (σ, τ) grid) costs
    one contraction.
    """
    from scipy import sparse

    mu_nodes = np.asarray(mu_nodes, float)
    widths = np.asarray(widths, float)
    J = mu_nodes.size
    wi, wo, wt = disk_quadrature(mu_nodes, xp=np)
    mu_o = wo[..., 2]
    rho2 = (wo[..., 0] + wi[:, None, 0]) ** 2 + wo[..., 1] ** 2
    mu_bar = 0.5 * (mu_nodes[:, None] + mu_o)
    T = np.zeros((J, J * J, widths.size))
    for j in range(J):
        g = geometric_factor(rho2[j], 2.0 * mu_bar[j], xp=np) * wt[j] / (mu_nodes[j] * mu_o[j])
        basis = np.exp(-rho2[j][:, None] / widths**2) * g[:, None]  # (Q, K)
        if J == 1:
            T[0, 0] = basis.sum(0)
            continue
        m0, t = _interp_index(mu_bar[j], mu_nodes, xp=np)
        l0, s = _interp_index(mu_o[j], mu_nodes, xp=np)
        q = np.arange(mu_o[j].size)
        rows = np.concatenate([l0 * J + m0, l0 * J + m0 + 1, (l0 + 1) * J + m0, (l0 + 1) * J + m0 + 1])
        vals = np.concatenate([(1 - s) * (1 - t), (1 - s) * t, s * (1 - t), s * t])
        W = sparse.csr_matrix((vals, (rows, np.tile(q, 4))), shape=(J * J, q.size))
        T[j] = W @ basis
    return T.reshape(J, J, J, widths.size)


def symmetric_scale(Kmat, R_inc, a0, iterations: int, xp=jnp):
    """a (J,) with a_j Σ_l K_jl a_l = R_inc,j: symmetric Sinkhorn iteration a ← √(a R / (K a)) from a0
    (0 where R_inc = 0). `xp` = numpy (table builds) or jax.numpy (grid interpolation, differentiable)."""
    pos = R_inc > 0

    def step(a):
        Ka = Kmat @ a
        return xp.where(pos, xp.sqrt(xp.maximum(a, 0.0) * R_inc / xp.maximum(Ka, 1e-300)), 0.0)

    if xp is np:
        a = a0
        for _ in range(iterations):
            a = step(a)
        return a
    return jax.lax.fori_loop(0, iterations, lambda _, a: step(a), a0)
