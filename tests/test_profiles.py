"""Rough-profile synthesis, measured line scans, processing and statistics."""

import jax
import numpy as np
import pytest

from paintjax.wave._profiles import (
    LineScan,
    load_line_scan,
    process_line_scan,
    profile_statistics,
    profiles_from_heights,
    synthesize_profiles,
)


@pytest.mark.parametrize("correlation", ["gaussian", "exponential"])
def test_synthesis_reproduces_statistics(correlation):
    """Mean σ and τ of 64 long profiles within 4 standard errors (+ the O(τ/L) estimator bias)."""
    sigma, tau, L = 0.051, 0.64, 64.0
    p = synthesize_profiles(jax.random.PRNGKey(7), sigma, tau, length_um=L, spacing_um=0.02, num_profiles=64, correlation=correlation)
    st = profile_statistics(p.h, p.spacing)
    s, t = st["sigma_um"], st["tau_um"]
    se_s, se_t = s.std(ddof=1) / np.sqrt(s.size), t.std(ddof=1) / np.sqrt(t.size)
    bias = 2.0 * tau / L  # finite record, statistics about the sample mean
    assert abs(s.mean() - sigma) <= 4 * se_s + bias * sigma
    assert abs(t.mean() - tau) <= 4 * se_t + 2 * bias * tau
    # single realisations scatter, but not wildly
    assert np.all(np.abs(s / sigma - 1) < 0.4)


def test_synthesis_is_seeded_and_derivatives_consistent():
    a = synthesize_profiles(jax.random.PRNGKey(1), 0.05, 0.6, length_um=10.0, spacing_um=0.02, num_profiles=2)
    b = synthesize_profiles(jax.random.PRNGKey(1), 0.05, 0.6, length_um=10.0, spacing_um=0.02, num_profiles=2)
    c = synthesize_profiles(jax.random.PRNGKey(2), 0.05, 0.6, length_um=10.0, spacing_um=0.02, num_profiles=2)
    np.testing.assert_array_equal(np.asarray(a.h), np.asarray(b.h))
    assert not np.allclose(np.asarray(a.h), np.asarray(c.h))
    h, dh = np.asarray(a.h[0]), np.asarray(a.dh[0])
    fd = (np.roll(h, -1) - np.roll(h, 1)) / (2 * a.spacing)  # periodic profile
    assert np.max(np.abs(fd - dh)) <= 2e-3 * np.max(np.abs(dh))
    assert a.h.shape == (2, a.x.shape[0]) and abs(a.length - 10.0) < 1e-12


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(sigma_um=-0.1), "sigma_um"),
        (dict(tau_um=0.0), "tau_um"),
        (dict(length_um=1.0), "length_um"),
        (dict(spacing_um=0.5), "spacing_um"),
        (dict(num_profiles=0), "num_profiles"),
        (dict(correlation="lorentz"), "correlation"),
    ],
)
def test_synthesis_errors(kwargs, match):
    args = dict(sigma_um=0.05, tau_um=0.6, length_um=10.0, spacing_um=0.02, num_profiles=1) | kwargs
    with pytest.raises(ValueError, match=match):
        synthesize_profiles(jax.random.PRNGKey(0), args.pop("sigma_um"), args.pop("tau_um"), **args)


def _scan_file(tmp_path, x, h, name="scan.csv", header="x,height\n", sep=","):
    path = tmp_path / name
    path.write_text(header + "".join(f"{a}{sep}{b}\n" for a, b in zip(x, h)))
    return path


def _measured_like(seed=0, n=1500, L=20.0):
    p = synthesize_profiles(jax.random.PRNGKey(seed), 0.051, 0.64, length_um=L, spacing_um=L / n, num_profiles=1)
    return np.asarray(p.x) - float(p.x[0]), np.asarray(p.h[0])


def test_load_units_and_resampling(tmp_path):
    x, h = _measured_like()
    rng = np.random.default_rng(0)
    xn = np.sort(x + rng.uniform(-0.3, 0.3, x.size) * (x[1] - x[0]))  # non-uniform spacing
    hn = np.interp(xn, x, h)
    path = _scan_file(tmp_path, xn * 1e3, hn * 1e3, sep=" ", header="# scan in nm\nx height\n")
    scan = load_line_scan(path, units="nm")
    np.testing.assert_allclose(scan.x, xn, rtol=1e-12)
    xu, hu = process_line_scan(scan)
    assert np.allclose(np.diff(xu), np.diff(xu)[0])
    assert abs(hu[0]) < 1e-12 and abs(hu[-1]) < 1e-12
    st = profile_statistics(hu, xu[1] - xu[0])
    assert 0.02 < st["sigma_um"] < 0.08 and 0.3 < st["tau_um"] < 1.0
    mm = load_line_scan(_scan_file(tmp_path, x * 1e-3, h * 1e-3, name="mm.csv"), units="mm")
    np.testing.assert_allclose(mm.h, h, rtol=1e-9)


def test_processing_removes_curvature():
    """A parabolic platelet bow 50× the roughness is removed by the 50 % Gaussian filter."""
    x, h = _measured_like(seed=3)
    L = x[-1] - x[0]
    bow = 2.5 * ((x - L / 2) / (L / 2)) ** 2
    xu, hu = process_line_scan(LineScan(x, h + bow))
    x0, h0 = process_line_scan(LineScan(x, h))
    s_bowed = profile_statistics(hu, xu[1] - xu[0])["sigma_um"]
    s_plain = profile_statistics(h0, x0[1] - x0[0])["sigma_um"]
    assert abs(s_bowed / s_plain - 1) < 0.1
    assert abs(hu[0]) < 1e-12 and abs(hu[-1]) < 1e-12


def test_scan_errors(tmp_path):
    x, h = _measured_like()
    h_nan = h.copy()
    h_nan[10] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        load_line_scan(_scan_file(tmp_path, x, h_nan, name="nan.csv"))
    xb = x.copy()
    xb[100], xb[101] = xb[101], xb[100]
    with pytest.raises(ValueError, match="monotonic"):
        load_line_scan(_scan_file(tmp_path, xb, h, name="order.csv"))
    with pytest.raises(ValueError, match="units"):
        load_line_scan(_scan_file(tmp_path, x, h, name="u.csv"), units="inch")
    coarse = slice(None, None, 60)  # ~4 points per correlation length
    with pytest.raises(ValueError, match="undersampled"):
        process_line_scan(LineScan(x[coarse], h[coarse]))
    with pytest.raises(ValueError, match="cutoff_fraction"):
        process_line_scan(LineScan(x, h), cutoff_fraction=0.0)


def test_reversed_scan_and_solver_grid():
    x, h = _measured_like()
    scan = LineScan(x[::-1], h[::-1])
    xu, hu = process_line_scan(scan)
    p = profiles_from_heights(xu, hu, spacing_um=0.0278)
    assert p.h.shape[0] == 1 and abs(float(p.x.mean())) < 1e-9
    assert abs(p.length - (xu[-1] - xu[0])) < 1e-9
    np.testing.assert_allclose(np.asarray(p.h[0, [0, -1]]), 0.0, atol=2e-3)
