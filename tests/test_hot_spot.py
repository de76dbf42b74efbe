"""The hot spot (paintjax.instrument._hot_spot): overlap fraction, depth integral, limits, and its use in the
analytic single-scatter model. The tracer comparison (wide Poisson platelets) is in test_tracer_single_scatter.py."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate

from paintjax import GammaTilt, ma98_geometry
from paintjax.brdf._analytic import BeckmannBRDF
from paintjax.instrument._geometry import refract_into_coat
from paintjax.instrument._hot_spot import HotSpot, boolean_escape_monte_carlo, square_overlap_fraction
from paintjax.instrument._single_scatter import microfacet_reflectance_factor


def _unit(v):
    v = np.asarray(v, dtype=float)
    return jnp.asarray(v / np.linalg.norm(v, axis=-1, keepdims=True))


def test_square_overlap_fraction_matches_monte_carlo():
    rng = np.random.default_rng(0)
    psi = rng.uniform(0.0, 2.0 * np.pi, 200_000)
    for x in (0.0, 0.2, 0.7, 1.0, 1.1, 1.3, 1.5):
        sample = np.clip(1 - x * np.abs(np.cos(psi)), 0, None) * np.clip(1 - x * np.abs(np.sin(psi)), 0, None)
        se = sample.std() / np.sqrt(sample.size)
        assert abs(float(square_overlap_fraction(x)) - sample.mean()) < 4 * se + 1e-12, x


def test_joint_escape_matches_direct_quadrature():
    """One width, horizontal platelets: G against nested adaptive quadrature of the defining integral."""
    w, ell = 16.0, 5.0
    hot = HotSpot.for_layer((w * 0.99999, w, w * 1.00001), thickness=0.02, pvc=0.02 / ell)
    wi = _unit([0.47, 0.0, 0.88])
    # near the retro direction the paths part by 1e-4 and 1e-3 µm per unit depth, far below the
    # 0.01 µm table cells: the interpolated overlap integral must still have slope ρ(0) = 1 there
    near_retro = [np.asarray(wi) / float(wi[2]) + np.array([sep / ell, 0.0, 0.0]) for sep in (1e-4, 1e-3)]
    for wo in [[-0.33, 0.0, 0.94], [0.0, 0.0, 1.0], [0.3, 0.2, 0.93], [0.6, 0.0, 0.8], *near_retro]:
        wo = _unit(wo)
        d = np.asarray(wi[:2] / wi[2] - wo[:2] / wo[2])
        length = ell * np.linalg.norm(d)

        def inner(u):
            return integrate.quad(lambda v: float(square_overlap_fraction(v * length / w)), 0.0, u, limit=200)[0]

        ref = integrate.quad(lambda u: np.exp(-2.0 * u + inner(u)), 0.0, 60.0, limit=200)[0]
        got = float(hot.joint_escape(wi, wo, 1.0, 1.0))
        assert abs(got - ref) < 2e-4 * ref, (np.asarray(wo), got, ref)


@pytest.mark.parametrize("width", [2.0, 16.0])
def test_joint_escape_matches_boolean_monte_carlo(width):
    """The closed form against an independent Monte Carlo of the Boolean layer it describes (fresh
    Poisson squares around every pair of paths), thin horizontal platelets, w/ℓ = 0.4 and 3.2, at
    45° illumination from 30° beyond specular to the illuminator side."""
    ell, gamma = 5.0, (-30.0, 25.0, 110.0)
    geo = ma98_geometry(45.0, gamma)
    wi = np.asarray(refract_into_coat(geo.illumination_air(), 1.5))
    wo = np.asarray(refract_into_coat(geo.detectors_air(), 1.5))
    G = np.asarray(HotSpot.for_layer((width * 0.99999, width, width * 1.00001), thickness=0.02, pvc=0.02 / ell).joint_escape(wi, wo, 1.0, 1.0))
    for k, g in enumerate(gamma):
        mc, se = boolean_escape_monte_carlo(width, 0.0, ell, wi, wo[k], samples=20_000, seed=k)
        print(f"w {width} γ {g}: closed form {G[k]:.4f}, Monte Carlo {mc:.4f} ± {se:.4f}")
        assert abs(mc - G[k]) < 4.0 * se, g
        assert G[k] - 0.5 > 10.0 * se  # the check has teeth: independent paths give 1/2


def test_boolean_monte_carlo_retro_direction_with_side_walls():
    """At the retro direction the exit retraces the entry, so G is the top faces' share of first hits,
    1 / (1 + (t/w)(4/π) tan θ) for Poisson boxes with black side walls: a check of the reference itself."""
    wi = np.asarray(refract_into_coat(ma98_geometry(45.0).illumination_air(), 1.5))
    tan = np.sqrt(1.0 - wi[2] ** 2) / wi[2]
    for w, t in ((4.0, 0.4), (2.0, 0.2)):
        mc, se = boolean_escape_monte_carlo(w, t, 5.0, wi, wi, samples=20_000, seed=3)
        exact = 1.0 / (1.0 + (t / w) * (4.0 / np.pi) * tan)
        print(f"w {w}, t {t}: Monte Carlo {mc:.4f} ± {se:.4f}, exact {exact:.4f}")
        assert abs(mc - exact) < 4.0 * se
        assert 1.0 - exact > 10.0 * se


def test_boolean_monte_carlo_bad_input():
    wi = np.array([0.0, 0.0, 1.0])
    with pytest.raises(ValueError, match="thickness"):
        boolean_escape_monte_carlo(2.0, 2.0, 5.0, wi, wi)
    with pytest.raises(ValueError, match="mean_free_depth"):
        boolean_escape_monte_carlo(2.0, 0.0, -1.0, wi, wi)
    with pytest.raises(ValueError, match="wi and wo"):
        boolean_escape_monte_carlo(2.0, 0.0, 5.0, wi, -wi)
    with pytest.raises(ValueError, match="samples"):
        boolean_escape_monte_carlo(2.0, 0.0, 5.0, wi, wi, samples=0)


def test_size_law_weights_each_platelet_by_its_area():
    """ρ(s) of a size law = E[w² ρ_w(s)] / E[w²], against Monte Carlo widths drawn from the law."""
    from paintjax.microstructure._sizes import LogNormalSizes

    sizes = LogNormalSizes.from_quantiles(8.0, 16.0, 30.0)
    hot = HotSpot.for_layer(sizes, thickness=1.0, pvc=0.2)
    s_grid, integral = np.asarray(hot.separation), np.asarray(hot.overlap_integral)
    rho_model = np.gradient(integral, s_grid)
    w = sizes.sample_np(np.random.default_rng(4), 400_000)
    for s in (2.0, 6.0, 12.0, 20.0, 30.0):
        ref = np.mean(w**2 * square_overlap_fraction(s / w)) / np.mean(w**2)
        number_weighted = np.mean(square_overlap_fraction(s / w))
        got = float(np.interp(s, s_grid, rho_model))
        assert abs(got - ref) < 3e-3, (s, got, ref)
        if s >= 6.0:
            assert abs(number_weighted - ref) > 5 * 3e-3  # the check tells the two weightings apart


def test_limits():
    wi, wo = _unit([0.47, 0.0, 0.88]), _unit([-0.2, 0.1, 0.97])
    ai, ao = 1.1, 0.9
    tiny = HotSpot.for_layer((0.001, 0.0011, 0.0012), thickness=1.0, pvc=0.2)
    assert float(tiny.joint_escape(wi, wo, ai, ao)) == pytest.approx(1.0 / (ai + ao), rel=1e-3)  # independent paths
    hot = HotSpot.for_layer(None, thickness=1.0, pvc=0.2)
    assert float(hot.joint_escape(wi, wi, ai, ao)) == pytest.approx(1.0 / (ai + ao - np.sqrt(ai * ao)), rel=1e-10)  # retro
    # the correlation weakens as the exit moves away from the retro direction
    far = [float(hot.joint_escape(wi, _unit([-s, 0.0, 1.0]), 1.0, 1.0)) for s in (-0.5, 0.0, 0.5, 1.0)]
    assert np.all(np.diff(far) < 0) and 0.5 < far[-1] < far[0] < 1.0


def test_single_scatter_without_correlation_is_the_independent_model():
    geo, tilt = ma98_geometry(45.0), GammaTilt(2.29, 2.18)
    brdf = BeckmannBRDF(0.1, 0.6, n_medium=1.5)
    tiny = HotSpot.for_layer((0.001, 0.0011, 0.0012), thickness=1.0, pvc=0.2)
    a = np.asarray(microfacet_reflectance_factor(geo, tilt, platelet=brdf))
    b = np.asarray(microfacet_reflectance_factor(geo, tilt, platelet=brdf, hot_spot=tiny))
    np.testing.assert_allclose(b, a, rtol=1e-3)
    c = np.asarray(microfacet_reflectance_factor(geo, tilt, platelet=brdf, hot_spot=HotSpot.for_layer((8.0, 16.0, 30.0))))
    assert np.all(c > 1.5 * a)  # the sample's platelets: 1.6-1.9x brighter single scattering


def test_hot_spot_needs_exit_occlusion():
    with pytest.raises(ValueError, match="exit_occlusion"):
        microfacet_reflectance_factor(ma98_geometry(45.0), GammaTilt(2.29, 2.18), exit_occlusion=False, hot_spot=HotSpot.for_layer(None))


@pytest.mark.parametrize("kwargs, word", [({"pvc": 0.0}, "pvc"), ({"pvc": 1.2}, "pvc"), ({"thickness": -1.0}, "thickness")])
def test_bad_input(kwargs, word):
    with pytest.raises(ValueError, match=word):
        HotSpot.for_layer(None, **kwargs)


def test_analytic_forward_takes_the_hot_spot():
    """The inverse layer's analytic forward map with a hot spot is the `paintjax microfacet` model (mirrors)."""
    import paintjax as pj
    from paintjax.cli._microfacet import compute

    s = pj.load_sample("silver1")
    theta = np.array([[s.tilt_shape.value, s.tilt_scale.value, 0.0]])
    hot = pj.AnalyticForward(rough=False, hot_spot=pj.HotSpot.for_sample(s))
    plain = pj.AnalyticForward(rough=False)
    np.testing.assert_allclose(np.asarray(hot(theta))[0], compute("silver1")["L_star"], rtol=1e-9)
    np.testing.assert_allclose(np.asarray(plain(theta))[0], compute("silver1", hot_spot=False)["L_star"], rtol=1e-9)
    assert hot.fingerprint() != plain.fingerprint()
    with pytest.raises(ValueError, match="hot_spot"):
        pj.AnalyticForward(hot_spot="yes")


def test_registered_analytic_hot_spot_forward():
    from paintjax.inverse._registry import make_forward

    theta = np.array([[2.29, 2.18, 0.051, 0.64, 0.0]])
    hot, plain = make_forward("analytic-hot-spot"), make_forward("analytic")
    assert hot.hot_spot is not None and plain.hot_spot is None
    assert np.all(np.asarray(hot(theta))[0, :3] > np.asarray(plain(theta))[0, :3] + 5.0)  # brighter by the hot spot
