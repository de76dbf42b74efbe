"""Where the emcee walkers start: dispersed over the posterior (checked against the exact posterior on a grid), or a ball."""

import numpy as np
import pytest

from paintjax.inverse._analytic import AnalyticForward
from paintjax.inverse._posterior import LogPosterior, sample_posterior
from paintjax.inverse._walker_start import dispersed, initial_walkers, laplace_covariance, posterior_mode, start_point

MIRROR = AnalyticForward(rough=False)
FREE = ("shape", "scale")
FIXED = {"diffuse": 0.15, "discrepancy": 0.0}
TRUTH = {"shape": 2.4, "scale": 2.1}


def _posterior(instrument_sd=0.3):
    x = np.tile([TRUTH["shape"], TRUTH["scale"], FIXED["diffuse"]], (16, 1))
    y = np.asarray(MIRROR(x))[0] + np.random.default_rng(3).normal(0.0, 0.3, 5)
    return LogPosterior(MIRROR, y, FREE, FIXED, instrument_sd=instrument_sd)


def _grid_moments(lp, centre, n=201):
    """Mean and SD (unconstrained coordinates) of the exact posterior by quadrature on an n × n grid about `centre`,
    10 Laplace-approximation SDs to either side (the edges must hold no mass)."""
    half = 10.0 * np.sqrt(np.diag(laplace_covariance(lp, centre)))
    axes = [np.linspace(c - d, c + d, n) for c, d in zip(centre, half)]
    U = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 2)
    logp = lp(U)
    w = np.exp(logp - np.max(logp))
    w /= w.sum()
    mean = w @ U
    assert w.reshape(n, n)[[0, -1], :].max() < 1e-6 and w.reshape(n, n)[:, [0, -1]].max() < 1e-6  # the grid holds the posterior
    return mean, np.sqrt(w @ (U - mean) ** 2)


def test_dispersed_walkers_follow_the_posterior_and_are_not_a_ball():
    """64 walkers drawn by adaptive importance sampling: their mean within 0.5 posterior SD of the exact posterior mean
    (quadrature on a grid), their spread between 0.6 and 2 posterior SDs in each coordinate — neither a small ball about
    the mode (what the R-hat rule cannot judge) nor scattered over the prior."""
    lp = _posterior()
    mode = posterior_mode(lp, [start_point(lp.spec, TRUTH)])
    mean, sd = _grid_moments(lp, mode)
    U, info = dispersed(lp, mode, 64, np.random.default_rng(0))
    assert U.shape == (64, 2) and np.all(np.isfinite(lp(U)))
    assert len(np.unique(U, axis=0)) == 64  # drawn without replacement
    assert info["importance_ess"] > 64, info
    z = (U.mean(0) - mean) / sd
    ratio = U.std(0) / sd
    print(f"walkers' mean offset {z} posterior SD; spread {ratio} posterior SD; importance ESS {info['importance_ess']:.0f}")
    assert np.all(np.abs(z) < 0.5), z
    assert np.all((ratio > 0.6) & (ratio < 2.0)), ratio


def test_starts_are_reproducible_and_ball_is_small():
    """The same generator gives the same walkers; on a posterior wider than the ball (3 L* repeatability: SD ≈ 0.15 in
    unconstrained coordinates) the dispersed walkers spread over it, the ball does not."""
    lp = _posterior(instrument_sd=3.0)
    a = initial_walkers(lp, None, 8, np.random.default_rng(1), 0)
    b = initial_walkers(lp, None, 8, np.random.default_rng(1), 0)
    np.testing.assert_array_equal(a, b)
    ball = initial_walkers(lp, None, 8, np.random.default_rng(1), 0, start="ball")
    sd = np.sqrt(np.diag(laplace_covariance(lp, posterior_mode(lp, [start_point(lp.spec, TRUTH)]))))
    assert np.max(np.std(ball, 0)) < 0.02 < 0.5 * np.min(sd) < np.min(np.std(a, 0)), (np.std(ball, 0), sd, np.std(a, 0))


def test_start_and_moves_are_checked():
    lp = _posterior()
    with pytest.raises(ValueError, match="start must be one of dispersed, ball"):
        initial_walkers(lp, None, 8, np.random.default_rng(0), 0, start="prior")
    with pytest.raises(ValueError, match="start must be one of"):
        sample_posterior(MIRROR, lp.measured, free=FREE, fixed=FIXED, start="wide", progress=False)
    with pytest.raises(ValueError, match="moves must be one of stretch, de"):
        sample_posterior(MIRROR, lp.measured, free=FREE, fixed=FIXED, moves="walk", progress=False)


def test_de_moves_sample_the_same_posterior():
    """The stretch move and the differential-evolution proposal, both from dispersed starts, give posterior means within
    0.25 posterior SD of the exact (grid) posterior mean, and SDs within 20 % of the exact SD."""
    lp = _posterior()
    mode = posterior_mode(lp, [start_point(lp.spec, TRUTH)])
    mean, sd = _grid_moments(lp, mode)
    kw = dict(free=FREE, fixed=FIXED, walkers=16, min_steps=500, max_steps=4000, check_every=250, min_ess=400, progress=False,
              inference_data=False, seed=4)
    for moves in ("stretch", "de"):
        post = sample_posterior(MIRROR, lp.measured, moves=moves, **kw)
        U = np.asarray(lp.spec.to_unconstrained(post.samples))
        z = (U.mean(0) - mean) / sd
        ratio = U.std(0) / sd
        print(f"{moves}: mean offset {z} SD, spread {ratio}, {post.steps} steps, acceptance {post.acceptance:.2f}")
        assert np.all(np.abs(z) < 0.25) and np.all(np.abs(ratio - 1) < 0.2), (moves, z, ratio)
