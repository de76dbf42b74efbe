"""Lightness, the spectral path and the flop index against colour-science and closed forms."""

import colour
import numpy as np
import pytest

import paintjax as pj


def test_lightness_known_values():
    Y = np.array([100.0, 18.418651851244416, 0.5, 0.0, 257.0])
    L = np.asarray(pj.lightness(Y))
    assert L[0] == pytest.approx(100.0, abs=1e-12)
    assert L[1] == pytest.approx(50.0, abs=1e-9)
    assert L[2] == pytest.approx(24389 / 27 * 0.005, abs=1e-12)  # linear branch below (6/29)^3
    assert L[3] == 0.0
    assert L[4] > 100.0  # metallics exceed 100: no clipping
    assert L[4] == pytest.approx(116 * 2.57 ** (1 / 3) - 16, abs=1e-9)


def test_lightness_matches_colour_science_including_above_100():
    Y = np.concatenate([np.linspace(0, 2, 50), np.linspace(2, 400, 200)])
    np.testing.assert_allclose(np.asarray(pj.lightness(Y)), pj.lightness_np(Y), atol=1e-10)


def test_reflectance_factor_round_trip():
    R = np.array([0.001, 0.05, 0.4, 1.0, 2.7])
    L = np.asarray(pj.reflectance_factor_to_lightness(R))
    np.testing.assert_allclose(pj.lightness_to_reflectance_factor(L), R, rtol=1e-12)


def test_spectral_path_matches_colour_sd_to_xyz():
    wl, W = pj.spectral_weights()
    rng = np.random.default_rng(0)
    for _ in range(3):
        values = rng.uniform(0.0, 1.5, wl.size)
        sd = colour.SpectralDistribution(dict(zip(wl, values)))
        shape = colour.SpectralShape(380, 780, 5)
        cmfs = colour.MSDS_CMFS["CIE 1964 10 Degree Standard Observer"].copy().align(shape)
        ill = colour.SDS_ILLUMINANTS["D65"].copy().align(shape)
        ref = colour.sd_to_XYZ(sd, cmfs, ill, method="Integration")
        ours = np.asarray(pj.spectral_to_xyz(values, W))
        np.testing.assert_allclose(ours, ref, rtol=1e-6, atol=1e-9)
        assert float(pj.spectral_lightness(values, W)) == pytest.approx(float(pj.lightness_np(ref[1])), abs=1e-6)


def test_perfect_reflector_is_y_100():
    wl, W = pj.spectral_weights()
    assert float(pj.spectral_to_xyz(np.ones(wl.size), W)[1]) == pytest.approx(100.0, abs=1e-10)


def test_flop_index_formula():
    L15, L45, L110 = 143.3, 58.6, 32.1
    assert float(pj.flop_index(L15, L45, L110)) == pytest.approx(2.69 * (L15 - L110) ** 1.11 / L45**0.86, rel=1e-14)


def test_bad_spectral_grid():
    with pytest.raises(ValueError, match="spectral grid"):
        pj.spectral_weights(300, 780, 5)
