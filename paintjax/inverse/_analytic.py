"""The analytic forward map: θ → five-angle L* through the single-scatter microfacet model, jittable.

The platelets' (σ, τ) enter through rough-platelet BRDFs that are smooth in them (the Kirchhoff
series lobe, or a Beckmann lobe, plus the coherent mirror part), so Optimistix and emcee can
differentiate and vectorise the map.
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..brdf._platelet import AbstractPlateletBRDF, MirrorBRDF
from ..instrument._geometry import Geometry, ma98_geometry, refract_into_coat
from ..instrument._hot_spot import HotSpot
from ..instrument._lightness import reflectance_factor_to_lightness
from ..microstructure._tilt import GammaTilt
from ..optics._fresnel import coat_internal_diffuse_reflectance, fresnel_conductor, fresnel_dielectric
from ._forward import ForwardModel


# ------------------------------------------------------------------------------------------
# Rough platelet BRDF with traced (σ, τ): analytic Kirchhoff (jit-able; the tracer forward uses the table grid)
# ------------------------------------------------------------------------------------------
def _metal_index(wavelength_um: float) -> complex:
    from ..optics._aluminium import aluminium_index

    with jax.ensure_compile_time_eval():
        return complex(np.asarray(aluminium_index(wavelength_um)))

def _set_optics(brdf, n_binder, wavelength_um, metal_index) -> None:
    """The binder index, wavelength and metal index fields of a rough-platelet BRDF (aluminium by default)."""
    brdf.n_binder = float(n_binder)
    brdf.wavelength_um = float(wavelength_um)
    brdf.metal_index = _metal_index(wavelength_um) if metal_index is None else complex(metal_index)



class CoherentMirrorBRDF(AbstractPlateletBRDF):
    """Coherent (specular) part of a rough metal platelet: Fresnel × exp(−(2kσ cosθ)²) (as `paintjax.brdf._analytic`).

    k = 2π n_binder / λ. Delta BRDF (mirror), so the microfacet model uses its closed form.
    """

    sigma: Float[Array, ""]
    metal_index: complex = eqx.field(static=True)
    n_binder: float = eqx.field(static=True)
    wavelength_um: float = eqx.field(static=True)
    is_delta = True

    def __init__(self, sigma, *, n_binder: float = 1.5, wavelength_um: float = 0.55, metal_index=None):
        self.sigma = jnp.asarray(sigma, dtype=jnp.result_type(float))
        _set_optics(self, n_binder, wavelength_um, metal_index)

    @property
    def medium_index(self):
        return self.n_binder

    def albedo(self, cos_i):
        k = 2.0 * jnp.pi * self.n_binder / self.wavelength_um
        c = jnp.abs(cos_i)
        return fresnel_conductor(c, self.n_binder, self.metal_index)[2] * jnp.exp(-((2.0 * k * self.sigma * c) ** 2))

    def evaluate(self, wi, wo):
        return jnp.zeros(jnp.broadcast_shapes(wi.shape, wo.shape)[:-1])

    pdf = evaluate  # a delta has no continuous part

    def sample(self, key, wi):
        normal = jnp.zeros_like(wi).at[..., 2].set(1.0)
        return 2.0 * wi[..., 2:3] * normal - wi, self.albedo(wi[..., 2])


#: Terms of the windowed Kirchhoff series (enough for X = (kσc)² up to ~50, i.e. σ ≤ 0.2 µm at 550 nm).
SERIES_WINDOW = 64


def windowed_kirchhoff_series(X, q2tau2, window: int = SERIES_WINDOW):
    """Σ_m e^{−X} X^m/(m! m) e^{−q²τ²/(4m)} over the `window` terms m ≥ max(1, ⌊X⌋ − 30) that carry the
    Poisson(X) mass (same sum as `paintjax.brdf._analytic.kirchhoff_series`, fixed cost for traced σ)."""
    from jax.scipy.special import gammaln

    m0 = jnp.maximum(1.0, jnp.floor(X) - 30.0)
    j = jnp.arange(window, dtype=jnp.result_type(float))
    m = m0[..., None] + j
    Xs = jnp.maximum(X, 1e-300)[..., None]
    log_m = jnp.log(m)
    # log m! = log m0! + Σ_{i<=j} log(m0 + i) − log m0 (one gammaln per node, cumulative logs after).
    log_fact = gammaln(m0 + 1.0)[..., None] + jnp.cumsum(log_m, -1) - log_m[..., :1]
    log_t = -Xs + m * jnp.log(Xs) - log_fact - log_m - q2tau2[..., None] / (4.0 * m)
    return jnp.sum(jnp.exp(log_t), -1)


class AbstractTracedLobeBRDF(AbstractPlateletBRDF):
    """Incoherent lobe of a rough aluminium platelet whose σ, τ (µm) are traced arrays, so the
    analytic forward can vmap over walkers and differentiate. Evaluation only: the analytic
    model integrates it by quadrature (`paintjax.brdf._analytic.BeckmannBRDF` samples)."""

    sigma: Float[Array, ""]
    tau: Float[Array, ""]
    metal_index: complex = eqx.field(static=True)
    n_binder: float = eqx.field(static=True)
    wavelength_um: float = eqx.field(static=True)
    is_delta: ClassVar[bool] = False

    def __init__(self, sigma, tau, *, n_binder: float = 1.5, wavelength_um: float = 0.55, metal_index=None):
        self.sigma = jnp.asarray(sigma, dtype=jnp.result_type(float))
        self.tau = jnp.asarray(tau, dtype=jnp.result_type(float))
        _set_optics(self, n_binder, wavelength_um, metal_index)

    @property
    def medium_index(self):
        return self.n_binder

    def sample(self, key, wi):  # not needed by the analytic model
        raise NotImplementedError(f"{type(self).__name__} is evaluated by quadrature only; use paintjax.BeckmannBRDF to sample")

    def pdf(self, wi, wo):  # not needed by the analytic model
        raise NotImplementedError(f"{type(self).__name__} is evaluated by quadrature only; use paintjax.BeckmannBRDF to sample")

    def albedo(self, cos_i):
        raise NotImplementedError(f"{type(self).__name__} has no tabulated albedo; use paintjax.BeckmannBRDF")


class KirchhoffLobeBRDF(AbstractTracedLobeBRDF):
    """Incoherent Kirchhoff (Beckmann–Spizzichino) lobe of a Gaussian aluminium platelet with
    *traced* σ, τ (µm), so it can be vmapped over walkers and differentiated.

    Same formula as `paintjax.brdf._analytic.BeckmannBRDF.incoherent` (its `kirchhoff_geometry`), with a
    fixed-size window of the series; its coherent part is `CoherentMirrorBRDF` (delta).
    Evaluation only (the analytic model integrates it by quadrature).
    """

    def evaluate(self, wi, wo):
        from ..brdf._analytic import kirchhoff_geometry

        k = 2.0 * np.pi * self.n_binder / self.wavelength_um
        cos_chi, c, X, q2tau2, pre = kirchhoff_geometry(wi, wo, k, self.sigma, self.tau)
        f = fresnel_conductor(cos_chi, self.n_binder, self.metal_index)[2] * pre * windowed_kirchhoff_series(X, q2tau2)
        return jnp.where((wi[..., 2] > 0) & (wo[..., 2] > 0), f, 0.0)


class BeckmannLobeBRDF(AbstractTracedLobeBRDF):
    """Geometric-optics (stationary-phase) limit of the Kirchhoff lobe with traced σ, τ (µm):

    f = (1 − e^{−X}) R(χ) D(h) / (4 cosθ_i cosθ_o),  X = (kσ(cosθ_i + cosθ_o))²,

    D the Beckmann distribution of slope parameter m = 2σ/τ (isotropic Gaussian surface,
    C(r) = σ² exp(−r²/τ²)), no shadowing — the limit quoted in `paintjax.brdf._analytic`. Fast (no series); it
    drops the diffraction broadening (kτ ≈ 12 for the reference platelets, so that is a few %).
    """

    def evaluate(self, wi, wo):
        ci, co = wi[..., 2], wo[..., 2]
        ok = (ci > 0) & (co > 0)
        h = wi + wo
        hn = jnp.maximum(jnp.linalg.norm(h, axis=-1), 1e-300)
        ch = jnp.clip(h[..., 2] / hn, 1e-9, 1.0)
        m = 2.0 * self.sigma / self.tau
        tan2 = (1.0 - ch**2) / ch**2
        D = jnp.exp(-tan2 / m**2) / (jnp.pi * m**2 * ch**4)
        R = fresnel_conductor(jnp.clip(0.5 * hn, 0.0, 1.0), self.n_binder, self.metal_index)[2]
        k = 2.0 * np.pi * self.n_binder / self.wavelength_um
        incoherent = -jnp.expm1(-((k * self.sigma * (jnp.clip(ci, 0.0, 1.0) + jnp.clip(co, 0.0, 1.0))) ** 2))
        f = incoherent * R * D / (4.0 * jnp.where(ok, ci * co, 1.0))
        return jnp.where(ok, f, 0.0)


def rough_platelets(sigma, tau, *, lobe: str = "beckmann", n_binder: float = 1.5, wavelength_um: float = 0.55, metal_index=None) -> tuple[AbstractPlateletBRDF, ...]:
    """Rough aluminium platelet as (coherent mirror part, incoherent lobe), σ, τ traceable.

    Arguments:
        lobe: ``"beckmann"`` (geometric-optics limit, fast) or ``"kirchhoff"`` (full series).
    """
    if lobe not in ("beckmann", "kirchhoff"):
        raise ValueError(f"lobe must be 'beckmann' or 'kirchhoff', got {lobe!r}")
    metal_index = _metal_index(wavelength_um) if metal_index is None else complex(metal_index)
    cls = BeckmannLobeBRDF if lobe == "beckmann" else KirchhoffLobeBRDF
    return (
        CoherentMirrorBRDF(sigma, n_binder=n_binder, wavelength_um=wavelength_um, metal_index=metal_index),
        cls(sigma, tau, n_binder=n_binder, wavelength_um=wavelength_um, metal_index=metal_index),
    )


# ------------------------------------------------------------------------------------------
# Analytic forward
# ------------------------------------------------------------------------------------------
class AnalyticForward(ForwardModel):
    """Analytic single-scatter forward map (`paintjax.instrument._single_scatter`) plus an optional Lambertian floor.

    Parameters consumed: ``shape, scale`` (tilt gamma), ``sigma, tau`` (platelet roughness, µm;
    only when `rough`), ``diffuse`` (albedo ρ of a Lambertian floor under the coat,
    R_d = T_i T_o ρ / (n² (1 − ρ r_i)); a stand-in for multiple scattering, 0 by default).

    Arguments:
        geometry: instrument geometry (default: MA98, 45° illumination, five standard angles).
        n: coat / binder refractive index.
        rough: rough platelets (σ, τ enter through the analytic Kirchhoff BRDF of `paintjax.brdf._analytic`) or mirrors.
        lobe: incoherent lobe, ``"beckmann"`` (its geometric-optics limit, fast; default) or
            ``"kirchhoff"`` (full series, ~30× slower).
        wavelength_um: wavelength of the platelet optics.
        tilt_nodes, azimuth_nodes: quadrature of the rough lobe over platelet normals.
        hot_spot: correlate the entry and exit paths over the platelet widths (`HotSpot`, e.g.
            `HotSpot.for_sample(load_sample("silver1"))`; brings the model within ≈ 3 L* of the
            tracer's single scattering); None (default): independent paths.
    """

    geometry: Geometry
    hot_spot: HotSpot | None
    n: float = eqx.field(static=True)
    rough: bool = eqx.field(static=True)
    wavelength_um: float = eqx.field(static=True)
    tilt_nodes: int = eqx.field(static=True)
    azimuth_nodes: int = eqx.field(static=True)
    lobe: str = eqx.field(static=True)
    metal_index: complex = eqx.field(static=True)
    _r_i: float = eqx.field(static=True)

    def __init__(self, geometry: Geometry | None = None, *, n: float = 1.5, rough: bool = True, wavelength_um: float = 0.55,
                 lobe: str = "beckmann", tilt_nodes: int = 64, azimuth_nodes: int = 48, hot_spot: HotSpot | None = None):
        if not (1.0 < float(n) <= 3.0):
            raise ValueError(f"coat refractive index n must lie in (1, 3], got {n!r}")
        if not (0.3 <= float(wavelength_um) <= 1.0):
            raise ValueError(f"wavelength_um must lie in [0.3, 1.0] µm, got {wavelength_um!r}")
        if int(tilt_nodes) < 8 or int(azimuth_nodes) < 8:
            raise ValueError(f"tilt_nodes and azimuth_nodes must be >= 8, got {tilt_nodes}, {azimuth_nodes}")
        self.geometry = ma98_geometry(45.0) if geometry is None else geometry
        if hot_spot is not None and not isinstance(hot_spot, HotSpot):
            raise ValueError(f"hot_spot must be a HotSpot or None, got {type(hot_spot).__name__}")
        self.hot_spot = hot_spot
        self.n = float(n)
        self.rough = bool(rough)
        self.wavelength_um = float(wavelength_um)
        self.tilt_nodes, self.azimuth_nodes = int(tilt_nodes), int(azimuth_nodes)
        if lobe not in ("beckmann", "kirchhoff"):
            raise ValueError(f"lobe must be 'beckmann' or 'kirchhoff', got {lobe!r}")
        self.lobe = lobe
        self.metal_index = _metal_index(self.wavelength_um)
        self._r_i = coat_internal_diffuse_reflectance(self.n)

    @property
    def parameter_names(self):
        return ("shape", "scale", "sigma", "tau", "diffuse") if self.rough else ("shape", "scale", "diffuse")

    @property
    def aspecular_deg(self):
        return np.asarray(self.geometry.aspecular_deg)

    def fingerprint(self):
        g = self.geometry
        return (
            f"AnalyticForward(v2,n={self.n},rough={self.rough},lobe={self.lobe},wl={self.wavelength_um},nodes={self.tilt_nodes}x{self.azimuth_nodes},"
            f"illum={float(g.illumination_polar_deg)},det={np.asarray(g.detector_polar_deg).tolist()},"
            f"az={np.asarray(g.detector_azimuth_deg).tolist()},ap={g.illumination_aperture_deg},{g.detector_aperture_deg}"
            + ("" if self.hot_spot is None else f",hot_spot={self.hot_spot.fingerprint()}") + ")"
        )

    def _one(self, theta):
        from ..instrument._single_scatter import microfacet_reflectance_factor, single_scatter_brdf

        tilt = GammaTilt(theta[0], theta[1])
        if self.rough:
            coherent, lobe = rough_platelets(
                theta[2], theta[3], lobe=self.lobe, n_binder=self.n, wavelength_um=self.wavelength_um, metal_index=self.metal_index
            )
            R = microfacet_reflectance_factor(self.geometry, tilt, n=self.n, platelet=coherent, hot_spot=self.hot_spot)
            # Incoherent lobe: same expression as microfacet_reflectance_factor with our quadrature size.
            g = self.geometry
            wi_air, wo_air = g.illumination_air(), g.detectors_air()
            wi, wo = refract_into_coat(wi_air, self.n), refract_into_coat(wo_air, self.n)
            Ti = 1.0 - fresnel_dielectric(wi_air[..., 2], 1.0, self.n)[2]
            To = 1.0 - fresnel_dielectric(wo_air[..., 2], 1.0, self.n)[2]
            f = single_scatter_brdf(wi[None, :], wo, tilt, lobe, hot_spot=self.hot_spot, tilt_nodes=self.tilt_nodes, azimuth_nodes=self.azimuth_nodes)
            R = R + jnp.pi * Ti * To * f / self.n**2
            rho = theta[4]
        else:
            R = microfacet_reflectance_factor(self.geometry, tilt, n=self.n, platelet=MirrorBRDF(n_binder=self.n, metal_index=self.metal_index),
                                              hot_spot=self.hot_spot)
            rho = theta[2]
        wi_air, wo_air = self.geometry.illumination_air(), self.geometry.detectors_air()
        Ti = 1.0 - fresnel_dielectric(wi_air[..., 2], 1.0, self.n)[2]
        To = 1.0 - fresnel_dielectric(wo_air[..., 2], 1.0, self.n)[2]
        R = R + Ti * To * rho / (self.n**2 * (1.0 - rho * self._r_i))
        return reflectance_factor_to_lightness(R)

    def evaluate(self, theta):
        if self.rough and self.geometry.detector_aperture_deg + self.geometry.illumination_aperture_deg > 0:
            raise ValueError("AnalyticForward(rough=True) supports point apertures only (aperture half-angles 0)")
        return jax.vmap(self._one)(theta)
