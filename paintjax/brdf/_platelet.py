"""Platelet BRDFs in the platelet's local frame (z = platelet normal, both faces alike).

Directions point away from the surface. A BRDF answers three questions: its value f(ω_i, ω_o),
an importance sample of ω_o given ω_i with its throughput weight f cosθ_o / pdf, and its
directional albedo ∫ f cosθ_o dω_o. Delta (mirror) BRDFs have no finite value; `is_delta` says so
and their sample is the mirror direction with weight R(θ_i).
"""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, PRNGKeyArray

from ..optics._aluminium import aluminium_index
from ..optics._fresnel import fresnel_conductor


def reflect(w: Float[Array, "... 3"], normal: Float[Array, "... 3"]) -> Float[Array, "... 3"]:
    """Mirror direction of w (pointing away) about a unit normal."""
    return 2.0 * jnp.sum(w * normal, axis=-1, keepdims=True) * normal - w


def cosine_hemisphere(u1, u2):
    """Cosine-distributed unit directions about +z (density cos θ / π) from uniforms u1, u2 in [0, 1)."""
    r = jnp.sqrt(u1)
    ph = 2.0 * jnp.pi * u2
    return jnp.stack([r * jnp.cos(ph), r * jnp.sin(ph), jnp.sqrt(jnp.clip(1.0 - u1, 0.0, 1.0))], -1)


def _check_reflectance(value) -> None:
    if value is None:
        return
    try:
        r = float(value)
    except (TypeError, ValueError):
        return
    if not (0.0 <= r <= 1.0):
        raise ValueError(f"reflectance must lie in [0, 1], got {value!r}")


class AbstractPlateletBRDF(eqx.Module):
    """Interface every platelet BRDF implements (local frame, vectorised over leading dims)."""

    is_delta: eqx.AbstractClassVar[bool]

    @abc.abstractmethod
    def evaluate(self, wi: Float[Array, "... 3"], wo: Float[Array, "... 3"]) -> Float[Array, "..."]:
        """f(ω_i, ω_o) [1/sr]; zero when either direction is below the plane."""

    @abc.abstractmethod
    def sample(self, key: PRNGKeyArray, wi: Float[Array, "... 3"]) -> tuple[Float[Array, "... 3"], Float[Array, "..."]]:
        """(ω_o, weight = f cosθ_o / pdf); weight 0 for samples below the plane."""

    @abc.abstractmethod
    def pdf(self, wi: Float[Array, "... 3"], wo: Float[Array, "... 3"]) -> Float[Array, "..."]:
        """Density per steradian with which `sample` returns ω_o, continuous part only (0 for a delta)."""

    @abc.abstractmethod
    def albedo(self, cos_i: Float[Array, "..."]) -> Float[Array, "..."]:
        """Directional-hemispherical reflectance ∫ f cosθ_o dω_o."""

    @property
    @abc.abstractmethod
    def medium_index(self) -> float | None:
        """Real index of the medium above the platelet that the BRDF was built for (None: any)."""


class MirrorBRDF(AbstractPlateletBRDF):
    """Smooth metal platelet: a mirror with the Fresnel reflectance of a metal in the binder.

    Arguments:
        metal_index: complex index of the metal (default: aluminium at `wavelength_um`).
        n_binder: real index of the surrounding binder.
        reflectance: optional constant reflectance overriding Fresnel (in [0, 1]).
    """

    metal_index: complex = eqx.field(static=True)
    n_binder: float = eqx.field(static=True)
    reflectance: float | None = eqx.field(static=True)
    is_delta: ClassVar[bool] = True

    def __init__(self, *, wavelength_um: float = 0.55, n_binder: float = 1.5, metal_index=None, reflectance=None):
        _check_reflectance(reflectance)
        if metal_index is None:
            with jax.ensure_compile_time_eval():  # a constant, also when built inside a jit trace
                metal_index = complex(np.asarray(aluminium_index(wavelength_um)))
        self.metal_index = complex(metal_index)
        self.n_binder = float(n_binder)
        self.reflectance = None if reflectance is None else float(reflectance)

    def fresnel(self, cos_i: Float[Array, "..."]) -> Float[Array, "..."]:
        """Reflectance at the local incidence cosine."""
        if self.reflectance is not None:
            return jnp.full(jnp.shape(cos_i), self.reflectance)
        return fresnel_conductor(cos_i, self.n_binder, self.metal_index)[2]

    def evaluate(self, wi, wo):
        return jnp.zeros(jnp.broadcast_shapes(wi.shape, wo.shape)[:-1])

    pdf = evaluate  # a delta has no continuous part

    def sample(self, key, wi):
        normal = jnp.zeros_like(wi).at[..., 2].set(1.0)
        return reflect(wi, normal), self.fresnel(jnp.abs(wi[..., 2]))

    def albedo(self, cos_i):
        return self.fresnel(cos_i)

    @property
    def medium_index(self):
        return self.n_binder


class LambertianBRDF(AbstractPlateletBRDF):
    """Diffuse (Lambertian) platelet faces of albedo a: f = a/π, exactly importance sampled.

    A reference BRDF for closed-form checks (white furnace, energy closure), not a model of
    aluminium. Reciprocal; `sample` returns cosine-distributed directions with weight a.

    Arguments:
        albedo: a in [0, 1].
    """

    albedo_value: Float[Array, ""]
    is_delta: ClassVar[bool] = False

    def __init__(self, albedo):
        a = float(albedo)
        if not 0.0 <= a <= 1.0:
            raise ValueError(f"albedo must lie in [0, 1], got {albedo!r}")
        self.albedo_value = jnp.asarray(a)

    def evaluate(self, wi, wo):
        ok = (wi[..., 2] > 0) & (wo[..., 2] > 0)
        return jnp.where(ok, self.albedo_value / jnp.pi, 0.0).astype(wi.dtype)

    def sample(self, key, wi):
        u = jax.random.uniform(key, wi.shape[:-1] + (2,), dtype=wi.dtype)
        return cosine_hemisphere(u[..., 0], u[..., 1]), jnp.broadcast_to(self.albedo_value, wi.shape[:-1]).astype(wi.dtype)

    def pdf(self, wi, wo):
        ok = (wi[..., 2] > 0) & (wo[..., 2] > 0)
        return jnp.where(ok, wo[..., 2] / jnp.pi, 0.0).astype(wi.dtype)

    def albedo(self, cos_i):
        return jnp.broadcast_to(self.albedo_value, jnp.shape(cos_i))

    @property
    def medium_index(self):
        return None  # a reference BRDF, not tied to a medium
