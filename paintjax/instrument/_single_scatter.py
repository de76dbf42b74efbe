"""Analytic single-scatter ("specular microfacet") model of a hiding platelet layer under a flat or wavy coat.

A semi-infinite random medium of thin platelets with normal density p(m) per steradian (gamma tilt,
uniform azimuth). A ray entering along −ω_i first meets a platelet of normal m with probability
p(m)|m·ω_i| / A(ω_i), A(ω) = ∫ p |m·ω| dω_m. Single scattering by platelet BRDF f_p gives, inside
the coat,

    f_in(ω_i, ω_o) = ∫ p(m) |m·ω_i| |m·ω_o| f_p(ω_i, ω_o; m) dω_m / D,
    D = A(ω_i) cosθ_o + A(ω_o) cosθ_i        (exit occlusion by the same medium, default)
    D = A(ω_i) cosθ_o                          (no exit occlusion),

which for mirror platelets collapses to f_in = R(ω_i·h) p(h) / (4 D), h the half vector. The
independent exit occlusion holds for platelets much narrower than the mean free path; for wide
ones the entry and exit paths are correlated (`paintjax.instrument._hot_spot`: D → μ_i μ_o / G). The
reflectance factor through a flat coat of index n is R(γ) = π T(θ_i) T(θ_o) f_in / n² (brief §3).
Platelets of finite thickness (`side_walls` = aspect t·E[w]/E[w²], 0 for thin platelets) add the
projected area of their black side walls to A: a w × w × t box seen along ω shows
w²|m·ω| + wt(|u·ω| + |v·ω|), on average over its in-plane rotation w²(|m·ω| + (t/w)(4/π)|m × ω|);
the side walls only extinguish (the tracer's `edges="absorb"`).
With exit occlusion the model is reciprocal. The platelet BRDF is pluggable: any
`AbstractPlateletBRDF` is integrated over the tilt distribution numerically.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..brdf._platelet import AbstractPlateletBRDF, MirrorBRDF
from ..microstructure._tilt import MAX_TILT_DEG, GammaTilt
from ..optics._interface import check_waviness, gauss_hermite_facets, seen_through_facet, slope_sd
from ._geometry import Geometry
from ._hot_spot import HotSpot
from ._lightness import reflectance_factor_to_lightness


def check_coat_index(n) -> None:
    """Raise unless the coat index n is a number in (1, 3] (a traced value is checked where it is concrete)."""
    if isinstance(n, jax.core.Tracer):
        return
    try:
        v = float(n)
    except (TypeError, ValueError):
        raise ValueError(f"coat refractive index n must be a number in (1, 3], got {n!r}") from None
    if not (1.0 < v <= 3.0):
        raise ValueError(f"coat refractive index n must lie in (1, 3], got {n!r}")


def check_platelet_medium(platelet: AbstractPlateletBRDF, n) -> None:
    """Raise if the platelet BRDF was built for another binder index than the coat index n.

    The binder and the clearcoat share one index (no optical interface between them, BRIEF §2), so
    a platelet BRDF computed in a binder of index n_b only fits a coat of index n = n_b. BRDFs that
    record no medium (`medium_index` None) and traced n are not checked."""
    nb = platelet.medium_index
    if nb is None or isinstance(n, jax.core.Tracer):
        return
    if not abs(float(nb) - float(n)) <= 1e-6 * float(n):
        raise ValueError(f"platelet BRDF was built for a binder of index {float(nb):g}, but the coat index n is {float(n):g}; "
                         f"rebuild the BRDF with that index (n_binder / n_medium = {float(n):g}) or set n = {float(nb):g}")


def _orthonormal_basis(m: Float[Array, "... 3"]):
    """Two tangents completing m to a right-handed frame (Frisvad/Duff, branchless)."""
    sign = jnp.where(m[..., 2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + m[..., 2])
    b = m[..., 0] * m[..., 1] * a
    t1 = jnp.stack([1.0 + sign * m[..., 0] ** 2 * a, sign * b, -sign * m[..., 0]], axis=-1)
    t2 = jnp.stack([b, sign + m[..., 1] ** 2 * a, -m[..., 1]], axis=-1)
    return t1, t2


def to_local(w: Float[Array, "... 3"], m: Float[Array, "... 3"]) -> Float[Array, "... 3"]:
    """Components of w in the frame (t1, t2, m) of a platelet with unit normal m."""
    t1, t2 = _orthonormal_basis(m)
    return jnp.stack([jnp.sum(w * t1, -1), jnp.sum(w * t2, -1), jnp.sum(w * m, -1)], axis=-1)


def _denominator(tilt: GammaTilt, wi, wo, exit_occlusion: bool, hot_spot: HotSpot | None = None, side_walls: float = 0.0):
    ci, co = wi[..., 2], wo[..., 2]
    area = (lambda c: tilt.projected_area(c)) if side_walls == 0 else (lambda c: tilt.projected_area(c) + side_walls * tilt.side_wall_area(c))
    if not exit_occlusion:
        if hot_spot is not None:
            raise ValueError("hot_spot correlates the exit occlusion with the entry: it needs exit_occlusion=True")
        return area(ci) * co
    if hot_spot is not None:  # correlated paths: μ_i μ_o / G (G = 1/(α_i + α_o) without correlation)
        return ci * co / hot_spot.joint_escape(wi, wo, area(ci) / ci, area(co) / co)
    return area(ci) * co + area(co) * ci


@eqx.filter_jit
def single_scatter_brdf(
    wi: Float[Array, "... 3"],
    wo: Float[Array, "... 3"],
    tilt: GammaTilt,
    platelet: AbstractPlateletBRDF,
    *,
    exit_occlusion: bool = True,
    hot_spot: HotSpot | None = None,
    side_walls: float = 0.0,
    tilt_nodes: int = 256,
    azimuth_nodes: int = 256,
) -> Float[Array, "..."]:
    """BRDF f_in(ω_i, ω_o) [1/sr] of the platelet layer, inside the coat (paint frame, z up).

    Arguments:
        wi, wo: unit directions inside the coat, pointing away from the layer (z > 0).
        tilt: platelet tilt law.
        platelet: platelet BRDF; mirrors use the closed form, others tilt/azimuth quadrature.
        exit_occlusion: attenuate the exiting ray by the same platelet medium (reciprocal form).
        hot_spot: with `exit_occlusion`, correlate the entry and exit attenuation over the
            platelets' finite width (`HotSpot`); None: independent (platelets ≪ mean free path).
        side_walls: platelet aspect t·E[w]/E[w²] ≥ 0 whose black side walls add to the extinction
            (module docstring); 0 (default): thin platelets.
        tilt_nodes, azimuth_nodes: quadrature sizes for non-delta platelet BRDFs (the defaults
            resolve platelet lobes down to ~0.5° wide; a 0.35° lobe needs them).
    """
    side_walls = float(side_walls)
    if not (side_walls >= 0.0 and np.isfinite(side_walls)):
        raise ValueError(f"side_walls (platelet aspect t/w) must be a finite number ≥ 0, got {side_walls!r}")
    denom = _denominator(tilt, wi, wo, exit_occlusion, hot_spot, side_walls)
    if platelet.is_delta:
        h = wi + wo
        h = h / jnp.linalg.norm(h, axis=-1, keepdims=True)
        cos_ih = jnp.sum(wi * h, axis=-1)
        return platelet.albedo(cos_ih) * tilt.density_per_solid_angle(h[..., 2]) / (4.0 * denom)
    # Non-delta: ∫ p(m)|m·wi||m·wo| f_p dω_m with t = 90° u² (dense at small tilt), uniform azimuth.
    x, w = np.polynomial.legendre.leggauss(tilt_nodes)
    u = 0.5 * (x + 1.0)
    t_deg = MAX_TILT_DEG * u**2
    dt_rad = np.deg2rad(MAX_TILT_DEG) * 2.0 * u * 0.5 * w  # dt = 90°·2u du
    phi = (np.arange(azimuth_nodes) + 0.5) * (2.0 * np.pi / azimuth_nodes)
    t = np.deg2rad(t_deg)[:, None]
    m = np.stack(np.broadcast_arrays(np.sin(t) * np.cos(phi), np.sin(t) * np.sin(phi), np.cos(t)), axis=-1)
    m = jnp.asarray(m.reshape(-1, 3))
    weight = jnp.asarray(np.repeat(dt_rad * np.sin(np.deg2rad(t_deg)), azimuth_nodes) * (2.0 * np.pi / azimuth_nodes))
    p = tilt.density_per_solid_angle(m[:, 2])
    wi_b, wo_b = wi[..., None, :], wo[..., None, :]
    mi = jnp.sum(wi_b * m, -1)
    mo = jnp.sum(wo_b * m, -1)
    side = jnp.where(mi >= 0, 1.0, -1.0)[..., None]  # which face the ray meets
    mm = side * m
    f = platelet.evaluate(to_local(wi_b, mm), to_local(wo_b, mm))
    same_side = (mi * mo) > 0
    integrand = jnp.where(same_side, p * jnp.abs(mi) * jnp.abs(mo) * f, 0.0)
    return jnp.sum(integrand * weight, axis=-1) / denom


@eqx.filter_jit
def microfacet_reflectance_factor(
    geometry: Geometry,
    tilt: GammaTilt,
    *,
    n: float = 1.5,
    platelet: AbstractPlateletBRDF | None = None,
    exit_occlusion: bool = True,
    hot_spot: HotSpot | None = None,
    side_walls: float = 0.0,
    aperture_nodes: int = 6,
    waviness_deg: float = 0.0,
    waviness_nodes: int = 8,
) -> Float[Array, " m"]:
    """Reflectance factor R = π T_i T_o f_in / n² at each detector of `geometry`.

    Finite aperture half-angles (if set on the geometry) are averaged over with a cone quadrature.
    A wavy clearcoat (`paintjax.optics._interface`) averages R over the visible facets of both crossings,
    R = E_{m_i, m_o}[v_i v_o π T(m_i) T(m_o) f_in(ω_i(m_i), ω_o(m_o))] / n², by tensor
    Gauss–Hermite quadrature of the slopes.

    Arguments:
        geometry: instrument geometry (directions in air).
        tilt: platelet tilt law.
        n: coat (and binder) refractive index.
        platelet: platelet BRDF (default: aluminium mirror in the binder at 550 nm).
        exit_occlusion, hot_spot, side_walls: see `single_scatter_brdf`.
        aperture_nodes: radial and azimuthal nodes of each aperture's cone quadrature.
        waviness_deg: RMS slope angle of the clearcoat surface [deg] (0 = flat).
        waviness_nodes: Gauss–Hermite nodes per slope component.

    Returns:
        Reflectance factor per detector.
    """
    if not isinstance(geometry, Geometry):
        raise ValueError(f"geometry must be a Geometry (paintjax.ma98_geometry), got {type(geometry).__name__}")
    if not isinstance(tilt, GammaTilt):
        raise ValueError(f"tilt must be a GammaTilt (the platelet tilt law), got {type(tilt).__name__}")
    check_coat_index(n)
    if platelet is None:
        platelet = MirrorBRDF(n_binder=n)
    check_platelet_medium(platelet, n)
    wi_air = cone_directions(geometry.illumination_air(), geometry.illumination_aperture_deg, aperture_nodes)
    wo_air = cone_directions(geometry.detectors_air(), geometry.detector_aperture_deg, aperture_nodes)
    wi_air, wi_w = wi_air
    wo_air, wo_w = wo_air  # (m, q, 3), (q,)
    waviness_deg = check_waviness(waviness_deg)
    facets, facet_w = (jnp.asarray(a) for a in gauss_hermite_facets(waviness_deg, waviness_nodes))
    wi, Ti = _through_coat(wi_air, facets, facet_w, n, slope_sd(waviness_deg))  # (qi·q, 3), (qi·q,)
    wo, To = _through_coat(wo_air, facets, facet_w, n, slope_sd(waviness_deg))  # (m, qo·q, 3), (m, qo·q)
    f = single_scatter_brdf(wi[None, None, :, :], wo[:, :, None, :], tilt, platelet, exit_occlusion=exit_occlusion, hot_spot=hot_spot,
                            side_walls=side_walls)
    R = jnp.pi * Ti[None, None, :] * To[:, :, None] * f / n**2
    return jnp.einsum("moi,o,i->m", R, jnp.repeat(wo_w, facets.shape[0]), jnp.repeat(wi_w, facets.shape[0]))


def _through_coat(w_air, facets, facet_w, n, sd):
    """Internal directions and weights v·T·(quadrature weight) of air directions w_air (..., q_a, 3) crossing facets (q, 3).

    Returns directions (..., q_a·q, 3) pointing away from the layer and weights (..., q_a·q).
    """
    w_in, vT = seen_through_facet(w_air[..., :, None, :], facets, n, sd)
    weight = vT * facet_w
    shape = w_air.shape[:-1]
    return w_in.reshape(*shape[:-1], -1, 3), weight.reshape(*shape[:-1], -1)


def cone_directions(axis: Float[Array, "... 3"], half_angle_deg: float, nodes: int):
    """Quadrature of a uniform cone of directions around each axis (one node when half-angle is 0).

    Returns:
        (directions (..., q, 3), weights (q,) summing to 1).
    """
    if half_angle_deg == 0.0:
        return axis[..., None, :], jnp.ones((1,))
    c0 = np.cos(np.deg2rad(half_angle_deg))
    x, w = np.polynomial.legendre.leggauss(nodes)
    cos_r = 1.0 - 0.5 * (x + 1.0) * (1.0 - c0)  # uniform in cos over the cap
    phi = (np.arange(nodes) + 0.5) * 2.0 * np.pi / nodes
    sin_r = np.sqrt(1.0 - cos_r**2)
    local = np.stack(np.broadcast_arrays(sin_r[:, None] * np.cos(phi), sin_r[:, None] * np.sin(phi), cos_r[:, None]), -1).reshape(-1, 3)
    weights = np.repeat(0.5 * w, nodes) / nodes
    t1, t2 = _orthonormal_basis(axis)
    local = jnp.asarray(local)
    dirs = local[:, 0, None] * t1[..., None, :] + local[:, 1, None] * t2[..., None, :] + local[:, 2, None] * axis[..., None, :]
    return dirs, jnp.asarray(weights)


def microfacet_lightness(geometry: Geometry, tilt: GammaTilt, **kwargs) -> Float[Array, " m"]:
    """L* of `microfacet_reflectance_factor` (same arguments)."""
    return reflectance_factor_to_lightness(microfacet_reflectance_factor(geometry, tilt, **kwargs))


