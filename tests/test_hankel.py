"""H0⁽¹⁾, H1⁽¹⁾ in JAX against scipy (AMOS) on a dense grid, plus derivatives and transforms."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.special as sp

from paintjax.wave._hankel import X_SWITCH, hankel0, hankel01, hankel01_far, hankel1

X = np.geomspace(1e-6, 1e4, 100_001)


@pytest.fixture(scope="module")
def values():
    h0, h1 = jax.jit(hankel01)(X)
    return np.asarray(h0), np.asarray(h1)


@pytest.mark.parametrize("order", [0, 1])
def test_relative_accuracy_dense_grid(values, order):
    ref = sp.hankel1(order, X)
    err = np.abs(values[order] - ref) / np.abs(ref)
    assert err.max() <= 1e-12, f"max relative error {err.max():.2e} at x = {X[np.argmax(err)]:.6g}"


@pytest.mark.parametrize("order", [0, 1])
def test_components_absolute_near_zeros(values, order):
    """J and Y separately: relative where they are large, absolute (scale |H|) near their zeros."""
    ref = sp.hankel1(order, X)
    for got, want in ((values[order].real, ref.real), (values[order].imag, ref.imag)):
        err = np.abs(got - want) / np.maximum(np.abs(want), np.abs(ref))
        assert err.max() <= 1e-12
    zeros = sp.jn_zeros(order, 50)
    h = np.asarray(hankel01(zeros)[order])
    assert np.max(np.abs(h.real)) <= 1e-13  # J_n vanishes there to absolute precision


def test_branches_agree_at_switch():
    x = np.linspace(X_SWITCH - 0.5, X_SWITCH + 0.5, 101)
    far = np.asarray(hankel01_far(np.maximum(x, X_SWITCH)))
    full = np.asarray(hankel01(x))
    m = x >= X_SWITCH
    assert np.max(np.abs(far[:, m] - full[:, m])) <= 1e-14


def test_custom_jvp_matches_recurrences():
    x = np.array([1e-3, 0.3, 2.0, 6.9, 7.1, 25.0, 900.0])
    (h0, h1), (d0, d1) = jax.jvp(hankel01, (jnp.asarray(x),), (jnp.ones_like(x),))
    np.testing.assert_allclose(np.asarray(d0), -sp.hankel1(1, x), rtol=1e-12)
    np.testing.assert_allclose(np.asarray(d1), sp.h1vp(1, x), rtol=1e-12)
    g = jax.grad(lambda t: jnp.real(hankel01(t)[0]) + jnp.imag(hankel01(t)[1]))(2.5)
    assert abs(float(g) - (-sp.j1(2.5) + sp.yvp(1, 2.5))) <= 1e-12


def test_vmap_and_shapes():
    x = np.geomspace(0.1, 100.0, 12).reshape(3, 4)
    h0 = jax.vmap(hankel0)(x)
    assert h0.shape == (3, 4) and jnp.iscomplexobj(h0)
    np.testing.assert_allclose(np.asarray(hankel1(x)), sp.hankel1(1, x), rtol=1e-12)


@pytest.mark.parametrize("bad", [0.0, -1.0, np.nan])
def test_rejects_non_positive(bad):
    with pytest.raises(ValueError, match="x must be"):
        hankel0(np.array([1.0, bad]))
