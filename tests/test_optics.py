"""Fresnel optics and aluminium constants against closed forms."""

import numpy as np
import pytest

import paintjax as pj


def _transmittance_from_amplitudes(cos_i, n1, n2):
    """Independent T_s, T_p from transmission amplitudes and the flux ratio n2 cosθt / n1 cosθi."""
    sin_t = n1 / n2 * np.sqrt(1 - cos_i**2)
    cos_t = np.sqrt(1 - sin_t**2)
    ts = 2 * n1 * cos_i / (n1 * cos_i + n2 * cos_t)
    tp = 2 * n1 * cos_i / (n2 * cos_i + n1 * cos_t)
    flux = n2 * cos_t / (n1 * cos_i)
    return flux * ts**2, flux * tp**2


@pytest.mark.parametrize("n1,n2", [(1.0, 1.5), (1.5, 1.0), (1.0, 2.4)])
def test_fresnel_energy_conservation(n1, n2):
    theta_c = np.arcsin(min(1.0, n2 / n1))
    theta = np.linspace(0.0, 0.999 * theta_c, 50)
    Rs, Rp, R = (np.asarray(a) for a in pj.fresnel_dielectric(np.cos(theta), n1, n2))
    Ts, Tp = _transmittance_from_amplitudes(np.cos(theta), n1, n2)
    np.testing.assert_allclose(Rs + Ts, 1.0, atol=1e-12)
    np.testing.assert_allclose(Rp + Tp, 1.0, atol=1e-12)
    np.testing.assert_allclose(R, 0.5 * (Rs + Rp), atol=1e-15)


def test_total_internal_reflection():
    n = 1.5
    theta_c = np.degrees(np.arcsin(1 / n))
    assert abs(theta_c - 41.81) < 0.01
    above = np.radians(np.linspace(theta_c + 0.01, 89.9, 30))
    below = np.radians(theta_c - 0.5)
    for R in pj.fresnel_dielectric(np.cos(above), n, 1.0):
        np.testing.assert_array_equal(np.asarray(R), 1.0)
    assert float(pj.fresnel_dielectric(np.cos(below), n, 1.0)[2]) < 1.0


def test_brewster_zero_for_p():
    for n1, n2 in [(1.0, 1.5), (1.5, 1.0)]:
        theta_b = np.arctan(n2 / n1)
        Rs, Rp, _ = pj.fresnel_dielectric(np.cos(theta_b), n1, n2)
        assert float(Rp) < 1e-20
        assert float(Rs) > 0.01


def test_normal_incidence_closed_form():
    _, _, R = pj.fresnel_dielectric(1.0, 1.0, 1.5)
    assert float(R) == pytest.approx(0.04, abs=1e-14)


def test_conductor_reduces_to_dielectric_for_real_index():
    c = np.cos(np.radians(np.linspace(0, 80, 9)))
    for a, b in zip(pj.fresnel_conductor(c, 1.0, 1.5 + 0j), pj.fresnel_dielectric(c, 1.0, 1.5)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), atol=1e-14)


def test_conductor_normal_incidence_closed_form():
    nk = 1.2 + 7.0j
    n1 = 1.5
    expected = ((nk.real - n1) ** 2 + nk.imag**2) / ((nk.real + n1) ** 2 + nk.imag**2)
    assert float(pj.fresnel_conductor(1.0, n1, nk)[2]) == pytest.approx(expected, rel=1e-13)


def test_coat_internal_diffuse_reflectance():
    # Brief §7: r_i ≈ 0.596 for n = 1.5; an independent trapezoid of the same integral agrees.
    ri = pj.coat_internal_diffuse_reflectance(1.5)
    mu = np.linspace(0, 1, 400001)
    R = np.asarray(pj.fresnel_dielectric(mu, 1.5, 1.0)[2])
    assert ri == pytest.approx(np.trapezoid(R * 2 * mu, mu), abs=2e-6)
    assert ri == pytest.approx(0.596, abs=5e-4)


def test_aluminium_lorentz_drude_against_rakic_1995_point():
    nk = complex(np.asarray(pj.aluminium_index(0.55)))
    ref = pj.RAKIC1995_550NM
    assert abs(nk.real - ref.real) < 0.06 and abs(nk.imag - ref.imag) < 0.2
    R_model = float(pj.aluminium_reflectance(1.0, 0.55, 1.5))
    R_ref = float(pj.fresnel_conductor(1.0, 1.5, ref)[2])
    assert R_ref == pytest.approx(0.88, abs=0.005)  # brief §2
    assert R_model == pytest.approx(R_ref, abs=0.002)


def test_aluminium_visible_range_is_physical():
    wl = np.linspace(0.38, 0.78, 41)
    nk = np.asarray(pj.aluminium_index(wl))
    assert np.all(nk.real > 0) and np.all(nk.imag > 3)
    R = np.asarray(pj.aluminium_reflectance(1.0, wl, 1.5))
    assert np.all((R > 0.8) & (R < 0.95))


@pytest.mark.parametrize("bad", [0.05, 20.0, float("nan")])
def test_aluminium_wavelength_validation(bad):
    with pytest.raises(ValueError, match="wavelength_um"):
        pj.aluminium_index(bad)


def test_dielectric_index_validation():
    with pytest.raises(ValueError, match="n2"):
        pj.fresnel_dielectric(1.0, 1.0, -1.5)
