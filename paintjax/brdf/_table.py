"""Tabulated wave-based platelet BRDF: in-plane wave lobes → isotropic 3-D BRDF the tracer samples.

**Input.** Any in-plane lobe source with the fields of `paintjax.wave._solver.WaveLobes`: `incidence_deg`
(I,), `theta_s_deg` (S,) (θ_s > 0 on the specular side), `sigma` (I, S) total normalised bistatic
coefficient [1/rad] (∫σ dθ_s = reflected fraction), `sigma_coherent` (I, S), `reflected` (I,),
`absorbed` (I,). Sources: the wave solver (`source="wave"`, default) or the 1-D Kirchhoff closed
form (`kirchhoff_lobes`, used to validate the 2-D → 3-D step against `BeckmannBRDF`).

**Model.** The incoherent BRDF is written, in direction cosines β (see `paintjax.brdf._analytic`),

    f_inc(ω_i, ω_o) = a(μ_i) a(μ_o) G(ρ, c) L(ρ; μ̄) / (μ_i μ_o),   ρ = |β_i + β_o|,  c = μ_i + μ_o = 2μ̄,

a shift-invariant lobe L about the specular point (Harvey–Shack surface transfer function) whose
shape depends on the mean cosine μ̄ = c/2 (the Kirchhoff q_z), times the Kirchhoff geometric
(obliquity) factor G = (ρ² + c²)²/(4c²) = 4cos⁴χ/c² (Beckmann's F₃² cos²θ_i; `geometric_factor`),
which is the same function of (ρ, c) in the plane of incidence, (1 + cos(θ_i + θ_s))²/c². The
analytic Kirchhoff BRDF of a Gaussian surface is exactly of this form (L = R(χ) (kτ)²/(4π) × the
Beckmann series at X = (kσc)²), and the form is reciprocal by construction.
L(ρ; μ) = Σ_k C_k(μ) e^{−ρ²/w_k²} on fixed widths w_k, tabulated at the source incidences θ_j
(μ_j = cosθ_j) and interpolated linearly in μ.

**2-D → 3-D (inverse Abel).** For an isotropic surface the 1-D surface transfer function at a
given q_z is the projection of the 2-D one (generalised Harvey–Shack): the in-plane lobe per unit
β, p(u) = σ_inc(θ_s)/cosθ_s at u = sinθ_s − sinθ_i, divided by the in-plane obliquity
G(|u|, c)/(μ_i μ_o), is the projection of L(·; μ̄) on the plane of incidence. (Projecting G L
instead, as tables before version 6 did, ignores that G grows off the plane: 5 % at 40° and
tens of % near grazing.) Each in-plane sample (any incidence, cosθ_s > 0.1) is assigned to its
mean cosine μ̄; the coefficients C_j of node j are the non-negative least-squares fit (relative
error down to 1 % of the peak, hat weights in μ̄) of p μ_i μ_o / G by the projections
√π w_k e^{−u²/w_k²} of the basis — the inverse Abel transform, exact term by term (BASEX-style
basis expansion). The relative-error weights come from the fitted lobe, not the data (iteratively
reweighted, `fit_radial_lobe`): weights from the speckled data of a 10-profile average biased every
lobe ≈ 20 % low, uniformly (tables before version 7; a(μ) ≈ 1.10–1.2 made it up). `method="rotate"`
instead fits the in-plane *cut* e^{−u²/w_k²} (the original study's axisymmetric rotation of the
1-D lobe). Basis widths below `min_width` (2/(kτ) for tables built by `platelet_table_arrays`:
the width of the narrowest, m = 1, term of the Kirchhoff series of a Gaussian surface) are not
used, except the one just below it (`usable_widths`), so the speckle of a profile average — which
the memory effect repeats about the specular point of every incidence — is not fitted as
structure, while the two widths that bracket 2/(kτ) represent a lobe of exactly that width: the
lobe becomes that one term towards grazing, where tables before version 10 pinned it to the next
wider basis width (up to 16.5 % too wide, 8.7 % L1 from the 3-D Kirchhoff BRDF at 80° for the
measured roughness, and a lobe that jumped with τ).

**Small c: continuation in q_z.** In the plane of incidence a pair with μ_i + μ_o = c reaches
only |u| ≤ |sinθ_a − sinθ_b| ≤ 1 − √(1 − c²) from the specular point (`in_plane_reach`): when
both directions are oblique (c ≲ 1, nodes beyond ≈ 60° for platelet roughness) the in-plane data
see only the middle of the lobe, and the inverse Abel transform of a truncated projection is
undetermined (it overshot the tails many-fold, and a(μ) compensated by up to 14 %). Nodes whose
data reach less than `MIN_COVERAGE` = 99 % of their projected lobe, below the last node that does
(c_ref), take that node's lobe continued to their q_z with the generalised Harvey–Shack transfer
function (`continue_lobe`): the 2-D Fourier transform of L is g(r) = A e^{−X}(e^{Xγ(r)} − 1),
X = (kσc)², so γ(r) follows from the reference lobe and L at any c from γ. (kσ)² is estimated
from the surface's σ when the table is built for a surface (`platelet_table_arrays`, the grid's
`build_at`, `table_from_lobes(..., sigma_um=σ)`; version 12). For lobes of an unknown surface it is
estimated: from the source's coherent fraction R_coh/R = e^{−(2kσμ)²} over the covered incidences,
or without a usable coherent part as the value for which the continued lobe best matches every
node's in-plane data where they reach (`_roughness`; tables before version 11 used the lobe
integrals, which do not see (kσ)² once (kσc)² ≫ 1). Which nodes were
continued is stored (`continued`, with `lobe_coverage`). Since version 13 the continued lobes are a blend of the
continuations from c_ref's node and from the next one, weighted by how far c_ref's coverage is above 99 %
(w = (cov_ref − 0.99)/(cov_ref − cov_next)), so that a table does not jump where a node's coverage crosses 99 % as
σ or τ change (in version 12 the grid's `build_at` table at σ 0.091, τ 0.42 µm and one built directly there continued
from different nodes, coverage 0.990024 against 0.989980, and differed by 7.7 % L1 at 80°).

**Reflectance.** a(μ) is solved at build time (symmetric Sinkhorn iteration) so that at every
tabulated incidence ∫_disk f_inc dβ equals the source's incoherent reflectance; with the
coherent part the albedo equals the source's `reflected`, so absorption is the wave's.

**Outside the unit disk.** The part of the lobe that falls at |β_o| > 1 would be evanescent; it is
not discarded but redistributed proportionally over the propagating directions by a(μ) (the
Harvey–Shack renormalisation). The fraction of the incidence's own lobe that fell outside is
stored (`outside_fraction`) as a diagnostic.

**Coherent part.** R_coh(θ_j) = ∫σ_coh dθ_s, kept as the platelet's diffraction lobe (default) or a
delta (see `paintjax.brdf._analytic`). For wave sources the coherent coefficient is the solver's unbiased
estimate inside the specular beam (`paintjax.wave._solver.coherent_estimate`, Kirchhoff control variate),
an incidence whose estimate is negative getting 0 (`coherent_positive_part`). Each table records its
statistical errors: `reflectance_se`, `coherent_reflectance_se` and `lobe_relative_se` (rms relative
SE of the in-plane diffuse lobe over its half-maximum core). Unpolarised (the
source's default). Incidences beyond the last tabulated one (89° by default) use the last table
(constant extrapolation in μ, documented not silent). Wave tables take incidences above the
solver's beam limit (≈74.3° for 20 µm profiles) from the 1-D Kirchhoff shape with a Fresnel-scaled
reflectance (`_wave_with_grazing_extension`; `wave_solved` records which).

**Sampling.** A Gaussian mixture in β about the specular point: the inverse-Abel lobe of the
incidence's own in-plane data (`proposal_coef`), plus 2 % uniform over the disk and the coherent
branch; `pdf` is its exact density, and `sample` weights are f cosθ_o / pdf.

**Grid over (σ, τ).** `BRDFTableGrid.at(σ, τ)` interpolates the stacked table arrays with
monotone cubic Hermite (PCHIP, Fritsch–Butland slopes) in log σ, then log τ, after moving each
neighbour's lobe along the basis widths to the interpolated width: interpolating at the nodes,
non-negative (coefficients stay ≥ 0), continuous and differentiable in (σ, τ) for the inverse
layer. Its albedo is the interpolated reflectance (consistent to the interpolation error).
"""

from __future__ import annotations

import time
import warnings

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._cache import cached_arrays
from ..wave._checks import MAX_SIGMA_UM, MAX_TAU_UM, check_energy
from ..wave._solver import SOLVER_VERSION, default_spacing
from ._analytic import (
    DEFAULT_PLATELET_WIDTH_UM,
    AbstractLobeBRDF,
    check_coherent,
    check_positive,
    coherent_lobe_width,
    disk_quadrature,
    metal_index_or_aluminium,
)
from ._in_plane import (
    DEFAULT_INCIDENCE_DEG,
    DEFAULT_NUM_PROFILES,
    _wave_with_grazing_extension,
    as_numpy_lobes,
    check_medium_index,
    kirchhoff_lobes,
)
from ._lobe_basis import (
    COS_MIN,
    DEFAULT_NUM_WIDTHS,
    _hat,
    _interp_index,
    _interp_rows,
    _lobe_widths,
    continue_uncovered,
    fit_radial_lobe,
    geometric_factor,
    normalisation_tensor,
    symmetric_scale,
)
from ._radial_texture import incidence_lookup, log_radial_texture, lookup_index, radial_lookup

#: Bumped when the table construction changes (part of the cache key).
TABLE_VERSION = 13  # 11: the lobe fits' ridge is relative to each basis function; 12: the q_z continuation uses the known (kσ)²;
#                     13: the continuation blends its two reference nodes (continuous where coverage crosses MIN_COVERAGE)


def _table_arrays_from_lobes(lobes, *, method: str = "abel", num_widths: int = DEFAULT_NUM_WIDTHS, min_width: float = 0.0, sinkhorn_iterations: int = 300,
                             kroughness2: float | None = None) -> dict:
    """Build the table arrays (numpy) from in-plane lobes (basis widths ≥ `min_width`, β units; `kroughness2` the
    surface's (kσ)² in the medium when known, else estimated from the lobes for the q_z continuation)."""
    if method not in ("abel", "rotate"):
        raise ValueError(f"method must be 'abel' or 'rotate', got {method!r}")
    inc = np.asarray(lobes.incidence_deg, float)
    if inc.ndim != 1 or inc.size < 1 or np.any(inc < 0) or np.any(inc >= 90) or np.any(np.diff(inc) <= 0):
        raise ValueError(f"lobes.incidence_deg must be increasing angles in [0, 90), got {inc!r}")
    ts = np.deg2rad(np.asarray(lobes.theta_s_deg, float))
    sigma = np.asarray(lobes.sigma, float)
    sig_coh = np.asarray(lobes.sigma_coherent, float)
    reflected = np.asarray(lobes.reflected, float)
    absorbed = np.asarray(lobes.absorbed, float)
    if sigma.shape != (inc.size, ts.size) or sig_coh.shape != sigma.shape:
        raise ValueError(f"lobes.sigma and sigma_coherent must have shape {(inc.size, ts.size)}, got {sigma.shape}, {sig_coh.shape}")
    if not (np.all(np.isfinite(sigma)) and np.all(np.isfinite(sig_coh)) and np.all(np.isfinite(reflected))):
        raise ValueError("lobes contain non-finite values")
    widths = _lobe_widths(num_widths)
    sigma_sem, reflected_se, coherent_se = as_numpy_lobes(lobes).errors()
    R_coh = np.trapezoid(sig_coh, ts, axis=-1)
    R_inc = reflected - R_coh
    if np.any(R_inc < -1e-9) or np.any(R_coh < -1e-9):
        raise ValueError(f"lobes: coherent part exceeds the reflected fraction (R_coh={R_coh}, reflected={reflected})")
    R_inc, R_coh = np.maximum(R_inc, 0.0), np.maximum(R_coh, 0.0)  # only round-off (< 1e-9) removed
    if np.any(reflected > 1.0 + 1e-6):
        warnings.warn(f"lobe source reflects more than it receives at incidences {inc[reflected > 1 + 1e-6]} deg (not energy conserving)", stacklevel=3)
    cs = np.cos(ts)
    sb = np.sin(ts)
    dbeta = np.abs(np.gradient(sb))
    J = inc.size
    mu_nodes = np.cos(np.deg2rad(inc))
    # in-plane data p(u) per unit β, its mean cosine μ̄ = (μ_i + μ_o)/2 and its fit weight
    P = (sigma - sig_coh) / np.maximum(cs, 1e-300)
    U = sb[None, :] - np.sin(np.deg2rad(inc))[:, None]
    MU = 0.5 * (mu_nodes[:, None] + cs[None, :])
    pmax = np.max(np.where(cs > COS_MIN, P, 0.0), axis=1, keepdims=True)
    pmax = np.where(pmax > 0, pmax, 1.0)  # an incidence without incoherent light: absolute weights
    W = np.broadcast_to(np.sqrt(dbeta)[None, :], P.shape)  # × relative error down to 1 % of the peak (fit_radial_lobe)
    # f = a a G(ρ, c) L(ρ; μ̄) / (μ_i μ_o): fit the shift-invariant L to p μ_i μ_o / G(u, c) in the plane
    obliquity = mu_nodes[:, None] * cs[None, :] / geometric_factor(U**2, 2.0 * MU, xp=np)
    valid = np.broadcast_to(cs > COS_MIN, P.shape)
    coef = np.zeros((J, widths.size))
    resid = np.zeros(J)
    prop = np.zeros((J, widths.size))
    for j in range(J):
        h = _hat(MU, mu_nodes, j) * valid if J > 1 else valid.astype(float)
        sel = h > 0
        if not np.any(sel[j]):  # no data near this incidence's own mean cosine: use its own lobe
            sel = np.zeros_like(sel)
            sel[j] = cs > 0.02
            h = sel.astype(float)
        floor = (0.01 * pmax * obliquity)[sel]
        coef[j], resid[j] = fit_radial_lobe(U[sel], (P * obliquity)[sel], np.sqrt(h[sel]) * W[sel], widths, method, min_width, floor=floor)
        # sampling proposal: the shift-invariant lobe of this incidence alone (inverse Abel of p)
        own = cs > COS_MIN
        prop[j], _ = fit_radial_lobe(U[j, own], P[j, own], W[j, own], widths, "abel", min_width, floor=0.01 * pmax[j, 0])
        if not np.any(prop[j] > 0):  # no lobe: a proposal of the narrowest allowed width
            prop[j, min(int(np.searchsorted(widths, min_width)), widths.size - 1)] = 1.0
        prop[j] = prop[j] / np.sum(prop[j] * np.pi * widths**2)
    coef, coverage, continued = continue_uncovered(coef, widths, mu_nodes, R_coh, R_inc, kroughness2, min_width)
    # kernel of the symmetric normalisation: ∫_disk a(μ_o) L(ρ; μ̄) dβ at each tabulated incidence
    Kmat = np.einsum("jlmk,mk->jl", normalisation_tensor(mu_nodes, widths), coef)
    wi, wo, wt = disk_quadrature(mu_nodes, xp=np)
    rho2 = (wo[..., 0] + wi[:, None, 0]) ** 2 + wo[..., 1] ** 2
    outside = 1.0 - np.sum(np.sum(prop[:, None, :] * np.exp(-rho2[..., None] / widths**2), -1) * wt, -1)
    a = symmetric_scale(Kmat, R_inc, np.where(R_inc > 0, 1.0, 0.0), sinkhorn_iterations, xp=np)
    norm_err = float(np.max(np.abs(a * (Kmat @ a) - R_inc)))
    return {
        "incidence_deg": inc,
        "widths": widths,
        "coef": coef,
        "proposal_coef": prop,
        "scale": a,
        "reflectance": reflected,
        "coherent_reflectance": R_coh,
        "incoherent_reflectance": R_inc,
        "absorbed": absorbed,
        "outside_fraction": outside,
        "fit_residual": resid,
        "lobe_coverage": coverage,
        "continued": continued,
        "normalisation_error": np.asarray(norm_err),
        "reflectance_se": reflected_se,
        "coherent_reflectance_se": coherent_se,
        "lobe_relative_se": _lobe_relative_se(sigma - sig_coh, sigma_sem),
        "lobe_theta_s_deg": np.asarray(lobes.theta_s_deg, float),
        "lobe_sigma": sigma,
        "lobe_sigma_coherent": sig_coh,
    }


def _kroughness2(sigma_um: float, wavelength_um: float, n_medium: float) -> float:
    """(kσ)² of a surface of rms height σ in a medium of index n, k = 2πn/λ0: the roughness of the q_z continuation."""
    return float((2.0 * np.pi * n_medium / wavelength_um * sigma_um) ** 2)


def _lobe_relative_se(incoherent, sem) -> np.ndarray:
    """Per incidence, the rms relative standard error of the in-plane diffuse lobe where it exceeds half its peak."""
    core = incoherent >= 0.5 * np.max(incoherent, axis=-1, keepdims=True)
    rel = np.where(core & (incoherent > 0), sem / np.where(incoherent > 0, incoherent, 1.0), 0.0)
    return np.sqrt(np.sum(rel**2, -1) / np.maximum(core.sum(-1), 1))


class TabulatedBRDF(AbstractLobeBRDF):
    """Tabulated isotropic platelet BRDF built from in-plane (wave) lobes over incidence 0–89°.

    Construct with `table_from_lobes` or `platelet_brdf_table`; see the module docstring for the
    construction. `albedo(cosθ_i)` is the tabulated (wave) reflectance, interpolated in cosθ_i.

    Fields (arrays over tabulated incidences J and basis widths K): incidence_deg (J,), widths (K,),
    coef (J, K) lobe coefficients C_j, proposal_coef (J, K) unit-mass sampling lobes, scale (J,)
    symmetric normalisation a, coherent_reflectance_table, incoherent_reflectance_table, absorbed,
    outside_fraction (J,); static n_medium, the binder index the lobes were computed in (None:
    not recorded, so the tracer cannot check it against the coat index). Derived in the
    constructor: lobe_texture, proposal_texture (J, R) and proposal_mass (J,), the rows' radial
    sums on a fine grid (`_radial_texture`, ≤ 2 × 10⁻⁴ from the sums), which `evaluate`, `pdf` and
    `sample` look up, incidence_lookup (B,), bins in cosθ that find the two rows about an
    incidence, and coherent_scale (M,), the coherent lobe's symmetric scale (`_coherent_lobe`);
    static radial_texture=False sums over the basis and searches the rows instead (the reference).
    """

    incidence_deg: Float[Array, " J"]
    widths: Float[Array, " K"]
    coef: Float[Array, "J K"]
    proposal_coef: Float[Array, "J K"]
    scale: Float[Array, " J"]
    coherent_reflectance_table: Float[Array, " J"]
    incoherent_reflectance_table: Float[Array, " J"]
    absorbed: Float[Array, " J"]
    outside_fraction: Float[Array, " J"]
    lobe_texture: Float[Array, "J R"]
    proposal_texture: Float[Array, "J R"]
    proposal_mass: Float[Array, " J"]
    incidence_lookup: Int[Array, " B"]
    coherent_scale: Float[Array, " M"]
    coherent: str = eqx.field(static=True)
    coherent_width: float = eqx.field(static=True)
    n_medium: float | None = eqx.field(static=True)
    radial_texture: bool = eqx.field(static=True)

    def __init__(self, incidence_deg, widths, coef, proposal_coef, scale, coherent_reflectance_table, incoherent_reflectance_table, absorbed, outside_fraction, *, coherent="lobe", coherent_width=0.0083, n_medium=None,
                 radial_texture=True):
        check_coherent(coherent)
        check_positive("coherent_width", coherent_width, 1.0)
        if n_medium is not None:
            check_medium_index(n_medium)
        self.n_medium = None if n_medium is None else float(n_medium)
        self.incidence_deg, self.widths, self.coef, self.scale = incidence_deg, widths, coef, scale
        self.proposal_coef = proposal_coef
        self.coherent_reflectance_table, self.incoherent_reflectance_table = coherent_reflectance_table, incoherent_reflectance_table
        self.absorbed, self.outside_fraction = absorbed, outside_fraction
        self.coherent, self.coherent_width, self.radial_texture = coherent, float(coherent_width), bool(radial_texture)
        # the rows' radial lobes and sampling densities on a fine grid (`_radial_texture`), looked up by the tracer
        self.lobe_texture = log_radial_texture(coef, widths)
        self.proposal_texture = log_radial_texture(proposal_coef, widths)
        self.proposal_mass = jnp.sum(jnp.asarray(proposal_coef) * np.pi * jnp.asarray(widths) ** 2, -1)
        self.incidence_lookup = incidence_lookup(jnp.cos(jnp.deg2rad(jnp.asarray(incidence_deg))))
        self.coherent_scale = self._derive_coherent_scale()

    @classmethod
    def from_arrays(cls, arrays: dict, *, coherent: str = "lobe", coherent_width: float = 0.0083, n_medium: float | None = None) -> "TabulatedBRDF":
        """A table from the arrays of `platelet_table_arrays` (e.g. read from the cache), built in a binder of index `n_medium`."""
        f = lambda key: jnp.asarray(np.asarray(arrays[key], float))  # noqa: E731
        return cls(
            f("incidence_deg"), f("widths"), f("coef"), f("proposal_coef"), f("scale"), f("coherent_reflectance"), f("incoherent_reflectance"),
            f("absorbed"), f("outside_fraction"), coherent=coherent, coherent_width=coherent_width, n_medium=n_medium,
        )

    def with_radial_texture(self, enabled: bool) -> "TabulatedBRDF":
        """The same table, its radial lobes looked up in the textures (True) or summed over the basis (False)."""
        return TabulatedBRDF(
            self.incidence_deg, self.widths, self.coef, self.proposal_coef, self.scale, self.coherent_reflectance_table,
            self.incoherent_reflectance_table, self.absorbed, self.outside_fraction, coherent=self.coherent,
            coherent_width=self.coherent_width, n_medium=self.n_medium, radial_texture=enabled,
        )

    @property
    def medium_index(self):
        return self.n_medium

    @property
    def mu_nodes(self):
        return jnp.cos(jnp.deg2rad(self.incidence_deg))

    def _index(self, mu):
        """(j0, t): μ between tabulated incidences j0 and j0 + 1 (the lookup, or a binary search for the reference)."""
        if self.radial_texture and self.incidence_lookup.shape[0] > 0:
            return lookup_index(mu, self.mu_nodes, self.incidence_lookup)
        return _interp_index(jnp.asarray(mu), self.mu_nodes)

    def _at(self, values, mu):
        return _interp_rows(values, *self._index(mu))

    def lobe(self, mu_bar, rho2):
        """G(ρ, 2μ̄) L(ρ; μ̄): the radial lobe times the geometric factor (f_inc = a(μ_i) a(μ_o) G L / (μ_i μ_o))."""
        j0, t = self._index(mu_bar)
        if self.radial_texture:
            L = radial_lookup(self.lobe_texture, j0, t, rho2)
        else:
            L = jnp.sum(_interp_rows(self.coef, j0, t) * jnp.exp(-rho2[..., None] / self.widths**2), -1)
        return L * geometric_factor(rho2, 2.0 * mu_bar)

    def incoherent(self, wi, wo):
        mi, mo = wi[..., 2], wo[..., 2]
        rho2 = jnp.sum((wi[..., :2] + wo[..., :2]) ** 2, -1)
        obl = jnp.maximum(mi * mo, 1e-300)
        f = self._at(self.scale, mi) * self._at(self.scale, mo) * self.lobe(0.5 * (mi + mo), rho2) / obl
        return jnp.where((mi > 0) & (mo > 0), f, 0.0)

    def coherent_reflectance(self, cos_i):
        return self._at(self.coherent_reflectance_table, cos_i)

    def incoherent_albedo(self, cos_i):
        return self._at(self.incoherent_reflectance_table, cos_i)

    def proposal(self, cos_i):
        c = self._at(self.proposal_coef, cos_i)
        probs = c * np.pi * self.widths**2
        probs = probs / jnp.sum(probs, -1, keepdims=True)
        return jnp.broadcast_to(self.widths, probs.shape), probs

    def proposal_density(self, cos_i, rho2):
        if not self.radial_texture:
            return super().proposal_density(cos_i, rho2)
        j0, t = self._index(cos_i)
        mass = _interp_rows(self.proposal_mass, j0, t)
        return radial_lookup(self.proposal_texture, j0, t, rho2) / jnp.maximum(mass, jnp.finfo(mass.dtype).tiny)

    def coherent_share(self, cos_i):
        rc, ri = self.coherent_reflectance(cos_i), self.incoherent_albedo(cos_i)
        return rc / jnp.maximum(rc + ri, 1e-300)

    def in_plane(self, incidence_deg, theta_o_deg) -> Float[Array, "I O"]:
        """f in the plane of incidence; θ_o > 0 on the specular side. Shape (len(inc), len(θ_o))."""
        ti = jnp.deg2rad(jnp.atleast_1d(jnp.asarray(incidence_deg, float)))[:, None]
        to = jnp.deg2rad(jnp.atleast_1d(jnp.asarray(theta_o_deg, float)))[None, :]
        wi = jnp.stack(jnp.broadcast_arrays(jnp.sin(ti), 0.0 * to, jnp.cos(ti)), -1)
        wo = jnp.stack(jnp.broadcast_arrays(-jnp.sin(to), 0.0 * ti, jnp.cos(to)), -1)
        return self.evaluate(wi, wo)


def table_from_lobes(
    lobes,
    *,
    method: str = "abel",
    coherent: str = "lobe",
    wavelength_um: float = 0.5,
    n_medium: float = 1.5,
    platelet_width_um: float = DEFAULT_PLATELET_WIDTH_UM,
    coherent_width: float | None = None,
    num_widths: int = DEFAULT_NUM_WIDTHS,
    min_width: float = 0.0,
    sigma_um: float | None = None,
) -> TabulatedBRDF:
    """Tabulated BRDF from any in-plane lobe source (fields of `WaveLobes`), uncached.

    Arguments:
        lobes: in-plane lobes over incidence angles in [0, 90) (increasing).
        method: "abel" (inverse Abel, default) or "rotate" (axisymmetric rotation of the 1-D lobe).
        coherent: "lobe" (default) or "delta" for the coherent part.
        wavelength_um, n_medium, platelet_width_um: set the coherent lobe width λ0/(n D √(2π)).
        coherent_width: explicit β standard deviation of the coherent lobe.
        num_widths: number of Gaussian basis widths.
        min_width: narrowest basis width used (β units); `platelet_table_arrays` uses 2/(kτ),
            the narrowest term of a Gaussian surface's diffuse lobe, so profile-average speckle
            is not fitted as structure.
        sigma_um: rms height of the surface [µm] when known: the q_z continuation towards grazing then uses
            (kσ)², k = 2π n_medium / wavelength_um; None (default) estimates (kσ)² from the lobes.
    """
    check_coherent(coherent)
    if sigma_um is not None:
        check_positive("sigma_um", sigma_um, MAX_SIGMA_UM)
    arrays = _table_arrays_from_lobes(lobes, method=method, num_widths=num_widths, min_width=min_width,
                                      kroughness2=None if sigma_um is None else _kroughness2(sigma_um, wavelength_um, n_medium))
    if coherent_width is None:
        coherent_width = coherent_lobe_width(wavelength_um, n_medium, platelet_width_um)
    return TabulatedBRDF.from_arrays(arrays, coherent=coherent, coherent_width=coherent_width, n_medium=n_medium)




def platelet_table_arrays(
    sigma_um: float,
    tau_um: float,
    *,
    source: str = "wave",
    wavelength_um: float = 0.5,
    n_medium: float = 1.5,
    metal_index=None,
    length_um: float = 20.0,
    num_profiles: int = DEFAULT_NUM_PROFILES,
    seed: int = 0,
    incidence_deg=None,
    theta_s_deg=None,
    boundary: str = "impedance",
    polarization: str = "unpolarized",
    correlation: str = "gaussian",
    points_per_wavelength=None,
    method: str = "abel",
    num_widths: int = DEFAULT_NUM_WIDTHS,
    cache: bool = True,
    cache_dir=None,
    heartbeat=None,
) -> tuple[dict, dict]:
    """Arrays of a platelet BRDF table, built or read from the content-hashed cache.

    `heartbeat`: while the wave solver runs, called every few seconds as `heartbeat(fraction of the profiles
    solved, seconds)` (`profile_averaged_lobes`; e.g. `paintjax._progress.print_progress`); not part of the key.

    Returns:
        (arrays, info) with info = {"cache_hit", "seconds", "key inputs"}.
    """
    check_positive("sigma_um", sigma_um, MAX_SIGMA_UM)
    check_positive("tau_um", tau_um, MAX_TAU_UM)
    check_positive("wavelength_um", wavelength_um, 20.0)
    check_medium_index(n_medium)
    if source not in ("wave", "kirchhoff"):
        raise ValueError(f"source must be 'wave' or 'kirchhoff', got {source!r}")
    if method not in ("abel", "rotate"):
        raise ValueError(f"method must be 'abel' or 'rotate', got {method!r}")
    inc = DEFAULT_INCIDENCE_DEG if incidence_deg is None else np.asarray(incidence_deg, float)
    if theta_s_deg is None:
        theta_s_deg = np.linspace(-89.5, 89.5, 359) if source == "wave" else np.linspace(-89.75, 89.75, 719)
    ts = np.asarray(theta_s_deg, float)
    metal = metal_index_or_aluminium(metal_index, wavelength_um)
    min_width = float(2.0 * wavelength_um / (2.0 * np.pi * n_medium * tau_um))  # 2/(kτ)
    inputs = {
        "table_version": TABLE_VERSION, "source": source, "sigma_um": float(sigma_um), "tau_um": float(tau_um),
        "wavelength_um": float(wavelength_um), "n_medium": float(n_medium), "metal_index": metal,
        "incidence_deg": inc, "theta_s_deg": ts, "method": method, "num_widths": int(num_widths),
    }
    if source == "wave":
        # the synthesised profiles need two grid steps per correlation length
        dx = default_spacing(wavelength_um, n_medium, points_per_wavelength, sigma_um=float(sigma_um), tau_um=float(tau_um),
                             correlation=correlation)
        if tau_um < 2.0 * dx:
            raise ValueError(f"tau_um must be at least {2.0 * dx:.3g} µm for the wave solver's grid ({dx:.3g} µm at "
                             f"wavelength_um={float(wavelength_um):g}; finer with more points_per_wavelength), got {tau_um!r}; "
                             "or use source='kirchhoff'")
        inputs |= {
            "length_um": float(length_um), "num_profiles": int(num_profiles), "seed": int(seed), "boundary": boundary,
            "polarization": polarization, "correlation": correlation,
            "points_per_wavelength": None if points_per_wavelength is None else float(points_per_wavelength),
            "solver_version": SOLVER_VERSION,
        }

    def build():
        solved = np.ones(inc.size, bool)
        if source == "wave":
            lobes = _wave_with_grazing_extension(
                sigma_um, tau_um, inc, ts, length_um=length_um, num_profiles=num_profiles, seed=seed,
                wavelength_um=wavelength_um, n_medium=n_medium, boundary=boundary, polarization=polarization,
                correlation=correlation, points_per_wavelength=points_per_wavelength, metal_index=metal, heartbeat=heartbeat,
            )
            solved = np.isin(inc, lobes[1])
            lobes = lobes[0]
        else:
            lobes = kirchhoff_lobes(sigma_um, tau_um, incidence_deg=inc, theta_s_deg=ts, wavelength_um=wavelength_um, n_medium=n_medium, metal_index=metal)
        out = _table_arrays_from_lobes(lobes, method=method, num_widths=num_widths, min_width=min_width,
                                       kroughness2=_kroughness2(sigma_um, wavelength_um, n_medium))
        out["wave_solved"] = solved
        return out

    t0 = time.perf_counter()
    arrays, hit = cached_arrays("brdf_table", inputs, build, folder=cache_dir, use_cache=cache)
    if source == "wave":  # each profile's solution conserves energy to ~1e-3 when converged
        check_energy(arrays["reflectance"], arrays["absorbed"], inc, solved=arrays["wave_solved"],
                     what=f"sigma_um={float(sigma_um):g}, tau_um={float(tau_um):g}: the wave solution",
                     fix=f"the default (curvature-following) sampling or more points_per_wavelength, a gentler roughness "
                         f"(rms slope ≈ {np.degrees(np.arctan(np.sqrt(2.0) * sigma_um / tau_um)):.0f}°), or source='kirchhoff'")
    return arrays, {"cache_hit": hit, "seconds": time.perf_counter() - t0}


def platelet_brdf_table(
    sigma_um: float,
    tau_um: float,
    *,
    coherent: str = "lobe",
    platelet_width_um: float = DEFAULT_PLATELET_WIDTH_UM,
    coherent_width: float | None = None,
    **kwargs,
) -> TabulatedBRDF:
    """Platelet BRDF table for roughness (σ, τ) [µm], cached on disk (see `platelet_table_arrays`).

    Arguments:
        sigma_um, tau_um: rms height and correlation length of the platelet surface [µm].
        coherent: "lobe" (default) or "delta".
        platelet_width_um, coherent_width: width of the coherent lobe (see `paintjax.brdf._analytic`).
        **kwargs: `platelet_table_arrays` options (source, wavelength_um, n_medium, metal_index,
            length_um, num_profiles, seed, incidence_deg, theta_s_deg, method, cache, cache_dir, ...).
    """
    check_coherent(coherent)
    arrays, _ = platelet_table_arrays(sigma_um, tau_um, **kwargs)
    if coherent_width is None:
        coherent_width = coherent_lobe_width(kwargs.get("wavelength_um", 0.5), kwargs.get("n_medium", 1.5), platelet_width_um)
    return TabulatedBRDF.from_arrays(arrays, coherent=coherent, coherent_width=coherent_width, n_medium=kwargs.get("n_medium", 1.5))

