"""Inverse-layer parameters: bijections, Jacobians, priors, validation."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import quad

from paintjax.inverse._parameters import PARAMETERS, Parameter, ParameterSpec, get_parameter, make_spec

ALL = tuple(PARAMETERS)


def test_round_trip_all_parameters():
    spec = make_spec(ALL)
    rng = np.random.default_rng(0)
    z = rng.uniform(1e-6, 1 - 1e-6, size=(200, len(spec)))
    x = np.asarray(spec.from_unit(z))
    assert np.all(x >= spec.lower) and np.all(x <= spec.upper)
    u = np.asarray(spec.to_unconstrained(x))
    np.testing.assert_allclose(np.asarray(spec.from_unconstrained(u)), x, rtol=1e-10, atol=1e-12)
    # and the other way round, over a wide range of u
    u2 = rng.normal(0, 4, size=(200, len(spec)))
    np.testing.assert_allclose(np.asarray(spec.to_unconstrained(spec.from_unconstrained(u2))), u2, rtol=1e-7, atol=1e-7)


def test_map_is_monotone_and_bounded_at_extremes():
    spec = make_spec(("shape", "scale", "sigma", "tau", "discrepancy"))
    u = jnp.linspace(-30, 30, 601)[:, None] * jnp.ones(len(spec))
    x = np.asarray(spec.from_unconstrained(u))
    assert np.all(np.diff(x, axis=0) >= 0)
    assert np.all(np.isfinite(x)) and np.all(x >= spec.lower) and np.all(x <= spec.upper)


def test_log_det_jacobian_matches_autodiff():
    spec = make_spec(("shape", "scale", "sigma", "tau", "diffuse", "discrepancy"))
    u = jnp.asarray(np.random.default_rng(1).normal(0, 1.5, len(spec)))
    J = jax.jacfwd(spec.from_unconstrained)(u)
    np.testing.assert_allclose(float(spec.log_det_jacobian(u)), float(jnp.log(jnp.abs(jnp.linalg.det(J)))), rtol=1e-10)


@pytest.mark.parametrize("name", ALL)
def test_prior_is_normalised_in_both_coordinates(name):
    spec = make_spec((name,))
    p = spec.parameters[0]
    in_x = quad(lambda v: float(np.exp(spec.log_prior(np.array([v])))), p.lower, p.upper, limit=200)[0]
    in_u = quad(lambda v: float(np.exp(spec.log_prior_unconstrained(np.array([v])))), -60, 60, limit=400)[0]
    assert in_x == pytest.approx(1.0, rel=1e-6)
    assert in_u == pytest.approx(1.0, rel=1e-5)
    assert float(spec.log_prior(np.array([p.upper + 1.0]))) == -np.inf


def test_prior_samples_follow_prior():
    spec = make_spec(("shape", "diffuse", "discrepancy"))
    x = np.asarray(spec.sample_prior(jax.random.key(0), 20000))
    assert np.all(x >= spec.lower) and np.all(x <= spec.upper)
    # log-uniform: log x uniform → median at the geometric mean of the bounds
    sh = get_parameter("shape")
    assert np.median(x[:, 0]) == pytest.approx(np.sqrt(sh.lower * sh.upper), rel=0.05)
    assert np.median(x[:, 1]) == pytest.approx(0.5 * (0.0 + get_parameter("diffuse").upper), rel=0.05)
    # truncated half-Cauchy(5) on [0, 50]: median = 5 tan(atan(10)/2)
    assert np.median(x[:, 2]) == pytest.approx(5 * np.tan(np.arctan(10) / 2), rel=0.05)


def test_priors_are_not_centred_on_measured_values():
    # Weak priors: the measured Silver #1 values sit well inside the boxes but are not their centres.
    spec = make_spec(("shape", "scale", "sigma", "tau"))
    centre = spec.center()
    measured = np.array([2.29, 2.18, 0.051, 0.64])
    assert np.all(np.abs(np.log(centre / measured)) > 0.1)
    assert np.all(spec.to_unit(measured) > 0.1) and np.all(spec.to_unit(measured) < 0.9)


def test_bounds_override_and_dict_helpers():
    spec = make_spec(("shape", "scale"), {"scale": (0.5, 5.0)})
    assert spec.parameters[1].lower == 0.5 and spec.parameters[1].upper == 5.0
    d = spec.as_dict([2.0, 1.0])
    assert d == {"shape": 2.0, "scale": 1.0}
    np.testing.assert_array_equal(spec.from_dict(d), [2.0, 1.0])


def test_bad_inputs_name_the_parameter():
    with pytest.raises(ValueError, match="unknown parameter 'tilt'"):
        make_spec(("tilt",))
    with pytest.raises(ValueError, match="distinct"):
        ParameterSpec(["shape", "shape"])
    with pytest.raises(ValueError, match="lower < upper"):
        Parameter("a", 2.0, 1.0)
    with pytest.raises(ValueError, match="lower > 0"):
        Parameter("a", 0.0, 1.0, scale="log", default=0.5)
    with pytest.raises(ValueError, match="prior must be one of"):
        Parameter("a", 0.0, 1.0, prior="normal")
    with pytest.raises(ValueError, match="not free"):
        make_spec(("shape",), {"sigma": (0.01, 0.1)})
    spec = make_spec(("shape", "sigma"))
    with pytest.raises(ValueError, match=r"sigma must lie in \[0.02, 0.2\] µm"):
        spec.check([2.0, 5.0])
    with pytest.raises(ValueError, match="2 entries"):
        spec.check([2.0])
    with pytest.raises(ValueError, match="missing values"):
        spec.from_dict({"shape": 1.0})
