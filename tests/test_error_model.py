"""The emulators' heavy-tailed, regional, correlated error model (`paintjax.inverse._error_model`) against
closed forms: the scale mixture is the (multivariate) Student-t where no normal term is added, the normal
where ν = ∞, the numerical convolution of the two otherwise; angles left out are marginalised; its draws
follow its density and correlation; maximum likelihood recovers a known ν, slope and correlation; and the
shipped tracer emulator's errors are heavy-tailed, regional and joint between the angles, as measured."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from paintjax.inverse import EmulatorError, fit_emulator_error


def _density(model, r, var, z=0.5):
    r = np.atleast_1d(np.asarray(r, float))[:, None]
    out = model.residual_log_density(jnp.asarray(r), jnp.full(r.shape, float(var)), jnp.full((r.shape[0], 1), z))
    return np.asarray(out)


@pytest.mark.parametrize("df", [1.0, 2.4, 5.0, 30.0])
def test_mixture_is_student_t_without_normal_terms(df):
    model = EmulatorError([2.0], [0.0], df)
    r = np.linspace(0.0, 2000.0, 801)  # out to 1000 scales
    np.testing.assert_allclose(_density(model, r, 0.0), stats.t.logpdf(r, df, scale=2.0), atol=5e-4)


@pytest.mark.parametrize("df", [2.4, 30.0])
def test_mixture_is_the_convolution_with_a_normal(df):
    model = EmulatorError([2.0], [0.0], df)
    r = np.linspace(-60.0, 60.0, 25)
    x = np.linspace(-600.0, 600.0, 120001)
    conv = np.array([np.trapezoid(stats.t.pdf(x, df, scale=2.0) * stats.norm.pdf(v - x, scale=0.7), x) for v in r])
    np.testing.assert_allclose(np.exp(_density(model, r, 0.49)), conv, rtol=1e-3)
    # normalised: the density integrates to one
    grid = np.r_[-np.geomspace(3000.0, 0.01, 20000), np.linspace(-0.01, 0.01, 3), np.geomspace(0.01, 3000.0, 20000)]
    assert np.trapezoid(np.exp(_density(model, grid, 0.49)), grid) == pytest.approx(1.0, abs=2e-3 if df < 3 else 1e-6)


def test_infinite_df_is_normal_and_the_slope_scales_over_the_box():
    model = EmulatorError([1.5], [0.0, -2.0], np.inf)
    r = np.linspace(-10.0, 10.0, 41)[:, None]
    z = jnp.asarray(np.tile([[0.3, 0.9]], (41, 1)))  # scale 1.5·exp(−2·(0.9 − 0.5)) = 1.5 e^−0.8
    got = np.asarray(model.residual_log_density(jnp.asarray(r), jnp.full(r.shape, 0.25), z))
    np.testing.assert_allclose(got, stats.norm.logpdf(r[:, 0], scale=np.sqrt(0.25 + (1.5 * np.exp(-0.8)) ** 2)), rtol=1e-12)
    with pytest.raises(ValueError, match="df must be >= 1"):
        EmulatorError([1.0], [0.0], 0.5)


_R3 = np.array([[1.0, 0.5, -0.3], [0.5, 1.0, 0.2], [-0.3, 0.2, 1.0]])


@pytest.mark.parametrize("df", [2.4, 8.0])
def test_joint_law_is_the_multivariate_t_and_the_convolution_with_a_normal(df):
    """Three correlated angles: without normal terms the density is the multivariate Student-t of shape D R D
    (scipy), with them the integral over the mixing variable of the normal of covariance V + w D R D (quadrature)."""
    from scipy import integrate

    scale, slope = np.array([2.0, 1.0, 0.5]), np.array([0.8])
    model = EmulatorError(scale, slope, df, _R3)
    rng = np.random.default_rng(1)
    r, z = rng.standard_t(3.0, (6, 3)) * 3.0, rng.random((6, 1))
    c = scale * np.exp(0.8 * (z - 0.5))
    got = np.asarray(model.residual_log_density(jnp.asarray(r), jnp.zeros((6, 3)), jnp.asarray(z)))
    want = [stats.multivariate_t.logpdf(r[i], shape=np.outer(c[i], c[i]) * _R3, df=df) for i in range(6)]
    np.testing.assert_allclose(got, want, atol=1e-6)
    var = np.array([0.3, 0.05, 0.6])
    got = np.asarray(model.residual_log_density(jnp.asarray(r), jnp.broadcast_to(var, (6, 3)), jnp.asarray(z)))
    law = stats.invgamma(df / 2.0, scale=df / 2.0)
    for i in range(6):
        def integrand(logw):
            w = np.exp(logw)
            return stats.multivariate_normal.pdf(r[i], cov=np.diag(var) + w * np.outer(c[i], c[i]) * _R3) * law.pdf(w) * w
        want = integrate.quad(integrand, -30.0, 30.0, limit=400, epsabs=0.0, epsrel=1e-10)[0]
        assert got[i] == pytest.approx(np.log(want), abs=1e-6), i
    normal = EmulatorError(scale, slope, np.inf, _R3)
    got = np.asarray(normal.residual_log_density(jnp.asarray(r), jnp.broadcast_to(var, (6, 3)), jnp.asarray(z)))
    want = [stats.multivariate_normal.logpdf(r[i], cov=np.diag(var) + np.outer(c[i], c[i]) * _R3) for i in range(6)]
    np.testing.assert_allclose(got, want, rtol=1e-12)


@pytest.mark.parametrize("df", [3.0, np.inf])
def test_angles_left_out_are_marginalised(df):
    """The density over the angles in `have` is the density of the law restricted to those angles (`select`),
    row by row, whatever the values at the angles left out."""
    model = EmulatorError([2.0, 1.0, 0.5], [0.3], df, _R3)
    rng = np.random.default_rng(2)
    r, z, var = rng.normal(0.0, 2.0, (4, 3)), rng.random((4, 1)), np.full((4, 3), 0.09)
    have = np.array([[True, False, True], [False, True, True], [True, True, True], [False, False, True]])
    got = np.asarray(model.residual_log_density(jnp.asarray(r), jnp.asarray(var), jnp.asarray(z), jnp.asarray(have)))
    for i in range(4):
        rows = np.flatnonzero(have[i])
        want = model.select(rows).residual_log_density(jnp.asarray(r[i:i + 1, rows]), jnp.asarray(var[i:i + 1, rows]), jnp.asarray(z[i:i + 1]))
        assert got[i] == pytest.approx(float(want[0]), abs=1e-10), i
    moved = np.where(have, r, 1e3)
    np.testing.assert_allclose(model.residual_log_density(jnp.asarray(moved), jnp.asarray(var), jnp.asarray(z), jnp.asarray(have)), got)


def test_joint_density_is_differentiable():
    """Its gradient (through the per-row eigendecomposition; NUTS and the run-to-run fit use it) matches central
    differences in the residuals, the normal variances and the unit-cube point, with an angle left out too."""
    import jax

    model = EmulatorError([2.0, 1.0, 0.5], [0.8], 4.0, _R3)
    r0, v0, z0 = jnp.asarray([1.5, -0.7, 2.2]), jnp.asarray([0.3, 0.05, 0.6]), jnp.asarray([0.3])
    for have in (None, jnp.asarray([True, False, True])):
        def f(q):
            return model.residual_log_density(q[None, :3], q[None, 3:6], q[None, 6:], have)[0]

        q = jnp.concatenate([r0, v0, z0])
        grad = np.asarray(jax.grad(f)(q))
        fd = np.array([(f(q + 1e-6 * e) - f(q - 1e-6 * e)) / 2e-6 for e in np.eye(7)])
        np.testing.assert_allclose(grad, fd, atol=1e-6)
        assert np.all(np.isfinite(grad))


def test_joint_draws_have_the_correlation_and_the_shared_tail():
    """Draws share one mixing variable per row: their correlation is R (a t law's, ν > 2), and a row large at one
    angle is large at the others; with R = I, independent t draws would show no such dependence."""
    model = EmulatorError([1.0, 1.0, 1.0], [0.0], 6.0, _R3)
    rng = np.random.default_rng(7)
    e = model.sample(rng, np.zeros((200000, 3)), np.full((200000, 1), 0.5))
    np.testing.assert_allclose(np.corrcoef(e.T), _R3, atol=0.02)
    indep = EmulatorError([1.0, 1.0, 1.0], [0.0], 6.0).sample(rng, np.zeros((200000, 3)), np.full((200000, 1), 0.5))
    assert abs(np.corrcoef(indep.T)[0, 1]) < 0.02
    assert np.corrcoef(np.abs(indep).T)[0, 1] > 0.1  # |e| share the mixing variable: dependent though uncorrelated


def test_draws_follow_the_density():
    model = EmulatorError([2.0], [0.0], 2.4)
    rng = np.random.default_rng(3)
    draws = model.sample(rng, np.full((20000, 1), 0.49), np.full((20000, 1), 0.5))[:, 0]  # one angle: the t law
    grid = np.linspace(-4000.0, 4000.0, 800001)
    cdf = np.cumsum(np.exp(_density(model, grid, 0.49))) * (grid[1] - grid[0])
    ks = stats.kstest(draws, lambda v: np.interp(v, grid, cdf))
    assert ks.pvalue > 1e-3, ks


def test_maximum_likelihood_recovers_df_scales_slope_and_correlation():
    rng = np.random.default_rng(0)
    z = rng.random((720, 4))
    scale, slope = np.array([2.0, 1.7, 1.2, 1.0, 1.3, 1.4]), np.array([0.4, 0.5, -1.7, 0.0])
    R = np.eye(6)
    R[np.arange(5), np.arange(1, 6)] = R[np.arange(1, 6), np.arange(5)] = [0.6, -0.4, 0.3, 0.5, -0.2]
    truth = EmulatorError(scale, slope, 2.4, R)
    e = truth.sample(rng, np.zeros((720, 6)), z)
    fit = fit_emulator_error(z, e)
    assert fit.df == pytest.approx(2.4, rel=0.2)
    np.testing.assert_allclose(np.asarray(fit.scale), scale, rtol=0.15)
    np.testing.assert_allclose(np.asarray(fit.slope), slope, atol=0.3)
    np.testing.assert_allclose(np.asarray(fit.correlation), R, atol=0.1)
    normal = fit_emulator_error(z, rng.standard_normal((720, 6)))
    assert normal.df > 30 and np.all(np.abs(np.asarray(normal.slope)) < 0.3)
    assert np.max(np.abs(np.asarray(normal.correlation) - np.eye(6))) < 0.15
    with pytest.raises(ValueError, match="must be finite"):
        fit_emulator_error(z, np.full((720, 6), np.nan))


def test_shipped_tracer_emulator_errors_are_heavy_tailed_and_regional(tmp_path, monkeypatch):
    """The wide emulator's cross-validated errors: Student-t with few degrees of freedom (ν = 5.1 for the shipped
    emulator with its refined design and the joint law, 4.2 with independent angles, 2.95 before the refinement; a normal would put 0.3 % of them beyond 3 RMS, not 1.6 %),
    their scale falling with σ (smooth platelets are the hard ones), and the t law explains its held-out tracer runs
    better than the normal law with the same RMS."""
    from paintjax._cache import SHIPPED_DIR
    from paintjax.inverse import wide_tracer_emulator

    monkeypatch.setenv("PAINTJAX_CACHE", str(tmp_path / "empty"))
    em = wide_tracer_emulator(spread_theta=None)
    assert 1.5 < em.error.df < 6.0
    assert float(em.error.slope[em.spec.names.index("sigma")]) < -1.0
    with np.load(SHIPPED_DIR / f"emulator-{em.key}.npz") as d:
        theta, L = np.asarray(em.spec.from_unit(d["Zt"])), d["Yt"][:, 1:]  # the standard five of the six
    r = L - np.asarray(em(theta))
    zero = jnp.zeros(r.shape)
    t_law = float(np.sum(np.asarray(em.residual_log_density(jnp.asarray(r), zero, jnp.asarray(theta)))))
    normal = float(np.sum(stats.norm.logpdf(r, scale=em.error_sd)))
    print("t law", t_law, "normal", normal)
    assert t_law > normal + 20, (t_law, normal)


def test_run_to_run_fit_recovers_a_bias_over_the_box_and_a_regional_spread():
    """Residuals = the law's draws (its two angles correlated 0.6) + a bias linear over the box + a normal term whose
    scale varies over the box: the fit finds the bias within its stated standard errors, the spread and the correlation."""
    from paintjax.inverse._error_model import fit_run_to_run

    law = EmulatorError([1.0, 1.5], [0.0, 0.0], 2.4)
    rng = np.random.default_rng(5)
    z = rng.random((600, 2))
    sd, slope = np.array([2.0, 1.0]), np.array([1.5, -1.0])
    bias = np.array([[1.0, -0.5], [3.0, 0.0], [0.0, -2.0]])  # centre, then per unit of z₁ and z₂; one column per angle
    extra = rng.standard_normal((600, 2)) * sd * np.exp((z - 0.5) @ slope)[:, None]
    truth_mean = np.c_[np.ones(600), z - 0.5] @ bias
    drawn = law.with_correlation([[1.0, 0.6], [0.6, 1.0]])
    term = fit_run_to_run(law, z, drawn.sample(rng, np.zeros((600, 2)), z) + extra + truth_mean, df=2.4)
    assert float(term.correlation[0, 1]) == pytest.approx(0.6, abs=0.15)
    se = np.asarray(term.bias_se)
    np.testing.assert_allclose(se[:, 1] ** 2, np.diag(np.asarray(term.bias_cov)[1]))  # the marginal SDs of the covariance
    assert np.all(np.abs(np.asarray(term.bias) - bias) < 3.5 * se), (term.bias, se)
    assert np.all(se < 0.6)
    np.testing.assert_allclose(term.sd, sd, rtol=0.2)
    np.testing.assert_allclose(term.slope, slope, atol=0.4)
    np.testing.assert_allclose(np.asarray(term.mean(jnp.asarray(z[:3]))), np.c_[np.ones(3), z[:3] - 0.5] @ np.asarray(term.bias))
    # the predictive variance holds the spread and the bias's own uncertainty
    v = np.asarray(term.variance(jnp.asarray(z[:3])))
    spread = (np.asarray(term.sd) * np.exp((z[:3] - 0.5) @ np.asarray(term.slope))[:, None]) ** 2
    assert np.all(v > spread) and np.all(v < spread + 1.0)
    picked = term.select([1])
    np.testing.assert_allclose(np.asarray(picked.mean(jnp.asarray(z[:3]))), np.asarray(term.mean(jnp.asarray(z[:3])))[:, [1]])
    # without a bias in the data, none is found beyond its errors
    term0 = fit_run_to_run(law, z, law.sample(rng, np.zeros((600, 2)), z) + extra, df=2.4)
    se0 = np.asarray(term0.bias_se)
    assert np.all(np.abs(np.asarray(term0.bias)) < 3.5 * se0)
    assert abs(float(term0.correlation[0, 1])) < 0.15
    with pytest.raises(ValueError, match="every run needs a finite angle"):
        fit_run_to_run(law, z, np.full((600, 2), np.nan))
    with pytest.raises(ValueError, match="none may be infinite"):
        fit_run_to_run(law, z, np.full((600, 2), np.inf))
    assert float(term.df) == 2.4 and term.df_grid.size == 0  # ν given: none chosen
    np.testing.assert_allclose(np.asarray(term.law(law).correlation), np.asarray(term.correlation))


def test_run_to_run_fit_recovers_a_bent_bias_and_marginalises_angles_a_run_lacks():
    """A bias that bends along z₂ (square and cube terms): `curved=(1,)` finds its coefficients within their stated
    errors. With the second angle missing (NaN) in half the runs the fit still finds them, its errors grow, and each
    row's density is the law's with that angle marginalised."""
    from paintjax.inverse._error_model import _row_log_density, _unpack_run_to_run, fit_run_to_run, regional_scale

    law = EmulatorError([1.0, 1.5], [0.0, 0.0], 3.0)
    rng = np.random.default_rng(8)
    n = 500
    z = rng.random((n, 2))
    u = z - 0.5
    bias = np.array([[0.5, -1.0], [2.0, 0.0], [0.0, 1.0], [6.0, -4.0], [-10.0, 12.0]])  # 1, z₁, z₂, z₂², z₂³
    x = np.c_[np.ones(n), u, u[:, 1] ** 2, u[:, 1] ** 3]
    r = law.sample(rng, np.full((n, 2), 0.25), z) + x @ bias
    term = fit_run_to_run(law, z, r, df=3.0, curved=(1,))
    assert term.curved == (1,) and term.bias.shape == (5, 2) and term.bias_cov.shape == (2, 5, 5)
    se = np.asarray(term.bias_se)
    assert np.all(np.abs(np.asarray(term.bias) - bias) < 3.5 * se), (term.bias, se)
    np.testing.assert_allclose(np.asarray(term.mean(jnp.asarray(z[:4]))), x[:4] @ np.asarray(term.bias))
    assert term.select([1]).curved == (1,)
    gappy = r.copy()
    gappy[::2, 1] = np.nan
    half = fit_run_to_run(law, z, gappy, df=3.0, curved=(1,))
    se_half = np.asarray(half.bias_se)
    assert np.all(np.abs(np.asarray(half.bias) - bias) < 3.5 * se_half), (half.bias, se_half)
    assert np.all(se_half[:, 1] > se[:, 1])
    q = jnp.concatenate([jnp.log(half.sd), half.slope, half.bias.ravel(), jnp.zeros(1)])  # correlation 0 packed
    rows = _row_log_density(q, law, jnp.asarray(z[:4]), jnp.asarray(gappy[:4]), (1,))
    sd, slope, b, R = _unpack_run_to_run(q, 2, 2, (1,))
    v = np.asarray(regional_scale(sd, slope, jnp.asarray(z[:4]))) ** 2
    miss = np.nan_to_num(gappy[:4]) - x[:4] @ np.asarray(b)
    expect = law.with_correlation(R).residual_log_density(miss, v, z[:4], np.isfinite(gappy[:4]))
    np.testing.assert_allclose(np.asarray(rows), np.asarray(expect), rtol=1e-10)
    with pytest.raises(ValueError, match="curved"):
        fit_run_to_run(law, z, r, df=3.0, curved=(2,))
    # a fold whose training runs all lack an angle (one run of six has it) still gives finite scores and terms
    rng0 = np.random.default_rng(0)
    z6 = rng0.random((6, 2))
    sparse = law.sample(rng0, np.full((6, 2), 0.25), z6)
    sparse[:5, 1] = np.nan
    few = fit_run_to_run(law, z6, sparse, df_grid=(3.0,), folds=3)
    assert np.all(np.isfinite(np.asarray(few.df_score))) and np.all(np.isfinite(np.asarray(few.bias)))


@pytest.mark.parametrize("true_df, chosen", [(1.5, 1.5), (50.0, 8.0)])
def test_run_to_run_fit_chooses_the_tail_of_the_misses_by_cross_validation(true_df, chosen):
    """Misses drawn with a heavier (ν 1.5) or a lighter (ν 50) tail than the cross-validated law claims (ν 4): the fit
    chooses, of ν 1.5 and 8, the one nearer the truth by the held-out folds' log density, and its law carries it."""
    from paintjax.inverse._error_model import fit_run_to_run

    claimed = EmulatorError([1.0, 1.5], [0.0, 0.0], 4.0)
    rng = np.random.default_rng(11)
    z = rng.random((300, 2))
    truth = EmulatorError([1.0, 1.5], [0.0, 0.0], true_df)
    misses = truth.sample(rng, np.full((300, 2), 0.25), z)
    term = fit_run_to_run(claimed, z, misses, df_grid=(1.5, 8.0), folds=3)
    assert float(term.df) == chosen and term.law(claimed).df == chosen
    np.testing.assert_array_equal(np.asarray(term.df_grid), [1.5, 8.0])
    assert np.all(np.isfinite(np.asarray(term.df_score)))
    assert float(term.df_score[[1.5, 8.0].index(chosen)]) == float(np.max(np.asarray(term.df_score)))
    with pytest.raises(ValueError, match="folds"):
        fit_run_to_run(claimed, z, misses, folds=1)
    few = fit_run_to_run(claimed, z[:4], misses[:4], df_grid=(1.5, 8.0))  # fewer misses than folds: leave-one-out
    assert float(few.df) in (1.5, 8.0) and np.all(np.isfinite(np.asarray(few.df_score)))
    one = fit_run_to_run(claimed, z[:1], misses[:1])  # nothing to hold out: the law's own ν
    assert float(one.df) == 4.0 and one.df_grid.size == 0
    with pytest.raises(ValueError, match="df_grid"):
        fit_run_to_run(claimed, z, misses, df_grid=(0.5,))
