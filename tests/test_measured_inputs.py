"""The published inputs as data: their likelihood (closed forms), its place in the posterior, and the
posterior-predictive consistency check."""

from __future__ import annotations

import types

import equinox as eqx
import jax
import numpy as np
import pytest
from scipy.stats import multivariate_normal

from paintjax import load_sample
from paintjax.inverse import ForwardModel, LogPosterior, MeasuredInputs, gamma_fit_sd, posterior_predictive_check
from paintjax.inverse._analytic import AnalyticForward

MIRROR = AnalyticForward(rough=False)


def test_tilt_likelihood_is_the_fisher_normal_of_a_gamma_fit():
    inputs = MeasuredInputs(None, 0.051, 0.64, "rq", 2.29, 2.18, 200)
    k, th = 2.5, 2.0
    sk, st, r = gamma_fit_sd(k, th, 200)
    cov = [[sk**2, r * sk * st], [r * sk * st, st**2]]
    want = multivariate_normal(mean=[k, th], cov=cov).logpdf([2.29, 2.18])
    got = float(inputs.log_likelihood({"shape": jax.numpy.asarray(k), "scale": jax.numpy.asarray(th)}))
    assert got == pytest.approx(want, rel=1e-9)
    assert MeasuredInputs(None, 0.051, 0.64, "rq", 2.29, 2.18, 0).log_likelihood({"shape": 2.5, "scale": 2.0}) == 0.0


def test_bad_inputs_name_the_field():
    with pytest.raises(ValueError, match="tilt_platelets"):
        MeasuredInputs(None, 0.051, 0.64, "rq", 2.29, 2.18, -1)
    with pytest.raises(ValueError, match="definition"):
        MeasuredInputs(None, 0.051, 0.64, "ra", 2.29, 2.18, 10)
    with pytest.raises(ValueError, match="sigma_hat_um"):
        MeasuredInputs(None, float("nan"), 0.64, "rq", 2.29, 2.18, 10)


def test_posterior_adds_exactly_the_input_likelihood():
    s = load_sample("silver1")
    inputs = MeasuredInputs.for_sample(s, None, tilt_platelets=300)
    kw = dict(free=("shape", "scale", "discrepancy"), fixed={"diffuse": 0.15})
    plain = LogPosterior(MIRROR, s.L_star, **kw)
    with_inputs = LogPosterior(MIRROR, s.L_star, inputs=inputs, **kw)
    U = np.random.default_rng(0).normal(size=(16, 3))
    x = np.asarray(plain.spec.from_unconstrained(U))
    extra = np.asarray(inputs.log_likelihood({"shape": x[:, 0], "scale": x[:, 1]}))
    assert np.allclose(with_inputs(U) - plain(U), extra, rtol=1e-9, atol=1e-9)


def test_posterior_predictive_check_separates_fit_from_misfit():
    """Draws around the truth: data generated there pass (p well above 0.01); data 6 L* off fail."""
    truth = np.array([2.6, 1.9, 0.15])
    L = np.asarray(MIRROR(np.tile(truth, (16, 1))))[0]
    rng = np.random.default_rng(1)
    draws = truth + rng.normal(scale=[0.02, 0.02, 0.002], size=(64, 3))
    result = types.SimpleNamespace(names=("shape", "scale", "diffuse"), samples=draws)
    good = posterior_predictive_check(result, MIRROR, L + rng.normal(scale=0.3, size=5), seed=0)
    bad = posterior_predictive_check(result, MIRROR, L + np.array([6.0, -6.0, 6.0, -6.0, 6.0]), seed=0)
    assert good["p_value"] > 0.05 and bad["p_value"] < 1e-6
    assert np.all(good["L_star_q05"] < good["L_star_q95"])
    # diffuse neither sampled nor fixed: its registered default (0), as in the posterior
    two = types.SimpleNamespace(names=("shape", "scale"), samples=draws[:, :2])
    a = posterior_predictive_check(two, MIRROR, L, seed=0)
    b = posterior_predictive_check(two, MIRROR, L, fixed={"diffuse": 0.0}, seed=0)
    assert a["p_value"] == b["p_value"]


@pytest.mark.parametrize("heavy", [False, True])
def test_predictive_p_value_standard_error_matches_its_spread_over_seeds(heavy):
    """The stated Monte Carlo SE of p is the spread of p over independent checks: 48 seeds, each drawing
    64 of 4096 posterior draws (and, for the counted p, its own replicates). The seeds' SD of p lies within
    0.7–1.4 of the mean stated SE (the SD of 48 values is itself uncertain by ≈ 10 %)."""
    truth = np.array([2.6, 1.9, 0.15])
    L = np.asarray(MIRROR(np.tile(truth, (16, 1))))[0]
    rng = np.random.default_rng(7)
    draws = truth + rng.normal(scale=[0.05, 0.05, 0.005], size=(4096, 3))
    result = types.SimpleNamespace(names=("shape", "scale", "diffuse"), samples=draws)
    forward, kw = (_HeavyTailed(3.0), dict(replicates=20)) if heavy else (MIRROR, {})
    y = L + np.array([1.0, -1.0, 1.0, -0.5, 0.5])
    checks = [posterior_predictive_check(result, forward, y, max_draws=64, seed=s, instrument_sd=1.0, **kw) for s in range(48)]
    p, se = np.array([c["p_value"] for c in checks]), np.array([c["p_value_se"] for c in checks])
    assert np.all(se > 0) and 0.05 < np.mean(p) < 0.95, (np.mean(p), np.mean(se))
    ratio = np.std(p, ddof=1) / np.mean(se)
    assert 0.7 <= ratio <= 1.4, (ratio, np.std(p, ddof=1), np.mean(se))


class _HeavyTailed(ForwardModel):
    """The mirror model with a stated Student-t error of scale 1 L* at every angle (as an emulator states its own)."""

    df: float = eqx.field(static=True)
    parameter_names = MIRROR.parameter_names
    aspecular_deg = MIRROR.aspecular_deg

    def evaluate(self, theta):
        return MIRROR.evaluate(theta)

    def fingerprint(self):
        return f"heavy-tailed mirror, df={self.df}"

    @property
    def error_df(self):
        return self.df

    def _law(self):
        from paintjax.inverse import EmulatorError

        return EmulatorError(np.ones(5), np.zeros(3), self.df)

    def residual_log_density(self, r, var, theta, have=None):
        return self._law().residual_log_density(r, var, theta, have)

    def sample_residual(self, rng, var, theta):
        return self._law().sample(rng, var, np.asarray(theta))


def test_predictive_check_under_a_heavy_tailed_model_error():
    """Replicated data from a (multivariate) Student-t model error: data drawn from that law pass, data 20 L* off
    fail; without normal terms the counted p-value is the multivariate t's exact tail (the deviance is monotone in
    Q = |r|², and Q/m is F(m, ν)), and with many degrees of freedom the normal law's exact χ² tail (to its Monte
    Carlo error). One mixing variable serves all angles: 8 L* off at every angle is not rare under ν = 3 (p ≈ 0.003)."""
    from scipy import stats

    truth = np.array([2.6, 1.9, 0.15])
    L = np.asarray(MIRROR(np.tile(truth, (16, 1))))[0]
    rng = np.random.default_rng(4)
    draws = truth + rng.normal(scale=[0.02, 0.02, 0.002], size=(64, 3))
    result = types.SimpleNamespace(names=("shape", "scale", "diffuse"), samples=draws)
    heavy = _HeavyTailed(3.0)
    y = L + heavy.sample_residual(rng, np.full((1, 5), 0.09), truth[None])[0]
    good = posterior_predictive_check(result, heavy, y, seed=0, replicates=200)
    bad = posterior_predictive_check(result, heavy, L + np.array([20.0, -20.0, 20.0, -20.0, 20.0]), seed=0, replicates=200)
    assert good["replicates"] == 200 and good["p_value"] > 0.05 and bad["p_value"] < 1e-3
    y8 = L + np.array([8.0, -8.0, 8.0, -8.0, 8.0])
    counted = posterior_predictive_check(result, heavy, y8, instrument_sd=1e-6, seed=0, replicates=2000)
    q = np.sum((y8 - np.asarray(MIRROR(draws))) ** 2, axis=1)
    exact = np.mean(stats.f.sf(q / 5.0, 5, 3.0))
    assert counted["draws"] == len(draws) and counted["p_value"] == pytest.approx(exact, rel=0.15), (counted["p_value"], exact)
    near_normal = _HeavyTailed(100.0)
    y = L + np.array([1.2, -0.8, 1.5, 0.3, -1.9])  # a χ² of ≈ 7.4 over 5 angles at unit scale
    counted = posterior_predictive_check(result, near_normal, y, instrument_sd=1e-6, seed=0, replicates=400)["p_value"]
    exact = posterior_predictive_check(result, AnalyticForward(rough=False), y, instrument_sd=1.0, seed=0)["p_value"]
    assert counted == pytest.approx(exact, abs=0.02), (counted, exact)
    with pytest.raises(ValueError, match=r"replicates must be an integer in \[1, 100000\]"):
        posterior_predictive_check(result, heavy, y, replicates=0)
    with pytest.raises(ValueError, match="max_draws must be an integer >= 2"):
        posterior_predictive_check(result, heavy, y, max_draws=1)
    with pytest.raises(ValueError, match="at least 2 posterior draws"):
        posterior_predictive_check(types.SimpleNamespace(names=result.names, samples=draws[:1]), heavy, y)


def test_panel_posteriors_give_a_verdict_from_the_strict_run():
    """`panel_posteriors` through the shipped tracer emulator (short chains): every requested run, the
    input-shift table, and a verdict that is the δ = 0 run's predictive p-value against DISAGREE_P."""
    import jax

    jax.config.update("jax_enable_x64", True)
    from paintjax import load_sample
    from paintjax.inverse import DISAGREE_P, build_reading_model, make_forward, panel_posteriors

    forward = make_forward("tracer-emulator-wide", ("shape", "scale", "sigma", "tau"), {})
    s = load_sample("silver2")
    r = panel_posteriors(forward, s, build_reading_model(progress=False), runs=("L* and inputs, no discrepancy",), walkers=16,
                         max_steps=300, min_ess=0.0, seed=1)
    strict = r["L* and inputs, no discrepancy"]
    assert "discrepancy" not in strict["posterior"].names
    assert set(strict["input_shift"]) == {"sigma", "tau", "shape", "scale"}
    assert r["verdict"] == ("disagree" if strict["check"]["p_value"] < DISAGREE_P else "agree")
    with pytest.raises(ValueError, match="runs must be among"):
        panel_posteriors(forward, s, None, runs=("L* only",))
