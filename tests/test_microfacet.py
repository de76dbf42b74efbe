"""Analytic single-scatter model: independent implementation, white furnace, reciprocity, pluggable BRDF."""

from typing import ClassVar

import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate, stats

import paintjax as pj
from paintjax.instrument._single_scatter import single_scatter_brdf


def _independent_reflectance_factor(shape, scale, n, R_platelet, gammas, exit_occlusion=True):
    """Straight NumPy/SciPy re-implementation of brief §3 for mirror platelets."""
    law = stats.gamma(shape, scale=scale)
    mass = law.cdf(90.0)

    def p_solid(cos_t):
        t = np.degrees(np.arccos(cos_t))
        return law.pdf(t) / mass * (180 / np.pi) / (2 * np.pi * np.sin(np.radians(t)))

    def area(theta):
        w = np.array([np.sin(theta), 0, np.cos(theta)])
        f = lambda phi, t: law.pdf(np.degrees(t)) / mass * (180 / np.pi) / (2 * np.pi) * abs(  # noqa: E731
            np.cos(t) * w[2] + np.sin(t) * np.cos(phi) * w[0]
        )
        return integrate.dblquad(f, 0, np.pi / 2, 0, 2 * np.pi, epsabs=1e-11)[0]

    def T(theta_air):
        c = np.cos(theta_air)
        ct = np.sqrt(1 - (np.sin(theta_air) / n) ** 2)
        rs = (c - n * ct) / (c + n * ct)
        rp = (n * c - ct) / (n * c + ct)
        return 1 - 0.5 * (rs**2 + rp**2)

    ti = np.radians(45.0)
    ti_in = np.arcsin(np.sin(ti) / n)
    out = []
    for g in gammas:
        to = np.radians(45.0 - g)
        to_in = np.arcsin(np.sin(to) / n)
        wi = np.array([-np.sin(ti_in), 0, np.cos(ti_in)])
        wo = np.array([np.sin(to_in), 0, np.cos(to_in)])
        h = (wi + wo) / np.linalg.norm(wi + wo)
        Ai, Ao = area(-ti_in), area(abs(to_in))
        D = Ai * wo[2] + (Ao * wi[2] if exit_occlusion else 0.0)
        f = R_platelet * p_solid(h[2]) / (4 * D)
        out.append(np.pi * T(ti) * T(abs(to)) * f / n**2)
    return np.array(out)


@pytest.mark.parametrize("exit_occlusion", [True, False])
def test_matches_independent_implementation(exit_occlusion):
    g = pj.ma98_geometry(45.0, pj.STANDARD_ASPECULAR[:4])
    tilt = pj.GammaTilt(2.29, 2.18)
    ours = np.asarray(
        pj.microfacet_reflectance_factor(g, tilt, platelet=pj.MirrorBRDF(reflectance=0.88), exit_occlusion=exit_occlusion)
    )
    ref = _independent_reflectance_factor(2.29, 2.18, 1.5, 0.88, pj.STANDARD_ASPECULAR[:4], exit_occlusion)
    np.testing.assert_allclose(ours, ref, rtol=1e-6)


def _hemisphere_integral(f_of_wo, theta_c, half_width_deg=58.0, n=800):
    """∫ f cosθ_o dω_o over a cap around theta_c (in-plane), where the lobe lives."""
    x, w = np.polynomial.legendre.leggauss(n)
    # Use a local frame around the lobe centre: polar a ∈ [0, half_width], azimuth b.
    a = np.radians(half_width_deg) * 0.5 * (x + 1)
    wa = np.radians(half_width_deg) * 0.5 * w
    b = np.pi * (x + 1)
    wb = np.pi * w
    A, B = np.meshgrid(a, b, indexing="ij")
    centre = np.array([np.sin(theta_c), 0, np.cos(theta_c)])
    e1 = np.array([np.cos(theta_c), 0, -np.sin(theta_c)])
    e2 = np.array([0, 1.0, 0])
    d = np.sin(A)[..., None] * (np.cos(B)[..., None] * e1 + np.sin(B)[..., None] * e2) + np.cos(A)[..., None] * centre
    vals = np.asarray(f_of_wo(jnp.asarray(d)))
    cos_o = np.clip(d[..., 2], 0, None)
    return np.sum(vals * cos_o * np.sin(A) * wa[:, None] * wb[None, :])


def test_white_furnace_without_exit_occlusion():
    # Lossless mirrors, no exit occlusion: everything that meets the layer leaves, ∫ f cos dω = 1.
    tilt = pj.GammaTilt(2.98, 2.10)
    theta_i = np.radians(30.0)
    wi = jnp.array([-np.sin(theta_i), 0.0, np.cos(theta_i)])
    mirror = pj.MirrorBRDF(reflectance=1.0)
    f = lambda wo: single_scatter_brdf(wi, wo, tilt, mirror, exit_occlusion=False)  # noqa: E731
    assert _hemisphere_integral(f, theta_i) == pytest.approx(1.0, abs=1e-3)


def test_reciprocity_with_exit_occlusion():
    tilt = pj.GammaTilt(2.29, 2.18)
    rng = np.random.default_rng(1)
    wi = rng.normal(size=(20, 3)) * [0.3, 0.3, 0] + [0, 0, 1]
    wo = -wi * [1, 1, -1] + rng.normal(size=(20, 3)) * 0.05
    wi, wo = (jnp.asarray(v / np.linalg.norm(v, axis=1, keepdims=True)) for v in (wi, wo))
    m = pj.MirrorBRDF()
    a = np.asarray(single_scatter_brdf(wi, wo, tilt, m))
    b = np.asarray(single_scatter_brdf(wo, wi, tilt, m))
    assert np.all(a > 0)
    np.testing.assert_allclose(a, b, rtol=1e-12)


class _NarrowLobe(pj.AbstractPlateletBRDF):
    """A normalised von Mises–Fisher lobe about the mirror direction (test double for a rough platelet)."""

    kappa: float
    is_delta: ClassVar[bool] = False

    def evaluate(self, wi, wo):
        r = wi * jnp.array([-1.0, -1.0, 1.0])
        vmf = self.kappa / (2 * jnp.pi) * jnp.exp(self.kappa * (jnp.sum(r * wo, -1) - 1.0))
        return jnp.where((wi[..., 2] > 0) & (wo[..., 2] > 0), vmf / jnp.maximum(wo[..., 2], 1e-12), 0.0)

    def sample(self, key, wi):
        raise NotImplementedError

    pdf = sample

    def albedo(self, cos_i):
        return jnp.ones_like(cos_i)

    @property
    def medium_index(self):
        return None  # a lossless test lobe, not tied to a binder


def test_pluggable_platelet_brdf_tends_to_the_mirror():
    g = pj.ma98_geometry(45.0, [15.0, 25.0, 45.0])
    tilt = pj.GammaTilt(2.98, 2.10)
    width = np.radians(0.7)
    lobe = _NarrowLobe(kappa=1.0 / width**2)
    rough = np.asarray(pj.microfacet_reflectance_factor(g, tilt, platelet=lobe))
    mirror = np.asarray(pj.microfacet_reflectance_factor(g, tilt, platelet=pj.MirrorBRDF(reflectance=1.0)))
    np.testing.assert_allclose(rough, mirror, rtol=0.03)


def test_finite_aperture_is_an_average_near_the_centre_value():
    tilt = pj.GammaTilt(2.29, 2.18)
    point = np.asarray(pj.microfacet_reflectance_factor(pj.ma98_geometry(45.0), tilt))
    wide = np.asarray(pj.microfacet_reflectance_factor(pj.ma98_geometry(45.0, detector_aperture_deg=1.0), tilt))
    np.testing.assert_allclose(wide[:3], point[:3], rtol=0.05)
    assert not np.allclose(wide, point, rtol=1e-6)


def test_bad_inputs():
    with pytest.raises(ValueError, match="reflectance"):
        pj.MirrorBRDF(reflectance=1.2)
    with pytest.raises(ValueError, match="coat refractive index"):
        pj.microfacet_reflectance_factor(pj.ma98_geometry(), pj.GammaTilt(2, 2), n=0.9)


def test_platelet_brdf_must_be_built_for_the_coat_index():
    """Binder and clearcoat share one index: a platelet BRDF made in n_b = 1.5 does not fit a 1.6 coat."""
    geo, tilt = pj.ma98_geometry(), pj.GammaTilt(2.29, 2.18)
    with pytest.raises(ValueError, match=r"built for a binder of index 1.5, but the coat index n is 1.6"):
        pj.microfacet_reflectance_factor(geo, tilt, n=1.6, platelet=pj.MirrorBRDF(n_binder=1.5))
    with pytest.raises(ValueError, match="binder of index 1.5"):
        pj.microfacet_reflectance_factor(geo, tilt, n=1.6, platelet=pj.BeckmannBRDF(0.051, 0.64))
    matched = np.asarray(pj.microfacet_reflectance_factor(geo, tilt, n=1.6, platelet=pj.MirrorBRDF(n_binder=1.6)))
    default = np.asarray(pj.microfacet_reflectance_factor(geo, tilt, n=1.6))  # the default mirror takes the coat's index
    np.testing.assert_array_equal(matched, default)
    assert pj.LambertianBRDF(0.5).medium_index is None  # a reference BRDF is not checked


def test_side_walls_projected_area():
    """Black side walls of w × w × t boxes: (4/π) E|m × ω| per unit aspect, against independent quadrature."""

    tilt = pj.GammaTilt(2.29, 2.18)
    law = stats.gamma(2.29, scale=2.18)
    norm = law.cdf(90.0)
    for theta in (0.0, 28.0, 60.0):
        th = np.deg2rad(theta)

        def mean_sine(t_deg):  # azimuthal mean of |m × ω| for a tilt t
            t = np.deg2rad(t_deg)
            return integrate.quad(lambda p: np.sqrt(max(0.0, 1 - (np.cos(t) * np.cos(th) + np.sin(t) * np.sin(th) * np.cos(p)) ** 2)),
                                  0, np.pi)[0] / np.pi

        ref = (4 / np.pi) * integrate.quad(lambda t: law.pdf(t) * mean_sine(t), 0, 90, limit=200)[0] / norm
        assert float(tilt.side_wall_area(np.cos(th))) == pytest.approx(ref, rel=2e-4), theta


def test_side_walls_darken_and_validate():
    geo = pj.ma98_geometry(45.0)
    tilt = pj.GammaTilt(2.29, 2.18)
    thin = np.asarray(pj.microfacet_reflectance_factor(geo, tilt))
    boxes = np.asarray(pj.microfacet_reflectance_factor(geo, tilt, side_walls=0.06))
    assert np.all(boxes < thin) and np.all(boxes > 0.9 * thin)
    np.testing.assert_array_equal(np.asarray(pj.microfacet_reflectance_factor(geo, tilt, side_walls=0.0)), thin)
    with pytest.raises(ValueError, match="side_walls"):
        pj.microfacet_reflectance_factor(geo, tilt, side_walls=-0.1)


def test_tilt_density_is_finite_at_the_pole_in_float32():
    """The half vector along the normal (γ = 0) must not give 0/0 in the default float32."""
    import jax

    tilt = pj.GammaTilt(2.29, 2.18)
    p = tilt.density_per_solid_angle(jnp.float32(1.0))  # float32 arithmetic, also with x64 enabled
    assert np.isfinite(np.asarray(p))
    g = jax.grad(lambda c: tilt.projected_area(c))(0.7)  # safe branches: a finite gradient
    assert np.isfinite(float(g))
    with pytest.raises(ValueError, match="has no mass below 90"):
        pj.GammaTilt(200.0, 50.0)
