"""The virtual orientation measurement against closed forms: the Fisher SD of a gamma fit, apparent tilts."""

from __future__ import annotations

import numpy as np
import pytest

from paintjax.inverse import apparent_tilt_deg, fit_gamma, gamma_fit_sd, platelets_for_sd, tilt_fit_distribution


def test_fit_sd_follows_the_fisher_information():
    """200 simulated studies of 1000 platelets: the fitted shape's and scale's SDs within 15 % of the
    asymptotic (Fisher) values (the SD of an SD from 200 draws is ≈ 5 %), means within 2 SE of the truth."""
    d = tilt_fit_distribution(0, 2.29, 2.18, 1000, replicates=200)
    sd_k, sd_th, rho = gamma_fit_sd(2.29, 2.18, 1000)
    assert d["shape_sd"] == pytest.approx(sd_k, rel=0.15)
    assert d["scale_sd"] == pytest.approx(sd_th, rel=0.15)
    assert d["correlation"] == pytest.approx(rho, abs=0.05)
    assert abs(d["shape_mean"] - 2.29) < 2 * sd_k / np.sqrt(200) + 0.01


def test_platelets_for_sd_inverts_the_fit_sd():
    n = platelets_for_sd(2.29, 2.18, 0.05)
    assert gamma_fit_sd(2.29, 2.18, n)[0] == pytest.approx(0.05, rel=1e-3)


def test_apparent_tilts():
    """A section along the tilt direction shows the true tilt, across it none; apparent tilts are smaller."""
    t = np.array([1.0, 5.0, 20.0])
    assert np.allclose(apparent_tilt_deg(t, 0.0), t)
    assert np.allclose(apparent_tilt_deg(t, np.pi / 2), 0.0, atol=1e-12)
    assert np.all(apparent_tilt_deg(t, 1.0) < t)
    sec = tilt_fit_distribution(1, 2.29, 2.18, 500, section=True, replicates=20)
    true = tilt_fit_distribution(1, 2.29, 2.18, 500, replicates=20)
    assert sec["shape_mean"] * sec["scale_mean"] < true["shape_mean"] * true["scale_mean"]  # smaller mean tilt


def test_fit_gamma_recovers_a_large_sample_and_refuses_bad_tilts():
    rng = np.random.default_rng(0)
    k, th = fit_gamma(rng.gamma(2.98, 2.10, 200_000))
    assert k == pytest.approx(2.98, rel=0.02) and th == pytest.approx(2.10, rel=0.02)
    with pytest.raises(ValueError, match="tilts_deg"):
        fit_gamma([1.0, -2.0, 3.0])
    with pytest.raises(ValueError, match="num_platelets"):
        tilt_fit_distribution(0, 2.29, 2.18, 1)
