"""Least squares (Optimistix LM, multi-start), forward models and the emulator."""

import os

import numpy as np
import pytest

from paintjax.inverse._analytic import AnalyticForward
from paintjax.inverse._emulator import build_emulator, emulator_check
from paintjax.inverse._fit import fit_least_squares
from paintjax.inverse._forward import CallableForward
from paintjax.inverse._parameters import make_spec
from paintjax.inverse._registry import make_forward

MIRROR = AnalyticForward(rough=False)
TRUTH = {"shape": 2.6, "scale": 1.9, "diffuse": 0.15}


def curve(model, x):
    """One L* curve, evaluated in the 16-row batch shape the inverse layer compiles for."""
    return np.asarray(model(np.tile(np.asarray(x, dtype=float), (16, 1))))[0]


def _truth_curve(model=MIRROR, truth=TRUTH):
    return curve(model, [truth[n] for n in model.parameter_names])


def test_forward_shapes_and_validation():
    y = MIRROR(np.tile([[2.0, 2.0, 0.1], [3.0, 1.5, 0.0]], (8, 1)))
    assert y.shape == (16, 5) and np.all(np.isfinite(y))
    assert np.all(np.diff(y[0]) < 0)  # lightness falls away from specular
    with pytest.raises(ValueError, match="theta must have shape"):
        MIRROR(np.ones((2, 4)))
    with pytest.raises(ValueError, match="lobe must be"):
        AnalyticForward(lobe="phong")
    with pytest.raises(ValueError, match="refractive index n"):
        AnalyticForward(n=0.5)
    with pytest.raises(ValueError, match="unknown forward model"):
        make_forward("raytracer")
    with pytest.raises(ValueError, match="not inputs of this forward model"):
        MIRROR.restrict(("sigma",))
    with pytest.raises(ValueError, match=r"fixed value of diffuse must lie in \[0, 0.5\]"):
        MIRROR.restrict(("shape",), {"diffuse": 2.0})


def test_noise_free_recovery_from_several_starts():
    y = _truth_curve()
    fr = fit_least_squares(MIRROR, y, free=("shape", "scale", "diffuse"), n_starts=6, seed=1)
    assert fr.success and fr.n_starts == 6
    for n, v in TRUTH.items():
        assert fr.values[n] == pytest.approx(v, rel=1e-4)
    # at least 3 independent starts reach the truth on their own
    hits = [s for s in fr.starts if all(abs(s["x"][n] / v - 1) < 1e-3 for n, v in TRUTH.items())]
    assert len(hits) >= 3
    assert fr.chi2 < 1e-8 and np.max(np.abs(fr.residuals)) < 1e-4


def test_optimum_on_a_bound_gives_finite_uncertainties(tmp_path):
    """Data from outside an emulator's box: least squares walks shape to the bound (u → ∞, where the
    logit map's derivative rounds to 0 and the clipped emulator is flat). The covariance must stay
    finite (Jacobian taken at the edge band) and the bound be named. (It raised LinAlgError before.)"""
    spec = make_spec(("shape", "scale"), {"shape": (1.5, 4.0), "scale": (1.2, 3.5)})
    em = build_emulator(MIRROR.restrict(spec.names, {"diffuse": 0.15}), spec, n_train=32, n_test=16, seed=0, cache_dir=tmp_path, batch=16)
    y = np.asarray(MIRROR(np.array([[8.0, 2.0, 0.15]])))[0]
    fr = fit_least_squares(em, y, free=("shape", "scale"), n_starts=4, seed=0)
    print(fr.values, fr.stderr, fr.at_bound, fr.status)
    assert fr.values["shape"] == pytest.approx(4.0, rel=1e-3) and "shape" in fr.at_bound
    assert np.all(np.isfinite(fr.covariance)) and all(np.isfinite(v) and v > 0 for v in fr.stderr.values())


def test_noisy_recovery_and_covariance():
    rng = np.random.default_rng(7)
    y = _truth_curve() + rng.normal(0, 0.3, 5)
    fr = fit_least_squares(MIRROR, y, free=("shape", "scale", "diffuse"), n_starts=4, seed=2)
    assert fr.success
    for n, v in TRUTH.items():
        assert abs(fr.values[n] - v) < 4 * fr.stderr[n] + 1e-9
        assert fr.stderr[n] > 0
    assert fr.covariance.shape == (3, 3) and np.allclose(fr.covariance, fr.covariance.T)
    assert fr.scale2 >= 1.0 and fr.dof == 2
    d = fr.to_dict()
    assert set(d["params"]) == {"shape", "scale", "diffuse"} and len(d["L_star_fit"]) == 5


def test_rough_platelets_sigma_tau_recovered():
    rough = AnalyticForward(rough=True)
    truth = {"shape": 2.3, "scale": 2.2, "sigma": 0.05, "tau": 0.7, "diffuse": 0.0}
    y = curve(rough, [truth[n] for n in rough.parameter_names])
    fr = fit_least_squares(rough, y, free=("sigma", "tau"), fixed={"shape": 2.3, "scale": 2.2}, n_starts=3, seed=0)
    assert fr.success
    assert fr.values["sigma"] == pytest.approx(0.05, rel=1e-3)
    assert fr.values["tau"] == pytest.approx(0.7, rel=1e-3)
    assert fr.fixed["shape"] == 2.3 and fr.fixed["diffuse"] == 0.0


def test_multistart_survives_failing_starts():
    # A forward that is NaN for part of the box: those starts fail, the fit still succeeds.
    def fn(theta):  # plain NumPy around the compiled model (no new compilation)
        L = np.asarray(MIRROR(np.asarray(theta)))
        return np.where(np.asarray(theta)[:, :1] > 6.0, np.nan, L)

    broken = CallableForward(fn, MIRROR.parameter_names, identity="test-broken-mirror-v1")
    y = _truth_curve()
    fr = fit_least_squares(broken, y, free=("shape", "scale", "diffuse"), n_starts=8, seed=3)
    assert fr.success
    assert fr.values["shape"] == pytest.approx(TRUTH["shape"], rel=1e-3)
    assert any(not np.isfinite(s["chi2"]) or s["status"] != "successful" for s in fr.starts)


def test_discrepancy_moment_estimate():
    y = _truth_curve() + np.array([3.0, -3.0, 3.0, -3.0, 3.0])
    fr = fit_least_squares(MIRROR, y, free=("shape", "scale", "discrepancy"), fixed={"diffuse": 0.15}, n_starts=3)
    assert fr.discrepancy is not None and fr.discrepancy > 1.0
    assert np.isnan(fr.stderr["discrepancy"])


def test_unidentified_parameters_get_infinite_errors():
    """Three weighted angles cannot fix three parameters of which the data see a flat direction:
    the pseudo-inverse's zero variance would claim a precision the data do not have."""
    y = _truth_curve()
    full = fit_least_squares(MIRROR, y, free=("shape", "scale", "diffuse"), n_starts=3)
    assert all(np.isfinite(v) and v > 0 for v in full.stderr.values())
    with pytest.warns(RuntimeWarning, match="the data do not identify"):
        two = fit_least_squares(MIRROR, y, free=("shape", "scale", "diffuse"), weights=[1, 1, 0, 0, 0], n_starts=3)
    assert two.dof < 0 and any(np.isinf(v) for v in two.stderr.values())


def test_discrepancy_estimate_ignores_weight_scale():
    y = _truth_curve() + np.array([3.0, -3.0, 3.0, -3.0, 3.0])
    kw = dict(free=("shape", "scale", "discrepancy"), fixed={"diffuse": 0.15}, n_starts=3)
    a = fit_least_squares(MIRROR, y, weights=[1] * 5, **kw).discrepancy
    b = fit_least_squares(MIRROR, y, weights=[2] * 5, **kw).discrepancy
    assert a == pytest.approx(b, rel=1e-6)


def test_fit_bad_inputs():
    with pytest.raises(ValueError, match="measured must have 5 values"):
        fit_least_squares(MIRROR, [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="finite"):
        fit_least_squares(MIRROR, [1.0, 2.0, np.nan, 4.0, 5.0])
    with pytest.raises(ValueError, match="weights must be 5 finite non-negative"):
        fit_least_squares(MIRROR, _truth_curve(), weights=[1, 1, -1, 1, 1])
    with pytest.raises(ValueError, match=r"n_starts must be an integer in \[1, 1024\]"):
        fit_least_squares(MIRROR, _truth_curve(), n_starts=0)
    for bad in (0.0, np.inf):
        with pytest.raises(ValueError, match="instrument_sd must be a finite number > 0"):
            fit_least_squares(MIRROR, _truth_curve(), instrument_sd=bad)
    with pytest.raises(ValueError, match="both free and fixed"):
        fit_least_squares(MIRROR, _truth_curve(), free=("shape",), fixed={"shape": 2.0})
    with pytest.raises(ValueError, match="x0 of shape must lie"):
        fit_least_squares(MIRROR, _truth_curve(), free=("shape", "scale"), x0={"shape": 100.0, "scale": 1.0})


def test_emulator_cached_with_measured_error(tmp_path):
    spec = make_spec(("shape", "scale"), {"shape": (1.5, 4.0), "scale": (1.2, 3.5)})
    target = MIRROR.restrict(spec.names, {"diffuse": 0.15})
    em = build_emulator(target, spec, n_train=32, n_test=16, seed=0, cache_dir=tmp_path, batch=16)
    assert em.parameter_names == ("shape", "scale")
    err = em.error_sd
    assert err.shape == (5,) and np.all(err >= 0) and np.max(err) < 1.0
    files = list(tmp_path.glob("emulator-*.npz"))
    assert len(files) == 1 and not list(tmp_path.glob("*.partial.npz"))
    again = build_emulator(target, spec, n_train=32, n_test=16, seed=0, cache_dir=tmp_path)
    assert again.key == em.key and np.allclose(again.error_sd, err)
    x = np.array([[2.3, 2.2], [3.1, 1.6]])
    x = np.tile(x, (8, 1))
    chk = emulator_check(em, target, x)
    assert np.all(chk["max_abs"] < 2.0)
    # The emulator is a ForwardModel: least squares runs on it, the held-out error widens the residual scale.
    y = np.asarray(target(np.tile([[2.6, 1.9]], (16, 1))))[0]
    fr = fit_least_squares(em, y, free=("shape", "scale"), n_starts=3)
    assert fr.values["shape"] == pytest.approx(2.6, rel=0.05) and fr.values["scale"] == pytest.approx(1.9, rel=0.05)
    with pytest.raises(ValueError, match="exceed the emulator's training box"):
        fit_least_squares(em, y, free=("shape", "scale"), bounds={"shape": (1.0, 4.0)})
    with pytest.raises(ValueError, match=r"fixed value of scale must lie in the emulator's training box \[1.2, 3.5\]"):
        fit_least_squares(em, y, free=("shape",), fixed={"scale": 0.5})  # the GP would clip it to 1.2 silently


def test_emulator_gp_is_the_closed_form_posterior_mean(tmp_path):
    """The emulator's tinygp GPs against the textbook formula in NumPy/SciPy: with its fitted
    hyperparameters, mean(z) = k(z, X) (K + s² I)⁻¹ y for the Matérn-5/2 kernel with ARD length scales."""
    from scipy.spatial.distance import cdist

    spec = make_spec(("shape", "scale"), {"shape": (1.5, 4.0), "scale": (1.2, 3.5)})
    target = MIRROR.restrict(spec.names, {"diffuse": 0.1})
    em = build_emulator(target, spec, n_train=24, n_test=8, seed=1, cache_dir=tmp_path, batch=32)
    X, Z = np.asarray(em.X), np.random.default_rng(2).random((7, 2))
    Y = np.asarray(target(np.asarray(spec.from_unit(X))))
    for k in range(5):
        h = np.asarray(em.hyper[k])
        ls, amp2, noise = np.exp(h[:2]), np.exp(2 * h[2]), np.exp(2 * h[3]) + 1e-8

        def matern(a, b):
            r = np.sqrt(5.0) * cdist(a / ls, b / ls)
            return amp2 * (1 + r + r**2 / 3) * np.exp(-r)

        y = (Y[:, k] - float(em.y_mean[k])) / float(em.y_std[k])
        mean = matern(Z, X) @ np.linalg.solve(matern(X, X) + noise * np.eye(len(X)), y)
        want = float(em.y_mean[k]) + float(em.y_std[k]) * mean
        np.testing.assert_allclose(np.asarray(em(np.asarray(spec.from_unit(Z))))[:, k], want, rtol=1e-9, atol=1e-9)


def test_emulator_with_physics_informed_mean(tmp_path):
    """A cheap model as the GP's linear prior mean and extra inputs: fn = mirror model + a smooth,
    angle-dependent offset. The informed emulator must beat the plain GP on the same design, and
    switching the mean re-fits from the cached design without calling fn again."""
    spec = make_spec(("shape", "scale"), {"shape": (1.5, 4.0), "scale": (1.2, 3.5)})
    cheap = MIRROR.restrict(spec.names, {"diffuse": 0.0})
    calls = []

    def fn(x):
        calls.append(len(x))
        y = np.asarray(cheap(x))
        return 1.3 * y + 4.0 * np.log(x[:, :1]) * np.array([1.0, 0.5, 0.2, 0.1, 0.1]) + 3.0

    kw = dict(source="mirror-plus-offset-v1", n_train=16, n_test=16, seed=0, cache_dir=tmp_path, batch=16)
    plain = build_emulator(fn, spec, **kw)
    informed = build_emulator(fn, spec, **kw, mean=cheap, mean_features=(0, 1, 2))
    assert sum(calls) == 32  # the second build re-fitted the cached design
    assert informed.fingerprint() != plain.fingerprint()
    print("held-out RMS plain", np.round(plain.error_sd, 3), "informed", np.round(informed.error_sd, 3),
          "LOO informed", np.round(informed.held_out_loo_rms, 3))
    assert np.all(informed.error_sd < 0.5 * plain.error_sd)
    x = np.array([[2.3, 2.2], [3.1, 1.6]])
    np.testing.assert_allclose(np.asarray(informed(x)), fn(x), atol=4 * np.max(informed.error_sd) + 0.05)
    with pytest.raises(ValueError, match="mean must be a jit-able Restricted model"):
        build_emulator(fn, spec, **kw, mean=MIRROR.restrict(("scale", "shape"), {"diffuse": 0.0}))
    with pytest.raises(ValueError, match="mean_features"):
        build_emulator(fn, spec, **kw, mean=cheap, mean_features=(7,))
    again = build_emulator(fn, spec, **kw, mean=cheap, mean_features=(0, 1, 2))  # read from the cache
    assert sum(calls) == 32 + len(x)  # only the direct check above
    np.testing.assert_allclose(np.asarray(again(x)), np.asarray(informed(x)))


def test_emulator_design_resumes_from_checkpoint(tmp_path):
    calls = []

    def fn(x):
        calls.append(len(x))
        if len(calls) == 2:
            raise KeyboardInterrupt  # interrupted after the first batch
        return np.stack([np.sin(x[:, 0]) * 50 + 60, x[:, 1] * 10, x[:, 0] + x[:, 1], np.cos(x[:, 1]) + 5, x[:, 0] ** 2], -1)

    spec = make_spec(("shape", "scale"))
    with pytest.raises(KeyboardInterrupt):
        build_emulator(fn, spec, source="toy-v1", n_train=16, n_test=8, batch=8, cache_dir=tmp_path)
    assert len(list(tmp_path.glob("*.partial.npz"))) == 1
    em = build_emulator(fn, spec, source="toy-v1", n_train=16, n_test=8, batch=8, cache_dir=tmp_path)
    assert sum(calls) == 8 + 8 + 16  # first batch, the interrupted call, then only the remaining 16
    assert em.error_sd.shape == (5,)
    with pytest.raises(ValueError, match="source must identify fn"):
        build_emulator(fn, spec, n_train=16, n_test=8, cache_dir=None)


def test_a_start_stopped_at_the_step_limit_is_continued_not_dropped():
    """With a 3-step budget no start converges; the lowest-χ² start is continued from where it stopped
    (its status says so) and reaches the truth, instead of the fit reporting an unconverged start."""
    y = _truth_curve()
    short = fit_least_squares(MIRROR, y, free=("shape", "scale", "diffuse"), n_starts=4, seed=1, max_steps=3, continuations=0)
    fr = fit_least_squares(MIRROR, y, free=("shape", "scale", "diffuse"), n_starts=4, seed=1, max_steps=3, continuations=30)
    assert not short.success and short.chi2 > fr.chi2
    assert any("continued" in s["status"] for s in fr.starts)
    assert fr.chi2 == min(s["chi2"] for s in fr.starts if np.isfinite(s["chi2"]))  # the lowest over all starts
    assert fr.values["shape"] == pytest.approx(TRUTH["shape"], rel=1e-3)


def test_fit_verdict_says_whether_the_model_fits():
    y = _truth_curve()
    good = fit_least_squares(MIRROR, y + np.array([0.2, -0.1, 0.1, -0.2, 0.1]), free=("shape", "scale"), fixed={"diffuse": 0.15}, n_starts=3)
    assert good.p_value > 0.01 and "consistent" in good.fit_verdict()
    bad = fit_least_squares(MIRROR, y + np.array([6.0, -6.0, 6.0, -6.0, 6.0]), free=("shape", "scale"), fixed={"diffuse": 0.15}, n_starts=3)
    assert bad.p_value < 0.01 and "does NOT fit" in bad.fit_verdict() and bad.scale2 > 1
    assert "NOT fit" in bad.summary() and bad.to_dict()["verdict"] == bad.fit_verdict()
    zero = fit_least_squares(MIRROR, y, free=("shape", "scale", "diffuse"), weights=[1, 1, 1, 0, 0], n_starts=3)
    assert zero.dof == 0 and zero.p_value is None and "cannot test the model" in zero.fit_verdict()


def test_known_inputs_are_gaussian_terms_of_the_objective():
    """A known input (value ± sd) is one more standardised residual: a very tight one pins the parameter
    at its value and its SD at the input's; a loose one leaves the data's optimum; each counts as data."""
    y = _truth_curve()
    free = ("shape", "scale", "diffuse")
    plain = fit_least_squares(MIRROR, y, free=free, n_starts=4, seed=1)
    tight = fit_least_squares(MIRROR, y, free=free, n_starts=4, seed=1, priors={"shape": (3.0, 1e-5)})
    loose = fit_least_squares(MIRROR, y, free=free, n_starts=4, seed=1, priors={"shape": (3.0, 1e3)})
    assert tight.values["shape"] == pytest.approx(3.0, abs=1e-4) and tight.stderr["shape"] <= 1.0001e-5 * np.sqrt(tight.scale2)
    assert tight.dof == plain.dof + 1 and tight.chi2 > plain.chi2 + 1.0
    r = tight.standardized_residuals
    assert r.shape == (5 + 3,) and r[5 + 1] == 0 and r[5 + 2] == 0  # rows of the inputs without a prior are zero
    assert r[5] == pytest.approx((tight.values["shape"] - 3.0) / 1e-5, rel=1e-6)
    assert loose.values["shape"] == pytest.approx(TRUTH["shape"], rel=1e-4)
    with pytest.raises(ValueError, match="known input 'sigma' is not a free parameter"):
        fit_least_squares(MIRROR, y, free=free, priors={"sigma": (0.05, 0.01)})
    with pytest.raises(ValueError, match="known input shape needs a finite value and an sd > 0"):
        fit_least_squares(MIRROR, y, free=free, priors={"shape": (3.0, 0.0)})


def test_emulator_design_on_a_dask_cluster_matches_the_serial_design(tmp_path):
    """The design's batches as tasks on two worker processes give the same design values, checkpoint
    and emulator as the serial loop (the callable travels to the workers by pickling)."""
    distributed = pytest.importorskip("distributed")

    def fn(x):
        return np.stack([np.sin(x[:, 0]) * 50 + 60, x[:, 1] * 10, x[:, 0] + x[:, 1], np.cos(x[:, 1]) + 5, x[:, 0] ** 2], -1)

    spec = make_spec(("shape", "scale"))
    serial = build_emulator(fn, spec, source="toy-dask", n_train=16, n_test=8, batch=3, cache_dir=tmp_path / "serial")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        spread = build_emulator(fn, spec, source="toy-dask", n_train=16, n_test=8, batch=3, cache_dir=tmp_path / "dask", client=client)
        assert sorted(client.run(os.getpid).values()) != [os.getpid()]  # real worker processes
    (a,), (b,) = list((tmp_path / "serial").glob("*.npz")), list((tmp_path / "dask").glob("*.npz"))
    with np.load(a) as da, np.load(b) as db:
        np.testing.assert_array_equal(da["Y"], db["Y"])
        np.testing.assert_array_equal(da["Yt"], db["Yt"])
    x = np.tile([[2.0, 1.5]], (16, 1))
    np.testing.assert_allclose(np.asarray(spread(x)), np.asarray(serial(x)), rtol=1e-12)


def test_emulator_refinement_reuses_the_base_design_and_samples_the_sub_box(tmp_path):
    """`refine`: the base design is read from its own file and only the added runs are made, all inside the
    sub-box (unit coordinates) of the named parameter; the refined emulator has its own key, reads from its cache,
    and follows a map that is steep there better than the base emulator (held-out points in that corner);
    a bad sub-box is an error that names it."""
    spec = make_spec(("shape", "scale"), {"shape": (1.0, 4.0), "scale": (1.0, 4.0)})
    calls = []

    def fn(x):  # steep in the low-shape corner, as L* is in σ where platelets are smooth
        calls.append(np.array(x))
        s = np.log(x[:, :1] / 1.0) / np.log(4.0)
        return 50.0 + 40.0 * np.exp(-((s / 0.12) ** 2)) * np.array([1.0, 0.8, 0.6, 0.4, 0.2]) + 2.0 * x[:, 1:2]

    kw = dict(source="steep-corner-v1", n_train=16, n_test=8, seed=0, cache_dir=tmp_path, batch=32)
    base = build_emulator(fn, spec, **kw)
    n_base = sum(len(c) for c in calls)
    refined = build_emulator(fn, spec, **kw, refine={"shape": (0.0, 0.3)}, n_refine=16)
    added = np.concatenate(calls)[n_base:]
    assert len(added) == 16 and refined.key != base.key and refined.X.shape[0] == 32
    z = np.asarray(spec.to_unit(added))
    assert np.all(z[:, 0] <= 0.3 + 1e-12) and z[:, 1].min() < 0.2 and z[:, 1].max() > 0.8
    again = build_emulator(fn, spec, **kw, refine={"shape": (0.0, 0.3)}, n_refine=16)
    assert sum(len(c) for c in calls) == n_base + 16 and again.key == refined.key  # from its cache
    test = np.asarray(spec.from_unit(np.random.default_rng(5).random((64, 2)) * [0.3, 1.0]))
    truth = fn(test)
    rms = lambda em: np.sqrt(np.mean((np.asarray(em(test)) - truth) ** 2))  # noqa: E731
    print("held-out RMS in the corner: base", rms(base), "refined", rms(refined))
    assert rms(refined) < 0.5 * rms(base), (rms(refined), rms(base))
    for bad in ({"tau": (0.0, 0.3)}, {"shape": (0.4, 0.3)}, {"shape": (-0.1, 0.3)}):
        with pytest.raises(ValueError, match="refine"):
            build_emulator(fn, spec, **kw, refine=bad, n_refine=4)
