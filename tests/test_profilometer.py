"""The virtual profilometer against closed forms: Rq = σ and the 1/e length = τ on ideal scans, the
Gaussian point-spread function's (σ, τ), the σ readings on a sine, the likelihood's normalisation."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from paintjax.inverse import SIGMA_DEFINITIONS, Profilometer, ReadingModel, profile_roughness, smoothed_gaussian_statistics

LONG = dict(cutoff_fraction=None, scan_range_um=(200.0, 200.0), num_platelets=8)


def test_ideal_instrument_without_filtering_reads_the_true_sigma_and_tau():
    """Noiseless Gaussian surface, no filter, no PSF: Rq → σ and the 1/e crossing → τ (8 scans of 200 µm:
    sampling SD ≈ 2 % in σ, 3 % in τ)."""
    d = Profilometer(resolution_um=0.0, pixel_um=0.02, **LONG).measure(jax.random.PRNGKey(1), 0.051, 0.64)
    assert d["sigma_um"] == pytest.approx(0.051, rel=0.05)
    assert d["tau_um"] == pytest.approx(0.64, rel=0.07)


@pytest.mark.parametrize("resolution", [0.55, 1.0])
def test_point_spread_function_follows_the_smoothed_gaussian_closed_form(resolution):
    """A Gaussian PSF of SD s turns (σ, τ) into (σ√(τ/τ_s), τ_s = √(τ² + 4s²))."""
    want_s, want_t = smoothed_gaussian_statistics(0.051, 0.64, resolution)
    assert want_t > 0.64 and want_s < 0.051
    d = Profilometer(resolution_um=resolution, pixel_um=0.02, **LONG).measure(jax.random.PRNGKey(2), 0.051, 0.64)
    assert d["sigma_um"] == pytest.approx(float(want_s), rel=0.05)
    assert d["tau_um"] == pytest.approx(float(want_t), rel=0.07)


def test_sigma_readings_on_a_sine():
    """h = A sin kx: Rq = A/√2, successive extrema differ by 2A (local peak-to-valley), Rt = 2A."""
    x = np.linspace(0.0, 20.0, 4001)
    h = 0.03 * np.sin(2 * np.pi * x / 1.25)  # 16 whole periods
    assert profile_roughness(h, "rq") == pytest.approx(0.03 / np.sqrt(2), rel=2e-3)
    assert profile_roughness(h, "local_pv") == pytest.approx(0.06, rel=1e-3)
    assert profile_roughness(h, "scan_pv") == pytest.approx(0.06, rel=1e-3)


def test_published_procedure_reads_low_and_is_reproducible():
    """The filter (cutoff 50 % of a 10–30 µm scan) removes the long-wavelength part of a Gaussian
    spectrum, so Rq reads below the PSF-smoothed σ; the same key gives the same numbers."""
    p = Profilometer()
    a = p.measure(jax.random.PRNGKey(3), 0.051, 0.64)
    b = p.measure(jax.random.PRNGKey(3), 0.051, 0.64)
    assert a["sigma_um"] == b["sigma_um"] and a["tau_um"] == b["tau_um"]
    assert a["sigma_um"] < float(smoothed_gaussian_statistics(0.051, 0.64, p.resolution_um)[0])
    readings = a["sigma_um_by_definition"]
    assert readings["rq"] < readings["local_pv"] < readings["scan_pv"]


def test_reading_likelihood_is_a_normalised_density():
    """`ReadingModel.log_likelihood` is a density in the reading (σ̂, τ̂): it integrates to one."""
    const = lambda v: np.array([v, v])  # noqa: E731 (moments that do not vary with τ)
    model = ReadingModel(np.log([0.3, 3.0]), {d: const(np.log(0.8)) for d in SIGMA_DEFINITIONS}, {d: const(0.1) for d in SIGMA_DEFINITIONS},
                         {d: const(0.6) for d in SIGMA_DEFINITIONS}, const(np.log(0.6)), const(0.08))
    s = np.linspace(0.025, 0.065, 161)
    t = np.linspace(0.4, 0.9, 161)
    S, T = np.meshgrid(s, t, indexing="ij")
    dens = np.exp(np.asarray(model.log_likelihood(0.05, 1.0, S, T)))  # true σ 0.05: σ̂ centred on 0.05 × 0.8
    assert np.trapezoid(np.trapezoid(dens, t, axis=1), s) == pytest.approx(1.0, abs=2e-3)


@pytest.mark.parametrize("kwargs,name", [({"resolution_um": -0.1}, "resolution_um"), ({"pixel_um": 0.0}, "pixel_um"),
                                          ({"num_platelets": 0}, "num_platelets"), ({"scan_range_um": (30.0, 10.0)}, "scan_range_um"),
                                          ({"cutoff_fraction": 1.5}, "cutoff_fraction"), ({"sigma_definition": "ra"}, "sigma_definition")])
def test_bad_settings_name_the_parameter(kwargs, name):
    with pytest.raises(ValueError, match=name):
        Profilometer(**kwargs)


def test_bad_surface_names_the_parameter():
    with pytest.raises(ValueError, match="tau_um"):
        Profilometer().measure(jax.random.PRNGKey(0), 0.05, 4.0)
    with pytest.raises(ValueError, match="sigma_um"):
        Profilometer().measure(jax.random.PRNGKey(0), float("nan"), 0.6)


def test_sigma_only_scales_the_reading():
    """Every step is linear in the heights and the 1/e length ignores their scale: with the same key, σ̂/σ
    and τ̂ do not depend on σ. `ReadingModel` rests on this."""
    p = Profilometer()
    a = p.measure(jax.random.PRNGKey(5), 0.02, 0.5)
    b = p.measure(jax.random.PRNGKey(5), 0.08, 0.5)
    for name in ("rq", "local_pv", "scan_pv"):
        assert a["sigma_um_by_definition"][name] / 0.02 == pytest.approx(b["sigma_um_by_definition"][name] / 0.08, rel=1e-9)
    assert a["tau_um"] == pytest.approx(b["tau_um"], rel=1e-12)


def test_reading_model_matches_a_direct_campaign_distribution(tmp_path):
    """The interpolated model at a node reproduces that node's simulated moments, scales exactly with σ,
    and its likelihood is smooth (finite gradient) in (σ, τ)."""
    from paintjax.inverse import build_reading_model

    m = build_reading_model(tau_nodes_um=[0.4, 0.8], campaigns=8, seed=3, cache_dir=tmp_path)
    again = build_reading_model(tau_nodes_um=[0.4, 0.8], campaigns=8, seed=3, cache_dir=tmp_path)  # from the cache
    assert np.allclose(np.asarray(m.log_tau_hat_mean), np.asarray(again.log_tau_hat_mean))
    d = Profilometer().campaign_distribution(jax.random.fold_in(jax.random.PRNGKey(3), 1), 0.05, 0.8, 8)
    mean_r, sd_r, mean_t, sd_t, _ = (float(v) for v in m.moments(0.8, "rq"))
    assert mean_r == pytest.approx(d["log_sigma_mean"] - np.log(0.05), abs=1e-9)
    assert mean_t == pytest.approx(d["log_tau_mean"], abs=1e-9)
    l1 = float(m.log_likelihood(0.05, 0.6, 0.03, 0.55))
    l2 = float(m.log_likelihood(0.10, 0.6, 0.06, 0.55))
    assert l2 == pytest.approx(l1 - np.log(2.0), abs=1e-9)  # σ scales: the density in σ̂ picks up the Jacobian 1/2
    g = jax.grad(lambda st: m.log_likelihood(st[0], st[1], 0.03, 0.55))(jax.numpy.array([0.05, 0.6]))
    assert np.all(np.isfinite(np.asarray(g)))
