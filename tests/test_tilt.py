"""Gamma tilt law: normalisation per solid angle, sampling, projected area."""

import jax
import numpy as np
import pytest
from scipy import integrate, stats

import paintjax as pj


@pytest.mark.parametrize("shape,scale", [(2.29, 2.18), (2.98, 2.10), (1.5, 10.0)])
def test_density_per_solid_angle_integrates_to_one(shape, scale):
    tilt = pj.GammaTilt(shape, scale)
    # Composite Gauss–Legendre in u, t = (π/2) u² (smooths the t^(k−2) edge for k < 2), one
    # vectorised call of our density.
    x, w = np.polynomial.legendre.leggauss(40)
    edges = np.linspace(0.0, 1.0, 91)
    u = (0.5 * (x[None] + 1) * np.diff(edges)[:, None] + edges[:-1, None]).ravel()
    wu = (0.5 * w[None] * np.diff(edges)[:, None]).ravel()
    t, wt = 0.5 * np.pi * u**2, np.pi * u * wu
    p = np.asarray(tilt.density_per_solid_angle(np.cos(t)))
    assert np.sum(p * 2 * np.pi * np.sin(t) * wt) == pytest.approx(1.0, abs=1e-8)


def test_pdf_matches_scipy_gamma():
    tilt = pj.GammaTilt(2.29, 2.18)
    t = np.linspace(0.1, 40, 50)
    ref = stats.gamma(2.29, scale=2.18).pdf(t) / stats.gamma(2.29, scale=2.18).cdf(90)
    np.testing.assert_allclose(np.asarray(tilt.pdf_deg(t)), ref, rtol=1e-10)


def test_sampling_follows_the_law_and_is_seeded():
    tilt = pj.GammaTilt(2.98, 2.10)
    a = np.asarray(tilt.sample_deg(jax.random.key(0), 20000))
    b = np.asarray(tilt.sample_deg(jax.random.key(0), 20000))
    np.testing.assert_array_equal(a, b)
    ks = stats.kstest(a, stats.gamma(2.98, scale=2.10).cdf)
    assert ks.pvalue > 0.01, ks


def test_projected_area_closed_forms():
    # Untilted platelets see cosθ; a tilt t below 90° − θ gives exactly cos t cosθ.
    tilt = pj.GammaTilt(2.29, 2.18)
    law = stats.gamma(2.29, scale=2.18)
    mass = law.cdf(90.0)
    mean_cos = integrate.quad(lambda t: law.pdf(t) * np.cos(np.radians(t)), 0, 90, limit=200)[0] / mass
    c = np.cos(np.radians(20.0))
    # Tilts above 70° contribute the crossing term, but their mass is < 1e-12 here.
    assert float(tilt.projected_area(c)) == pytest.approx(mean_cos * c, rel=1e-9)
    # At grazing view the average of |sin t cos φ| is (2/π) <sin t>.
    mean_sin = integrate.quad(lambda t: law.pdf(t) * np.sin(np.radians(t)), 0, 90, limit=200)[0] / mass
    assert float(tilt.projected_area(0.0)) == pytest.approx(2 / np.pi * mean_sin, rel=1e-6)


@pytest.mark.parametrize("shape,scale,name", [(-1.0, 2.0, "shape"), (2.0, 0.0, "scale"), (np.nan, 2.0, "shape"), (2.0, 120.0, "scale")])
def test_bad_parameters(shape, scale, name):
    with pytest.raises(ValueError, match=name):
        pj.GammaTilt(shape, scale)
