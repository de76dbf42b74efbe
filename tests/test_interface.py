"""The clearcoat interface (paintjax.optics._interface): facet refraction, Smith-normalised visible weights,
exact visible-normal sampling, and the wavy-coat analytic model's limits and reciprocity."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from paintjax import GammaTilt, MirrorBRDF, custom_geometry, ma98_geometry
from paintjax.instrument._single_scatter import microfacet_reflectance_factor
from paintjax.optics._interface import (
    check_waviness,
    gauss_hermite_facets,
    reflect,
    refract,
    sample_facet_normal,
    sample_visible_facet,
    slope_sd,
    smith_masking,
    visible_weight,
)

K = 4.0


def _direction(theta_deg, phi_deg=30.0):
    t, p = np.deg2rad(theta_deg), np.deg2rad(phi_deg)
    return jnp.asarray([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])


def test_refraction_obeys_snell_at_a_tilted_facet():
    m = jnp.asarray([0.3, -0.2, 0.9])
    m = m / jnp.linalg.norm(m)
    d = jnp.asarray([0.5, 0.1, -0.8])
    d = d / jnp.linalg.norm(d)
    n = 1.5
    t, cos_i = refract(d, m, 1.0 / n)
    assert abs(float(jnp.linalg.norm(t)) - 1.0) < 1e-12
    sin_i = np.linalg.norm(np.cross(np.asarray(d), np.asarray(m)))
    sin_t = np.linalg.norm(np.cross(np.asarray(t), np.asarray(m)))
    assert abs(sin_i - n * sin_t) < 1e-12 and float(cos_i) > 0
    # coplanar with d and m, and the mirror keeps the angle
    assert abs(np.dot(np.cross(np.asarray(d), np.asarray(m)), np.asarray(t))) < 1e-12
    r = reflect(d, m)
    assert abs(float(jnp.dot(r, m)) + float(jnp.dot(d, m))) < 1e-12


@pytest.mark.parametrize("waviness", [4.0, 15.0])
def test_visible_weight_has_unit_mean(waviness):
    """Smith masking normalises the visible projected area: E_slopes[v] = 1 at every angle."""
    m, w = gauss_hermite_facets(waviness, 64)
    sd = slope_sd(waviness)
    for theta in (0.0, 30.0, 60.0, 80.0, 88.0):
        mean = float(jnp.sum(visible_weight(_direction(theta)[None], jnp.asarray(m), sd) * w))
        assert abs(mean - 1.0) < 2e-3, (theta, mean)
    # without masking the mean would exceed 1 at grazing angles: the normalisation is not idle
    assert float(smith_masking(_direction(88.0), sd)) < 0.99


@pytest.mark.parametrize("theta", [0.0, 45.0, 85.0])
def test_visible_normal_sampling_matches_weighted_draws(theta):
    """Exact inversion sampling and weighted slope draws give the same facet statistics (K·SE)."""
    n = 200_000
    sd = slope_sd(10.0)
    om = _direction(theta)
    k1, k2 = jax.random.split(jax.random.PRNGKey(3))
    u = jax.random.uniform(k1, (2, n), minval=1e-7, maxval=1.0 - 1e-7)
    m_exact = sample_visible_facet(jnp.broadcast_to(om, (n, 3)), sd, u[0], u[1])
    v = jax.random.uniform(k2, (2, n), minval=1e-7, maxval=1.0 - 1e-7)
    m_w = sample_facet_normal(sd, v[0], v[1])
    wt = visible_weight(om[None], m_w, sd)
    for g in (lambda mm: mm[:, 0], lambda mm: mm[:, 1], lambda mm: mm @ om, lambda mm: mm[:, 0] ** 2):
        a, b = np.asarray(g(m_exact)), np.asarray(wt * g(m_w))
        se = np.hypot(a.std() / np.sqrt(n), b.std() / np.sqrt(n))
        assert abs(a.mean() - b.mean()) < K * se + 1e-12, (theta, a.mean(), b.mean(), se)
    assert np.all(np.asarray(m_exact @ om) > 0)  # only front-facing facets


def test_wavy_analytic_model_limits_and_reciprocity():
    tilt = GammaTilt(2.29, 2.18)
    geo = ma98_geometry(45.0)
    flat = np.asarray(microfacet_reflectance_factor(geo, tilt))
    tiny = np.asarray(microfacet_reflectance_factor(geo, tilt, waviness_deg=0.05))
    np.testing.assert_allclose(tiny, flat, rtol=2e-3)
    wavy = np.asarray(microfacet_reflectance_factor(geo, tilt, waviness_deg=10.0))
    assert np.max(np.abs(wavy / flat - 1.0)) > 0.05  # the waviness does something
    # reciprocity: swap source (30°, azimuth 180° by default) and detector (50°, 70°), out of plane
    a = microfacet_reflectance_factor(custom_geometry(30.0, [50.0], [70.0]), tilt, platelet=MirrorBRDF(), waviness_deg=10.0)
    b = microfacet_reflectance_factor(custom_geometry(50.0, [30.0], [180.0], illumination_azimuth_deg=70.0), tilt,
                                      platelet=MirrorBRDF(), waviness_deg=10.0)
    assert abs(float(a[0]) / float(b[0]) - 1.0) < 1e-6, (a, b)


def test_check_waviness_names_parameter_and_range():
    assert check_waviness(3) == 3.0
    for bad in (-1.0, 16.0, float("nan"), "x"):
        with pytest.raises(ValueError, match="waviness_deg"):
            check_waviness(bad)
