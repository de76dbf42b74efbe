"""The tracer as a forward map of the inverse layer (common random numbers) and its registered emulator.

Tiny settings: a 120 µm tile, 2048 rays, closed-form Kirchhoff tables on a 2 × 2 (σ, τ) grid.
"""

import jax.numpy as jnp
import numpy as np
import pytest

from paintjax.inverse._registry import FORWARDS, make_forward
from paintjax.inverse._tracer_emulator import direct_tracer, tracer_info
from paintjax.inverse._tracer_forward import TracerLStar, TracerSettings

TINY = TracerSettings(rays=2048, tile_um=120.0, table_source="kirchhoff", sigma_nodes=(0.04, 0.08, 2),
                      tau_nodes=(0.5, 1.0, 2), lanes=256, batches=8)
THETA = np.array([[2.5, 2.0, 0.055, 0.7], [4.0, 3.0, 0.07, 0.6]])


@pytest.fixture(scope="module")
def fn():
    return TracerLStar(TINY)


def test_deterministic_in_the_seed_and_finite(fn):
    a = fn(THETA)
    b = fn(THETA)
    assert a.shape == (2, 5) and np.all(np.isfinite(a))
    np.testing.assert_array_equal(a, b)  # common random numbers: same seed, same numbers
    c = fn.evaluate(THETA, seed=7)
    assert np.max(np.abs(c - a)) > 0.05  # another seed is another Monte Carlo realisation
    # lightness falls away from the specular direction for these tilts
    assert np.all(np.diff(a[:, :3], axis=1) < 0)
    with pytest.raises(ValueError, match="sigma must lie in the BRDF grid range"):
        fn(np.array([[2.5, 2.0, 0.2, 0.7]]))
    with pytest.raises(ValueError, match="theta must have shape"):
        fn(np.ones((2, 3)))


def test_smooth_under_common_random_numbers(fn):
    """Under common random numbers the bright angles (15°, 25°) respond to a ±1 % step in shape
    (transported array tilts) or σ (interpolated BRDF grid) like a smooth function: both one-sided
    differences small, of the same sign and of similar size (a fresh array per θ, as the generator
    makes it, moves them by several L* at random). With 8192 rays: at 25° a 1 % step in σ moves L*
    by only ≈ 0.2, and with the module's 2048 rays the paths' discrete events (roulette, which
    platelet a ray meets) still move it by ±0.05 per 0.25 % step, the size of the signal."""
    import dataclasses

    fn = TracerLStar(dataclasses.replace(TINY, rays=8192))
    base = fn(THETA[:1])[0]
    for j in (0, 2):
        up, down = THETA[:1].copy(), THETA[:1].copy()
        up[0, j] *= 1.01
        down[0, j] *= 0.99
        d_up = fn(up)[0, :2] - base[:2]
        d_down = base[:2] - fn(down)[0, :2]
        assert np.all(np.abs(d_up) < 3.0) and np.all(np.abs(d_down) < 3.0), (j, d_up, d_down)
        assert np.all(np.sign(d_up) == np.sign(d_down)), (j, d_up, d_down)
        ratio = np.abs(d_up) / np.maximum(np.abs(d_down), 1e-12)
        assert np.all((ratio > 1 / 3) & (ratio < 3)), (j, d_up, d_down)
    # the transported ("crn") array at the reference tilt is the reference array itself
    from paintjax.inverse._tracer_forward import REFERENCE_TILT

    a, ref = fn.array(*REFERENCE_TILT, seed=0), fn.reference_array(0)
    np.testing.assert_allclose(np.asarray(a.normals), np.asarray(ref.normals), atol=1e-6)
    np.testing.assert_allclose(np.asarray(a.centers), np.asarray(ref.centers), atol=1e-5)


def test_minus_15_is_traced_in_its_own_pass_and_leaves_the_five_angles_bit_for_bit(fn):
    """`extra_aspecular=(-15,)`: the same array and paths, −15° in a second pass, so the standard five
    are the five-angle tracer's numbers exactly; the registered narrow emulator refuses −15° by name."""
    import dataclasses

    six = TracerLStar(dataclasses.replace(TINY, extra_aspecular=(-15.0,)))
    a6 = six(THETA[:1])
    assert six.angles == (-15.0, 15.0, 25.0, 45.0, 75.0, 110.0) and a6.shape == (1, 6) and np.all(np.isfinite(a6))
    np.testing.assert_array_equal(a6[:, 1:], fn(THETA[:1]))
    np.testing.assert_array_equal(six.with_angles((-15.0,))(THETA[:1])[:, 0], a6[:, 0])
    assert six.settings.identity() != TINY.identity() and "extra_aspecular" not in TINY.identity()
    with pytest.raises(ValueError, match=r"forward model 'tracer-emulator' gives L\* at 15, 25, 45, 75, 110°, not at -15°"):
        make_forward("tracer-emulator", ("shape", "scale", "sigma", "tau"), angles=(-15.0, 15.0, 25.0))
    with pytest.raises(ValueError, match="extra_aspecular must be distinct"):
        TracerSettings(extra_aspecular=(15.0,))


def test_brdf_between_nodes(fn):
    """The default table at (σ, τ) is `build_at`'s; "at" selects the differentiable interpolation. At a node both
    are the node's table (the same L* to rounding); between nodes they differ, the setting enters the cache key,
    and an unknown value is refused by name."""
    import dataclasses

    assert TINY.brdf_between_nodes == "build_at"
    other = TracerLStar(dataclasses.replace(TINY, brdf_between_nodes="at"))
    assert other.settings.identity() != TINY.identity()
    node = np.array([[2.5, 2.0, 0.04, 0.5]])
    np.testing.assert_allclose(other(node), fn(node), atol=1e-3)
    grid = fn.brdf_grid()
    between = THETA[:1]
    built, interpolated = fn.brdf_at(*between[0, 2:]), other.brdf_at(*between[0, 2:])
    assert fn.brdf_at(*between[0, 2:]) is built  # the passes of one θ share the table
    np.testing.assert_allclose(np.asarray(built.coef), np.asarray(grid.build_at(*between[0, 2:]).coef))
    np.testing.assert_allclose(np.asarray(interpolated.coef), np.asarray(grid.at(*between[0, 2:]).coef))
    assert not np.allclose(np.asarray(built.coef), np.asarray(interpolated.coef))
    with pytest.raises(ValueError, match="brdf_between_nodes must be 'build_at' or 'at'"):
        TracerSettings(brdf_between_nodes="nearest")


def test_crn_mean_over_reference_arrays(fn):
    """`arrays=2`: the CRN L* is the mean of the two reference arrays' runs (seeds 0 and 1, half the rays each), its SE
    the rays' SE of that mean; independent runs (mode "rsa") stay one array with all the rays; the setting enters the
    cache key, bad counts are refused by name, and seeds of other runs may not reuse a reference array's seed."""
    import dataclasses

    from paintjax.inverse._tracer_forward import independent_runs

    two = TracerLStar(dataclasses.replace(TINY, arrays=2))
    half = TracerLStar(dataclasses.replace(TINY, rays=TINY.rays // 2))
    L, se = two.evaluate(THETA[:1], return_se=True)
    runs = [half.evaluate(THETA[:1], seed=s, return_se=True) for s in (0, 1)]
    np.testing.assert_allclose(L, 0.5 * (runs[0][0] + runs[1][0]), rtol=1e-12)
    np.testing.assert_allclose(se, 0.5 * np.hypot(runs[0][1], runs[1][1]), rtol=1e-12)
    assert np.max(np.abs(runs[0][0] - runs[1][0])) > 0.05  # two arrays, two realisations
    np.testing.assert_array_equal(two.evaluate(THETA[:1], seed=5, mode="rsa"), fn.evaluate(THETA[:1], seed=5, mode="rsa"))
    assert two.settings.identity() != TINY.identity() and '"arrays"' not in TINY.identity()
    assert two.settings.crn_seeds == (0, 1)
    for bad in (0, 3, 65):
        with pytest.raises(ValueError, match="arrays must be an integer in"):
            dataclasses.replace(TINY, arrays=bad)
    with pytest.raises(ValueError, match=r"none of the CRN seeds \[0, 1\]"):
        independent_runs(two, THETA[:1], [1])


def test_registered_emulator_builds_from_a_tiny_design_and_caches(tmp_path):
    assert "tracer-emulator" in FORWARDS
    # a plain GP: six design points cannot support the analytic mean's three extra inputs
    opts = dict(settings=TINY, cache_dir=tmp_path, n_train=6, n_test=4, batch=5,
                spread_theta=((2.5, 2.0, 0.055, 0.7),), spread_seeds=(21, 22), analytic_mean=False, independent=0)
    em = make_forward("tracer-emulator", ("shape", "scale", "diffuse"), {"sigma": 0.06, "tau": 0.7},
                      {"shape": (2.0, 4.0), "scale": (1.5, 3.0)}, **opts)
    assert em.parameter_names == ("shape", "scale")
    info = tracer_info(em)
    assert info["tracer_evaluations_this_call"] == 10 + 2 + 1  # design + held-out set + seed spread (2 independent + 1 CRN)
    assert len(list(tmp_path.glob("emulator-*.npz"))) == 1
    held, loo, spread = (np.asarray(info[k]) for k in ("held_out_rms_crn", "loo_rms_crn", "seed_spread_sd"))
    assert np.all(spread > 0)
    cv = np.sqrt((6 * loo**2 + 4 * held**2) / 10)  # held-out errors pooled with leave-one-out ones
    np.testing.assert_allclose(info["cv_rms_crn"], cv)
    np.testing.assert_allclose(em.error_sd, np.sqrt(cv**2 + spread**2))
    x = np.array([[3.0, 2.2]])
    y_em = np.asarray(em(np.tile(x, (16, 1))))[0]
    y_direct = direct_tracer(em)(np.c_[x, [[0.06, 0.7]]])[0]
    assert np.all(np.isfinite(y_em))
    # the emulator is within a few of its own stated errors of the tracer it emulates
    assert np.all(np.abs(y_em - y_direct) < 4 * em.error_sd + 0.5), (y_em, y_direct, em.error_sd)
    # second build: read from the cache, no tracer run
    em2 = make_forward("tracer-emulator", ("shape", "scale"), {"sigma": 0.06, "tau": 0.7},
                       {"shape": (2.0, 4.0), "scale": (1.5, 3.0)}, **opts)
    assert tracer_info(em2)["tracer_evaluations_this_call"] == 0
    np.testing.assert_allclose(np.asarray(em2(np.tile(x, (16, 1))))[0], y_em)
    # independent runs (fresh arrays and rays): only they are traced; their regional spread enters the likelihood
    em3 = make_forward("tracer-emulator", ("shape", "scale"), {"sigma": 0.06, "tau": 0.7},
                       {"shape": (2.0, 4.0), "scale": (1.5, 3.0)}, **(opts | {"independent": 4}))
    info3 = tracer_info(em3)
    assert info3["tracer_evaluations_this_call"] == 4 and info3["independent_runs"] == 4
    t = em3.run_to_run
    assert t.sd.shape == (5,) and t.slope.shape == (2,) and t.bias.shape == (3, 5) and em3.fingerprint() != em2.fingerprint()
    # it predicts an independent run: the GP of the CRN tracer less the fitted bias
    np.testing.assert_allclose(np.asarray(em3(np.tile(x, (16, 1))))[0], y_em - np.asarray(t.mean(em3.unit_coordinates(jnp.asarray(x))))[0])
    r, var = jnp.full((1, 5), 3.0), jnp.full((1, 5), 0.09)
    assert not np.allclose(em3.residual_log_density(r, var, jnp.asarray(x)), em2.residual_log_density(r, var, jnp.asarray(x)))
