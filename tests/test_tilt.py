"""Gamma tilt law: normalisation per solid angle, sampling, projected area."""

import jax
import numpy as np
import pytest
from scipy import integrate, stats

import paintjax as pj


@pytest.mark.parametrize("shape,scale", [(2.29, 2.18), (2.98, 2.10), (1.5, 10.0)])
def test_density_per_solid_angle_integrates_to_one(shape, scale):
    tilt = pj.GammaTilt(shape, scale)
    f = lambda t: float(tilt.density_per_solid_angle(np.cos(t))) * 2 * np.pi * np.sin(t)  # noqa: E731
    total, _ = integrate.quad(f, 0, np.pi / 2, points=[np.radians(shape * scale)], limit=200)
    assert total == pytest.approx(1.0, abs=1e-8)


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
    mean_cos = integrate.quad(lambda t: float(tilt.pdf_deg(t)) * np.cos(np.radians(t)), 0, 90, limit=200)[0]
    c = np.cos(np.radians(20.0))
    # Tilts above 70° contribute the crossing term, but their mass is < 1e-12 here.
    assert float(tilt.projected_area(c)) == pytest.approx(mean_cos * c, rel=1e-9)
    # At grazing view the average of |sin t cos φ| is (2/π) <sin t>.
    mean_sin = integrate.quad(lambda t: float(tilt.pdf_deg(t)) * np.sin(np.radians(t)), 0, 90, limit=200)[0]
    assert float(tilt.projected_area(0.0)) == pytest.approx(2 / np.pi * mean_sin, rel=1e-6)


@pytest.mark.parametrize("shape,scale,name", [(-1.0, 2.0, "shape"), (2.0, 0.0, "scale"), (np.nan, 2.0, "shape"), (2.0, 120.0, "scale")])
def test_bad_parameters(shape, scale, name):
    with pytest.raises(ValueError, match=name):
        pj.GammaTilt(shape, scale)
