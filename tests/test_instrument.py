"""Instrument geometry against the brief's §3 numbers."""

import numpy as np
import pytest

import paintjax as pj


def test_detector_polar_angles_and_sides():
    g = pj.ma98_geometry(45.0, pj.ASPECULAR_45)
    # γ = −15 → 60° specular side; 15 → 30°; 25 → 20°; 45 → normal; 75 → 30° illuminator; 110 → 65° illuminator.
    np.testing.assert_allclose(np.asarray(g.detector_polar_deg), [60, 30, 20, 0, 30, 65], atol=1e-12)
    d = np.asarray(g.detectors_air())
    assert d[0, 0] > 0 and d[1, 0] > 0 and d[4, 0] < 0 and d[5, 0] < 0
    src = np.asarray(g.illumination_air())
    np.testing.assert_allclose(src, [-np.sin(np.pi / 4), 0, np.cos(np.pi / 4)], atol=1e-15)
    # The specular direction is at γ = 0: the mirror image of the source.
    spec = np.asarray(pj.ma98_geometry(45.0, [0.0]).detectors_air())[0]
    np.testing.assert_allclose(spec, [-src[0], 0, src[2]], atol=1e-15)


def test_probed_tilts_match_brief():
    g = pj.ma98_geometry(45.0, pj.STANDARD_ASPECULAR)
    np.testing.assert_allclose(np.asarray(g.probed_tilt_deg(1.5)), [4.33, 7.47, 14.06, 23.80, 32.65], atol=0.01)


def test_refracted_angles_follow_snell():
    g = pj.ma98_geometry(45.0, pj.STANDARD_ASPECULAR)
    wi = np.asarray(g.illumination_in_coat(1.5))
    assert np.degrees(np.arccos(wi[2])) == pytest.approx(np.degrees(np.arcsin(np.sin(np.pi / 4) / 1.5)), abs=0.01)
    assert np.degrees(np.arccos(wi[2])) == pytest.approx(28.13, abs=0.01)
    wo = np.asarray(g.detectors_in_coat(1.5))
    air = np.radians(np.asarray(g.detector_polar_deg))
    np.testing.assert_allclose(np.arccos(wo[:, 2]), np.arcsin(np.sin(air) / 1.5), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(wo, axis=1), 1.0, atol=1e-14)


def test_fifteen_degree_illumination_set():
    g = pj.ma98_geometry(15.0, pj.ASPECULAR_15)
    np.testing.assert_allclose(np.asarray(g.detector_polar_deg), [60, 30, 0, 30, 65], atol=1e-12)
    tilts = np.asarray(g.probed_tilt_deg(1.5))
    # Detector along the normal: the mirror bisects the refracted illumination and the normal.
    assert tilts[2] == pytest.approx(0.5 * np.degrees(np.arcsin(np.sin(np.radians(15)) / 1.5)), abs=1e-9)


def test_custom_geometry_matches_ma98_in_plane_and_flags_out_of_plane():
    g = pj.ma98_geometry(45.0, [15.0, 75.0])
    c = pj.custom_geometry(45.0, [30.0, 30.0, 40.0], [0.0, 180.0, 90.0])
    np.testing.assert_allclose(np.asarray(c.aspecular_deg)[:2], [15.0, 75.0])
    assert np.isnan(np.asarray(c.aspecular_deg)[2])
    np.testing.assert_allclose(np.asarray(c.detectors_air())[:2], np.asarray(g.detectors_air()), atol=1e-15)
    # normal illumination: every detector shares a plane with the source, γ = −θ at any azimuth
    normal = pj.custom_geometry(0.0, [0.0, 20.0, 20.0, 60.0], [0.0, 0.0, 90.0, 37.0])
    np.testing.assert_allclose(np.asarray(normal.aspecular_deg), [0.0, -20.0, -20.0, -60.0])


def test_mirror_tilt_of_specular_is_zero():
    g = pj.ma98_geometry(45.0, [0.0])
    assert float(g.probed_tilt_deg(1.5)[0]) == pytest.approx(0.0, abs=1e-6)


@pytest.mark.parametrize("gamma", [-45.0, 135.0, 200.0, float("nan")])
def test_aspecular_out_of_range(gamma):
    with pytest.raises(ValueError, match="aspecular_deg"):
        pj.ma98_geometry(45.0, [15.0, gamma])


def test_bad_aperture_and_illumination():
    with pytest.raises(ValueError, match="detector_aperture_deg"):
        pj.ma98_geometry(45.0, detector_aperture_deg=-1.0)
    with pytest.raises(ValueError, match="illumination_deg"):
        pj.ma98_geometry(0.0)
    with pytest.raises(ValueError, match="detector_polar_deg"):
        pj.custom_geometry(45.0, [95.0])
    with pytest.raises(ValueError, match="illumination_polar_deg"):  # the side is the azimuth's: γ would be wrong
        pj.custom_geometry(-45.0, [45.0])
    with pytest.raises(ValueError, match=r"detector_polar_deg must lie in \[0, "):  # likewise for detectors
        pj.custom_geometry(45.0, [-30.0, 30.0], [0.0, 180.0])
    for bad in (float("nan"), 1e300):
        with pytest.raises(ValueError, match="illumination_azimuth_deg"):
            pj.custom_geometry(45.0, [30.0], illumination_azimuth_deg=bad)
        with pytest.raises(ValueError, match="detector_azimuth_deg"):
            pj.custom_geometry(45.0, [30.0], [bad])


def test_aperture_cones_stay_above_the_horizon():
    """A cone around a steep direction must not reach below the horizon (where the NEE would fold
    directions back up and the histogram can never score): polar + half-angle < 90°."""
    pj.ma98_geometry(45.0, [-40.0], detector_aperture_deg=4.9)  # detector at 85°: 4.9° fits
    with pytest.raises(ValueError, match="detector_aperture_deg must be below 5°"):
        pj.ma98_geometry(45.0, [-40.0], detector_aperture_deg=20.0)
    with pytest.raises(ValueError, match="illumination_aperture_deg"):
        pj.custom_geometry(85.0, [30.0], illumination_aperture_deg=20.0)
    with pytest.raises(ValueError, match="detector_aperture_deg"):
        pj.custom_geometry(30.0, [80.0, 10.0], detector_aperture_deg=10.0)
    g = pj.ma98_geometry(45.0, detector_aperture_deg=20.0)  # MA98's steepest detector is at 65°
    assert g.detector_aperture_deg == 20.0


def test_hemisphere_quadrature_integrates_isotropic_radiance():
    """Isotropic radiance under the coat leaves as R ∝ T_o: Σ w_j T_o,j / n² = 1 − r_i (the coat's internal
    diffuse reflectance, an independent closed form)."""
    import jax.numpy as jnp

    from paintjax import coat_internal_diffuse_reflectance, fresnel_dielectric, hemisphere_quadrature

    geo, w = hemisphere_quadrature(1.5)
    mu = np.cos(np.deg2rad(np.asarray(geo.detector_polar_deg)))
    T = 1.0 - np.asarray(fresnel_dielectric(jnp.asarray(mu), 1.0, 1.5)[2])
    assert float(np.sum(w * T)) / 1.5**2 == pytest.approx(1.0 - float(coat_internal_diffuse_reflectance(1.5)), rel=1e-6)
    assert np.all(np.asarray(geo.illumination_polar_deg) == 0.0) and np.max(np.asarray(geo.detector_polar_deg)) <= 85.0
