"""Platelet BRDFs: reciprocity, stated reflectance, unbiased importance sampling (issue 4)."""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from paintjax import BeckmannBRDF, HeTorranceBRDF, MirrorBRDF, TabulatedBRDF
from paintjax.brdf import hemisphere_directions
from paintjax.brdf._he_torrance import effective_roughness, shadowing
from paintjax.brdf._in_plane import kirchhoff_lobes
from paintjax.brdf._table import table_from_lobes

SIGMA, TAU = 0.051, 0.64  # platelet roughness [µm]


def direction(theta_deg, phi_deg=0.0):
    t, p = np.deg2rad(theta_deg), np.deg2rad(phi_deg)
    return np.stack(np.broadcast_arrays(np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)), -1)


@functools.lru_cache(maxsize=None)
def kirchhoff_table(coherent="lobe"):
    inc = np.concatenate([np.arange(0.0, 88.0, 6.0), [89.0]])
    return table_from_lobes(kirchhoff_lobes(SIGMA, TAU, incidence_deg=inc), coherent=coherent)


@functools.lru_cache(maxsize=None)
def brdfs():
    return {
        "beckmann": BeckmannBRDF(SIGMA, TAU),
        "beckmann_delta": BeckmannBRDF(SIGMA, TAU, coherent="delta"),
        "he_torrance": HeTorranceBRDF(SIGMA, TAU),
        "he_torrance_rough_air": HeTorranceBRDF(0.28, 1.77, n_medium=1.0, coherent="delta"),
        "table": kirchhoff_table(),
        "table_delta": kirchhoff_table("delta"),
    }


@functools.lru_cache(maxsize=None)
def _jitted(name):
    return eqx.filter_jit(lambda b, *a: getattr(b, name)(*a))


def call(brdf, name, *args):
    """brdf.<name>(*args) under jit (the BRDF is a pytree argument; compilations are reused)."""
    return _jitted(name)(brdf, *args)


def hemisphere_integral(brdf, theta_i_deg, n=120):
    """∫ f_inc cosθ_o dω_o on a (θ_o, φ_o) Gauss–Legendre × uniform grid (independent of the BRDF)."""
    wo, wt = hemisphere_directions(n, 2 * n)
    wi = direction(theta_i_deg, 17.0)  # an arbitrary azimuth: the BRDFs are isotropic
    f = call(brdf, "incoherent", jnp.asarray(wi), wo)
    return float(np.sum(np.asarray(f) * wt))


@pytest.mark.parametrize("name", ["beckmann", "beckmann_delta", "he_torrance", "he_torrance_rough_air", "table"])
def test_reciprocity(name):
    brdf = brdfs()[name]
    rng = np.random.default_rng(0)
    wi = direction(rng.uniform(0, 85, 400), rng.uniform(0, 360, 400))
    wo = direction(rng.uniform(0, 85, 400), rng.uniform(0, 360, 400))
    # include near-specular pairs, where the lobe is large
    wo[:200] = -wi[:200] * np.array([1, 1, -1]) + 0.05 * rng.normal(size=(200, 3)) * np.array([1, 1, 0])
    wo[:200] /= np.linalg.norm(wo[:200], axis=-1, keepdims=True)
    f_io = np.asarray(call(brdf, "evaluate", jnp.asarray(wi), jnp.asarray(wo)))
    f_oi = np.asarray(call(brdf, "evaluate", jnp.asarray(wo), jnp.asarray(wi)))
    assert np.all(np.isfinite(f_io)) and np.all(f_io >= 0)
    assert np.max(np.abs(f_io - f_oi)) <= 1e-12 * np.max(f_io) + 1e-14
    assert np.max(f_io) > 0.1


def test_mirror_reciprocal_and_reflectance():
    m = MirrorBRDF(wavelength_um=0.5)
    wi = jnp.asarray(direction(np.array([0.0, 30.0, 60.0]), 40.0))
    wo, w = m.sample(jax.random.PRNGKey(0), wi)
    np.testing.assert_allclose(np.asarray(w), np.asarray(m.albedo(wi[:, 2])), rtol=1e-14)
    np.testing.assert_allclose(np.asarray(wo[:, 2]), np.asarray(wi[:, 2]), rtol=1e-14)
    assert np.all(np.asarray(m.evaluate(wi, wo)) == np.asarray(m.evaluate(wo, wi)))


@pytest.mark.parametrize("theta_i", [0.0, 35.0, 65.0])
def test_kirchhoff_reflectance(theta_i):
    """∫ f cosθ_o dω_o (independent quadrature) equals the stated incoherent + coherent reflectance."""
    b = BeckmannBRDF(SIGMA, TAU)
    mu = np.cos(np.deg2rad(theta_i))
    stated = float(call(b, "incoherent_albedo", jnp.asarray(mu)))
    assert abs(hemisphere_integral(b, theta_i) - stated) < 2e-3 * stated
    # the coherent diffraction lobe carries R_coh (fine quadrature around the specular point)
    s = b.coherent_width
    r = np.linspace(0, 8 * s, 400)[1:]
    ph = (np.arange(128) + 0.5) * 2 * np.pi / 128
    wi = direction(theta_i)
    bx = -wi[0] + r[:, None] * np.cos(ph)
    by = r[:, None] * np.sin(ph)
    wo = np.stack([bx, by, np.sqrt(1 - bx**2 - by**2)], -1)
    coh = np.asarray(call(b, "_coherent_lobe", jnp.asarray(wi), jnp.asarray(wo)))
    integral = np.sum(coh * r[:, None]) * (r[1] - r[0]) * 2 * np.pi / 128
    np.testing.assert_allclose(integral, float(call(b, "coherent_reflectance", jnp.asarray(mu))), rtol=2e-3)
    # total: incoherent + coherent is a physically sensible reflectance below the Fresnel one + few %
    assert 0.0 < float(call(b, "albedo", jnp.asarray(mu))) < 1.0


def test_he_torrance_limits():
    mu = jnp.asarray([1.0, 0.5, 0.2])
    s_eff = np.asarray(effective_roughness(mu, mu, 0.28, 1.77))
    assert s_eff[0] == pytest.approx(0.28, rel=1e-9) and np.all(np.diff(s_eff) < 0) and np.all(s_eff > 0)
    S = np.asarray(shadowing(mu, 0.28, 1.77))
    assert S[0] == pytest.approx(1.0, abs=1e-12) and np.all(np.diff(S) < 0)
    # at normal incidence and observation He–Torrance reduces to Kirchhoff with σ_eff = σ, S = 1
    ht, bk = HeTorranceBRDF(0.28, 1.77, n_medium=1.0), BeckmannBRDF(0.28, 1.77, n_medium=1.0)
    z = jnp.asarray([0.0, 0.0, 1.0])
    assert float(ht.incoherent(z, z)) == pytest.approx(float(bk.incoherent(z, z)), rel=1e-9)



@pytest.mark.parametrize("name", ["beckmann", "table"])
@pytest.mark.parametrize("theta_i", [0.0, 40.0, 60.0, 75.0, 80.0, 85.0, 88.0])
def test_coherent_lobe_carries_the_coherent_reflectance(name, theta_i):
    """The narrow coherent lobe included in `evaluate` integrates (fine polar quadrature about the
    specular point, clipped at the disk) to the `coherent_reflectance` that `albedo` states, within
    0.05 %, up to 88° incidence. Measured ≤ 6 × 10⁻⁶ up to 75° and ≤ 5 × 10⁻⁵ at 80–88°, for both the
    Beckmann and the tabulated BRDF. Before the lobe's symmetric per-incidence scale (it took R_coh at
    the pair's mean cosine and a straight-edge cut of the disk) it was +2.4 % at 80° and −9 % at 85°."""
    brdf = brdfs()[name]
    s = brdf.coherent_width
    wi = direction(theta_i)
    r = np.linspace(0, 8 * s, 2000)[1:]
    ph = (np.arange(512) + 0.5) * 2 * np.pi / 512
    bx, by = -wi[0] + r[:, None] * np.cos(ph), r[:, None] * np.sin(ph)
    inside = bx**2 + by**2 < 1.0
    wo = np.stack([bx, by, np.sqrt(np.clip(1 - bx**2 - by**2, 1e-12, None))], -1)
    coh = np.asarray(call(brdf, "_coherent_lobe", jnp.asarray(wi), jnp.asarray(wo))) * inside
    integral = np.sum(coh * r[:, None]) * (r[1] - r[0]) * 2 * np.pi / 512
    stated = float(call(brdf, "coherent_reflectance", jnp.asarray(wi[2])))
    assert stated > 0.01
    assert abs(integral / stated - 1.0) < 5e-4, (integral, stated)


@pytest.mark.parametrize(
    "name, theta_i",
    [("beckmann", 10.0), ("beckmann_delta", 60.0), ("he_torrance", 60.0), ("he_torrance_rough_air", 10.0), ("table", 10.0), ("table", 60.0), ("table_delta", 40.0)],
)
def test_sampling_unbiased(name, theta_i):
    """Monte Carlo ∫ f cos / pdf equals the quadrature albedo; no sample below the plane."""
    brdf = brdfs()[name]
    n = 40_000
    wi = jnp.broadcast_to(jnp.asarray(direction(theta_i, 30.0)), (n, 3))
    wo, w = call(brdf, "sample", jax.random.PRNGKey(1), wi)
    wo, w = np.asarray(wo), np.asarray(w)
    assert np.all(np.isfinite(w)) and np.all(w >= 0)
    assert np.all(wo[:, 2] >= 0.0)
    np.testing.assert_allclose(np.linalg.norm(wo, axis=-1), 1.0, atol=1e-12)
    mu = np.cos(np.deg2rad(theta_i))
    quad = float(call(brdf, "coherent_reflectance", jnp.asarray(mu))) + hemisphere_integral(brdf, theta_i)
    mc, se = w.mean(), w.std() / np.sqrt(n)
    assert abs(mc - quad) < 4 * se + 2e-3 * quad, (mc, se, quad)
    # the weight is f cos / pdf with the pdf the BRDF reports (continuous samples)
    if brdf.coherent == "lobe":
        f = np.asarray(brdf.evaluate(wi[:1000], jnp.asarray(wo[:1000])))
        pdf = np.asarray(brdf.pdf(wi[:1000], jnp.asarray(wo[:1000])))
        ok = w[:1000] > 0
        np.testing.assert_allclose(w[:1000][ok], (f * wo[:1000, 2] / pdf)[ok], rtol=1e-9)


def test_sampling_lower_face():
    """Both faces scatter alike: a direction below the plane is answered below the plane."""
    b = BeckmannBRDF(SIGMA, TAU)
    wi = jnp.broadcast_to(jnp.asarray(direction(30.0) * np.array([1, 1, -1])), (2000, 3))
    wo, w = call(b, "sample", jax.random.PRNGKey(2), wi)
    assert np.all(np.asarray(wo)[:, 2] <= 0) and np.all(np.asarray(w) >= 0)


def test_interface_and_errors():
    for brdf in brdfs().values():
        assert brdf.is_delta is False
    assert MirrorBRDF.is_delta is True
    with pytest.raises(ValueError, match="sigma_um"):
        BeckmannBRDF(-0.1, 0.64)
    with pytest.raises(ValueError, match="tau_um"):
        HeTorranceBRDF(0.05, 0.0)
    with pytest.raises(ValueError, match="coherent"):
        BeckmannBRDF(0.05, 0.64, coherent="narrow")
    with pytest.raises(ValueError, match="n_medium"):
        BeckmannBRDF(0.05, 0.64, n_medium=-1.0)


def test_jit_and_vmap_friendly():
    table = kirchhoff_table()
    wi = jnp.asarray(direction(np.array([5.0, 25.0, 45.0]), 10.0))
    wo = jnp.asarray(direction(np.array([8.0, 20.0, 50.0]), 185.0))
    f_jit = jax.jit(lambda brdf, a, b: brdf.evaluate(a, b))(table, wi, wo)
    f_vmap = jax.vmap(table.evaluate)(wi, wo)
    np.testing.assert_allclose(np.asarray(f_jit), np.asarray(f_vmap), rtol=1e-12)
    assert isinstance(table, TabulatedBRDF)


def test_lambertian_reference_brdf():
    """Lambertian platelets: albedo by quadrature of f cos, sample weights = f cos / pdf, reciprocity, bad albedo."""
    import jax

    from paintjax import LambertianBRDF

    b = LambertianBRDF(0.7)
    wi = jnp.asarray([[0.3, 0.1, np.sqrt(1 - 0.1)]])
    wo, w = b.sample(jax.random.PRNGKey(0), jnp.broadcast_to(wi, (4096, 3)))
    np.testing.assert_allclose(np.asarray(w), 0.7)
    f, p = np.asarray(b.evaluate(jnp.broadcast_to(wi, wo.shape), wo)), np.asarray(b.pdf(jnp.broadcast_to(wi, wo.shape), wo))
    np.testing.assert_allclose(f * np.asarray(wo[:, 2]) / p, 0.7, rtol=1e-12)
    np.testing.assert_allclose(f, np.asarray(b.evaluate(wo, jnp.broadcast_to(wi, wo.shape))))
    mu = np.linspace(0, 1, 20001)
    assert float(np.trapezoid(2 * np.pi * mu * 0.7 / np.pi, mu)) == pytest.approx(float(b.albedo(0.5)), rel=1e-8)
    with pytest.raises(ValueError, match="albedo"):
        LambertianBRDF(1.2)
