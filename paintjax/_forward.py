"""Forward maps of the inverse layer: microstructure parameters θ → five-angle L*.

A `ForwardModel` names the parameters it consumes (`parameter_names`, a subset of
`paintjax._parameters.PARAMETERS`), maps a batch θ (leading dim, columns in that order) to L* at
the instrument's angles, and states an extra per-angle standard deviation `error_sd` that the
likelihood adds (zero for direct models, the held-out error for emulators). Implementations:

* `AnalyticForward` – the analytic single-scatter model of `_microfacet` (milliseconds, jit and
  differentiable). Smooth (mirror) platelets, or rough platelets whose σ, τ enter through a
  platelet BRDF. To stay jit-able and differentiable its rough BRDF is the *analytic* Kirchhoff (Beckmann–Spizzichino) BRDF of a Gaussian surface from
  `_beckmann` (coherent part exp(−(2kσ cosθ)²) as a mirror, incoherent lobe by quadrature), with
  σ, τ traced (`KirchhoffLobeBRDF`). No multiple scattering and no primer: far from specular
  (75°, 110°) it predicts almost no light (the ray tracer, with the wave-based BRDF grid, is the
  forward model of `_tracer_forward`, "tracer-emulator"). The
  optional `diffuse` parameter adds a Lambertian floor under the coat as a crude stand-in for the
  missing multiple scattering (off unless freed).
* `CallableForward` – any Python callable (the ray tracer, with common random numbers, i.e. a
  fixed key closed over so its output is a smooth function of θ). Not assumed jit-able. The
  tracer's callable and its registered emulator ("tracer-emulator") live in `_tracer_forward`.
* `Emulator` – a Gaussian-process emulator (Matérn-5/2, ARD, one GP per angle) of any forward
  callable, trained on a scrambled-Sobol design in the parameters' unit cube, with its held-out
  RMS error measured on an independent Latin-hypercube set, pooled with the training design's
  leave-one-out errors, and exposed as `error_sd`. Built by
  `build_emulator`, cached on disk under a content-hashed key (atomic writes; the expensive design
  evaluations are check-pointed so an interrupted build resumes). Optionally physics-informed: a
  cheap `mean` model (the tracer emulator uses the analytic single-scatter model) gives a linear
  prior mean per angle and, at chosen angles, extra GP inputs; the GP then learns only what the
  cheap model misses.
"""

from __future__ import annotations

import abc
import hashlib
import json
import math
import os
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import ClassVar, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._brdf import AbstractPlateletBRDF, MirrorBRDF
from ._cache import default_cache_dir
from ._hot_spot import HotSpot
from ._instrument import STANDARD_ASPECULAR, Geometry, ma98_geometry, refract_into_coat
from ._io import atomic_savez
from ._lightness import reflectance_factor_to_lightness
from ._optics import coat_internal_diffuse_reflectance, fresnel_conductor, fresnel_dielectric
from ._parameters import ParameterSpec, get_parameter
from ._tilt import GammaTilt

EMULATOR_VERSION = 1  # meaning of the cached design evaluations (bump to re-run them)
EMULATOR_FIT_VERSION = 4  # meaning of the fit on top of them (a change only re-fits, from the cached design)


# ------------------------------------------------------------------------------------------
# Interface
# ------------------------------------------------------------------------------------------
class ForwardModel(eqx.Module):
    """θ (batch, p) → L* (batch, m) at `aspecular_deg`; columns of θ in `parameter_names` order."""

    @property
    @abc.abstractmethod
    def parameter_names(self) -> tuple[str, ...]:
        """Names of the parameters this model consumes, in column order."""

    @property
    @abc.abstractmethod
    def aspecular_deg(self) -> np.ndarray:
        """Aspecular angles [deg] of the outputs."""

    @property
    def error_sd(self) -> np.ndarray:
        """Per-angle standard deviation of the model's own error (added to the likelihood)."""
        return np.zeros(len(self.aspecular_deg))

    @property
    def jittable(self) -> bool:
        """Whether `evaluate` may be traced by JAX (jit, vmap, jacfwd)."""
        return True

    @abc.abstractmethod
    def evaluate(self, theta: Float[Array, "batch p"]) -> Float[Array, "batch m"]:
        """Traceable batched evaluation (no validation)."""

    @abc.abstractmethod
    def fingerprint(self) -> str:
        """Stable text identifying the model and its settings (for cache keys)."""

    def __call__(self, theta: Float[ArrayLike, "batch p"]) -> Float[Array, "batch m"]:
        """L* for a batch of parameter vectors (a 1-D θ gives a 1-D result).

        Arguments:
            theta: (batch, p) or (p,) values in `parameter_names` order.

        Returns:
            (batch, m) or (m,) L*.
        """
        t = jnp.asarray(theta, dtype=jnp.result_type(float))
        if t.shape[-1:] != (len(self.parameter_names),) or t.ndim not in (1, 2):
            raise ValueError(
                f"theta must have shape (batch, {len(self.parameter_names)}) with columns "
                f"{', '.join(self.parameter_names)}, got {t.shape}"
            )
        one = t.ndim == 1
        t2 = t[None] if one else t
        out = _jit_evaluate(self, t2) if self.jittable else jnp.asarray(self.evaluate(t2))
        return out[0] if one else out

    def restrict(self, names: Sequence[str], fixed: Mapping[str, float] | None = None) -> "Restricted":
        """This model as a function of the parameters `names` only, the others held at `fixed`
        (or their registered defaults)."""
        return Restricted(self, tuple(names), dict(fixed or {}))


@eqx.filter_jit
def _jit_evaluate(model: ForwardModel, theta):
    return model.evaluate(theta)


class Restricted:
    """A forward model as a function of a subset of its parameters (others held fixed).

    Calling it maps (batch, len(names)) → (batch, m); `full(x)` gives the full θ.
    """

    def __init__(self, model: ForwardModel, names: tuple[str, ...], fixed: dict[str, float]):
        unknown = [n for n in names if n not in model.parameter_names]
        if unknown:
            raise ValueError(f"free parameters {unknown} are not inputs of this forward model (inputs: {', '.join(model.parameter_names)})")
        extra = [n for n in fixed if n not in model.parameter_names and n != "discrepancy"]
        if extra:
            raise ValueError(f"fixed parameters {extra} are not inputs of this forward model (inputs: {', '.join(model.parameter_names)})")
        both = [n for n in names if n in fixed]
        if both:
            raise ValueError(f"parameters {both} cannot be both free and fixed")
        self.model, self.names = model, names
        self.fixed = {n: float(fixed.get(n, get_parameter(n).default)) for n in model.parameter_names if n not in names}
        for n, v in self.fixed.items():
            p = get_parameter(n)
            if not (p.lower <= v <= p.upper) or not math.isfinite(v):
                raise ValueError(f"fixed value of {n} must lie in [{p.lower:g}, {p.upper:g}] {p.unit}".rstrip() + f", got {v!r}")
        self._cols = [names.index(n) if n in names else -1 for n in model.parameter_names]
        self._vals = np.array([self.fixed.get(n, 0.0) for n in model.parameter_names])

    def full(self, x: Float[ArrayLike, "batch k"]) -> Float[Array, "batch p"]:
        return _assemble(jnp.asarray(x), self._cols, self._vals)

    def evaluate(self, x):
        return self.model.evaluate(self.full(x))

    def __call__(self, x):
        return self.model(self.full(x))

    @property
    def jittable(self) -> bool:
        return self.model.jittable

    def fingerprint(self) -> str:
        return f"{self.model.fingerprint()}|free={','.join(self.names)}|fixed={json.dumps(self.fixed, sort_keys=True)}"


# ------------------------------------------------------------------------------------------
# Rough platelet BRDF with traced (σ, τ): analytic Kirchhoff (jit-able; the tracer forward uses the table grid)
# ------------------------------------------------------------------------------------------
def _metal_index(wavelength_um: float) -> complex:
    from ._aluminium import aluminium_index

    with jax.ensure_compile_time_eval():
        return complex(np.asarray(aluminium_index(wavelength_um)))


class CoherentMirrorBRDF(AbstractPlateletBRDF):
    """Coherent (specular) part of a rough metal platelet: Fresnel × exp(−(2kσ cosθ)²) (as `_beckmann`).

    k = 2π n_binder / λ. Delta BRDF (mirror), so the microfacet model uses its closed form.
    """

    sigma: Float[Array, ""]
    metal_index: complex = eqx.field(static=True)
    n_binder: float = eqx.field(static=True)
    wavelength_um: float = eqx.field(static=True)
    is_delta = True

    def __init__(self, sigma, *, n_binder: float = 1.5, wavelength_um: float = 0.55, metal_index=None):
        self.sigma = jnp.asarray(sigma, dtype=jnp.result_type(float))
        self.n_binder = float(n_binder)
        self.wavelength_um = float(wavelength_um)
        self.metal_index = _metal_index(wavelength_um) if metal_index is None else complex(metal_index)

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
    Poisson(X) mass (same sum as `_beckmann.kirchhoff_series`, fixed cost for traced σ)."""
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
    model integrates it by quadrature (`_beckmann.BeckmannBRDF` samples)."""

    sigma: Float[Array, ""]
    tau: Float[Array, ""]
    metal_index: complex = eqx.field(static=True)
    n_binder: float = eqx.field(static=True)
    wavelength_um: float = eqx.field(static=True)
    is_delta: ClassVar[bool] = False

    def __init__(self, sigma, tau, *, n_binder: float = 1.5, wavelength_um: float = 0.55, metal_index=None):
        self.sigma = jnp.asarray(sigma, dtype=jnp.result_type(float))
        self.tau = jnp.asarray(tau, dtype=jnp.result_type(float))
        self.n_binder = float(n_binder)
        self.wavelength_um = float(wavelength_um)
        self.metal_index = _metal_index(wavelength_um) if metal_index is None else complex(metal_index)

    @property
    def medium_index(self):
        return self.n_binder

    def sample(self, key, wi):  # not needed by the analytic model
        raise NotImplementedError(f"{type(self).__name__} is evaluated by quadrature only; use _beckmann.BeckmannBRDF to sample")

    def pdf(self, wi, wo):  # not needed by the analytic model
        raise NotImplementedError(f"{type(self).__name__} is evaluated by quadrature only; use _beckmann.BeckmannBRDF to sample")

    def albedo(self, cos_i):
        raise NotImplementedError(f"{type(self).__name__} has no tabulated albedo; use _beckmann.BeckmannBRDF")


class KirchhoffLobeBRDF(AbstractTracedLobeBRDF):
    """Incoherent Kirchhoff (Beckmann–Spizzichino) lobe of a Gaussian aluminium platelet with
    *traced* σ, τ (µm), so it can be vmapped over walkers and differentiated.

    Same formula as `_beckmann.BeckmannBRDF.incoherent` (its `kirchhoff_geometry`), with a
    fixed-size window of the series; its coherent part is `CoherentMirrorBRDF` (delta).
    Evaluation only (the analytic model integrates it by quadrature).
    """

    def evaluate(self, wi, wo):
        from ._beckmann import kirchhoff_geometry

        k = 2.0 * np.pi * self.n_binder / self.wavelength_um
        cos_chi, c, X, q2tau2, pre = kirchhoff_geometry(wi, wo, k, self.sigma, self.tau)
        f = fresnel_conductor(cos_chi, self.n_binder, self.metal_index)[2] * pre * windowed_kirchhoff_series(X, q2tau2)
        return jnp.where((wi[..., 2] > 0) & (wo[..., 2] > 0), f, 0.0)


class BeckmannLobeBRDF(AbstractTracedLobeBRDF):
    """Geometric-optics (stationary-phase) limit of the Kirchhoff lobe with traced σ, τ (µm):

    f = (1 − e^{−X}) R(χ) D(h) / (4 cosθ_i cosθ_o),  X = (kσ(cosθ_i + cosθ_o))²,

    D the Beckmann distribution of slope parameter m = 2σ/τ (isotropic Gaussian surface,
    C(r) = σ² exp(−r²/τ²)), no shadowing — the limit quoted in `_beckmann`. Fast (no series); it
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
    """Analytic single-scatter forward map (`_microfacet`) plus an optional Lambertian floor.

    Parameters consumed: ``shape, scale`` (tilt gamma), ``sigma, tau`` (platelet roughness, µm;
    only when `rough`), ``diffuse`` (albedo ρ of a Lambertian floor under the coat,
    R_d = T_i T_o ρ / (n² (1 − ρ r_i)); a stand-in for multiple scattering, 0 by default).

    Arguments:
        geometry: instrument geometry (default: MA98, 45° illumination, five standard angles).
        n: coat / binder refractive index.
        rough: rough platelets (σ, τ enter through the analytic Kirchhoff BRDF of `_beckmann`) or mirrors.
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
        from ._microfacet import microfacet_reflectance_factor, single_scatter_brdf

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


# ------------------------------------------------------------------------------------------
# Any callable (the tracer)
# ------------------------------------------------------------------------------------------
class CallableForward(ForwardModel):
    """Wrap a Python callable θ (batch, p) → L* (batch, m) as a `ForwardModel`.

    For the ray tracer: close over a fixed PRNG key (common random numbers) so the output is a
    smooth, deterministic function of θ. Not traced by JAX unless `jittable=True`.

    Arguments:
        fn: the callable.
        parameter_names: its input columns (registered parameter names).
        identity: a string that changes whenever `fn`'s behaviour does (cache keys depend on it).
        aspecular_deg: output angles.
        jittable: whether `fn` may be traced by JAX.
    """

    fn: Callable = eqx.field(static=True)
    names: tuple[str, ...] = eqx.field(static=True)
    identity: str = eqx.field(static=True)
    angles: tuple[float, ...] = eqx.field(static=True)
    is_jittable: bool = eqx.field(static=True)

    def __init__(self, fn: Callable, parameter_names: Sequence[str], identity: str, aspecular_deg=STANDARD_ASPECULAR, jittable: bool = False):
        if not callable(fn):
            raise ValueError("fn must be callable")
        for n in parameter_names:
            get_parameter(n)
        if not identity:
            raise ValueError("identity must be a non-empty string describing the callable and its settings")
        self.fn, self.names, self.identity = fn, tuple(parameter_names), str(identity)
        self.angles = tuple(float(a) for a in aspecular_deg)
        self.is_jittable = bool(jittable)

    @property
    def parameter_names(self):
        return self.names

    @property
    def aspecular_deg(self):
        return np.asarray(self.angles)

    @property
    def jittable(self):
        return self.is_jittable

    def evaluate(self, theta):
        return jnp.asarray(self.fn(theta))

    def fingerprint(self):
        return f"CallableForward({self.identity},{','.join(self.names)},{self.angles})"


# ------------------------------------------------------------------------------------------
# Gaussian-process emulator
# ------------------------------------------------------------------------------------------
def _matern52(x1, x2, log_ls, log_amp):
    d = (x1[:, None, :] - x2[None, :, :]) / jnp.exp(log_ls)
    r = jnp.sqrt(jnp.sum(d**2, -1) + 1e-12)
    s5 = jnp.sqrt(5.0) * r
    return jnp.exp(2.0 * log_amp) * (1.0 + s5 + 5.0 / 3.0 * r**2) * jnp.exp(-s5)


def _gram(X, hyp):
    """Training covariance K of a GP with packed hyperparameters (log length scales, log amplitude, log noise)."""
    p = X.shape[1]
    return _matern52(X, X, hyp[:p], hyp[p]) + (jnp.exp(2.0 * hyp[p + 1]) + 1e-8) * jnp.eye(X.shape[0])


def _neg_log_marginal(hyp, X, y):
    p = X.shape[1]
    log_ls, log_noise = hyp[:p], hyp[p + 1]
    L = jnp.linalg.cholesky(_gram(X, hyp))
    a = jax.scipy.linalg.cho_solve((L, True), y)
    nll = 0.5 * y @ a + jnp.sum(jnp.log(jnp.diag(L)))
    # Weak log-normal regularisation of the hyperparameters keeps the optimum away from degenerate corners.
    reg = 0.5 * jnp.sum(((log_ls - jnp.log(0.3)) / 1.5) ** 2) + 0.5 * ((log_noise - jnp.log(1e-3)) / 3.0) ** 2
    return nll + reg


#: Starting (length scale, noise) pairs of the hyperparameter search; the best marginal likelihood wins
#: (one start alone landed in different local optima for near-identical data).
_GP_STARTS = ((0.3, 1e-2), (1.0, 1e-2), (0.1, 1e-2), (0.3, 0.1))


@jax.jit
def _fit_gp(X, Y):
    """Fit one GP per output column of Y (standardised): type-II maximum likelihood by optimistix BFGS
    from several starts (`_GP_STARTS`), keeping the best."""
    import optimistix as optx

    p = X.shape[1]
    objective = lambda h, y: _neg_log_marginal(h, X, y)  # noqa: E731

    def from_start(y, ls, noise):
        h0 = jnp.concatenate([jnp.full((p,), jnp.log(ls)), jnp.zeros(1), jnp.full((1,), jnp.log(noise))])
        sol = optx.minimise(objective, optx.BFGS(rtol=1e-6, atol=1e-6), h0, args=y, max_steps=300, throw=False)
        h = jnp.where(jnp.all(jnp.isfinite(sol.value)), sol.value, h0)
        val = objective(h, y)
        return h, jnp.where(jnp.isfinite(val), val, jnp.inf)

    starts = jnp.asarray(_GP_STARTS)

    def fit_one(y):
        hs, vals = jax.vmap(lambda st: from_start(y, st[0], st[1]))(starts)
        h = hs[jnp.argmin(vals)]
        h = h.at[p + 1].set(jnp.clip(h[p + 1], jnp.log(1e-5), jnp.log(0.3)))
        alpha = jax.scipy.linalg.cho_solve((jnp.linalg.cholesky(_gram(X, h)), True), y)
        return h, alpha

    return jax.vmap(fit_one, in_axes=1)(Y)


class Emulator(ForwardModel):
    """Gaussian-process emulator of a forward map over the box of `spec` (see `build_emulator`).

    Inputs are the parameters of `spec` (physical units); outside the box they are clipped.
    `error_sd` is the cross-validated RMS error per angle: the held-out errors (independent LHS set)
    pooled with the leave-one-out errors of the training design, so that it rests on all
    n_train + n_test runs (the held-out set alone is small); `held_out_rms` and `held_out_loo_rms`
    are the two parts, `held_out_max` the largest held-out error.
    With a `mean_model`, L* = c₀ + c₁·L*_mean + GP([unit θ, standardised L*_mean at `mean_features`]).
    """

    X: Float[Array, "n q"]
    alpha: Float[Array, "m n"]
    hyper: Float[Array, "m q"]
    y_mean: Float[Array, " m"]
    y_std: Float[Array, " m"]
    spec: ParameterSpec = eqx.field(static=True)
    angles: tuple[float, ...] = eqx.field(static=True)
    held_out_rms: tuple[float, ...] = eqx.field(static=True)
    held_out_max: float = eqx.field(static=True)
    source: str = eqx.field(static=True)
    key: str = eqx.field(static=True)
    mean_model: "ForwardModel | None" = None
    mean_cols: tuple[int, ...] = eqx.field(static=True, default=())
    mean_vals: tuple[float, ...] = eqx.field(static=True, default=())
    mean_features: tuple[int, ...] = eqx.field(static=True, default=())
    mean_coef: Float[Array, "m 2"] | None = None
    feature_shift: Float[Array, " f"] | None = None
    feature_scale: Float[Array, " f"] | None = None
    held_out_loo_rms: tuple[float, ...] = eqx.field(static=True, default=())
    fit_id: str = eqx.field(static=True, default="")
    n_test: int = eqx.field(static=True, default=0)

    @property
    def parameter_names(self):
        return self.spec.names

    @property
    def aspecular_deg(self):
        return np.asarray(self.angles)

    @property
    def error_sd(self):
        held = np.asarray(self.held_out_rms)
        if not self.held_out_loo_rms:
            return held
        n_train, n_test = self.X.shape[0], self.n_test
        return np.sqrt((n_train * np.asarray(self.held_out_loo_rms) ** 2 + n_test * held**2) / (n_train + n_test))

    def fingerprint(self):
        return f"Emulator({self.key},{hashlib.sha256(self.fit_id.encode()).hexdigest()[:12]})"

    def evaluate(self, theta):
        z = jnp.clip(self.spec.to_unit(theta), 0.0, 1.0)
        prior = 0.0
        if self.mean_model is not None:
            a = self.mean_model.evaluate(_assemble(self.spec.from_unit(z), self.mean_cols, self.mean_vals))
            prior = self.mean_coef[:, 0] + self.mean_coef[:, 1] * a
            z = jnp.concatenate([z, (a[:, list(self.mean_features)] - self.feature_shift) / self.feature_scale], axis=-1)
        q = z.shape[-1]

        def one(h, a):
            return _matern52(z, self.X, h[:q], h[q]) @ a

        gp = jax.vmap(one, out_axes=1)(self.hyper, self.alpha)
        return prior + self.y_mean + self.y_std * gp


def _assemble(x, cols, vals):
    """Full parameter vectors of a restricted model: column c of x, or the fixed value where c < 0."""
    return jnp.stack([x[..., c] if c >= 0 else jnp.full(x.shape[:-1], v, dtype=x.dtype) for c, v in zip(cols, vals)], axis=-1)


def _sobol(n: int, d: int, seed: int) -> np.ndarray:
    from scipy.stats import qmc

    m = int(math.ceil(math.log2(max(n, 2))))
    return qmc.Sobol(d, scramble=True, seed=seed).random_base2(m)[:n]


def _lhs(n: int, d: int, seed: int) -> np.ndarray:
    from scipy.stats import qmc

    return qmc.LatinHypercube(d, seed=seed).random(n)


def emulator_key(source: str, spec: ParameterSpec, n_train: int, n_test: int, seed: int) -> str:
    """Content hash of everything that determines an emulator."""
    text = json.dumps([EMULATOR_VERSION, source, spec.fingerprint(), int(n_train), int(n_test), int(seed)])
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def _evaluate_design(fn, Z: np.ndarray, spec: ParameterSpec, batch: int, checkpoint: Path | None, progress: bool) -> np.ndarray:
    """Evaluate fn on the unit-cube design Z in batches, check-pointing after each batch."""
    n = Z.shape[0]
    Y, done = None, 0
    if checkpoint is not None and checkpoint.exists():
        with np.load(checkpoint) as d:
            if d["Z"].shape == Z.shape and np.allclose(d["Z"], Z):
                Y, done = np.array(d["Y"]), int(d["done"])
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=n, initial=done, desc="emulator design", leave=False)
    while done < n:
        stop = min(n, done + batch)
        x = np.asarray(spec.from_unit(Z[done:stop]))
        y = np.asarray(fn(x), dtype=float)
        if Y is None:
            Y = np.full((n, y.shape[1]), np.nan)
        Y[done:stop] = y
        done = stop
        if checkpoint is not None:
            atomic_savez(checkpoint, Z=Z, Y=Y, done=done)
        if bar is not None:
            bar.update(y.shape[0])
    if bar is not None:
        bar.close()
    return Y


def build_emulator(
    fn: Callable | ForwardModel | "Restricted",
    spec: ParameterSpec,
    *,
    source: str | None = None,
    n_train: int = 256,
    n_test: int = 64,
    seed: int = 0,
    cache_dir: str | os.PathLike | None | Literal["default"] = "default",
    batch: int = 64,
    aspecular_deg=None,
    progress: bool = False,
    mean: "Restricted | None" = None,
    mean_features: Sequence[int] = (),
) -> Emulator:
    """Train (or load from cache) a GP emulator of `fn` over the box of `spec`.

    The training design is a scrambled Sobol sequence in the unit cube of `spec` (linear or log
    coordinates), the test design an independent Latin hypercube; `fn` is called in batches with
    physical θ (batch, len(spec)). Give `fn` common random numbers (a fixed key) when it is
    stochastic. The cache file is `<cache_dir>/emulator-<key>.npz`, key = hash of `source`,
    the spec, the design sizes and the seed; design evaluations are check-pointed to
    `<key>.partial.npz` so an interrupted build resumes.

    Arguments:
        fn: forward callable of the parameters of `spec`, a `ForwardModel` with exactly those
            inputs, or a `Restricted` model.
        spec: free parameters and their box.
        source: identity of `fn` for the cache key (defaults to its `fingerprint()`; required for
            plain callables).
        n_train, n_test: design sizes (n_train ≥ 8·len(spec) recommended).
        seed: seed of both designs.
        cache_dir: cache folder; "default" is `default_cache_dir()/emulators`; None for no cache.
        batch: evaluations per call of `fn`.
        aspecular_deg: output angles (defaults to those of `fn` or the five standard ones).
        progress: show a progress bar over the design.
        mean: optional cheap, jit-able model of the same parameters (a `Restricted`): the GP then
            emulates fn − (c₀ + c₁·mean) per angle, with the mean's L* at `mean_features` (output
            columns) as extra inputs. Changing it re-fits from the cached design, no new fn calls.
        mean_features: output columns of `mean` used as GP inputs.

    Returns:
        An `Emulator` (a `ForwardModel` over `spec.names`).
    """
    if n_train < 2 * len(spec) + 2 or n_test < 4:
        raise ValueError(f"n_train must be >= {2 * len(spec) + 2} and n_test >= 4, got {n_train}, {n_test}")
    if isinstance(fn, (ForwardModel, Restricted)):
        names = fn.names if isinstance(fn, Restricted) else fn.parameter_names
        if tuple(names) != spec.names:
            raise ValueError(f"fn inputs {tuple(names)} differ from the spec's parameters {spec.names}")
        source = source or fn.fingerprint()
        if aspecular_deg is None:
            aspecular_deg = (fn.model if isinstance(fn, Restricted) else fn).aspecular_deg
    if not source:
        raise ValueError("source must identify fn (a string that changes with its behaviour) for the cache key")
    angles = tuple(float(a) for a in (STANDARD_ASPECULAR if aspecular_deg is None else aspecular_deg))
    key = emulator_key(source, spec, n_train, n_test, seed)
    if cache_dir == "default":
        cache_dir = default_cache_dir() / "emulators"
    path = None if cache_dir is None else Path(cache_dir) / f"emulator-{key}.npz"
    if mean is not None:
        if not isinstance(mean, Restricted) or tuple(mean.names) != spec.names or not mean.jittable:
            raise ValueError(f"mean must be a jit-able Restricted model of exactly the parameters {spec.names} (in that order)")
        if tuple(float(a) for a in mean.model.aspecular_deg) != angles:
            raise ValueError(f"mean's angles {list(mean.model.aspecular_deg)} differ from the emulated ones {list(angles)}")
        if any(not 0 <= int(i) < len(angles) for i in mean_features):
            raise ValueError(f"mean_features must be output columns in [0, {len(angles) - 1}], got {list(mean_features)}")
    mean_id = "none" if mean is None else f"{mean.fingerprint()}|features={list(mean_features)}"
    fit_id = f"v{EMULATOR_FIT_VERSION}|{mean_id}"
    arrays = None
    if path is not None and path.exists():
        with np.load(path) as d:
            arrays = {k: np.array(d[k]) for k in d.files}
        if str(arrays.get("fit_id", "")) == fit_id:
            return _emulator_from_arrays(arrays, spec, angles, source, key, mean, mean_features)
        if "Z" not in arrays and "X" in arrays:  # files of fit version 1 stored the design as X
            arrays["Z"] = arrays["X"]
        arrays = {k: arrays[k] for k in ("Z", "Y", "Zt", "Yt", "design_seconds") if k in arrays}  # re-fit the cached design
    if arrays is None or "Z" not in arrays:
        t0 = time.perf_counter()
        Z = _sobol(n_train, len(spec), seed)
        Zt = _lhs(n_test, len(spec), seed + 1)
        ckpt = None if path is None else path.with_suffix(".partial.npz")
        Yall = _evaluate_design(fn, np.concatenate([Z, Zt]), spec, batch, ckpt, progress)
        if not np.all(np.isfinite(Yall)):
            raise ValueError("the forward callable returned non-finite L* on the design; narrow the parameter bounds")
        arrays = dict(Z=Z, Y=Yall[:n_train], Zt=Zt, Yt=Yall[n_train:], design_seconds=time.perf_counter() - t0)
    else:
        ckpt = None
    arrays = arrays | _fit_emulator(arrays["Z"], arrays["Y"], arrays["Zt"], arrays["Yt"], spec, mean, mean_features, angles, source, key)
    arrays["fit_id"] = np.array(fit_id)
    if path is not None:
        atomic_savez(path, **arrays)
        if ckpt is not None and ckpt.exists():
            ckpt.unlink()
    return _emulator_from_arrays(arrays, spec, angles, source, key, mean, mean_features)


def _mean_inputs(spec, mean, mean_features, Z):
    """(L* of the mean model at the unit-cube points Z, the columns used as features)."""
    a = np.asarray(mean.evaluate(jnp.asarray(spec.from_unit(Z))))
    return a, a[:, list(mean_features)]


def _fit_emulator(Z, Y, Zt, Yt, spec, mean, mean_features, angles, source, key) -> dict:
    """GP fit (with the optional physics-informed mean) and its held-out and leave-one-out errors."""
    t0 = time.perf_counter()
    out = {}
    X, target = Z, Y
    if mean is not None:
        a, f = _mean_inputs(spec, mean, mean_features, Z)
        coef = np.stack([np.linalg.lstsq(np.c_[np.ones(len(a)), a[:, k]], Y[:, k], rcond=None)[0] for k in range(Y.shape[1])])
        shift, scale = f.mean(0), f.std(0) + 1e-9
        X = np.concatenate([Z, (f - shift) / scale], axis=1)
        target = Y - (coef[:, 0] + coef[:, 1] * a)
        out |= dict(mean_coef=coef, feature_shift=shift, feature_scale=scale)
    y_mean, y_std = target.mean(0), target.std(0) + 1e-12
    hyper, alpha = _fit_gp(jnp.asarray(X), jnp.asarray((target - y_mean) / y_std))
    out |= dict(X=X, alpha=np.asarray(alpha), hyper=np.asarray(hyper), y_mean=y_mean, y_std=y_std,
                loo_rms=_loo_rms(X, (target - y_mean) / y_std, np.asarray(hyper)) * y_std)
    em = _emulator_from_arrays(out | dict(held_out_rms=np.zeros(Y.shape[1]), held_out_max=0.0, Zt=Zt), spec, angles, source, key, mean, mean_features)
    err = np.asarray(em(np.asarray(spec.from_unit(Zt)))) - Yt
    out["held_out_rms"] = np.sqrt(np.mean(err**2, axis=0))
    out["held_out_max"] = float(np.max(np.abs(err)))
    out["train_seconds"] = time.perf_counter() - t0
    return out


def _loo_rms(X, Ys, hyper) -> np.ndarray:
    """Leave-one-out RMS error of each standardised output column (closed form, α_i / (K⁻¹)_ii)."""
    rms = []
    for k in range(Ys.shape[1]):
        Ki = np.linalg.inv(np.asarray(_gram(jnp.asarray(X), jnp.asarray(hyper[k]))))
        rms.append(np.sqrt(np.mean((Ki @ Ys[:, k] / np.diag(Ki)) ** 2)))
    return np.asarray(rms)


def _emulator_from_arrays(a: dict, spec, angles, source, key, mean=None, mean_features=()) -> Emulator:
    opt = lambda k: None if mean is None else jnp.asarray(a[k])  # noqa: E731
    return Emulator(
        X=jnp.asarray(a["X"]),
        alpha=jnp.asarray(a["alpha"]),
        hyper=jnp.asarray(a["hyper"]),
        y_mean=jnp.asarray(a["y_mean"]),
        y_std=jnp.asarray(a["y_std"]),
        spec=spec,
        angles=angles,
        held_out_rms=tuple(float(v) for v in np.asarray(a["held_out_rms"])),
        held_out_max=float(a["held_out_max"]),
        source=source,
        key=key,
        mean_model=None if mean is None else mean.model,
        mean_cols=() if mean is None else tuple(int(c) for c in mean._cols),
        mean_vals=() if mean is None else tuple(float(v) for v in mean._vals),
        mean_features=tuple(int(i) for i in mean_features) if mean is not None else (),
        mean_coef=opt("mean_coef"),
        feature_shift=opt("feature_shift"),
        feature_scale=opt("feature_scale"),
        held_out_loo_rms=tuple(float(v) for v in np.asarray(a.get("loo_rms", ()))),
        fit_id=str(a.get("fit_id", "")),
        n_test=int(np.asarray(a["Zt"]).shape[0]) if "Zt" in a else 0,
    )


def emulator_check(emulator: Emulator, direct: Callable, x: Float[ArrayLike, "n p"]) -> dict:
    """Compare an emulator with direct evaluations at parameter vectors x (e.g. posterior draws).

    Returns:
        dict with per-angle RMS and max |difference| and the emulator's own held-out RMS.
    """
    x = np.asarray(x, dtype=float)
    d = np.asarray(emulator(x)) - np.asarray(direct(x))
    return {"rms": np.sqrt(np.mean(d**2, 0)), "max_abs": np.max(np.abs(d), 0), "error_sd": emulator.error_sd, "n": x.shape[0]}


# ------------------------------------------------------------------------------------------
# Registry of named forward models (the CLI's --forward)
# ------------------------------------------------------------------------------------------
def _analytic(free, fixed, bounds, **kw):
    return AnalyticForward()


def _analytic_kirchhoff(free, fixed, bounds, **kw):
    return AnalyticForward(lobe="kirchhoff")


def _analytic_hot_spot(free, fixed, bounds, **kw):
    from ._samples import load_sample

    return AnalyticForward(hot_spot=HotSpot.for_sample(load_sample("silver1")))  # both reference samples share this layer


def _analytic_mirror(free, fixed, bounds, **kw):
    return AnalyticForward(rough=False)


def _analytic_emulator(free, fixed, bounds, *, cache_dir="default", n_train: int = 256, n_test: int = 64, seed: int = 0, progress: bool = False, **kw):
    from ._parameters import make_spec

    base = AnalyticForward()
    names = tuple(n for n in free if n != "discrepancy")
    spec = make_spec(names, {k: v for k, v in (bounds or {}).items() if k in names})
    restricted = base.restrict(names, {k: v for k, v in (fixed or {}).items() if k != "discrepancy"})
    return build_emulator(restricted, spec, n_train=n_train, n_test=n_test, seed=seed, cache_dir=cache_dir, progress=progress)


#: name → (factory(free, fixed, bounds, **options) → ForwardModel, one-line description).
#: The tracer registers e.g. "tracer-emulator" with `register_forward`.
FORWARDS: dict[str, tuple[Callable, str]] = {
    "analytic": (_analytic, "analytic single scatter, rough platelets (Beckmann limit of the Kirchhoff BRDF)"),
    "analytic-kirchhoff": (_analytic_kirchhoff, "analytic single scatter, full Kirchhoff series lobe (slower)"),
    "analytic-hot-spot": (_analytic_hot_spot, "'analytic' with the entry and exit paths correlated over the reference samples' "
                          "platelet widths (D50 16 µm, t 1 µm, PVC 0.2; closer to the tracer's single scattering)"),
    "analytic-mirror": (_analytic_mirror, "analytic single scatter, mirror platelets (σ, τ not used)"),
    "analytic-emulator": (_analytic_emulator, "Gaussian-process emulator of 'analytic' (tests the emulator path the tracer will use)"),
}


def register_forward(name: str, factory: Callable, description: str) -> None:
    """Make a forward model available by name (CLI ``--forward``, `make_forward`).

    Arguments:
        name: the name.
        factory: ``factory(free, fixed, bounds, **options) -> ForwardModel``; for the tracer,
            typically `build_emulator` over a `CallableForward` with a fixed key.
        description: one line for ``--help``.
    """
    if not name or not callable(factory):
        raise ValueError("register_forward needs a non-empty name and a callable factory")
    FORWARDS[name] = (factory, description)


def make_forward(name: str, free: Sequence[str] = (), fixed: Mapping[str, float] | None = None,
                 bounds: Mapping[str, tuple[float, float]] | None = None, **options) -> ForwardModel:
    """Build the registered forward model `name` for the given free/fixed parameters."""
    if name not in FORWARDS:
        raise ValueError(f"unknown forward model {name!r}; known: {', '.join(FORWARDS)}")
    return FORWARDS[name][0](tuple(free), dict(fixed or {}), dict(bounds or {}), **options)
