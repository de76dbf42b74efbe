"""Posterior sampling: calibration (coverage on synthetic data), HDF5 resume, outputs, errors."""

import json
from multiprocessing.dummy import Pool as ThreadPool

import arviz as az
import jax
import numpy as np
import pytest
from scipy.stats import binom

from paintjax.inverse._analytic import AnalyticForward
from paintjax.inverse._chain import chain_diagnostics
from paintjax.inverse._parameters import make_spec
from paintjax.inverse._posterior import LogPosterior, sample_posterior
from paintjax.inverse._posterior_output import corner_plot, save_netcdf

MIRROR = AnalyticForward(rough=False)
FREE = ("shape", "scale")
FIXED = {"diffuse": 0.15, "discrepancy": 0.0}
N_DATASETS = 20


def _data(theta, rng):
    x = np.tile([theta["shape"], theta["scale"], FIXED["diffuse"]], (16, 1))  # the compiled batch shape
    return np.asarray(MIRROR(x))[0] + rng.normal(0.0, 0.3, 5)


def test_coverage_on_synthetic_datasets():
    """20 datasets with truths drawn from the prior and 0.3 L* noise; short chains started at the
    truth (burn-in discarded). Each 50 % / 90 % interval must cover its truth at a rate inside the
    central 99 % binomial range (per parameter: n = 20)."""
    spec = make_spec(FREE)
    truths = np.asarray(spec.sample_prior(jax.random.key(2026), N_DATASETS))
    rng = np.random.default_rng(11)
    hits = {0.5: np.zeros(len(FREE)), 0.9: np.zeros(len(FREE))}
    for i, t in enumerate(truths):
        truth = dict(zip(FREE, t))
        y = _data(truth, rng)
        post = sample_posterior(MIRROR, y, free=FREE, fixed=FIXED, walkers=8, max_steps=180, min_steps=180, check_every=180,
                                min_ess=0, init=truth, seed=i, progress=False, inference_data=False)
        for level in hits:
            for j, n in enumerate(FREE):
                lo, hi = post.interval(n, level)
                hits[level][j] += lo <= truth[n] <= hi
    for level, h in hits.items():
        lo, hi = binom.ppf(0.005, N_DATASETS, level), binom.ppf(0.995, N_DATASETS, level)
        print(f"coverage {level:.0%}: {dict(zip(FREE, h.astype(int)))} of {N_DATASETS} (99% binomial range [{lo:.0f}, {hi:.0f}])")
        assert np.all(h >= lo) and np.all(h <= hi), (level, h)


def test_hdf5_backend_resumes_after_interruption(tmp_path):
    y = _data({"shape": 2.4, "scale": 2.1}, np.random.default_rng(0))
    path = tmp_path / "chain.h5"
    kw = dict(free=FREE, fixed=FIXED, walkers=8, min_steps=1, check_every=40, min_ess=0, init={"shape": 2.4, "scale": 2.1},
              seed=5, backend_path=path, progress=False)

    class FlakyPool:  # a pool whose map dies on its 30th call: an interrupted run
        def __init__(self):
            self.calls, self.inner = 0, ThreadPool(2)
            self._processes = 2

        def map(self, fn, parts):
            self.calls += 1
            if self.calls == 30:
                raise KeyboardInterrupt
            return self.inner.map(fn, parts)

    with pytest.raises(KeyboardInterrupt, match="interrupted after .* steps; the chain in .* is kept: rerun the same command to resume"):
        sample_posterior(MIRROR, y, max_steps=80, pool=FlakyPool(), **kw)
    import emcee

    done = emcee.backends.HDFBackend(str(path), read_only=True).iteration
    assert 1 <= done < 80
    first = emcee.backends.HDFBackend(str(path), read_only=True).get_chain()[:done].copy()
    post = sample_posterior(MIRROR, y, max_steps=80, **kw)
    assert post.steps == 80
    back = emcee.backends.HDFBackend(str(path), read_only=True).get_chain()
    np.testing.assert_array_equal(back[:done], first)  # nothing lost, nothing redone
    # A request for other data never touches the stored chain: refused, unless overwrite=True.
    with pytest.raises(ValueError, match="holds 80 steps of a chain that was sampled for other data"):
        sample_posterior(MIRROR, y + 1.0, max_steps=40, **kw)
    np.testing.assert_array_equal(emcee.backends.HDFBackend(str(path), read_only=True).get_chain(), back)
    with pytest.raises(ValueError, match="resume=False"):
        sample_posterior(MIRROR, y, max_steps=40, resume=False, **kw)
    post2 = sample_posterior(MIRROR, y + 1.0, max_steps=40, overwrite=True, **kw)
    assert post2.steps == 40
    # A damaged chain file (a run killed while emcee wrote in place) is named, not a raw h5py error.
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    with pytest.raises(ValueError, match="is not a readable emcee chain"):
        sample_posterior(MIRROR, y, max_steps=40, **kw)


def test_outputs_netcdf_corner_and_pool(tmp_path):
    y = _data({"shape": 2.4, "scale": 2.1}, np.random.default_rng(1))
    with ThreadPool(2) as pool:
        post = sample_posterior(MIRROR, y, free=FREE + ("discrepancy",), fixed={"diffuse": 0.15}, walkers=12, max_steps=120,
                                min_steps=1, check_every=60, min_ess=0, init={"shape": 2.4, "scale": 2.1, "discrepancy": 0.5},
                                seed=1, progress=False, pool=pool)
    d = post.to_dict()
    for key in ("mean", "q05", "q95", "tau_int"):
        assert set(FREE) <= set(d[key])
    assert "mean_tilt" in d["mean"] and d["q05"]["shape"] <= d["mean"]["shape"] <= d["q95"]["shape"]
    json.dumps(d)
    nc = save_netcdf(post.idata, tmp_path / "post.nc")
    idata = az.from_netcdf(nc)
    assert set(FREE) <= set(idata.posterior.data_vars) and "discrepancy" in idata.posterior.data_vars
    assert idata.posterior["shape"].shape[0] == 12  # walkers as chains
    np.testing.assert_allclose(idata.observed_data["L_star"].values, y)
    fig = corner_plot(post, reference={"shape": 2.4, "scale": 2.1}, path=tmp_path / "corner.png")
    assert (tmp_path / "corner.png").stat().st_size > 1000
    import matplotlib.pyplot as plt

    plt.close(fig)


def test_log_posterior_is_vectorised_and_includes_error_terms():
    y = _data({"shape": 2.4, "scale": 2.1}, np.random.default_rng(2))
    lp = LogPosterior(MIRROR, y, free=FREE + ("discrepancy",), fixed={"diffuse": 0.15})
    U = np.random.default_rng(0).normal(0, 1, (5, 3))
    batch = lp(U)
    one = np.array([lp(U[i : i + 1])[0] for i in range(5)])
    np.testing.assert_allclose(batch, one, rtol=1e-10)
    assert batch.shape == (5,) and np.all(np.isfinite(batch))


def test_jax_log_density_is_the_log_posterior_and_differentiable():
    """The JAX log density for gradient-based samplers (NUTS) equals the vectorised log posterior point by
    point, and its gradient matches central finite differences."""
    y = _data({"shape": 2.4, "scale": 2.1}, np.random.default_rng(2))
    lp = LogPosterior(MIRROR, y, free=FREE + ("discrepancy",), fixed={"diffuse": 0.15})
    U = np.random.default_rng(1).normal(0, 0.5, (4, 3))
    f = jax.jit(lp.jax_log_density())
    np.testing.assert_allclose([float(f(u)) for u in U], lp(U), rtol=1e-10)
    g, h = np.asarray(jax.grad(f)(U[0])), 1e-5
    fd = [(float(f(U[0] + h * e)) - float(f(U[0] - h * e))) / (2 * h) for e in np.eye(3)]
    np.testing.assert_allclose(g, fd, rtol=1e-4, atol=1e-6)
    from paintjax.inverse import CallableForward

    slow = CallableForward(lambda x: np.asarray(MIRROR(x)), MIRROR.parameter_names, "mirror-callable")
    with pytest.raises(ValueError, match="not jit-able"):
        LogPosterior(slow, y, free=FREE, fixed=FIXED).jax_log_density()


def test_chain_diagnostics_on_known_chains():
    """Independent normal draws (32 walkers × 400 steps): R-hat within 1 ± 0.01 and bulk ESS near the
    12 800 draws; walkers stuck at two different means: R-hat far above 1.01. A chain of 3 steps is
    too short (NaN), so it can never pass the rule."""
    rng = np.random.default_rng(0)
    rhat, ess = chain_diagnostics(rng.standard_normal((400, 32, 2)))
    assert np.all(np.abs(rhat - 1.0) < 0.01) and np.all((ess > 0.8 * 12800) & (ess < 1.2 * 12800)), (rhat, ess)
    stuck = rng.standard_normal((400, 32, 2)) + np.repeat([0.0, 1.0], 16)[None, :, None]
    assert np.all(chain_diagnostics(stuck)[0] > 1.1)
    assert np.all(np.isnan(chain_diagnostics(rng.standard_normal((3, 32, 2)))[0]))


def test_stopping_rule_requires_rhat_and_bulk_ess():
    """A run that stops as converged has every parameter's split R-hat ≤ max_rhat and bulk ESS ≥ min_ess
    (walkers as chains). With the τ and ESS parts of the rule made loose, the chain stops once τ has settled;
    the same chain with an R-hat bound it cannot meet runs on to max_steps and is not converged."""
    y = _data({"shape": 3.0, "scale": 1.5}, np.random.default_rng(5))
    kw = dict(free=FREE, fixed=FIXED, walkers=16, min_steps=250, check_every=250, init={"shape": 3.0, "scale": 1.5},
              seed=0, progress=False, inference_data=False)
    post = sample_posterior(MIRROR, y, max_steps=6000, min_ess=300, **kw)
    assert post.converged and post.steps < 6000
    assert max(post.rhat.values()) <= 1.01 and min(post.ess_bulk.values()) >= 300, (post.rhat, post.ess_bulk)
    loose = sample_posterior(MIRROR, y, max_steps=3000, min_ess=0, n_tau=1, max_rhat=np.inf, **kw)
    assert loose.converged and loose.steps < 3000
    strict = sample_posterior(MIRROR, y, max_steps=loose.steps, min_ess=0, n_tau=1, max_rhat=1.0 + 1e-9, **kw)  # the same chain
    assert not strict.converged and strict.steps == loose.steps
    with pytest.raises(ValueError, match="max_rhat must be >= 1"):
        sample_posterior(MIRROR, y, max_rhat=0.99, **kw)


def test_default_start_is_the_mode_of_the_posterior_with_its_inputs():
    """Without `init` the walkers start about the maximum of the posterior being sampled, not at the L*-only
    least-squares fit: with L* made at shape 3 and a known shape of 5.0 ± 0.01, the start is the point where
    the two pulls balance (a maximum: a step of 0.02 along any unconstrained axis lowers the log posterior),
    near 5 and far above the fit's log posterior."""
    from paintjax.inverse._fit import fit_least_squares
    from paintjax.inverse._measured_inputs import KnownInputs
    from paintjax.inverse._walker_start import initial_walkers, posterior_mode, start_point

    y = _data({"shape": 3.0, "scale": 1.5}, np.random.default_rng(7))
    lp = LogPosterior(MIRROR, y, FREE, FIXED, inputs=KnownInputs({"shape": (5.0, 0.01)}))
    fr = fit_least_squares(MIRROR, y, free=FREE, fixed=FIXED, seed=0)
    assert abs(fr.values["shape"] - 3.0) < 0.3  # the L* alone point elsewhere
    fit_start = start_point(lp.spec, fr.values)
    mode = posterior_mode(lp, [fit_start, start_point(lp.spec, dict(fr.values) | {"shape": 5.0})])
    top = float(lp(mode[None, :])[0])
    for axis in range(mode.size):
        for step in (-0.02, 0.02):
            assert float(lp((mode + step * np.eye(mode.size)[axis])[None, :])[0]) < top
    U = initial_walkers(lp, None, 8, np.random.default_rng(0), 0, start="ball")
    shape = np.asarray(lp.spec.from_unconstrained(U))[:, 0]
    assert np.all(np.abs(shape - 5.0) < 0.2), shape
    assert np.min(lp(U)) > float(lp(fit_start[None, :])[0]) + 1000


def test_posterior_bad_inputs():
    y = [140.0, 100.0, 50.0, 30.0, 20.0]
    with pytest.raises(ValueError, match="walkers must be even, >= 2"):
        sample_posterior(MIRROR, y, free=FREE, fixed=FIXED, walkers=3, progress=False)
    with pytest.raises(ValueError, match="measured must have 5 values"):
        sample_posterior(MIRROR, y[:4], free=FREE, fixed=FIXED, progress=False)
    with pytest.raises(ValueError, match="fixed discrepancy must lie"):
        LogPosterior(MIRROR, y, free=FREE, fixed={"discrepancy": -1.0})
    with pytest.raises(ValueError, match="unknown parameter"):
        sample_posterior(MIRROR, y, free=("shape", "tilt"), progress=False)
    with pytest.raises(ValueError, match="init value of shape must lie"):
        sample_posterior(MIRROR, y, free=FREE, fixed=FIXED, init={"shape": 500.0}, progress=False)
    with pytest.raises(ValueError, match=r"init names \['shap'\]"):
        sample_posterior(MIRROR, y, free=FREE, fixed=FIXED, init={"shap": 2.0}, progress=False)


def test_angles_left_out_and_per_angle_sd():
    """An angle left out (`angles`) does not enter the likelihood, whatever it holds (NaN included); a
    per-angle SD equal everywhere is the scalar one; a larger SD at one angle weakens only that term."""
    y = np.asarray(_data({"shape": 2.4, "scale": 2.1}, np.random.default_rng(3)), float)
    U = np.random.default_rng(1).normal(0, 1, (16, 2))
    free = FREE
    base = LogPosterior(MIRROR, y, free=free, fixed=FIXED)(U)
    np.testing.assert_allclose(LogPosterior(MIRROR, y, free=free, fixed=FIXED, instrument_sd=[0.3] * 5)(U), base, rtol=1e-12)
    mask = np.array([True, True, False, True, True])
    out1 = LogPosterior(MIRROR, np.where(mask, y, np.nan), free=free, fixed=FIXED, angles=mask)(U)
    y2 = y.copy()
    y2[2] += 40.0
    out2 = LogPosterior(MIRROR, y2, free=free, fixed=FIXED, angles=mask)(U)
    np.testing.assert_allclose(out1, out2, rtol=1e-12)
    assert not np.allclose(out1, base)
    with pytest.raises(ValueError, match="angles must be 5 booleans"):
        LogPosterior(MIRROR, y, free=free, fixed=FIXED, angles=[True, False])
    with pytest.raises(ValueError, match="instrument_sd must be a finite number > 0"):
        LogPosterior(MIRROR, y, free=free, fixed=FIXED, instrument_sd=[0.3, 0.3, -1.0, 0.3, 0.3])


def test_known_inputs_likelihood_is_the_gaussian_closed_form():
    from paintjax.inverse._measured_inputs import KnownInputs

    k = KnownInputs({"sigma": (0.05, 0.01), "tau": (0.6, 0.1)})
    s, t = np.array([0.05, 0.07]), np.array([0.6, 0.4])
    expect = (-0.5 * ((s - 0.05) / 0.01) ** 2 - np.log(np.sqrt(2 * np.pi) * 0.01)
              - 0.5 * ((t - 0.6) / 0.1) ** 2 - np.log(np.sqrt(2 * np.pi) * 0.1))
    np.testing.assert_allclose(np.asarray(k.log_likelihood({"sigma": s, "tau": t, "shape": s})), expect, rtol=1e-12)
    shift = k.shift_table({"sigma": np.full(10, 0.07)})
    assert list(shift) == ["sigma"] and shift["sigma"]["z"] == pytest.approx(-2.0)
    with pytest.raises(ValueError, match="known input tau needs a finite value and an sd > 0"):
        KnownInputs({"tau": (0.6, -0.1)})


def test_posterior_piled_against_a_box_edge_is_flagged():
    """Data far outside the prior box in shape: the posterior piles against the box's upper edge of
    shape and the result says so (at_edge, summary); a well-inside posterior raises no flag."""
    from paintjax.inverse._posterior import edges

    spec = make_spec(("shape", "scale"), {"shape": (1.5, 3.0), "scale": (1.0, 3.0)})
    rng = np.random.default_rng(0)
    piled = np.column_stack([3.0 - 0.01 * rng.random(400), 1.0 + 2.0 * rng.random(400)])
    inside = np.column_stack([2.0 + 0.1 * rng.standard_normal(400), 2.0 + 0.1 * rng.standard_normal(400)])
    assert edges(spec, piled) == {"shape": "upper"} and edges(spec, inside) == {}
