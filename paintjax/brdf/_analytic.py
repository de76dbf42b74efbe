"""Lobe BRDFs in direction-cosine space, and the analytic Kirchhoff (Beckmann) BRDF of a Gaussian metal.

**Direction-cosine space.** β = (x, y) components of a unit direction in the platelet frame
(z = normal). Since dω = dβ / cosθ, the BRDF f(ω_i, ω_o) is also the reflected power per unit
β-area: ∫ f cosθ_o dω_o = ∫_disk f dβ_o over the unit disk |β_o| < 1. The specular point of ω_i is
β₀ = −β_i and lobes are functions of ρ = |β_o − β₀| = |β_o + β_i| (Harvey–Shack).

**Kirchhoff BRDF** (scalar stationary-phase Kirchhoff, Beckmann–Spizzichino series, no shadowing)
of an isotropic Gaussian surface, C(r) = σ² exp(−r²/τ²), in a medium of index n (k = 2πn/λ0),
times the unpolarised Fresnel reflectance R(χ) of the metal at the local incidence angle χ
(cos χ = |ω_i + ω_o| / 2); c = cosθ_i + cosθ_o, X = (kσc)²:

    f_inc = R(χ) · 4cos⁴χ / (cosθ_i cosθ_o c²) · (kτ)² / (4π) · Σ_{m≥1} e^{−X} X^m / (m! m) · e^{−(kρτ)² / (4m)}

and a coherent (specular) reflectance R(θ_i) exp(−(2kσ cosθ_i)²). Its geometric-optics limit is
R(χ) D(h) / (4 cosθ_i cosθ_o) with the Beckmann normal distribution D of slope parameter 2σ/τ;
its in-plane 1-D counterpart is the closed form of the domain brief §4.

**Coherent part.** Every lobe BRDF carries a coherent reflectance R_coh(θ_i), either as a delta
(`coherent="delta"`: `evaluate` omits it, `sample` returns the mirror direction for it) or, by
default, as a narrow lobe (`coherent="lobe"`): the diffraction lobe of a finite platelet, a
Gaussian in β of standard deviation s per axis (default λ0 / (n D √(2π)), the Gaussian with the
peak and area of the sinc² pattern of a square of width D), carrying exactly R_coh(θ_i) into the
unit disk at every incidence through a symmetric scale h(μ_i) h(μ_o) (`_coherent_lobe`: reciprocal,
right at the disk's edge too). The lobe keeps next-event estimation in the tracer able to see the
coherent light.
"""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import gammaln
from jaxtyping import Array, Float

from ..optics._aluminium import aluminium_index
from ..optics._fresnel import fresnel_conductor
from ._coherent_lobe import coherent_lobe, coherent_lobe_scale, coherent_scale_nodes
from ._platelet import AbstractPlateletBRDF

#: Probability with which lobe samplers draw β uniformly over the disk (bounds the weights).
UNIFORM_FRACTION = 0.02
#: Default platelet width D [µm] that sets the width of the coherent diffraction lobe (size D50).
DEFAULT_PLATELET_WIDTH_UM = 16.0
#: Radial panel breaks of the disk quadrature (β units); 12 Gauss–Legendre nodes per panel.
_DISK_BREAKS = np.array([0.0, 0.004, 0.012, 0.03, 0.06, 0.1, 0.16, 0.25, 0.38, 0.55, 0.8, 1.1, 1.5, 2.0])


def check_positive(name: str, value, hi: float = np.inf) -> None:
    """ValueError naming `name` unless value is a finite number in (0, hi] (traced values pass)."""
    try:
        v = np.asarray(value, dtype=float)
    except (jax.errors.TracerArrayConversionError, jax.errors.ConcretizationTypeError):
        return
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number in (0, {hi:g}], got {value!r}") from None
    if np.any(~np.isfinite(v)) or np.any(v <= 0) or np.any(v > hi):
        raise ValueError(f"{name} must lie in (0, {hi:g}], got {value!r}")


def check_coherent(coherent: str) -> None:
    if coherent not in ("lobe", "delta"):
        raise ValueError(f"coherent must be 'lobe' or 'delta', got {coherent!r}")


def metal_index_or_aluminium(metal_index, wavelength_um: float) -> complex:
    """The given complex metal index, or aluminium (Rakić Lorentz–Drude) at the vacuum wavelength."""
    if metal_index is None:
        return complex(np.asarray(aluminium_index(wavelength_um)))
    m = complex(metal_index)
    if not (np.isfinite(m.real) and np.isfinite(m.imag) and m.real >= 0 and m.imag >= 0):
        raise ValueError(f"metal_index must be a finite complex index n + ik with n, k ≥ 0, got {metal_index!r}")
    return m


def coherent_lobe_width(wavelength_um: float, n_medium: float, platelet_width_um: float) -> float:
    """Standard deviation per axis in β of the coherent diffraction lobe of a square platelet."""
    check_positive("platelet_width_um", platelet_width_um)
    return float(wavelength_um / (n_medium * platelet_width_um * np.sqrt(2.0 * np.pi)))


def _safe_sqrt(x):
    return jnp.sqrt(jnp.maximum(x, 1e-300))


def flip_to_upper(w):
    """(w with z ≥ 0, sign) — the BRDFs are two-sided: both faces scatter alike."""
    sign = jnp.where(w[..., 2] < 0, -1.0, 1.0)
    return w * jnp.stack([jnp.ones_like(sign), jnp.ones_like(sign), sign], -1), sign


def hemisphere_directions(n_theta: int = 200, n_phi: int = 400):
    """Directions and weights of ∫ g(ω) cosθ dω over the upper hemisphere: Gauss–Legendre in θ, midpoints in φ.

    Returns:
        (ω (n_theta · n_phi, 3) as a JAX array, weights (n_theta · n_phi,) as NumPy).
    """
    if int(n_theta) != n_theta or int(n_phi) != n_phi or n_theta < 1 or n_phi < 1:
        raise ValueError(f"n_theta and n_phi must be positive integers, got {n_theta!r}, {n_phi!r}")
    x, w = np.polynomial.legendre.leggauss(int(n_theta))
    th = 0.25 * np.pi * (x + 1.0)
    ph = (np.arange(n_phi) + 0.5) * 2.0 * np.pi / n_phi
    wo = np.stack(np.broadcast_arrays(np.sin(th)[:, None] * np.cos(ph), np.sin(th)[:, None] * np.sin(ph), np.cos(th)[:, None]), -1)
    wt = (0.25 * np.pi * w * np.cos(th) * np.sin(th))[:, None] * (2.0 * np.pi / n_phi) * np.ones_like(ph)
    return jnp.asarray(wo.reshape(-1, 3)), wt.ravel()


def disk_quadrature(cos_i: Float[Array, "..."], n_phi: int = 64, n_gl: int = 12, xp=jnp):
    """Quadrature over the unit β-disk in polar coordinates around the specular point of ω_i.

    ω_i = (sinθ_i, 0, cosθ_i); the radial panels are clipped at the disk edge, so the rule
    integrates exactly the propagating part. Integrand f(ω_i, ω_o) gives ∫ f cosθ_o dω_o.
    `xp` is jax.numpy (default) or numpy (host-side table builds, no compilation).

    Returns:
        (wi (..., 3), wo (..., Q, 3), weights (..., Q)).
    """
    sqrt = lambda x: xp.sqrt(xp.maximum(x, 1e-300))  # noqa: E731
    cos_i = xp.asarray(cos_i)
    sin_i = sqrt(1.0 - cos_i**2)
    x, w = np.polynomial.legendre.leggauss(n_gl)
    phi = (np.arange(n_phi) + 0.5) * 2.0 * np.pi / n_phi
    b = sin_i[..., None]  # specular point at β = (−b, 0)
    cphi, sphi = np.cos(phi), np.sin(phi)
    rho_max = b * cphi + sqrt(1.0 - b**2 * sphi**2)  # (..., P), distance to the circle
    lo = xp.minimum(_DISK_BREAKS[:-1], rho_max[..., None])  # (..., P, panels)
    hi = xp.minimum(_DISK_BREAKS[1:], rho_max[..., None])
    half = 0.5 * (hi - lo)
    rho = (lo + half)[..., None] + half[..., None] * x  # (..., P, panels, n_gl)
    wt = half[..., None] * w * rho * (2.0 * np.pi / n_phi)
    bx = -b[..., None, None] + rho * cphi[:, None, None]
    by = rho * sphi[:, None, None] * xp.ones_like(bx)
    shape = bx.shape[:-3] + (-1,)
    bx, by, wt = bx.reshape(shape), by.reshape(shape), wt.reshape(shape)
    bz = sqrt(1.0 - bx**2 - by**2)
    wo = xp.stack([bx, by, bz], -1)
    wi = xp.stack([sin_i, xp.zeros_like(sin_i), cos_i], -1)
    return wi, wo, wt


class AbstractLobeBRDF(AbstractPlateletBRDF):
    """A continuous lobe about the specular point plus a coherent part (delta or narrow lobe).

    Subclasses give the incoherent (diffuse) BRDF, the coherent reflectance, a Gaussian-mixture
    proposal in β about the specular point and the sampling share of the coherent part; this base
    class provides `evaluate`, `sample`, `pdf` and `albedo` consistently.
    """

    coherent: eqx.AbstractVar[str]
    coherent_width: eqx.AbstractVar[float]
    coherent_scale: eqx.AbstractVar[Float[Array, " M"]]
    is_delta: ClassVar[bool] = False

    @abc.abstractmethod
    def incoherent(self, wi: Float[Array, "... 3"], wo: Float[Array, "... 3"]) -> Float[Array, "..."]:
        """The incoherent (diffuse) part of f [1/sr], reciprocal; zero below the plane."""

    @abc.abstractmethod
    def coherent_reflectance(self, cos_i: Float[Array, "..."]) -> Float[Array, "..."]:
        """Power reflected coherently (specular) at incidence cosine cos_i."""

    @abc.abstractmethod
    def incoherent_albedo(self, cos_i: Float[Array, "..."]) -> Float[Array, "..."]:
        """∫ f_inc cosθ_o dω_o over the hemisphere."""

    @abc.abstractmethod
    def proposal(self, cos_i: Float[Array, "..."]) -> tuple[Float[Array, "... K"], Float[Array, "... K"]]:
        """(widths w_k, probabilities p_k) of the sampling mixture Σ p_k e^{−ρ²/w_k²} / (π w_k²)."""

    @abc.abstractmethod
    def coherent_share(self, cos_i: Float[Array, "..."]) -> Float[Array, "..."]:
        """Probability with which `sample` draws the coherent part (≈ its share of the albedo)."""

    def proposal_density(self, cos_i: Float[Array, "..."], rho2: Float[Array, "..."]) -> Float[Array, "..."]:
        """The sampling mixture Σ p_k e^{−ρ²/w_k²} / (π w_k²) of `proposal` at squared offset ρ² from specular."""
        widths, probs = self.proposal(cos_i)
        return jnp.sum(probs * jnp.exp(-rho2[..., None] / widths**2) / (np.pi * widths**2), -1)

    # ------------------------------------------------------------------ coherent lobe
    def _derive_coherent_scale(self) -> Float[Array, " M"]:
        """The coherent lobe's symmetric scale h on `coherent_scale_nodes()` (empty for a delta); constructors
        store it as `coherent_scale` once `coherent_reflectance` can be evaluated."""
        if self.coherent != "lobe":
            return jnp.zeros((0,))
        return coherent_lobe_scale(self.coherent_reflectance(jnp.asarray(coherent_scale_nodes())), self.coherent_width)

    def _coherent_lobe(self, wi, wo):
        """Narrow Gaussian lobe h(μ_i) h(μ_o) G_s(ρ) carrying R_coh(μ_i) into the disk, reciprocal (`_coherent_lobe` module)."""
        return coherent_lobe(self.coherent_scale, self.coherent_width, wi, wo)

    def evaluate(self, wi, wo):
        up = (wi[..., 2] > 0) & (wo[..., 2] > 0)
        f = self.incoherent(wi, wo)
        if self.coherent == "lobe":
            f = f + self._coherent_lobe(wi, wo)
        return jnp.where(up, f, 0.0)

    def albedo(self, cos_i):
        return self.coherent_reflectance(cos_i) + self.incoherent_albedo(cos_i)

    def _beta_density(self, wi, wo):
        """Sampling density per unit β-area of the continuous branches (incl. the coherent lobe)."""
        cos_i = wi[..., 2]
        rho2 = jnp.sum((wi[..., :2] + wo[..., :2]) ** 2, -1)
        gauss = self.proposal_density(cos_i, rho2)
        q_inc = UNIFORM_FRACTION / np.pi + (1.0 - UNIFORM_FRACTION) * gauss
        pc = self.coherent_share(cos_i)
        q = (1.0 - pc) * q_inc
        if self.coherent == "lobe":
            s = self.coherent_width
            q = q + pc * jnp.exp(-0.5 * rho2 / s**2) / (2.0 * np.pi * s**2)
        return q

    def pdf(self, wi: Float[Array, "... 3"], wo: Float[Array, "... 3"]) -> Float[Array, "..."]:
        """Density per steradian with which `sample` returns ω_o (continuous part; 0 below the plane)."""
        up = (wi[..., 2] > 0) & (wo[..., 2] > 0)
        return jnp.where(up, self._beta_density(wi, wo) * wo[..., 2], 0.0)

    def sample(self, key, wi):
        wi, sign = flip_to_upper(wi)
        batch = wi.shape[:-1]
        cos_i = wi[..., 2]
        pc = self.coherent_share(cos_i)
        dt = wi.dtype
        # one draw of the branch, the mixture component, the radius and the azimuth uniforms
        u, u_comp, u_r, u_phi = jnp.moveaxis(jax.random.uniform(key, batch + (4,), dt), -1, 0)
        is_coh = u < pc
        u_inc = (u - pc) / jnp.maximum(1.0 - pc, 1e-300)
        is_unif = (~is_coh) & (u_inc < UNIFORM_FRACTION)
        widths, probs = self.proposal(cos_i)
        # the component by inverting the mixture's cumulative weights (not a Gumbel draw per component)
        cdf = jnp.cumsum(probs, -1)
        comp = jnp.sum(cdf[..., :-1] < ((1.0 - u_comp) * cdf[..., -1])[..., None], -1)  # (1 − u) in (0, 1]
        w = jnp.take_along_axis(widths, comp[..., None], axis=-1)[..., 0]
        v = 1.0 - u_r  # in (0, 1]
        phi = 2.0 * np.pi * u_phi
        rho = jnp.where(is_coh, self.coherent_width * jnp.sqrt(-2.0 * jnp.log(v)), w * jnp.sqrt(-jnp.log(v)))
        e = jnp.stack([jnp.cos(phi), jnp.sin(phi)], -1)
        beta = jnp.where(is_unif[..., None], jnp.sqrt(v)[..., None] * e, -wi[..., :2] + rho[..., None] * e)
        b2 = jnp.sum(beta**2, -1)
        valid = b2 < 1.0 - 1e-12
        mirror = jnp.concatenate([-wi[..., :2], wi[..., 2:]], -1)
        wo = jnp.concatenate([beta, _safe_sqrt(1.0 - b2)[..., None]], -1)
        wo = jnp.where(valid[..., None], wo, mirror)
        f = self.evaluate(wi, wo)
        q = self._beta_density(wi, wo)
        weight = jnp.where(valid, f / jnp.maximum(q, 1e-300), 0.0)
        if self.coherent == "delta":
            wo = jnp.where(is_coh[..., None], mirror, wo)
            weight = jnp.where(is_coh, self.coherent_reflectance(cos_i) / jnp.maximum(pc, 1e-300), weight)
        wo = wo * jnp.stack([jnp.ones_like(sign), jnp.ones_like(sign), sign], -1)
        return wo, weight

    def quadrature_albedo(self, cos_i: Float[Array, "..."], n_phi: int = 64, n_gl: int = 12) -> Float[Array, "..."]:
        """∫ f_inc cosθ_o dω_o by the disk quadrature (the coherent part is not included)."""
        wi, wo, wt = disk_quadrature(cos_i, n_phi, n_gl)
        return jnp.sum(self.incoherent(wi[..., None, :], wo) * wt, -1)


def kirchhoff_series(X: Float[Array, "..."], q2tau2: Float[Array, "..."], num_terms: int) -> Float[Array, "..."]:
    """Σ_{m=1}^{M} e^{−X} X^m / (m! m) · e^{−q²τ²/(4m)} (log-space terms, no overflow)."""
    m = jnp.arange(1, num_terms + 1, dtype=jnp.result_type(float))
    Xs = jnp.maximum(X, 1e-300)[..., None]
    log_t = -Xs + m * jnp.log(Xs) - gammaln(m + 1.0) - jnp.log(m) - q2tau2[..., None] / (4.0 * m)
    return jnp.sum(jnp.exp(log_t), -1)


def series_terms(kc_sigma_max: float) -> int:
    """Number of series terms that makes the Poisson(X) tail negligible for X ≤ (kσc)²_max."""
    X = kc_sigma_max**2
    return int(np.ceil(X + 12.0 * np.sqrt(X) + 25.0))


def kirchhoff_geometry(wi, wo, k, sigma_um, tau_um):
    """(cosχ, c, X, (kρτ)², prefactor 4cos⁴χ/(cosθ_i cosθ_o c²) · (kτ)²/(4π)) of the Kirchhoff lobe."""
    ci, co = wi[..., 2], wo[..., 2]
    h2 = jnp.sum((wi + wo) ** 2, -1)  # = 4 cos²χ
    cos_chi = 0.5 * _safe_sqrt(h2)
    c = ci + co
    X = (k * sigma_um * c) ** 2
    q2tau2 = k**2 * jnp.sum((wi[..., :2] + wo[..., :2]) ** 2, -1) * tau_um**2
    pre = h2**2 / 4.0 / jnp.maximum(ci * co * c**2, 1e-300) * (k * tau_um) ** 2 / (4.0 * np.pi)
    return cos_chi, c, X, q2tau2, pre


class AbstractGaussianMetalBRDF(AbstractLobeBRDF):
    """Lobe BRDF of a metal with Gaussian height statistics (σ, τ): the settings, validation,
    Fresnel factor and Gaussian-slope proposal that the Kirchhoff and He–Torrance models share.
    Subclasses supply `incoherent`, `coherent_reflectance` and `coherent_share`."""

    sigma_um: float = eqx.field(static=True)
    tau_um: float = eqx.field(static=True)
    wavelength_um: float = eqx.field(static=True)
    n_medium: float = eqx.field(static=True)
    metal_index: complex = eqx.field(static=True)
    coherent: str = eqx.field(static=True)
    coherent_width: float = eqx.field(static=True)
    num_terms: int = eqx.field(static=True)
    coherent_scale: Float[Array, " M"]

    def __init__(
        self,
        sigma_um: float,
        tau_um: float,
        *,
        wavelength_um: float = 0.5,
        n_medium: float = 1.5,
        metal_index=None,
        coherent: str = "lobe",
        platelet_width_um: float = DEFAULT_PLATELET_WIDTH_UM,
        coherent_width: float | None = None,
    ):
        check_positive("sigma_um", sigma_um, 10.0)
        check_positive("tau_um", tau_um, 1e3)
        check_positive("wavelength_um", wavelength_um, 20.0)
        check_positive("n_medium", n_medium, 5.0)
        check_coherent(coherent)
        self.sigma_um, self.tau_um = float(sigma_um), float(tau_um)
        self.wavelength_um, self.n_medium = float(wavelength_um), float(n_medium)
        self.metal_index = metal_index_or_aluminium(metal_index, wavelength_um)
        self.coherent = coherent
        if coherent_width is None:
            coherent_width = coherent_lobe_width(wavelength_um, n_medium, platelet_width_um)
        check_positive("coherent_width", coherent_width, 1.0)
        self.coherent_width = float(coherent_width)
        self.num_terms = series_terms(2.0 * self.k * self.sigma_um)
        self.coherent_scale = self._derive_coherent_scale()

    @property
    def medium_index(self):
        return self.n_medium

    @property
    def k(self) -> float:
        """Wavenumber in the medium [1/µm]."""
        return 2.0 * np.pi * self.n_medium / self.wavelength_um

    def fresnel(self, cos_chi):
        return fresnel_conductor(cos_chi, self.n_medium, self.metal_index)[2]

    def incoherent_albedo(self, cos_i):
        return self.quadrature_albedo(cos_i)

    def proposal(self, cos_i):
        return gaussian_proposal(cos_i, self.k, self.sigma_um, self.tau_um)


class BeckmannBRDF(AbstractGaussianMetalBRDF):
    """Analytic isotropic Kirchhoff (Beckmann–Spizzichino) BRDF of a Gaussian metal surface.

    Arguments:
        sigma_um: rms height σ [µm].
        tau_um: correlation length τ [µm] (1/e of the Gaussian autocorrelation).
        wavelength_um: vacuum wavelength λ0 [µm].
        n_medium: real index of the medium above the surface (binder 1.5, air 1.0).
        metal_index: complex metal index (default: aluminium at λ0).
        coherent: "lobe" (default, diffraction lobe of a platelet of width `platelet_width_um`) or "delta".
        platelet_width_um: platelet width D that sets the coherent lobe width.
        coherent_width: explicit β standard deviation of the coherent lobe (overrides D).
    """

    def incoherent(self, wi, wo):
        cos_chi, c, X, q2tau2, pre = kirchhoff_geometry(wi, wo, self.k, self.sigma_um, self.tau_um)
        f = self.fresnel(cos_chi) * pre * kirchhoff_series(X, q2tau2, self.num_terms)
        return jnp.where((wi[..., 2] > 0) & (wo[..., 2] > 0), f, 0.0)

    def coherent_reflectance(self, cos_i):
        cos_i = jnp.asarray(cos_i)
        return self.fresnel(cos_i) * jnp.exp(-((2.0 * self.k * self.sigma_um * cos_i) ** 2))

    def coherent_share(self, cos_i):
        return jnp.exp(-((2.0 * self.k * self.sigma_um * jnp.asarray(cos_i)) ** 2))


def gaussian_proposal(cos_i, k, sigma_um, tau_um):
    """Three-Gaussian proposal matched to the Kirchhoff lobe width (slope and diffraction terms)."""
    cos_i = jnp.asarray(cos_i)
    c = 2.0 * cos_i
    s0 = np.sqrt(2.0) * sigma_um / tau_um  # rms slope per axis
    core = np.sqrt(2.0) * jnp.sqrt((s0 * c) ** 2 + 2.0 / (k * tau_um) ** 2)  # e^{−ρ²/w²} width
    core = jnp.maximum(core, 1e-3)
    widths = core[..., None] * jnp.array([0.6, 1.0, 1.8])
    probs = jnp.broadcast_to(jnp.array([0.3, 0.45, 0.25]), widths.shape)
    return widths, probs
